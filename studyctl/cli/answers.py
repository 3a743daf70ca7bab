"""`studyctl answers`: answers collected outside the simulator (import) and corrections."""

from __future__ import annotations

from pathlib import Path

import click

from sim.text import counted
from studyctl.cli.common import DB, DRY_RUN, JSON, _done, _Group, _model_name


@click.group(cls=_Group)
def answers():
    """Answers collected outside the simulator."""


@answers.command("import")
@DB
@click.argument("csv_file", type=click.Path(dir_okay=False, path_type=Path))
@DRY_RUN
@JSON
def answers_import(db, csv_file, dry_run, as_json):
    """Import participant,model,item,answer[,trial] rows, each answer as its question's kind allows
    (yes/no; a rating; 0-100; a condition's name; text); any unknown value rejects the file."""
    from studyctl.paper_answers import import_answers

    out = import_answers(db, csv_file, dry_run=dry_run)
    _done(out, f"imported {counted(out['imported'], 'answer')}", as_json)


@answers.command("correct")
@DB
@click.option("--participant", required=True, help="The participant's code, e.g. P01.")
@click.option("--model", default="", callback=lambda c, p, v: _model_name(v),
              help="The condition the answer is about, e.g. fem; left out for a question asked once at the end.")
@click.option("--item", required=True, help="The question's id, e.g. natural.")
@click.option("--trial", type=click.IntRange(0, 10_000), default=None, help="The trial (0-based) of a question asked after every trial.")
@click.option("--answer", required=True, help="The right answer, as the question's kind allows: yes/no, a rating, 0-100, a condition, text.")
@click.option("--reason", required=True, help="Why (kept in the audit trail with the old value and your login).")
@DRY_RUN
@JSON
def answers_correct(db, participant, model, item, trial, answer, reason, dry_run, as_json):
    """Correct one stored answer; the old value, reason and who did it go to the `corrections` table."""
    from studyctl.participants import correct_answer

    out = correct_answer(db, participant, model, item, answer, reason, dry_run=dry_run, trial=trial)
    where = "/".join(x for x in (participant, out["model"], item) if x) + (f" trial {out['trial']}" if out["trial"] >= 0 else "")
    _done(out, f"corrected {where}: {out['old_shown']} -> {out['new_shown']} (audit trail kept)", as_json)
