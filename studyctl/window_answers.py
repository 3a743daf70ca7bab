"""Asking in the participant view (`--answers window`): keys for yes/no, ratings and choices;
free text falls back to the terminal (the window has no text entry)."""

from __future__ import annotations

from studyctl.asking import TerminalAnswers
from studyctl.errors import StoreError


class WindowAnswers:
    """Y / N for yes-no; the number keys for a rating (1..points, points up to 9); a blind
    label's letter for a choice. Keys pressed before a question appears answer nothing."""

    source = "window"

    def __init__(self, view):
        self.view = view
        self.terminal = TerminalAnswers(view=view)

    def begin(self, label: str) -> None:
        self.view.set_text(top=label, center="Please answer the questions", bottom="", question="", corner="")
        self.view.idle()

    def _keys(self):
        view = self.view
        view.idle()
        if view.closed:
            raise StoreError("the window was closed during the questionnaire; continue with --resume")
        return view.take_keys()

    def __call__(self, question, model: str, context: dict):
        view = self.view
        if question.kind == "text":  # no text entry in the window
            view.set_text(question=question.text, center="", bottom="Please type your answer in the terminal")
            try:
                return self.terminal(question, model, context)
            finally:
                view.set_text(question="", bottom="")
        labels = context.get("labels") or {}
        keys = {"yes_no": {"y": 1, "n": 0},
                "likert": {str(k): k for k in range(1, (question.points or 0) + 1)},
                "choice": {label.lower(): c for c, label in labels.items()}}.get(question.kind)
        if keys is None:
            raise StoreError(f"question {question.id}: a {question.kind} question cannot be answered in the window yet")
        hint = {"yes_no": "Y = yes     N = no",
                "likert": f"1 = {question.anchors[0]}   ...   {question.points} = {question.anchors[1]}     (press a number)"
                if question.anchors else "",
                "choice": "Press " + " / ".join(sorted(labels.values()))}[question.kind]
        view.take_keys()
        view.set_text(question=question.text, center="", bottom=hint)
        while True:
            for k in self._keys():
                if k in keys:
                    view.set_text(question="", bottom="")
                    return keys[k]
