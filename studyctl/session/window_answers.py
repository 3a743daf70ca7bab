"""Asking in the participant view (`--answers window`): keys and the mouse for every kind but
free text, which falls back to the terminal (the window has no text entry).

- yes/no: Y or N;
- likert: a rating scale (sim/view/window.py `show_scale`): with up to 9 points a number key answers at
  once; with any number of points the Left/Right arrows (or a click on a point) choose one and
  Enter (or a second click on the chosen point) confirms; Backspace takes the choice back;
- vas: a line from 0 to 100 (`show_slider`) with no mark until the person sets one with a click
  or a drag on it; the arrows move a mark by 1; Enter confirms a mark (without one it does
  nothing); Backspace takes the mark away;
- choice: one box per blind label; the label's letter answers at once, or a click / the arrows
  and Enter as for a rating. The answer is the chosen condition's name; the window shows only
  the labels.

While a question is shown the mouse never grasps the brain (the view's questionnaire mode), and
keys pressed and clicks made before a question appears answer nothing.
"""

from __future__ import annotations

from analysis.errors import StoreError
from analysis.study.questions import Kind
from studyctl.session.asking import TerminalAnswers


class WindowAnswers:
    """Answers typed with keys (and the mouse) in the participant view."""

    source = "window"

    def __init__(self, view):
        self.view = view
        self.terminal = TerminalAnswers(view=view)

    def begin(self, label: str) -> None:
        self.view.set_questionnaire(True)
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
        view.set_questionnaire(True)
        try:
            if question.kind == Kind.TEXT:  # no text entry in the window
                view.set_text(question=question.text, center="", bottom="Please type your answer in the terminal")
                return self.terminal(question, model, context)
            return self._ask(question, context.get("labels") or {})
        finally:
            view.answers.clear()
            view.set_text(question="", bottom="")
            view.set_questionnaire(False)

    def _ask(self, q, labels: dict[str, str]):
        view = self.view
        values: list = []  # what each box of a scale answers
        letters: dict = {}  # key -> answer at once
        if q.kind == Kind.YES_NO:
            letters = {"y": 1, "n": 0}
            hint = "Y = yes     N = no"
        elif q.kind == Kind.LIKERT:
            values = list(range(1, q.points + 1))
            view.answers.show_scale([str(v) for v in values], q.anchors)
            if q.points <= 9:
                letters = {str(v): v for v in values}
                hint = f"Press 1-{q.points}  (or choose with the Left/Right arrows or a click, then press Enter)"
            else:
                hint = "Choose with the Left/Right arrows or a click, then press Enter"
        elif q.kind == Kind.VAS:
            view.answers.show_slider(q.anchors)
            hint = "Click or drag on the line to set your mark (Left/Right arrows move it), then press Enter"
        elif q.kind == Kind.CHOICE:
            if not labels:
                raise StoreError(f"question {q.id}: a choice needs the conditions' labels")
            shown = sorted(labels.items(), key=lambda cl: cl[1])  # (condition, label), as the person knows them
            values = [c for c, _ in shown]
            view.answers.show_scale([label for _, label in shown])
            letters = {label.lower(): c for c, label in shown}
            hint = f"Press {' / '.join(label for _, label in shown)}  (or click one, then press Enter)"
        else:
            raise StoreError(f"question {q.id}: a {q.kind} question cannot be answered in the window")
        view.set_text(question=q.text, center="", bottom=hint)
        self._keys()  # what was pressed or clicked before the question appeared answers nothing
        w = view.answers.widget
        if w is not None:
            view.answers.select(None)
            view.answers.set_value(None)
            w.confirmed = w.dragging = False
        while True:
            for k in self._keys():
                if k in letters:
                    return letters[k]
                if w is None:
                    continue
                if k in ("left", "right"):
                    view.answers.move(-1 if k == "left" else 1)
                elif k == "backspace":
                    view.answers.select(None)
                    view.answers.set_value(None)
                elif k == "enter":
                    if w.kind == "scale" and w.selected is not None:
                        return values[w.selected]
                    if w.kind == "slider" and w.value is not None:
                        return float(w.value)
            if w is not None and w.kind == "scale" and w.confirmed and w.selected is not None:
                return values[w.selected]
