"""`studyctl report` and `studyctl export`: what is made from a study database (Table 1, plots,
statistics, a published table's check) and its pseudonymous tables as files."""

from __future__ import annotations

import json
import math
from pathlib import Path

import click

from brainsim_assets import path as _asset
from sim.errors import InputFileError
from sim.files import DATA_MAX_BYTES, read_input
from sim.text import counted
from studyctl.cli.common import (
    DB,
    FORCE,
    JSON,
    SEED,
    OutDir,
    OutFile,
    _Group,
    _print_json,
    read_snapshot,
    say_replaced,
    staged,
    write_output,
)
from studyctl.outputs import output_format

PAPER_TABLE = _asset("data/paper_table1.csv")
TABLE1_FORMATS = ("md", "csv", "latex", "html", "json")
FORMATS = ("md", "html", "json", "latex")  # report jnd and report validity
TEXT_FORMATS = ("md", "latex", "json")
FORMAT_DEFAULT = "md, or the one --out's suffix names"


@click.group(cls=_Group)
def report():
    """Reports made from a study database."""


HOLM = click.option("--holm", "holm_scope", type=click.Choice(["family", "question"]), default="family", show_default=True,
                    help="Holm over every pairwise test of every question (family), or within each question.")


@report.command("table1")
@DB
@HOLM
@click.option("--format", "fmt", type=click.Choice(TABLE1_FORMATS), default=None, show_default=FORMAT_DEFAULT, help="The output's format.")
@click.option("--out", "out_file", type=OutFile(), default=None, help="Write the report to this file (default: print it).")
@FORCE
@click.option("--accuracy", "accuracy_file", type=click.Path(exists=True, dir_okay=False, path_type=Path), default=None,
              help="accuracy.json from `studyctl bench accuracy --out`: add its tables (md, latex, html) and Pareto plot (html).")
@click.option("--stability", "stability_file", type=click.Path(exists=True, dir_okay=False, path_type=Path), default=None,
              help="stability.json from `studyctl bench stability --out`: add its heat map and unstable cases (md, html).")
def report_table1(db, holm_scope, fmt, out_file, force, accuracy_file, stability_file):
    """The seed paper's Table 1 with Wilson intervals, Cochran's Q and deformation times
    (html: one self-contained file with the statistics and plots)."""
    from analysis.reports.jnd_report import jnd_text
    from analysis.reports.study_report import table1_text

    target = staged(out_file, force, inputs={"--db": db, "--accuracy": accuracy_file, "--stability": stability_file})
    fmt = output_format(out_file, fmt, TABLE1_FORMATS, "md", "report table1")
    study = read_snapshot(db)
    if study.protocol.tasks and not study.protocol.questions:  # a discrimination study without questions: its section is the report
        if fmt == "csv":
            raise click.ClickException(f"--format {fmt}: the study asks no questions (no Table 1); its discrimination task "
                                       "reports as md, html, latex or json (`studyctl report jnd`)")
        _emit(jnd_text(study, fmt), target)
        return
    if _no_answers(study, fmt == "json"):
        return
    accuracy = _load_bench(accuracy_file, "accuracy", "rows") if accuracy_file else None
    stability = _load_bench(stability_file, "stability", "cases") if stability_file else None
    traces = None
    if fmt == "html":
        from studyctl.synthetic.force_traces import force_traces

        traces = force_traces(study.protocol)
    text = table1_text(study, fmt, holm_scope, accuracy, stability, traces)
    _emit(text, target)


# what `report plots` writes (analysis/reports/report.py write_plots' figure names, in any size's
# formats): an earlier set's figures go with --force, a user's own PDF or PNG in the folder stays
FIGURE_STEMS = ("rates", "ratings", "scores", "choice_*", "deformation", "force")
FIGURE_FILES = tuple(f"{stem}.{ext}" for stem in FIGURE_STEMS for ext in ("png", "svg", "pdf"))


def _emit(text: str, out) -> None:
    """A report's text: to `out` (saying so) or to stdout."""
    if out:
        write_output(out, text)
        click.echo(f"wrote {out.target}")
    else:
        click.echo(text, nl=False)


def _no_answers(study, as_json: bool) -> bool:
    """An empty study: say so (exit 0) instead of tables of 0/0 and NaN; nothing is written."""
    from analysis.reports.study_tables import incomplete_text
    from analysis.statistics.table1 import study_facts

    facts = study_facts(study)
    if facts.participants:
        return False
    incomplete = facts.incomplete_participants
    message = "no answers yet" if not incomplete else "no participant has answered every question for every model yet"
    if as_json:
        _print_json({"facts": facts.as_dict(), "message": message})
        return True
    flag = f"{facts.flag} " if facts.flag else ""
    if facts.mixed_source_participants:
        flag += f"WARNING: {', '.join(facts.mixed_source_participants)} answered both as a person and synthetically. "
    listed = "; incomplete: " + incomplete_text(facts) if incomplete else ""
    click.echo(f"{flag}{facts.study}: {message}{listed}; nothing to report")
    return True


def _load_bench(path: Path, kind: str, key: str) -> dict:
    """A bench's JSON (`studyctl bench KIND --out DIR` writes DIR/KIND.json)."""
    try:
        data = json.loads(read_input(path, DATA_MAX_BYTES))
    except InputFileError as exc:
        raise click.ClickException(str(exc)) from None
    except (OSError, ValueError) as exc:
        raise click.ClickException(f"{path}: not a `studyctl bench {kind}` result ({exc})") from None
    if not isinstance(data, dict) or not {key, "meta"} <= set(data):
        raise click.ClickException(f"{path}: not a `studyctl bench {kind}` result (needs {key} and meta; write one with `studyctl bench {kind} --out DIR`)")
    return data


@report.command("jnd")
@DB
@click.option("--format", "fmt", type=click.Choice(FORMATS), default=None, show_default=FORMAT_DEFAULT, help="The output's format.")
@click.option("--json", "as_json", is_flag=True, help="The same as --format json.")
@click.option("--out", "out_file", type=OutFile(), default=None, help="Write the report to this file (default: print it).")
@FORCE
def report_jnd(db, fmt, as_json, out_file, force):
    """Stiffness discrimination: each participant's psychometric fit and Weber fraction with its
    bootstrap 95% interval per condition, the conditions' geometric means, the group test (mixed
    model on log Weber fraction, Friedman, Holm pairs); html with psychometric plots."""
    target = staged(out_file, force, inputs={"--db": db})  # refused before the study is read
    fmt = output_format(out_file, "json" if as_json else fmt, FORMATS, "md", "report jnd")
    study = read_snapshot(db)
    if not study.protocol.tasks:
        raise click.ClickException(f"{db}: the study's protocol has no discrimination task ([[tasks]]); nothing to report")
    from analysis.reports.jnd_report import jnd_text

    _emit(jnd_text(study, fmt), target)


@report.command("plots")
@DB
@click.option("--out", "out_dir", required=True, type=OutDir(), help="A folder (made if missing) for the figure files.")
@FORCE
@click.option("--size", type=click.Choice(["screen", "single", "double"]), default="screen", show_default=True,
              help="screen: PNG and SVG at each figure's own size (the HTML report's); single or double: a journal's one or "
                   "two columns, 85 or 175 mm wide, as PDF (fonts embedded), SVG and 600-dpi PNG.")
@JSON
def report_plots(db, out_dir, force, size, as_json):
    """Rates with intervals, ratings, scores, choices, deformation times, and force traces against the converged reference."""
    from analysis.reports.figure_size import file_info
    from analysis.reports.report import write_plots
    from studyctl.synthetic.force_traces import force_traces

    target = staged(out_dir, force, folder=True, inputs={"--db": db}, own=FIGURE_FILES)
    study = read_snapshot(db)
    if _no_answers(study, as_json):
        return
    with target as tmp:  # every figure or none: a failed plot leaves no half set
        files = [target.final(f) for f in write_plots(study, tmp, force_traces(study.protocol), size=size)]
    say_replaced(target)
    if as_json:
        _print_json({"out": str(out_dir), "size": size, "files": [file_info(f) for f in files]})
        return
    click.echo(f"wrote {counted(len(files), 'file')} ({size} size) to {out_dir}")


@report.command("stats")
@DB
@HOLM
@click.option("--json", "as_json", is_flag=True, help="Machine-readable (the default output is a summary).")
def report_stats(db, holm_scope, as_json):
    """The protocol's primary analysis first (the proportional-odds GEE across rating items, else
    the logistic GEE across yes/no questions, else a score's mixed model, else the choice), then
    every question's tests: Cochran's Q and McNemar pairs (yes/no), Friedman and Wilcoxon pairs
    (ratings), mixed models (scores), the multinomial test (choices), Holm over the whole
    family; the deformation-time benchmark. Complete cases only."""
    from analysis.reports.study_tables import stats_summary
    from analysis.statistics.study_stats import study_stats

    study = read_snapshot(db)
    if _no_answers(study, as_json):
        return
    out = study_stats(study, holm_scope=holm_scope)
    if as_json:
        _print_json(out.as_dict())
        return
    click.echo("\n".join(stats_summary(out)))


@report.command("text")
@DB
@HOLM
@click.option("--style", type=click.Choice(["apa"]), default="apa", show_default=True, help="Number style: APA 7 (p = .066, p < .001).")
@click.option("--format", "fmt", type=click.Choice(TEXT_FORMATS), default=None, show_default=FORMAT_DEFAULT, help="The output's format.")
@click.option("--json", "as_json", is_flag=True, help="The same as --format json.")
@click.option("--out", "out_file", type=OutFile(), default=None, help="Write the report to this file (default: print it).")
@FORCE
def report_text(db, holm_scope, style, fmt, as_json, out_file, force):
    """The methods and results paragraphs for a paper (participants, design, apparatus, procedure,
    analysis, results), every number taken from what `report stats --json` prints (`report jnd
    --json` for a discrimination study); synthetic data said first, withheld statistics withheld
    with their reason."""
    from analysis.reports.paper_text import study_text

    target = staged(out_file, force, inputs={"--db": db})  # refused before the study is read
    fmt = output_format(out_file, "json" if as_json else fmt, TEXT_FORMATS, "md", "report text")
    study = read_snapshot(db)
    if not (study.protocol.tasks and not study.protocol.questions) and _no_answers(study, False):
        return
    _emit(study_text(study, holm_scope, fmt), target)


@report.command("published")
@click.option("--table", "table_file", type=click.Path(dir_okay=False, path_type=Path), default=PAPER_TABLE,
              show_default="the seed paper's Table 1, data/paper_table1.csv", help="The published table to check (CSV).")
@click.option("--json", "as_json", is_flag=True, help="Machine-readable output (JSON).")
def report_published(table_file, as_json):
    """Check a published Table 1: printed rates against their counts, and what counts allow."""
    from analysis.statistics.stats import published

    out = published(table_file)
    if as_json:
        _print_json(out)
        return
    if out["flags"]:
        for f in out["flags"]:
            click.echo(f"{f['item']} / {f['model']}: printed {f['printed']}, counts {f['yes']}/{f['yes'] + f['no']} give {f['computed']}")
    else:
        click.echo("every printed rate agrees with its counts")
    for h in out["homogeneity"]:
        if math.isnan(h["chi2"]):
            click.echo(f"{h['item']}: {h['note']}")
        else:
            click.echo(f"{h['item']}: chi2({h['df']}) = {h['chi2']:.2f}, p = {h['p_value']:.3g} (ignores the pairing)")
    click.echo(out["not_computable"])


@click.command("export", cls=click.Command)
@DB
@click.option("--format", "fmt", type=click.Choice(["csv", "parquet"]), default="csv", show_default=True, help="The files' format (parquet: the parquet extra).")
@click.option("--out", "out_dir", required=True, type=OutDir(), help="A folder (made if missing) for one file per table.")
@FORCE
@JSON
def export_cmd(db, fmt, out_dir, force, as_json):
    """Export the pseudonymous tables (never the identifying one)."""
    from studyctl.export import export

    target = export(db, out_dir, fmt, force=force)
    say_replaced(target)
    files = target.written
    if as_json:
        _print_json({"out": str(out_dir), "format": fmt, "files": [str(f) for f in files]})
        return
    click.echo(f"wrote {counted(len(files), 'file')} to {out_dir}")


@report.command("validity")
@DB
@click.option("--format", "fmt", type=click.Choice(FORMATS), default=None, show_default=FORMAT_DEFAULT, help="The output's format.")
@click.option("--json", "as_json", is_flag=True, help="The same as --format json.")
@click.option("--out", "out_file", type=OutFile(), default=None, help="Write the report to this file (default: print it).")
@FORCE
@click.option("--permutations", type=click.IntRange(1, 1_000_000), default=None, show_default="100",
              help="Permutations of the classifier's permutation test.")
@click.option("--group-permutations", type=click.IntRange(1, 1_000_000), default=None, show_default="1000",
              help="Permutations of the group labels for the group tests' Westfall-Young p.")
@click.option("--bootstrap", type=click.IntRange(1, 1_000_000), default=None, show_default="200",
              help="Bootstrap replicates of Cliff's delta's and the learning curves' intervals.")
@click.option("--seed", type=SEED, default=0, show_default=True, help="Seed of every resampling.")
def report_validity(db, fmt, as_json, out_file, force, permutations, group_permutations, bootstrap, seed):
    """Construct validity: the performance metrics compared between the participant groups
    (Kruskal-Wallis, Mann-Whitney pairs with Holm and Westfall-Young, Cliff's delta), the mixed model with several
    conditions, learning curves, the expert benchmark and scorecards, leave-one-out
    classification of the group, and the face-validity ratings per group (html: box and strip
    plots per group and learning curves per metric)."""
    from analysis.reports import validity_report as vr
    from studyctl.cli.common import _with_progress

    permutations = vr.DEFAULT_PERMUTATIONS if permutations is None else permutations
    bootstrap = vr.DEFAULT_BOOTSTRAP if bootstrap is None else bootstrap
    group_permutations = vr.DEFAULT_GROUP_PERMUTATIONS if group_permutations is None else group_permutations
    target = staged(out_file, force, inputs={"--db": db})  # refused before the study is read
    fmt = output_format(out_file, "json" if as_json else fmt, FORMATS, "md", "report validity")
    study = read_snapshot(db)
    rep = _with_progress("construct validity", lambda progress: vr.validity_report(
        study, permutations=permutations, group_permutations=group_permutations, bootstrap=bootstrap, seed=seed,
        progress=progress))
    text = {"json": vr.to_json, "html": vr.html, "latex": vr.latex}.get(fmt, vr.markdown)(rep)
    _emit(text, target)
