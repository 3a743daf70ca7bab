"""`studyctl participants` and `studyctl schedule`: registering people under pseudonymous
codes, consent, withdrawal, and their slots on the rig."""

from __future__ import annotations

import json
from pathlib import Path

import click

from sim.text import counted
from studyctl.cli.common import DB, DRY_RUN, FORCE, JSON, OutFile, _console, _done, _Group, _listing, _print_json


@click.group(cls=_Group)
def participants():
    """Participants (pseudonymous codes)."""


@participants.command("add")
@click.argument("code")
@click.option("--age", type=click.IntRange(0, 120), default=None, help="Age in years (0..120).")
@click.option("--name", default=None, help="Kept in a separate table that no export or report includes.")
@click.option("--contact", default=None, help="Kept in a separate table that no export or report includes.")
@click.option("--field", "fields", multiple=True, metavar="NAME=VALUE",
              help="A value of one of the protocol's [fields.NAME], e.g. --field experience=resident (repeatable; never a name).")
@click.option("--synthetic", is_flag=True, help="A SYNTHETIC participant (run only with `session run --synthetic`).")
@DB
@DRY_RUN
@JSON
def participants_add(code, age, name, contact, fields, synthetic, db, dry_run, as_json):
    """Register a participant under a pseudonymous CODE."""
    from analysis.errors import InputError
    from studyctl.registration import add_participant

    given: dict[str, str] = {}
    for f in fields:
        key, eq, value = f.partition("=")
        if not eq or not key.strip():
            raise InputError(f"--field: {f!r} is not NAME=VALUE, e.g. --field experience=resident")
        if key.strip() in given:
            raise InputError(f"--field: {key.strip()} is given twice")
        given[key.strip()] = value
    out = add_participant(db, code, age, name, contact, synthetic=synthetic, dry_run=dry_run, fields=given)
    _done(out, f"added {out['code']}" + (" (SYNTHETIC)" if synthetic else ""), as_json)


@participants.command("import")
@click.argument("csv_file", type=click.Path(dir_okay=False, path_type=Path))
@DB
@DRY_RUN
@JSON
def participants_import(csv_file, db, dry_run, as_json):
    """Register participants from a CSV (code, then optional age, name, contact, and a column per
    protocol field, e.g. experience): all or none. UTF-8 with or without BOM, ',' or ';'
    separated, headers in any case."""
    from studyctl.registration import import_participants

    out = import_participants(db, csv_file, dry_run=dry_run)
    _done(out, f"imported {counted(out['imported'], 'participant')}", as_json)


@participants.command("list")
@DB
@click.option("--json", "as_json", is_flag=True, help="Machine-readable output (JSON).")
def participants_list(db, as_json):
    """Every participant (codes only, never names): kind, consent, slot, session, answers."""
    from studyctl.participants import list_participants

    rows = list_participants(db)
    columns = ["code", "kind", "age", "consent", "slot", "session", "answers", "withdrawn"]
    if rows and "group" in rows[0]:
        columns.insert(3, "group")
    _listing(rows, as_json, db, "participants", columns)


@participants.command("consent")
@click.argument("code")
@click.option("--date", "given_on", default=None, help="The day the form was signed, YYYY-MM-DD (default: today).")
@click.option("--version", default=None, help="The consent form's version (default and only allowed: the protocol's).")
@DB
@DRY_RUN
@JSON
def participants_consent(code, given_on, version, db, dry_run, as_json):
    """Record that a person signed the consent form (needed before their session)."""
    from studyctl.participants import record_consent

    out = record_consent(db, code, given_on, version, dry_run=dry_run)
    _done(out, f"recorded consent of {code}: form {out['version']}, signed {out['given_on']}", as_json)


@participants.command("withdraw")
@click.argument("code")
@click.option("--reason", default="", help="Kept in the event log (optional; a person need not give one).")
@DB
@DRY_RUN
@JSON
def participants_withdraw(code, reason, db, dry_run, as_json):
    """A participant withdraws: no more sessions; their data kept or deleted as the protocol says
    (ethics.withdrawal); their contact details deleted; logged."""
    from studyctl.participants import withdraw

    out = withdraw(db, code, reason, dry_run=dry_run)
    _done(out, f"withdrawn {code}: {counted(out['sessions'], 'session')} and {counted(out['answers'], 'answer')} {out['data']}"
          + (f", {out['traces']} trace files deleted" if out["traces"] else "") + "; contact details deleted", as_json)


@participants.command("contacts")
@DB
@click.option("--out", "out_file", required=True, type=OutFile((".csv",)), help="The CSV file to write.")
@FORCE
@JSON
def participants_contacts(db, out_file, force, as_json):
    """EXPERIMENTER ONLY: names and contact details (the identifying table) to a CSV marked as such."""
    from studyctl.participants import export_contacts

    out = export_contacts(db, out_file, force=force)
    if out["replaced"]:
        click.echo(f"--force: overwrote {out['file']}", err=True)
    if as_json:
        _print_json(out)
        return
    click.echo(f"wrote {out['file']}: IDENTIFYING names and contacts of {counted(out['participants'], 'participant')} (readable by you only)")


@click.group("schedule", cls=_Group, invoke_without_command=True)
@click.option("--db", envvar="STUDYCTL_DB", show_envvar=True, type=click.Path(dir_okay=False, path_type=Path),
              help="Study database; required unless the STUDYCTL_DB environment variable names one.")
@click.option("--start", help="First day, YYYY-MM-DD (today or later).")
@click.option("--end", help="Last day, YYYY-MM-DD.")
@click.option("--hours", default="09:00-17:00", show_default=True, help="The lab's hours on weekdays, HH:MM-HH:MM.")
@click.option("--session-minutes", type=click.IntRange(5, 480), default=45, show_default=True, help="Each slot's length, minutes (5..480).")
@click.option("--availability", type=click.Path(dir_okay=False, path_type=Path), default=None, help="CSV: code,date,start,end.")
@click.option("--ics", type=OutFile((".ics",)), default=None, help="Write an iCalendar file (.ics).")
@FORCE
@click.option("--json", "as_json", is_flag=True, help="Machine-readable output (JSON).")
@DRY_RUN
@click.pass_context
def schedule_cmd(ctx, db, start, end, hours, session_minutes, availability, ics, force, as_json, dry_run):
    """Give each waiting participant a slot on the rig and a counterbalanced order
    (`schedule cancel CODE` frees a slot; scheduling again gives a new one)."""
    if ctx.invoked_subcommand is not None:
        return
    for name, value in (("--db", db), ("--start", start), ("--end", end)):
        if value is None:
            raise click.UsageError(f"Missing option '{name}'.")
    from studyctl.schedule import schedule_study

    existed = ics is not None and ics.exists()
    rows = schedule_study(db, start, end, hours, session_minutes, availability, ics, dry_run=dry_run, force=force)
    if existed and not dry_run:
        click.echo(f"--force: overwrote {ics}", err=True)
    if as_json:
        _print_json(rows)
        return
    from rich.table import Table

    with_slot = len([r for r in rows if r["slot_start"]])
    t = Table(title=("DRY RUN, nothing stored: " if dry_run else "") + f"Schedule ({with_slot} of {counted(len(rows), 'participant')} {'has' if with_slot == 1 else 'have'} a slot)")
    for col in ("participant", "start", "end", "order"):
        t.add_column(col)
    for r in rows:
        t.add_row(r["code"], r["slot_start"] or "-", (r["slot_end"] or "-")[11:16], " > ".join(json.loads(r["conditions"])))
    _console().print(t)
    if ics and not dry_run:
        click.echo(f"calendar: {ics}")


@schedule_cmd.command("cancel")
@click.argument("code")
@DB
@DRY_RUN
@JSON
def schedule_cancel(code, db, dry_run, as_json):
    """Free CODE's slot (their condition order is kept); run `schedule` again to reschedule."""
    from studyctl.participants import cancel_slot

    out = cancel_slot(db, code, dry_run=dry_run)
    _done(out, f"cancelled {code}'s slot at {out['cancelled']}; `studyctl schedule` gives a new one", as_json)
