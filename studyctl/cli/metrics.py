"""`studyctl metrics`: every stored trial's performance metrics (analysis/validity/metrics.py), tidy."""

from __future__ import annotations

import json

import click

from sim.jsonable import jsonable
from sim.text import counted
from studyctl.cli.common import DB, FORCE, OutFile, read_snapshot, staged, write_output
from studyctl.outputs import output_format


def _note(table) -> str:
    codes = table.loc[table["synthetic"], "code"].unique()
    return f"SYNTHETIC DATA: {len(codes)} of {counted(table['code'].nunique(), 'participant')} {'is' if len(codes) == 1 else 'are'} synthetic" if len(codes) else ""


@click.command("metrics", cls=click.Command)
@DB
@click.option("--format", "fmt", type=click.Choice(["csv", "json"]), default=None, show_default="csv, or the one --out's suffix names", help="The output's format.")
@click.option("--out", "out_file", type=OutFile((".csv", ".json")), default=None, help="Write to this file instead of stdout.")
@click.option("--speeds", is_flag=True, help="Instead of the rows: how the hands pulled (ramp speeds, ramp and hold times, "
              "distances: percentiles over the pulls) and the bench's typical and fast speeds read off them (docs/viscoelastic.md).")
@FORCE
def metrics_cmd(db, fmt, out_file, speeds, force):
    """Performance metrics from every stored trace, one row per participant, condition, trial,
    hand and metric (docs/metrics.md); synthetic participants' rows say so."""
    from analysis.validity.metrics import METRICS, metrics_table, pull_speeds, study_goals

    target = staged(out_file, force, inputs={"--db": db})  # refused before the work
    fmt = output_format(out_file, fmt, ("csv", "json"), "json" if speeds else "csv", "metrics")
    if speeds and fmt != "json":
        raise click.UsageError("--speeds writes JSON (--format json, or an --out of .json)")
    study = read_snapshot(db)
    table = metrics_table(study, study_goals(study))
    note = _note(table) if len(table) else f"{db}: no trial with a stored trace yet"
    if speeds:
        text = json.dumps(jsonable(pull_speeds(table) | {"note": note}), indent=2) + "\n"
        if target:
            write_output(target, text)
            click.echo(f"wrote {out_file}" + (f"; {note}" if note else ""))
        else:
            click.echo(text, nl=False)
        return
    if fmt == "json":
        text = json.dumps(jsonable({"note": note, "synthetic": bool(table["synthetic"].any()),
                                    "metrics": [vars(m) for m in METRICS], "rows": table.to_dict(orient="records")}), indent=2) + "\n"
    else:
        from analysis.reports.formatting import spreadsheet_frame

        text = spreadsheet_frame(table).to_csv(index=False)
    if target:
        write_output(target, text)
        click.echo(f"wrote {out_file} ({counted(len(table), 'row')})" + (f"; {note}" if note else ""))
        return
    click.echo(text, nl=False)
    if note and fmt == "csv":  # on stderr: the CSV on stdout stays parseable
        click.echo(note, err=True)
