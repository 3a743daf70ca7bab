"""Texts a file or a person gives, checked by one helper (`text_problem`): no control
characters (an ESC sequence would drive the participant's terminal, a NUL cuts a text short, a
right-to-left override shows other words than the file holds; tabs and line breaks aside where
a text may span lines) and a longest length per kind of text (docs/study.md, "Limits on input")."""

from __future__ import annotations

import unicodedata

LINE_BREAKS = "\t\n\r"  # the control characters a text may hold
NAME_MOST = 100  # a study's name, a scale's anchor, a consent form's version, a person's name
TITLE_MOST = 200  # a study's title, a person's contact
TEXT_MOST = 2000  # a question's text, a free-text answer, a reason given for a withdrawal or a correction
VALUE_MOST = 4096  # any other text of a TOML file (a path, a description): PATH_MAX on Linux
QUOTE_LIMIT = 40  # characters of a refused value an error line quotes


# the bidirectional controls (format characters, category Cf): one reorders the text after it, so
# a question or a name could show a participant or a report other words than the file holds
# (the joiners and the soft hyphen, which scripts need, stay allowed)
BIDI_CONTROLS = frozenset("\u061c\u200e\u200f\u202a\u202b\u202c\u202d\u202e\u2066\u2067\u2068\u2069")


def control_character(text: str, one_line: bool = False) -> tuple[int, str] | None:
    """(position, character) of the first control character (C0, DEL, C1, or a bidirectional
    control), tabs and line breaks aside unless `one_line`."""
    for i, c in enumerate(text):
        if (one_line or c not in LINE_BREAKS) and (unicodedata.category(c) == "Cc" or c in BIDI_CONTROLS):
            return i, c
    return None


def control_problem(text: str, one_line: bool = False) -> str | None:
    """Why `text` is refused for a control character, or None."""
    found = control_character(text, one_line)
    if found is None:
        return None
    i, c = found
    allowed = "a one-line text holds no control characters, tabs and line breaks included" if one_line else \
        "text may hold no control characters (tabs and line breaks aside)"
    return f"control character U+{ord(c):04X} at character {i + 1}; {allowed}"


def text_problem(text: str, most: int = VALUE_MOST, one_line: bool = False) -> str | None:
    """Why `text` is refused (a control character, or longer than `most` characters), or None."""
    if len(text) > most:
        return f"{len(text)} characters; allowed: at most {most}"
    return control_problem(text, one_line)


def quoted(value, limit: int = QUOTE_LIMIT) -> str:
    """`value` quoted for an error line: whole when short, else its first `limit` characters
    and its length."""
    text = str(value)
    if len(text) <= limit:
        return repr(text)
    return f"{text[:limit]!r}... ({len(text)} characters)"


IRREGULAR_PLURALS = {"person": "people", "analysis": "analyses"}


def counted(n: float, noun: str, plural: str | None = None) -> str:
    """`n` and the noun, singular for exactly one: "1 person", "2 people", "1 pair", "0 pairs"
    (a count written as a figure reads as singular only at one; `n` may be a float: 1.5 minutes)."""
    word = noun if n == 1 else plural or IRREGULAR_PLURALS.get(noun) or noun + "s"
    return f"{n:g} {word}" if isinstance(n, float) else f"{n} {word}"


def n_text(n: int) -> str:
    """A sample's size as the reports write it: "N = 12"."""
    return f"N = {n}"
