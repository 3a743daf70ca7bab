"""Asking a person: the terminal side (typed answers, keys during a run) and the prompt each
question kind shows. The window side is studyctl/session/window_answers.py.

An answerer is called as ``answerer(question, condition, context)`` and returns the answer's
typed value (analysis/study/questions.py): 0/1, an integer, a real or text; a choice returns the
chosen condition's name (the person sees and types only blind labels). `context` carries
``labels`` (condition -> blind label), ``trial`` (None unless asked after a trial),
``results`` (the condition's stored trials, for the synthetic observer) and ``features``
(every condition's observer features, for a synthetic choice).
"""

from __future__ import annotations

import select
import sys
import termios
from collections.abc import Callable

from analysis.errors import StoreError
from analysis.study.questions import AnswerError, Kind, allowed, parse_answer


def _stdin_tty() -> bool:
    try:
        return sys.stdin.isatty()
    except (AttributeError, ValueError):
        return False


def flush_input() -> None:
    """Discard whatever was typed and not yet read (e.g. keys pressed during training)."""
    if _stdin_tty():
        termios.tcflush(sys.stdin.fileno(), termios.TCIFLUSH)


def terminal_keys() -> list[str]:
    """Lines typed in the terminal since the last call, without blocking ("enter" for an empty
    one): the experimenter's keys during a run when no window has the focus."""
    if not _stdin_tty():
        return []

    out = []
    while select.select([sys.stdin], [], [], 0)[0]:
        line = sys.stdin.readline()
        if not line:
            break
        out.append(line.strip().lower() or "enter")
    return out


def read_line(prompt: str, idle: Callable[[], None] | None) -> str:
    """input(), but a window stays alive while the terminal waits."""
    if idle is None or not _stdin_tty():
        return input(prompt)

    sys.stdout.write(prompt)
    sys.stdout.flush()
    while not select.select([sys.stdin], [], [], 0.05)[0]:
        idle()
    line = sys.stdin.readline()
    if not line:
        raise EOFError
    return line.rstrip("\n")


def prompt_text(q, labels: dict[str, str] | None) -> str:
    """The terminal's prompt for one question: its text and what may be typed."""
    if q.kind == Kind.YES_NO:
        return f"{q.text} [y/n] "
    if q.kind == Kind.LIKERT:
        return f"{q.text}\n  1 = {q.anchors[0]} ... {q.points} = {q.anchors[1]}  [1-{q.points}] "
    if q.kind == Kind.VAS:
        ends = f": 0 = {q.anchors[0]}, 100 = {q.anchors[1]}" if q.anchors else ""
        return f"{q.text}\n  a number from 0 to 100{ends}  [0-100] "
    if q.kind == Kind.CHOICE:
        return f"{q.text} [{'/'.join(sorted(labels.values()))}] "
    return f"{q.text}\n  (free text; Enter when done) "


class TerminalAnswers:
    """Asks each question in the terminal until a value of its kind is given. Input typed
    before a question appears is discarded."""

    source = "terminal"

    def __init__(self, prompt: Callable[[str], str] | None = None, echo: Callable[[str], None] = print, view=None):
        self.prompt = prompt
        self.echo = echo
        self.view = view

    def begin(self, label: str) -> None:
        if self.view is not None:
            self.view.set_text(top=label, center="Please answer the questions in the terminal", bottom="", question="", corner="")
            self.view.idle()
        self.echo(f"\nQuestions about {label}.")

    def __call__(self, question, model: str, context: dict):
        labels = context.get("labels")
        while True:
            flush_input()
            text = prompt_text(question, labels)
            try:
                if self.prompt is not None:
                    reply = self.prompt(text)
                else:
                    reply = read_line(text, self.view.idle if self.view is not None else None)
            except EOFError:
                raise StoreError("the questionnaire got no answer (input closed); continue later with --resume") from None
            try:
                return parse_answer(question, reply, labels)
            except AnswerError as exc:
                self.echo(f"Please type it again: {exc}." if question.kind == Kind.TEXT else f"Please answer {allowed(question, labels)}.")
