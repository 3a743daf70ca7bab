"""`studyctl protocol`, `studyctl study` and `studyctl status`: protocol files, creating a study
database, and where a study stands."""

from __future__ import annotations

from pathlib import Path

import click

from sim.text import counted
from studyctl.cli.common import DB, DEFAULT_PROTOCOL, FORCE, JSON, _Group, _print_json


@click.group(cls=_Group)
def protocol():
    """Study protocol files."""


@protocol.command("new")
@click.option("--kind", type=click.Choice(["yes_no", "rating", "discrimination", "validity"]), required=True,
              help="yes_no: the paper's study; rating: ratings, SUS and a choice; discrimination: stiffness JND; validity: construct validity.")
@click.option("--out", "out_dir", type=click.Path(file_okay=False, path_type=Path), required=True, help="The folder for protocol.toml and scene.toml.")
@FORCE
@click.option("--name", default=None, help="The study's name (lower-case letters, digits, _)  [default: the example's]")
@JSON
def protocol_new(kind: str, out_dir: Path, force: bool, name: str | None, as_json: bool):
    """Write a protocol and its scene of a kind into a folder of your own, from the shipped example,
    with every path resolving from there; edit them, then `protocol validate`."""
    from studyctl.templates import new_protocol

    out = new_protocol(kind, out_dir, name, force=force)
    if out["replaced"]:
        click.echo(f"--force: overwrote {', '.join(out['replaced'])}", err=True)
    if as_json:
        _print_json(out)
        return
    click.echo(f"wrote {out['protocol']} ({out['name']}, from {Path(out['from']).name}) and {out['scene']}; "
               f"check your edits with `studyctl protocol validate {out['protocol']}`")


@protocol.command("validate")
@click.argument("file", type=click.Path(dir_okay=False, path_type=Path))
@JSON
def protocol_validate(file: Path, as_json: bool):
    """Check a protocol file; print every problem as FILE:LINE: field: message."""
    from studyctl.protocol import check_protocol

    p, problems = check_protocol(file)
    if as_json:
        _print_json({"file": str(file), "ok": not problems, "problems": problems,
                     **({"study": p.name, "conditions": list(p.conditions), "questions": len(p.questions),
                         "trials_per_condition": p.trials_per_condition, "target_participants": p.target_participants} if not problems else {})})
        if problems:
            raise SystemExit(1)
        return
    if problems:
        for line in problems:
            click.echo(line, err=True)
        raise SystemExit(1)
    what = [_count(len(p.conditions), "condition"), _count(len(p.questions), "question")]
    if p.trials_per_condition:  # a discrimination protocol has only its tasks' trials
        what.append(f"{_count(p.trials_per_condition, 'trial')} per condition")
    what += [f"{t.kind} of {t.parameter} in {_count(t.trials, 'trial')} per condition" for t in p.tasks]
    click.echo(f"{file}: ok ({p.name}: {', '.join(what)}, target {counted(p.target_participants, 'participant')})")


def _count(n: int, noun: str) -> str:
    return f"{n} {noun}" + ("" if n == 1 else "s")


@click.group(cls=_Group)
def study():
    """Study databases."""


@study.command("init")
@click.option("--protocol", "protocol_file", type=click.Path(dir_okay=False, path_type=Path), default=None,
              show_default="the shipped protocols/brain_pull_2015.toml", help="The study's protocol file (TOML).")
@DB
@JSON
def study_init(protocol_file: Path, db: Path, as_json: bool):
    """Create a study database for a protocol."""
    from studyctl.store import init_study

    out = init_study(db, protocol_file or DEFAULT_PROTOCOL)
    if as_json:
        _print_json(out)
        return
    click.echo(f"created {out['db']}: study {out['study']} (schema {out['schema_version']})")


@study.command("migrate")
@DB
@JSON
def study_migrate(db: Path, as_json: bool):
    """Upgrade a database of older software to this schema: a backup copy first, then every step
    in one transaction, whole or not at all."""
    from studyctl.store import migrate_study

    out = migrate_study(db)
    if as_json:
        _print_json(out)
        return
    if out["backup"] is None:
        click.echo(f"{db}: already schema {out['to']}; nothing to do")
        return
    click.echo(f"migrated {db} from schema {out['from']} to {out['to']}; the schema-{out['from']} file was copied to {out['backup']} first")


@click.command("status", cls=click.Command)
@DB
@click.option("--json", "as_json", is_flag=True, help="Machine-readable output (JSON).")
def status_cmd(db, as_json):
    """Where the study stands: participants, sessions by state, progress to the target N, who is next."""
    from studyctl.participants import status

    out = status(db)
    if as_json:
        _print_json(out)
        return
    p, c = out["participants"], out["complete"]
    mixed = f", {c['mixed']} of them with a person's answers too" if c["mixed"] else ""
    gone = out["complete_withdrawn"]
    click.echo(f"{out['study']}: {c['persons']} of {counted(out['target_participants'], 'person')} complete"
               + (f" (and {c['synthetic']} SYNTHETIC{mixed})" if c["synthetic"] else "")
               + (f" ({gone} of these withdrew, data kept: counted, as in the reports)" if gone else ""))
    if out["incomplete"]:
        click.echo("incomplete: " + ", ".join(f"{r['code']} ({r['answers']}/{r['of']})" for r in out["incomplete"]))
    gone_synthetic = p["withdrawn_synthetic"]
    click.echo(f"participants: {counted(p['persons'], 'person')} ({p['consented']} consented, {p['withdrawn'] - gone_synthetic} withdrawn), "
               f"{p['synthetic']} synthetic" + (f" ({gone_synthetic} withdrawn)" if gone_synthetic else ""))
    click.echo("sessions: " + (", ".join(f"{n} {k}" for k, n in sorted(out["sessions"].items())) or "none yet"))
    click.echo(f"answers: {out['answers']}")
    click.echo("next: " + ("; ".join(f"{r['code']} {r['slot_start'].replace('T', ' ')}" for r in out["next"]) or "nobody scheduled"))
