"""The kinds of participant field a protocol may record (`[fields.NAME] kind = ...`; the fields
themselves are studyctl/fields.py's): both layers read them, so they live here."""

from __future__ import annotations

from enum import StrEnum


class FieldKind(StrEnum):
    """A participant field's kind; a member equals its name as a protocol file writes it."""

    CHOICE = "choice"
    INTEGER = "integer"
    NUMBER = "number"
    TEXT = "text"
