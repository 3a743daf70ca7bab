"""Exceptions of the study library; the CLI (studyctl/cli/common.py) turns them into clean CLI errors."""


class StudyError(Exception):
    """A user-facing problem with a study, its database or its input files."""


class ProtocolError(StudyError):
    """A protocol file has problems; `problems` lists them, one 'FILE:LINE: field: message' each."""

    def __init__(self, problems: list[str]):
        self.problems = list(problems)
        super().__init__("\n".join(self.problems))


class StoreError(StudyError):
    """The study database is missing, of another version, or was asked something impossible."""


class InputError(StudyError):
    """A CSV or command-line value is invalid (the whole input is rejected)."""


class Interrupted(StudyError):
    """The user interrupted a command (Ctrl-C); the message says what was kept and how to go on."""
