"""Exceptions of the simulation library; the CLI turns them into one-line errors."""


class SimError(Exception):
    """Base class: a user-facing problem with input to the simulator."""


class ParameterError(SimError):
    """A model parameter or argument is missing, of the wrong type or out of range."""


class SceneError(SimError):
    """A scene file is unreadable or invalid."""


class MeshError(SimError):
    """A mesh file is unreadable or not a valid surface."""


class DeviceError(SimError):
    """A haptic device cannot be opened or has failed."""


class ViewError(SimError):
    """The participant view cannot open its window."""
