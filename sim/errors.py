"""Exceptions of the simulation library; the CLI turns them into clean errors (one line each;
a SceneError, one line per problem)."""


class SimError(Exception):
    """Base class: a user-facing problem with input to the simulator."""


class ParameterError(SimError):
    """A model parameter or argument is missing, of the wrong type or out of range."""


class SceneError(SimError):
    """A scene file is unreadable or invalid; `problems` lists every problem found, one
    'FILE:LINE: field: message' each (str(exc) is them joined by newlines)."""

    def __init__(self, problems: str | list[str]):
        if isinstance(problems, str):
            problems = problems.splitlines() or [problems]
        self.problems = list(problems)
        super().__init__("\n".join(self.problems))


class MeshError(SimError):
    """A mesh file is unreadable or not a valid surface."""


class DeviceError(SimError):
    """A haptic device cannot be opened or has failed."""


class ViewError(SimError):
    """The participant view cannot open its window."""


class InputFileError(SimError):
    """An input file that is not a regular file, is too large, or cannot be read (one line)."""
