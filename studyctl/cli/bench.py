"""`studyctl bench`: model error against run time, stability sweeps, the converged reference."""

from __future__ import annotations

import math
from pathlib import Path

import click

from sim.scene import DEFAULT_SCENE
from studyctl.cli.common import (
    FORCE,
    SCHEDULER,
    OutDir,
    _console,
    _Group,
    _print_json,
    _with_progress,
    say_replaced,
    staged,
)

# what each bench writes into --out (write_outputs of analysis/reports/accuracy_tables.py, stability_report.py, reference_report.py)
ACCURACY_FILES = ("accuracy.json", "accuracy.csv", "samples.csv", "accuracy.md", "accuracy.tex", "pareto.png", "pareto.svg")
STABILITY_FILES = ("stability.json", "stability.csv", "stability.md", "heatmap.png", "heatmap.svg")


@click.group(cls=_Group)
def bench():
    """Model error against run time, and stability on stiff and extreme cases."""


def _models(ctx, param, value):
    """--models: installed model names, comma-separated (None: every one)."""
    from sim.models.registry import installed, plugins

    models, _ = installed()
    if value is None:  # every model: say which of a lab's models the defaults cannot build
        from analysis.verification.accuracy import plugin_problem

        for name in plugins(models):
            if (problem := plugin_problem(name)) is not None:
                click.echo(f"not benched: {problem} ([models.{name}] in the scene, or --models after configuring it)", err=True)
        return None
    names = [n if n in models else n.replace("-", "_") for n in (v.strip() for v in value.split(",")) if n]
    unknown = [n for n in names if n not in models]
    if unknown or not names:
        raise click.BadParameter(f"{', '.join(unknown) or repr(value)}: not an installed model; installed: {', '.join(sorted(models))}")
    return tuple(names)


def _sweep_options(f):
    f = click.option("--models", callback=_models, default=None,
                     help="Only these models, comma-separated (default: every installed model, a lab's own included).")(f)
    f = SCHEDULER(f)
    f = click.option("--jobs", type=click.IntRange(1, 256), default=None, help="Local worker processes (default: every core).")(f)
    f = FORCE(f)
    f = click.option("--out", "out_dir", type=OutDir(), default=None, help="Write tables, JSON and plots here.")(f)
    f = click.option("--json", "as_json", is_flag=True, help="Machine-readable output (JSON).")(f)
    f = click.option("--quick", is_flag=True, help="The small sweep (CI, make demo).")(f)
    return f


@bench.command("accuracy")
@click.option("--scene", "scene_file", type=click.Path(dir_okay=False, path_type=Path), default=DEFAULT_SCENE, show_default="protocols/scenes/brain_pull.toml", help="The scene file (TOML).")
@click.option("--young", type=click.FloatRange(1.0, 1e9), default=None,
              help="The linear models' Young's modulus, Pa, with the tissue's law scaled alike [default: the scene's].")
@click.option("--test-places", type=click.IntRange(2, 20), default=None, help="Held-out grasp places, two directions each [default: 6, --quick: 2].")
@click.option("--speeds", default="quasi-static,typical,fast", show_default=True,
              help="The hand's speeds, comma-separated: quasi-static (the timeless truth) and those of data/pull_speeds.json (the viscoelastic truth, pulled and held).")
@_sweep_options
def bench_accuracy(scene_file, young, test_places, speeds, quick, as_json, out_dir, force, jobs, scheduler, models):
    """Every model and setting on the same pulls against the converged reference (the tissue's
    finite-strain law on P2 on body-fitted meshes, Richardson; shipped): calibrated with one stiffness scale on the
    calibration pulls, judged raw and calibrated on held-out pulls (within the JND with
    Wilson intervals, against the reference's band, direction error), time per tick and frame."""
    from analysis.reports import accuracy_tables
    from analysis.reports.formatting import shown
    from analysis.verification import accuracy, paper

    target = staged(out_dir, force, folder=True, expect=ACCURACY_FILES, inputs={"--scene": scene_file})  # refused before the sweep
    names = tuple(dict.fromkeys(n.strip() for n in speeds.split(",")))  # each speed once
    accuracy.bench_speeds(names)  # a speed not known: refused before the sweep
    kw = {"scene": scene_file, "young": young, "speeds": names} | ({"test_places": test_places} if test_places else {})
    settings = accuracy.default_settings(quick)
    kw["settings"] = settings if models is None else tuple(s for s in settings if s.model in models)
    cfg = accuracy.quick_config(**kw) if quick else accuracy.AccuracyConfig(**kw)
    result = _with_progress("accuracy: reference, then models", lambda p: accuracy.run_accuracy(cfg, jobs=jobs, scheduler=scheduler, progress=p))
    if target:
        with target as tmp:
            accuracy_tables.write_outputs(result, tmp)
        say_replaced(target)
    if as_json:
        _print_json(result)
        return
    from rich.table import Table

    t = Table(title=f"Force error on held-out pulls against run time (the linear models' E = {result['meta']['young_pa'] / 1e3:.3g} kPa)", caption=accuracy_tables.intro(result))
    for col in ("model", "setting", "speed", "calibration", "scale", "force error", "max", "within JND [95% CI] of decided", "decided/extrap./undec.",
                "in/out/undecided", "pulls",
                "direction deg", "tick us", "frame ms"):
        t.add_column(col, justify="left" if col in ("model", "setting", "speed", "calibration") else "right")
    for r in result["rows"]:
        t.add_row(r["model"], r["setting"], r["speed"], r["calibration"], shown(r["scale"], ".3g"), accuracy_tables.error_text(r).split(" / ")[0], shown(r["force_error_max"], ".1%"),
                  accuracy_tables.within_text(r, short=True), accuracy_tables.truth_counts(r).replace(" / ", "/"),
                  f"{r['within']}/{r['outside']}/{r['undecided']}", f"{r['pulls_within']}/{r['n_test_pulls']}",
                  shown(r["angle_deg"], ".1f"), f"{r['tick_us']:.2f}", f"{r['frame_ms']:.3g}")
    best = Table(title=f"Each class at its best (frame p99 within the budget, no pull given up; target {accuracy.TARGET_WITHIN:.0%} within the JND)")
    for col in ("model", "speed", "calibration", "best setting", "within JND [95% CI] of decided", "force error", "frame p50/p99 ms", "meets target", "left out"):
        best.add_column(col, justify="left" if col in ("model", "speed", "calibration", "best setting", "left out") else "right")
    for b in result["best"]:
        left = "; ".join(f"{k}: {v}" for k, v in b["left_out"].items()) or "none"
        if b["setting"] is None:
            best.add_row(b["model"], b["speed"], b["calibration"], f"none ({b['why']})", "", "", "", accuracy_tables.meets_text(b), left)
            continue
        best.add_row(b["model"], b["speed"], b["calibration"], b["setting"], accuracy_tables.within_text(b, short=True),
                     f"{b['force_error']:.1%}", f"{b['frame_ms']:.3g}/{b['frame_ms_p99']:.3g}", accuracy_tables.meets_text(b), left)
    console = _console()
    console.print(t)
    console.print(best)
    console.print(f"seed paper, ms per deformation frame (2014 PC): {paper.deformation_words('')}")
    if quick:
        console.print(accuracy.QUICK_NOTE)
    if out_dir:
        console.print(f"wrote {out_dir}/accuracy.md, accuracy.json, accuracy.csv, samples.csv, pareto.png")


@bench.command("stability")
@click.option("--scene", "scene_file", type=click.Path(dir_okay=False, path_type=Path), default=DEFAULT_SCENE, show_default="protocols/scenes/brain_pull.toml", help="The scene file (TOML).")
@_sweep_options
def bench_stability(scene_file, quick, as_json, out_dir, force, jobs, scheduler, models):
    """Sweep E, nu, time step, spring stiffness, plate-spring parameters, far pulls and 5 cm
    jumps for every model: stable, refused (with the reason) or unstable (with the time)."""
    from analysis.reports import stability_report
    from analysis.verification import stability

    target = staged(out_dir, force, folder=True, expect=STABILITY_FILES, inputs={"--scene": scene_file})  # refused before the sweep
    cases = stability.make_cases(quick, models)
    result = _with_progress("stability cases", lambda p: stability.run_stability(quick, scene_file, jobs=jobs, scheduler=scheduler, progress=p, cases=cases))
    if target:
        with target as tmp:
            stability_report.write_outputs(result, tmp)
        say_replaced(target)
    if as_json:
        _print_json(result)
    else:
        from rich.table import Table

        _, cols, _ = stability.outcome_grid(result["cases"])
        t = Table(title="Stability sweep: S stable, R refused, U unstable, . not applicable")
        t.add_column("model")
        t.add_column("cases: " + " ".join(cols), overflow="fold")
        by = {}
        for c in result["cases"]:
            by.setdefault(c["model"], {})[c["case"]] = c["outcome"][0].upper()
        for model, row in by.items():
            t.add_row(model, " ".join(row.get(c, ".") for c in cols))
        console = _console()
        console.print(t)
        console.print(stability_report.markdown(result).split("\n")[0])
        if out_dir:
            console.print(f"wrote {out_dir}/stability.md, stability.json, stability.csv, heatmap.png")
    m = result["meta"]
    if m["nan_sent"] or m["over_limit_sent"]:  # the safety promise broke: fail loudly
        raise click.ClickException(f"{m['nan_sent']} cases sent a NaN and {m['over_limit_sent']} an over-limit force to a device")


def _sizes_mm(ctx, param, value):
    if value is None:
        return None
    try:
        sizes = tuple(float(s) for s in value.split(","))
    except ValueError:
        raise click.BadParameter(f"{value!r}: two or three edge lengths in mm, comma-separated") from None
    if len(sizes) not in (2, 3) or len(set(sizes)) != len(sizes) or not all(2.0 <= s <= 30.0 for s in sizes):
        raise click.BadParameter(f"{value!r}: two or three different edge lengths in 2..30 mm, comma-separated")
    return sizes


@bench.command("reference")
@click.option("--scene", "scene_file", type=click.Path(dir_okay=False, path_type=Path), default=DEFAULT_SCENE, show_default="protocols/scenes/brain_pull.toml", help="The scene file (TOML).")
@click.option("--sizes", callback=_sizes_mm, default=None, help="fTetWild target edge lengths, mm, comma-separated [default: 8,6,4, the shipped meshes; --quick: 20,16].")
@click.option("--functional", type=click.Choice(["area", "vertices"]), default="area", show_default=True,
              help="The grasp: mean displacement of the surface area within the grasp radius, or of its vertices (does not converge).")
@click.option("--formulation", type=click.Choice(["finite-strain", "small-strain"]), default="finite-strain", show_default=True,
              help="The scene's law at finite strain (Newton along each pull; shipped for the shipped scene), or its small-strain "
                   "limit (one linear solve per pull and mesh).")
@click.option("--pulls", "pull_names", default=None, help="Only these bench pulls, comma-separated (e.g. left-lateral,extra1-anterior).")
@click.option("--jobs", type=click.IntRange(1, 256), default=None, help="Meshes made and pulls solved at once (default: every core).")
@click.option("--quick", is_flag=True, help="Two coarse meshes, the left hand's pulls, two samples (CI).")
@click.option("--json", "as_json", is_flag=True, help="Machine-readable output (JSON).")
@click.option("--out", "out_dir", type=OutDir(), default=None, help="Write reference.json and reference.md here.")
@FORCE
def bench_reference(scene_file, sizes, functional, formulation, pull_names, jobs, quick, as_json, out_dir, force):
    """A converged reference: the tissue's law on P2 tetrahedra on body-fitted (fTetWild) meshes
    of each hemisphere at three sizes, Richardson extrapolation and the grid convergence index
    for every calibration pull of the accuracy bench."""
    from analysis.reports import reference_report
    from analysis.verification import reference

    # refused before the solves
    target = staged(out_dir, force, folder=True, expect=("reference.json", "reference.md"), inputs={"--scene": scene_file})
    kw = {"scene": scene_file, "functional": functional, "formulation": formulation, "jobs": jobs}
    if sizes is not None:
        kw["sizes_mm"] = sizes
    if pull_names:
        kw["pulls"] = tuple(n.strip() for n in pull_names.split(","))
    cfg = reference.quick_config(**kw) if quick else reference.ReferenceConfig(**kw)
    result = _with_progress("reference meshes", lambda p: reference.run_reference(cfg, progress=p))
    if target:
        with target as tmp:
            reference_report.write_outputs(result, tmp)
        say_replaced(target)
    if as_json:
        _print_json(result)
        return
    from rich.table import Table

    m = result["meta"]
    t = Table(title=f"Converged reference: P2, {m['formulation']}, on fTetWild meshes, grasp functional: {m['functional']}; "
                    f"GCI half-band median {m['gci_median']:.1%}, largest {m['gci_max']:.1%} ({m['seconds']:.0f} s)")
    for col in ("pull", "d mm", *(f"F {s:g}mm N" for s in m["sizes_mm"]), "order", "status", "extrap. N", "GCI band", "< JND rel", "< 0.05 N"):
        t.add_column(col, justify="left" if col in ("pull", "status") else "right", no_wrap=col in ("pull", "status"))
    for s in result["samples"]:
        order = "-" if s["order"] is None or not math.isfinite(s["order"]) else f"{s['order']:.2f}"
        ext = "-" if s["force_ext_n"] is None or not math.isfinite(s["force_ext_n"]) else f"{s['force_ext_n']:.4f}"
        band = "-" if s["gci"] is None or not math.isfinite(s["gci"]) else f"+-{s['gci']:.1%}"
        status = {"order out of range": "p out of range", "oscillatory": "oscillating"}.get(s["status"], s["status"])
        t.add_row(s["pull"], f"{s['displacement_mm']:g}", *(f"{f:.4f}" for f in s["forces_n"]), order, status, ext, band,
                  "yes" if s["within_jnd_rel"] else "NO", "yes" if s["within_jnd_abs"] else "NO")
    console = _console()
    console.print(t)
    console.print("meshes: " + "; ".join(f"hemisphere {g['hemisphere']} {g['target_edge_mm']:g} mm: {g['nodes']} nodes, {g['tets']} tets, "
                                         f"h {g['h_mm']:.2f} mm, {g['mesh_s']:.0f} s{' (cached)' if g['cached'] else ''}" for g in result["meshes"]))
    console.print("band: Roache's GCI on the finest mesh (Fs = 1.25 with a monotone three-mesh order in 0.5..4; otherwise Fs = 3, order 2, "
                  "and at least the spread of the meshes, no extrapolation). '< JND rel': half-band below the JND fraction of the force "
                  "(10% at >= 0.5 N, 25% below); '< 0.05 N': half-band below 10% of 0.5 N.")
    if out_dir:
        console.print(f"wrote {out_dir}/reference.json, reference.md")
