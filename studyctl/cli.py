"""The `studyctl` command line: parse options, call one library function, print.

Library exceptions (`sim.errors.SimError`, `studyctl.errors.StudyError`) become one-line errors
(a file with several problems: one line each) with exit status 1; usage
mistakes are click's (exit status 2). No traceback reaches the user for either.
"""

from __future__ import annotations

import json
import math
import sqlite3
import sys
from pathlib import Path

import click

from analysis.sweep import SweepError
from brainsim_assets import path as _asset
from sim.errors import SimError
from sim.jsonable import jsonable
from sim.models.base import MAX_PULL_M, pull_problem
from sim.run import MAX_DURATION_S, VisualStep
from sim.scene import DEFAULT_SCENE
from studyctl.errors import InputError, StudyError

DEFAULT_PROTOCOL = _asset("protocols/brain_pull_2015.toml")
PAPER_TABLE = _asset("data/paper_table1.csv")


class _Group(click.Group):
    """Turns library errors into clean CLI errors; a subcommand named with hyphens also answers
    to underscores (`model plate_spring`, as models are spelt in files and `--model`)."""

    def get_command(self, ctx, cmd_name):
        return super().get_command(ctx, cmd_name) or super().get_command(ctx, cmd_name.replace("_", "-"))

    def invoke(self, ctx: click.Context):
        try:
            return super().invoke(ctx)
        except (SimError, StudyError, SweepError) as exc:
            raise click.ClickException(str(exc)) from None
        except sqlite3.OperationalError as exc:  # e.g. another process held the database for over 30 s
            raise click.ClickException(f"the study database: {exc} (another process may be writing to it; try again)") from None


def _console():
    from rich.console import Console

    console = Console()
    if not console.is_terminal:  # pipes and tests: wide, stable layout
        console = Console(width=120)
    return console


def _print_json(obj) -> None:
    click.echo(json.dumps(jsonable(obj), indent=2))


class Finite(click.FloatRange):
    """A float range that also refuses NaN (click's ranges let it through: NaN compares false)."""

    def convert(self, value, param, ctx):
        v = super().convert(value, param, ctx)
        if not math.isfinite(v):
            self.fail(f"{value!r} is not a finite number", param, ctx)
        return v


class OutFile(click.Path):
    """A file to write: its folder must exist and the suffix be one of `suffixes`, checked
    before any work is done (so a typo never costs a long run or leaves half a result)."""

    def __init__(self, suffixes: tuple[str, ...] | None = None):
        super().__init__(dir_okay=False, path_type=Path)
        self.suffixes = suffixes

    def convert(self, value, param, ctx):
        path = super().convert(value, param, ctx)
        if not path.parent.is_dir():
            self.fail(f"{path.parent} is not an existing folder", param, ctx)
        if self.suffixes and path.suffix.lower() not in self.suffixes:
            self.fail(f"{path.name}: allowed suffixes: {', '.join(self.suffixes)}", param, ctx)
        return path


class OutDir(click.Path):
    """A folder to write into (made if missing): nothing on its way may be a file."""

    def __init__(self):
        super().__init__(file_okay=False, path_type=Path)

    def convert(self, value, param, ctx):
        path = super().convert(value, param, ctx)
        for p in (path, *path.parents):
            if p.exists():
                if not p.is_dir():
                    self.fail(f"{p} is a file, not a folder", param, ctx)
                break
        return path


def _names(ctx, param, value):
    if value is None:
        return None
    names = [n.strip() for n in value.split(",")]
    if not all(names) or len(names) > 2:
        raise click.BadParameter(f"{value!r}: one or two device names, comma-separated")
    return names


FULLSCREEN = click.option("--fullscreen", is_flag=True,
                          help="The participant view fills the primary monitor (else a resizable 1280x720 window).")
DEVICES = click.option("--devices", "device_names", callback=_names, default=None,
                       help='OpenHaptics device names, comma-separated, e.g. "PHANToM 1,PHANToM 2" (default: the scene\'s).')


@click.group(cls=_Group, context_settings={"help_option_names": ["-h", "--help"]})
@click.version_option(package_name="brainsim-study", prog_name="studyctl")
def cli():
    """Haptic brain-surgery simulator: experiments, user studies and reports."""


# -- benches: model error against run time, stability sweeps ------------------------------

@cli.group(cls=_Group)
def bench():
    """Model error against run time, and stability on stiff and extreme cases."""


def _sweep_options(f):
    f = click.option("--scheduler", default=None, metavar="ADDRESS", help="Run the cases on a Dask cluster (tcp://host:8786).")(f)
    f = click.option("--jobs", type=click.IntRange(1, 256), default=None, help="Local worker processes (default: every core).")(f)
    f = click.option("--out", "out_dir", type=OutDir(), default=None, help="Write tables, JSON and plots here.")(f)
    f = click.option("--json", "as_json", is_flag=True)(f)
    f = click.option("--quick", is_flag=True, help="The small sweep (CI, make demo).")(f)
    return f


def _with_progress(label, fn):
    """`fn(progress)` with a progress bar that `progress(done, total)` advances, on stderr (a
    --json document on stdout stays clean)."""
    from rich.console import Console
    from rich.progress import Progress

    with Progress(transient=True, console=Console(stderr=True)) as progress:
        task = progress.add_task(label, total=None)
        return fn(lambda k, n: progress.update(task, completed=k, total=n))


@bench.command("accuracy")
@click.option("--scene", "scene_file", type=click.Path(dir_okay=False, path_type=Path), default=DEFAULT_SCENE, show_default="protocols/scenes/brain_pull.toml")
@click.option("--young", type=click.FloatRange(1.0, 1e9), default=None, help="Young's modulus of the bench tissue, Pa [default: the scene's].")
@click.option("--test-places", type=click.IntRange(2, 20), default=None, help="Held-out grasp places, two directions each [default: 6, --quick: 2].")
@_sweep_options
def bench_accuracy(scene_file, young, test_places, quick, as_json, out_dir, jobs, scheduler):
    """Every model and setting on the same pulls against the converged reference (P2 on
    body-fitted meshes, neo-Hookean, Richardson): calibrated with one stiffness scale on the
    calibration pulls, judged raw and calibrated on held-out pulls (within the JND with
    Wilson intervals, against the reference's band, direction error), time per tick and frame."""
    from analysis import accuracy

    kw = {"scene": scene_file, "young": young} | ({"test_places": test_places} if test_places else {})
    cfg = accuracy.quick_config(**kw) if quick else accuracy.AccuracyConfig(**kw)
    result = _with_progress("accuracy: reference, then models", lambda p: accuracy.run_accuracy(cfg, jobs=jobs, scheduler=scheduler, progress=p))
    if out_dir:
        accuracy.write_outputs(result, out_dir)
    if as_json:
        _print_json(result)
        return
    from rich.table import Table

    t = Table(title=f"Force error on held-out pulls against run time (E = {result['meta']['young_pa'] / 1e3:g} kPa)", caption=accuracy.intro(result))
    for col in ("model", "setting", "calibration", "scale", "force error", "max", "within JND [95% CI]", "in/out/undecided", "pulls",
                "direction deg", "tick us", "frame ms"):
        t.add_column(col, justify="left" if col in ("model", "setting", "calibration") else "right")
    for r in result["rows"]:
        t.add_row(r["model"], r["setting"], r["calibration"], f"{r['scale']:.3g}", f"{r['force_error']:.1%}", f"{r['force_error_max']:.1%}",
                  f"{r['within_jnd']:.0%} [{r['within_jnd_low']:.0%}, {r['within_jnd_high']:.0%}]",
                  f"{r['within']}/{r['outside']}/{r['undecided']}", f"{r['pulls_within']}/{r['n_test_pulls']}",
                  f"{r['angle_deg']:.1f}", f"{r['tick_us']:.2f}", f"{r['frame_ms']:.3g}")
    console = _console()
    console.print(t)
    console.print("seed paper, ms per deformation frame (2014 PC): plate-spring 14.69, FEM 21.35, mass-spring 23.08")
    if out_dir:
        console.print(f"wrote {out_dir}/accuracy.md, accuracy.json, accuracy.csv, samples.csv, pareto.png")


@bench.command("stability")
@click.option("--scene", "scene_file", type=click.Path(dir_okay=False, path_type=Path), default=DEFAULT_SCENE, show_default="protocols/scenes/brain_pull.toml")
@_sweep_options
def bench_stability(scene_file, quick, as_json, out_dir, jobs, scheduler):
    """Sweep E, nu, time step, spring stiffness, plate-spring parameters, far pulls and 5 cm
    jumps for every model: stable, refused (with the reason) or unstable (with the time)."""
    from analysis import stability

    result = _with_progress("stability cases", lambda p: stability.run_stability(quick, scene_file, jobs=jobs, scheduler=scheduler, progress=p))
    if out_dir:
        stability.write_outputs(result, out_dir)
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
        console.print(stability.markdown(result).split("\n")[0])
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
@click.option("--scene", "scene_file", type=click.Path(dir_okay=False, path_type=Path), default=DEFAULT_SCENE, show_default="protocols/scenes/brain_pull.toml")
@click.option("--young", type=Finite(1.0, 1e9), default=None, help="Young's modulus, Pa (forces are proportional to it) [default: the scene's].")
@click.option("--sizes", callback=_sizes_mm, default=None, help="fTetWild target edge lengths, mm, comma-separated [default: 8,5.5,4; --quick: 20,16].")
@click.option("--functional", type=click.Choice(["area", "vertices"]), default="area", show_default=True,
              help="The grasp: mean displacement of the surface area within the grasp radius, or of its vertices (FemModel's; does not converge).")
@click.option("--formulation", type=click.Choice(["linear", "neo-hookean"]), default="linear", show_default=True,
              help="Small-strain linear elasticity (one solve per pull), or compressible neo-Hookean (Newton; minutes per pull and mesh).")
@click.option("--pulls", "pull_names", default=None, help="Only these bench pulls, comma-separated (e.g. left-lateral,extra1-anterior).")
@click.option("--jobs", type=click.IntRange(1, 256), default=None, help="Meshes made at once (default: every core).")
@click.option("--quick", is_flag=True, help="Two coarse meshes, the left hand's pulls, two samples (CI).")
@click.option("--json", "as_json", is_flag=True)
@click.option("--out", "out_dir", type=OutDir(), default=None, help="Write reference.json and reference.md here.")
def bench_reference(scene_file, young, sizes, functional, formulation, pull_names, jobs, quick, as_json, out_dir):
    """A converged reference: P2 tetrahedra on body-fitted (fTetWild) meshes of each hemisphere at
    three sizes, Richardson extrapolation and the grid convergence index for every bench pull."""
    from analysis import reference

    kw = {"scene": scene_file, "young": young, "functional": functional, "formulation": formulation, "jobs": jobs}
    if sizes is not None:
        kw["sizes_mm"] = sizes
    if pull_names:
        kw["pulls"] = tuple(n.strip() for n in pull_names.split(","))
    cfg = reference.quick_config(**kw) if quick else reference.ReferenceConfig(**kw)
    result = _with_progress("reference meshes", lambda p: reference.run_reference(cfg, progress=p))
    if out_dir:
        reference.write_outputs(result, out_dir)
    if as_json:
        _print_json(result)
        return
    from rich.table import Table

    m = result["meta"]
    t = Table(title=f"Converged reference: P2 {m['formulation']} on fTetWild meshes, E = {m['young_pa'] / 1e3:g} kPa, "
                    f"nu = {m['poisson']:g}, grasp functional: {m['functional']}")
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


def main() -> None:
    cli(prog_name="studyctl")


# -- model ---------------------------------------------------------------------------------


@cli.group(cls=_Group)
def model():
    """Inspect and exercise the tissue models."""


@model.command("plate-spring")
@click.option("--params", "params_file", required=True, type=click.Path(dir_okay=False, path_type=Path), help="Parameter file (TOML, SI units).")
@click.option("--variant", type=click.Choice(["paper", "continuous"]), default="continuous", show_default=True)
@click.option("--force", "force", type=Finite(), default=None, help="Tension F in newtons, >= 0: print the deformation.")
@click.option("--displacement", "displacement", type=Finite(min=0.0, max=MAX_PULL_M), default=None,
              help=f"Displacement X in metres, 0..{MAX_PULL_M:g} (the longest pull the tissue models are meant for): print the force.")
@click.option("--json", "as_json", is_flag=True, help="Machine-readable output.")
def model_plate_spring(params_file: Path, variant: str, force, displacement, as_json: bool):
    """The paper's plate-spring model: layer table, X(F), or its inverse F(X).

    Without --force or --displacement it prints the layer table, the jumps of X(F) and the
    delay budget.
    """
    from sim.models.plate_spring import PlateSpring, load_params

    if force is not None and displacement is not None:
        raise click.UsageError("give --force or --displacement, not both")
    stack = PlateSpring(load_params(params_file), variant)
    if force is not None:
        sol = stack.deformation(force)
        out = {
            "variant": variant,
            "force": sol.force,
            "dcl": sol.dcl,
            "deformation": sol.deformation,
            "layer_deformation": list(sol.layer_deformation),
            "plate_deformation": sol.plate_deformation,
            "overstretched": sol.overstretched,
            "saturated": sol.saturated,
        }
        if as_json:
            _print_json(out)
        else:
            _print_solution(out)
        return
    if displacement is not None:
        f = stack.force(displacement)
        sol = stack.deformation(f)
        out = {"variant": variant, "displacement": displacement, "force": f, "dcl": sol.dcl, "saturated": displacement > stack.capacity_x}
        if as_json:
            _print_json(out)
        else:
            click.echo(f"force {f:.6g} N at displacement {displacement:.6g} m ({variant}; DCL layer {sol.dcl}"
                       + (", beyond the stack's capacity" if out["saturated"] else "") + ")")
        return
    table = {
        "variant": variant,
        "layers": stack.layer_table(),
        "jumps": [
            {"layer": j.layer, "force": j.force, "x_before": j.x_before, "x_after": j.x_after, "size": j.size, "kind": j.kind}
            for j in stack.jumps
        ],
        "capacity": {"deformation": stack.capacity_x, "force": stack.capacity_f},
        "delay_budget": {"period_s": 1e-3, "layers_in_budget": stack.layers_in_budget()},
    }
    if as_json:
        _print_json(table)
    else:
        _print_layer_table(table)


def _vector(ctx, param, value):
    if value is None:
        return None
    try:
        parts = [float(x) for x in value.split(",")]
    except ValueError:
        parts = []
    if len(parts) != 3:
        raise click.BadParameter(f"{value!r} is not three comma-separated numbers (metres)")
    names = ("DX", "DY", "DZ") if param is not None and param.name == "displacement" else ("X", "Y", "Z")
    bad = [name for name, x in zip(names, parts) if not math.isfinite(x)]
    if bad:
        raise click.BadParameter(f"{value!r}: {', '.join(bad)} {'is not a finite number' if len(bad) == 1 else 'are not finite numbers'}; "
                                 "allowed: three finite numbers (metres)")
    return tuple(parts)


def _pull(ctx, param, value):
    """A displacement vector no longer than the models are meant for (`MAX_PULL_M`)."""
    vec = _vector(ctx, param, value)
    if vec is not None and (problem := pull_problem(vec)) is not None:
        raise click.BadParameter(f"{value!r} {problem}")
    return vec


def _check_grasp(grasp, mesh) -> None:
    """Refuse a grasp point farther from the brain surface than the simulator's grasp reach
    (a button press that far away grasps nothing in a run)."""
    if grasp is None:
        return
    import numpy as np

    p = np.asarray(grasp, dtype=np.float64)
    dist = float(np.linalg.norm(mesh.vertices[mesh.nearest_vertex(p)] - p))
    reach = VisualStep.grasp_reach
    if dist > reach:
        ctx = click.get_current_context()
        param = next(q for q in ctx.command.params if q.name == "grasp")
        raise click.BadParameter(f"{','.join(f'{x:g}' for x in grasp)} is {dist * 1e3:.4g} mm from the brain surface; "
                                 f"allowed: within {reach * 1e3:g} mm of it (the simulator's grasp reach)", ctx, param)


@model.command("fem")
@click.option("--scene", "scene_file", type=click.Path(dir_okay=False, path_type=Path), default=DEFAULT_SCENE, show_default="protocols/scenes/brain_pull.toml")
@click.option("--resolution", type=float, default=None, help="Grid spacing in millimetres, 3..8 (default: the scene's, else 4).")
@click.option("--formulation", type=click.Choice(["linear", "corotational", "neo-hookean"]), default="linear", show_default=True)
@click.option("--grasp", required=True, callback=_vector, help=f"Grasp point X,Y,Z in metres, within the grasp reach ({VisualStep.grasp_reach * 1e3:g} mm) of the brain surface (snapped to it).")
@click.option("--displacement", required=True, callback=_pull, help=f"Displacement DX,DY,DZ of the grasp point in metres, at most {MAX_PULL_M:g} m long.")
@click.option("--steps", type=click.IntRange(1, 200), default=5, show_default=True, help="Load steps of the nonlinear solves.")
@click.option("--order", type=click.IntRange(1, 2), default=None, help="Element order: 1 linear, 2 quadratic tetrahedra (default: the scene's, else 1).")
@click.option("--json", "as_json", is_flag=True)
def model_fem(scene_file: Path, resolution, formulation: str, grasp, displacement, steps: int, order, as_json: bool):
    """Pull the brain once with the finite element model: force, displacement, phase times."""
    from sim.models.fem import static_pull
    from sim.scene import build_scene

    scene = build_scene(scene_file)
    _check_grasp(grasp, scene.mesh)
    out = static_pull(scene, grasp, displacement, None if resolution is None else resolution / 1e3, formulation, steps, order)
    if as_json:
        _print_json(out)
        _check_converged(out)
        return
    console = _console()
    f = out["force_n"]
    console.print(
        f"FEM ({out['formulation']}, {'quadratic' if out['order'] == 2 else 'linear'} tetrahedra, {out['resolution_mm']:g} mm: "
        f"{out['volume']['nodes']} corner nodes, {out['volume']['tets']} tetrahedra; "
        f"grasped hemisphere {out['part']['free_dofs']} unknowns)"
    )
    console.print(f"force on the hand: ({f[0]:.4g}, {f[1]:.4g}, {f[2]:.4g}) N, |F| = {out['force_magnitude_n']:.4g} N")
    console.print(f"largest displacement: {out['max_displacement_m'] * 1e3:.3f} mm")
    if out["locking"]:
        console.print("warning: the elements lock at this Poisson ratio (linear tetrahedra from 0.4, quadratic from 0.49): "
                      "forces are overestimated; try --order 2")
    if formulation != "linear":
        console.print(
            f"converged: {'yes' if out['converged'] else 'NO'}; iterations per load step {out['iterations']}; "
            f"final residuals {', '.join(f'{r:.1e}' for r in out['final_residuals'] if r is not None)}"
            + ("; inverted elements" if out["inverted_elements"] else "")
        )
        if out.get("completed_steps") is not None and out["completed_steps"] < out["load_steps"]:
            console.print(f"warning: the solve diverged after {out['completed_steps']} of {out['load_steps']} load steps; "
                          "the force and displacements above are those it reached, not the requested pull's")
    from rich.table import Table

    t = Table(title="phase times")
    t.add_column("phase")
    t.add_column("ms", justify="right")
    for k, v in out["times_ms"].items():
        t.add_row(k, f"{v:.4g}")
    console.print(t)
    _check_converged(out)


def _check_converged(out: dict) -> None:
    """A nonlinear solve that did not converge is a failure (exit status 1), not a result."""
    if out["converged"]:
        return
    n, done = out["load_steps"], out.get("completed_steps")
    where = f"diverged after {done} of {n} load steps" if done is not None and done < n else f"did not converge in {n} load step{'s' * (n != 1)}"
    raise click.ClickException(
        f"the {out['formulation']} solve {where}" + (" (elements inverted)" if out.get("inverted_elements") else "")
        + ": the force is not the requested pull's; try more --steps or a shorter --displacement"
    )


@model.command("mass-spring")
@click.option("--scene", "scene_file", type=click.Path(dir_okay=False, path_type=Path), default=DEFAULT_SCENE, show_default="protocols/scenes/brain_pull.toml")
@click.option("--resolution", type=float, default=None, help="Grid spacing in millimetres, 3..8 (default: the scene's).")
@click.option("--integrator", type=click.Choice(["explicit", "implicit", "local-global"]), required=True)
@click.option("--dt", type=Finite(min=0.0, min_open=True, max=0.1), required=True, help="Step in seconds, (0, 0.1].")
@click.option("--steps", type=click.IntRange(1, 1_000_000), default=100, show_default=True)
@click.option("--substep", is_flag=True, help="Split explicit steps above the critical step instead of refusing them.")
@click.option("--grasp", callback=_vector, default=None,
              help=f"Grasp point X,Y,Z in metres, within the grasp reach ({VisualStep.grasp_reach * 1e3:g} mm) of the brain surface (default: the scene's first hand).")
@click.option("--displacement", callback=_pull, default=None,
              help=f"Hand displacement DX,DY,DZ in metres, at most {MAX_PULL_M:g} m long (default: that hand's pull).")
@click.option("--json", "as_json", is_flag=True)
def model_mass_spring(scene_file, resolution, integrator, dt, steps, substep, grasp, displacement, as_json):
    """Hold a pull on the mass-spring brain and step it: stability, displacement, cost."""
    from sim.models.mass_spring import hold_pull
    from sim.scene import build_scene

    scene = build_scene(scene_file)
    _check_grasp(grasp, scene.mesh)
    out = hold_pull(scene, integrator, dt, steps, None if resolution is None else resolution / 1e3, substep, grasp, displacement)
    if as_json:
        _print_json(out)
        return
    console = _console()
    console.print(f"mass-spring ({out['nodes']} nodes, {out['springs']} springs), {integrator}, dt = {dt:g} s, {out['steps']} steps")
    console.print(f"critical_dt {out['critical_dt']:.4g} s with the coupling spring ({out['critical_dt_without_coupling']:.4g} s without)")
    if out["stable"]:
        f = out["force_on_hand_n"]
        console.print(f"stable; max displacement {out['max_displacement'] * 1e3:.3f} mm; force on the hand ({f[0]:.3g}, {f[1]:.3g}, {f[2]:.3g}) N")
    else:
        console.print(f"UNSTABLE (energy monitor) at t = {out['unstable_at']:.4g} s; no force is sent to a device")
    console.print(f"{out['ms_per_step']:.3f} ms per step" if out["ms_per_step"] is not None else "no step completed")


@cli.group(cls=_Group)
def calibrate():
    """Fit model parameters to a reference."""


@calibrate.command("plate-spring")
@click.option("--scene", "scene_file", type=click.Path(dir_okay=False, path_type=Path), default=DEFAULT_SCENE, show_default="protocols/scenes/brain_pull.toml")
@click.option("--reference", default="fem", show_default=True, help="fem (the scene's FEM) or a CSV with displacement_m, force_n.")
@click.option("--formulation", type=click.Choice(["neo-hookean", "linear"]), default="neo-hookean", show_default=True, help="FEM reference formulation.")
@click.option("--resolution", type=click.FloatRange(2, 8), default=3.0, show_default=True, help="FEM reference mesh spacing, mm (2 mm: about 8 min and 5 GB per pull the first time).")
@click.option("--max-displacement", type=click.FloatRange(min=0.001, max=0.1), default=0.024, show_default=True, help="m, the longest pull.")
@click.option("--samples", type=click.IntRange(3, 100), default=6, show_default=True, help="Points per pull.")
@click.option("--out", "out_file", type=OutFile((".toml",)), default=None, help="Write the fitted parameter file (.toml).")
@click.option("--json", "as_json", is_flag=True)
def calibrate_plate_spring(scene_file, reference, formulation, resolution, max_displacement, samples, out_file, as_json):
    """Fit h1, alpha, q and x_c1 (within their bounds) to the reference force-displacement curve."""
    import numpy as np

    from sim.calibrate import fem_curve, fit, read_curve, to_toml
    from sim.scene import load_scene

    spec = load_scene(scene_file)
    ps = spec.model_spec("plate_spring")
    if reference == "fem":
        xs, forces = fem_curve(scene_file, max_displacement * np.arange(1, samples + 1) / samples, formulation, resolution / 1000)
        reference = f"fem ({formulation}, {resolution:g} mm, the scene's {len(spec.hands)} scripted pulls)"
    else:
        xs, forces = read_curve(reference)
    params, rep = fit(ps.plate_spring, xs, forces, ps.variant)
    if out_file:
        Path(out_file).write_text(to_toml(params, f"Plate-spring parameters fitted by `studyctl calibrate plate-spring` to {reference}\n"
                                                  f"({rep['points']} points up to {xs.max() * 1e3:.0f} mm; {rep['within_jnd']:.0%} within the force JND)"))
    if as_json:
        _print_json(rep | {"reference": reference, "out": str(out_file) if out_file else None})
        return
    f = rep["fitted"]
    click.echo(f"fitted to {reference}: h1 {f['h1']:.5g} m, alpha {f['alpha']:.4g}, q {f['q']:.4g}, x_c1 {f['x_c1']:.5g} m")
    click.echo(f"{rep['within_jnd']:.0%} of {rep['points']} points within the force JND; worst {rep['max_jnd_units']:.2f} JND, rms {rep['rms_jnd_units']:.2f} JND")
    if out_file:
        click.echo(f"wrote {out_file}")


@calibrate.command("field")
@click.option("--scene", "scene_file", type=click.Path(dir_okay=False, path_type=Path), default=DEFAULT_SCENE, show_default="protocols/scenes/brain_pull.toml")
@click.option("--out", "out_file", type=OutFile((".npz",)), default=None, show_default="data/plate_spring_field.npz", help="The stiffness field.")
@click.option("--params-out", type=OutFile((".toml",)), default=None, help="Also write the located stack's curve here.")
@click.option("--formulation", type=click.Choice(["linear", "neo-hookean"]), default="linear", show_default=True,
              help="The curve: straight (the bench's linear reference) or fitted to the neo-Hookean / linear ratio of the calibration pulls.")
@click.option("--json", "as_json", is_flag=True)
def calibrate_field(scene_file, out_file, params_out, formulation, as_json):
    """The location-aware plate-spring's stiffness field: the reference's 3 x 3 grasp stiffness
    at the ico4 sites of both hemispheres (P2, 8 mm body-fitted mesh, area-mean grasp),
    interpolated to every vertex; with --params-out, the stack's curve too."""
    from analysis import field
    from analysis.accuracy import AccuracyConfig, sample_displacements
    from sim.calibrate import to_toml
    from sim.scene import load_scene

    rep = _with_progress("stiffness field sites", lambda p: field.build_field(scene_file, out_file or field.FIELD_FILE, progress=p))
    if params_out:
        start = load_scene(scene_file).model_spec("plate_spring").plate_spring
        xs = sample_displacements(AccuracyConfig())
        params, fit_rep = field.fit_shape(scene_file, start, xs, formulation)
        how = ("a one-layer stack: a straight curve, so the force is E K(v) d, as the bench's linear reference" if formulation == "linear" else
               f"fitted to the neo-Hookean / linear force ratio ({', '.join(f'{r:.3f}' for r in fit_rep['nonlinear_over_linear'])})\n"
               f"of the calibration pulls {', '.join(fit_rep['pulls'])} on the field's 8 mm P2 mesh; {fit_rep['within_jnd']:.0%} within the JND")
        Path(params_out).write_text(to_toml(params, (
            "Plate-spring stack for the location-aware model (variant \"located\"): only the curve's shape matters,\n"
            "the stiffness field (data/plate_spring_field.npz) sets its size and direction at each vertex.\n"
            f"Written by `studyctl calibrate field --params-out FILE --formulation {formulation}`:\n{how}.")))
        rep |= {"params_out": str(params_out), "shape_fit": fit_rep}
    if as_json:
        _print_json(rep)
        return
    click.echo(f"wrote {rep['path']}: {rep['sites']} sites, {rep['vertices']} vertices ({rep['seconds']:.0f} s)")
    if params_out:
        click.echo(f"wrote {params_out} ({formulation} curve)")


def _vertex_ids(ctx, param, value):
    if value is None:
        return None
    try:
        ids = [int(x) for x in value.split(",") if x.strip()]
    except ValueError:
        raise click.BadParameter(f"{value!r} is not a comma-separated list of surface vertex ids") from None
    if not ids or not all(0 <= v < 2**31 for v in ids):
        raise click.BadParameter(f"{value!r}: surface vertex ids are whole numbers from 0")
    return ids


@calibrate.command("rig")
@click.option("--db", envvar="STUDYCTL_DB", show_envvar=True, default=None, type=click.Path(dir_okay=False, path_type=Path),
              help="The study whose conditions are measured and which keeps the profile.")
@click.option("--protocol", "protocol_file", type=click.Path(dir_okay=False, path_type=Path), default=None,
              help="Measure this protocol's conditions without a study (with --out).")
@click.option("--trials", type=click.IntRange(1, 20), default=2, show_default=True, help="Lockstep trials per condition.")
@click.option("--profile", "profile_file", type=click.Path(dir_okay=False, path_type=Path), default=None,
              help="Keep this profile (from `calibrate rig --out` on the rig) with the study instead of measuring here.")
@click.option("--out", "out_file", type=OutFile((".json",)), default=None, help="Also write the profile as JSON.")
@click.option("--json", "as_json", is_flag=True)
def calibrate_rig(db, protocol_file, trials, profile_file, out_file, as_json):
    """Each condition's deformation time per frame on this machine (the rig), kept with the
    study: its synthetic participants perceive these as latency (studyctl/rig.py)."""
    from studyctl.protocol import load_protocol
    from studyctl.rig import measure, read_profile, store_profile

    if (db is None) == (protocol_file is None):
        raise InputError("name the study (--db) or, to write a profile only, a protocol (--protocol with --out)")
    if protocol_file is not None and (out_file is None or profile_file is not None):
        raise InputError("--protocol: measures without a study, so it needs --out (and no --profile)")
    if db is not None:
        from studyctl.store import Store

        store = Store(db, mode="read")
        try:
            protocol = store.protocol()
        finally:
            store.close()
    else:
        protocol = load_protocol(protocol_file)
    if profile_file is not None:
        profile, source = read_profile(profile_file), f"file {profile_file.name}"
    else:
        profile, source = _with_progress("rig trials", lambda p: measure(protocol, trials, progress=p)), "measured"
    if out_file is not None:
        Path(out_file).write_text(json.dumps(profile, indent=2) + "\n")
    if db is not None:
        store_profile(db, profile, source)
    if as_json:
        _print_json(profile | {"source": source})
        return
    for r in profile["conditions"]:
        click.echo(f"{r.get('condition', r['key'][:12])}: {r['frame_ms_p50']:.3f} ms per frame (p95 {r['frame_ms_p95']:.3f})")
    click.echo(f"rig: {profile.get('machine', 'unknown')}" + (f"; kept with {db}" if db else "") + (f"; wrote {out_file}" if out_file else ""))


@calibrate.command("truth")
@click.option("--scene", "scene_file", type=click.Path(dir_okay=False, path_type=Path), default=DEFAULT_SCENE, show_default="protocols/scenes/brain_pull.toml")
@click.option("--vertices", default=None, callback=_vertex_ids, help="Surface vertex ids, e.g. 3386,13629  [default: within 10 mm of the scene's hands]")
@click.option("--out", "out_file", type=OutFile((".npz",)), default=None, help="[default: the cache folder, where sessions find it]")
@click.option("--json", "as_json", is_flag=True)
def calibrate_truth(scene_file, vertices, out_file, as_json):
    """The synthetic observer's truth at grasp places: the converged P2 reference's grasp
    stiffness (body-fitted 8 / 5.5 / 4 mm meshes, Richardson). Needed for a scene, or grasp
    places, that the shipped table (data/observer_truth.npz) does not cover."""
    from analysis.truth import build_truth

    rep = build_truth(scene_file, out_file, vertices, progress=None if as_json else click.echo)
    if as_json:
        _print_json(rep)
        return
    click.echo(f"wrote {rep['out']}: {rep['vertices']} grasp places ({rep['seconds']:.0f} s); GCI median {rep['gci_median']:.1%}, "
               f"max {rep['gci_max']:.1%}")


def _print_solution(out: dict) -> None:
    from rich.table import Table

    t = Table(title=f"Plate-spring stack under F = {out['force']:.6g} N ({out['variant']})")
    t.add_column("layer", justify="right")
    t.add_column("deformation (m)", justify="right")
    for i, x in enumerate(out["layer_deformation"], start=1):
        t.add_row(str(i) + (" (DCL)" if i == out["dcl"] else ""), f"{x:.6g}")
    console = _console()
    console.print(t)
    console.print(
        f"X = {out['deformation']:.6g} m, DCL = layer {out['dcl']}, per-plate deformation {out['plate_deformation']:.6g} m, "
        f"overstretched: {'yes' if out['overstretched'] else 'no'}, saturated: {'yes' if out['saturated'] else 'no'}"
    )


def _print_layer_table(table: dict) -> None:
    from rich.table import Table

    t = Table(title=f"Plate-spring layers ({table['variant']})")
    for col in ("layer", "plates", "L (m)", "H (m)", "P (N/m)", "Pc (N/m)", "F consumed (N)", "starts at F (N)", "starts at X (m)", "T_i (ms)"):
        t.add_column(col, justify="right")
    for r in table["layers"]:
        t.add_row(
            str(r["layer"]), str(r["plates"]), f"{r['length_m']:.4g}", f"{r['thickness_m']:.4g}",
            f"{r['stiffness_n_per_m']:.4g}", f"{r['corrected_stiffness_n_per_m']:.4g}", f"{r['consumed_force_n']:.4g}",
            f"{r['start_force_n']:.4g}", f"{r['start_deformation_m']:.4g}",
            f"{r['cumulative_delay_s'] * 1e3:.3g}" + ("" if r["fits_haptic_period"] else " (over)"),
        )
    console = _console()
    console.print(t)
    if table["jumps"]:
        for j in table["jumps"]:
            console.print(
                f"jump at layer {j['layer']} -> {j['layer'] + 1}: X(F) jumps {j['kind']} by {abs(j['size']):.4g} m "
                f"at F = {j['force']:.4g} N"
            )
    else:
        console.print("X(F) is continuous: no jumps at layer transitions")
    cap = table["capacity"]
    console.print(
        f"capacity: X = {cap['deformation']:.4g} m at F = {cap['force']:.4g} N; "
        f"layers within the 1 ms haptic period: {table['delay_budget']['layers_in_budget']} of {len(table['layers'])}"
    )


# -- sim -----------------------------------------------------------------------------------


@cli.group(cls=_Group)
def sim():
    """Run scenes on the simulator."""


@sim.command("run")
@click.option("--scene", "scene_file", type=click.Path(dir_okay=False, path_type=Path), default=DEFAULT_SCENE, show_default="protocols/scenes/brain_pull.toml")
@click.option("--model", "model_name", default=None, callback=lambda c, p, v: _model_name(v),
              help="A model configured in the scene, e.g. plate_spring or plate-spring  [default: the scene's]")
@click.option("--duration", type=Finite(min=0.0, min_open=True, max=MAX_DURATION_S), default=None, help="Simulated seconds (default: the scene's).")
@click.option("--frames", "frames_dir", type=OutDir(), default=None, help="Write pictures, the force plot and the trace here.")
@click.option("--time-scale", type=Finite(min=0.0, max=1000.0), default=1.0, show_default=True, help="1 = real time; 0 = as fast as possible (lockstep, deterministic).")
@click.option("--view", type=click.Choice(["none", "offscreen", "window"]), default=None,
              help="window: draw the run live in the participant view; offscreen: pictures after the run (--frames); default: the scene's renderer.")
@click.option("--screenshot", type=OutFile((".png",)), default=None, help="With --view window: save the last frame shown (PNG).")
@FULLSCREEN
@click.option("--json", "as_json", is_flag=True, help="Machine-readable statistics.")
def sim_run(scene_file: Path, model_name, duration, frames_dir, time_scale: float, view, screenshot, fullscreen, as_json: bool):
    """Scripted simulated Omni hands grasp and pull the brain; the servo loop runs at 1 kHz."""
    from sim.run import run_scene, write_outputs
    from sim.scene import build_scene

    scene = build_scene(scene_file, model_name)
    view = view or scene.spec.renderer.kind
    if screenshot is not None and view != "window":
        raise click.UsageError("--screenshot needs --view window")
    if fullscreen and view != "window":
        raise click.UsageError("--fullscreen needs --view window")
    if view == "window":
        from sim.live import run_view

        result = run_view(scene, "window", duration=duration, time_scale=time_scale, screenshot=screenshot,
                          snapshots=frames_dir is not None and scene.spec.renderer.kind == "offscreen", fullscreen=fullscreen)
    else:
        result = run_scene(scene, duration=duration, time_scale=time_scale, snapshots=frames_dir is not None and view == "offscreen")
    stats = result.stats()
    if frames_dir is not None:
        if as_json:
            stats["frames"] = write_outputs(result, scene, frames_dir)
        else:
            from rich.progress import Progress

            with Progress(transient=True) as progress:
                task = progress.add_task("rendering frames", total=max(len(result.snapshots), 1))
                stats["frames"] = write_outputs(result, scene, frames_dir, progress=lambda k, n: progress.update(task, completed=k))
        stats["frames_dir"] = str(frames_dir)
    if screenshot is not None:
        stats["screenshot"] = str(screenshot)
    if as_json:
        _print_json(stats)
    else:
        _print_run(stats)


@sim.command("live")
@click.option("--scene", "scene_file", type=click.Path(dir_okay=False, path_type=Path), default=DEFAULT_SCENE, show_default="protocols/scenes/brain_pull.toml")
@click.option("--model", "model_name", default=None, callback=lambda c, p, v: _model_name(v),
              help="A model configured in the scene, e.g. plate_spring or plate-spring  [default: the scene's]")
@click.option("--device", type=click.Choice(["mouse", "simulated", "openhaptics"]), default="mouse", show_default=True)
@click.option("--duration", type=Finite(min=0.0, min_open=True, max=MAX_DURATION_S), default=600.0, show_default=True, help="Seconds at most; Q, Escape or closing the window ends it sooner.")
@click.option("--screenshot", type=OutFile((".png",)), default=None, help="Save the last frame shown (PNG).")
@FULLSCREEN
@DEVICES
@click.option("--json", "as_json", is_flag=True, help="Machine-readable statistics.")
def sim_live(scene_file: Path, model_name, device, duration, screenshot, fullscreen, device_names, as_json: bool):
    """Open the participant view and pull the brain (mouse: grasp under the cursor, drag, wheel)."""
    from sim.live import run_view
    from sim.scene import build_scene

    scene = build_scene(scene_file, model_name).with_device(device)
    scene.device_names = device_names
    result = run_view(scene, "window", duration=duration, screenshot=screenshot, live=True, fullscreen=fullscreen)
    stats = result.stats()
    if as_json:
        _print_json(stats)
    else:
        _print_run(stats)


def _print_run(s: dict) -> None:
    from rich.table import Table

    def us(d, k):
        return "-" if d.get(k) is None else f"{d[k]:.0f}"

    t = Table(title=f"{s['scene']}: {s['model']}, {s['duration_s']:g} s ({s['mode']})")
    t.add_column("measure")
    t.add_column("value", justify="right")
    t.add_row("servo ticks", f"{s['ticks']} at {s['rate_hz']:.0f} Hz")
    iv = s["tick_interval_us"]
    t.add_row("tick interval p50 / p99 / max (us)", f"{us(iv, 'p50')} / {us(iv, 'p99')} / {us(iv, 'max')}")
    tc = s["tick_compute_us"]
    t.add_row("tick compute p50 / p99 (us)", f"{us(tc, 'p50')} / {us(tc, 'p99')}")
    rf = s["read_to_force_us"]
    t.add_row("device read to force out p50 / p99 (us)", f"{us(rf, 'p50')} / {us(rf, 'p99')}")
    t.add_row("deadline misses", str(s["deadline_misses"]))
    dm = s["deformation_ms"]
    t.add_row("deformation per frame p50 / p99 (ms)", "-" if dm["p50"] is None else f"{dm['p50']:.3f} / {dm['p99']:.3f}")
    for name, f in s["max_force_per_hand_n"].items():
        t.add_row(f"max force, {name} hand (N)", f"{f:.3f}")
    t.add_row("events", ", ".join(f"{k} {v}" for k, v in sorted(s["events"].items())) or "none")
    if "view" in s:
        v = s["view"]
        m2p = v["motion_to_photon_ms"]
        t.add_row("view: frames shown, fps", f"{v['frames_shown']}, {v['fps'] or 0:.1f}")
        t.add_row("view: motion to photon p50 / p99 (ms)", "-" if m2p["p50"] is None else f"{m2p['p50']:.1f} / {m2p['p99']:.1f}")
    if "frames_dir" in s:
        t.add_row("pictures", f"{s['frames']} in {s['frames_dir']}")
    _console().print(t)


@cli.group(cls=_Group)
def devices():
    """Real haptic devices (OpenHaptics): find them and check the rig before a session."""


@devices.command("list")
@DEVICES
@click.option("--json", "as_json", is_flag=True)
def devices_list(device_names, as_json):
    """Try the configured device names (and "Default Device"); say what the library reports."""
    from sim.devices.check import candidate_names, list_devices

    out = list_devices(candidate_names(device_names or ()))
    if as_json:
        _print_json(out)
        return
    from rich.table import Table

    t = Table(title="OpenHaptics devices")
    for c in ("name", "found", "peak / continuous force (N)", "calibration"):
        t.add_column(c)
    for d in out:
        t.add_row(d["name"], "yes" if d["found"] else f"no ({d['error']})",
                  f"{d['peak_force_n']:.2f} / {d['continuous_force_n']:.2f}" if d["found"] else "-", ", ".join(d.get("calibration", [])))
    _console().print(t)


@devices.command("check")
@click.option("--scene", "scene_file", type=click.Path(dir_okay=False, path_type=Path), default=DEFAULT_SCENE, show_default="protocols/scenes/brain_pull.toml")
@DEVICES
@click.option("--seconds", type=click.FloatRange(1.0, 600.0), default=5.0, show_default=True, help="How long to watch the styluses.")
@click.option("--view", type=click.Choice(["none", "window"]), default="none", show_default=True, help="window: show both styluses live.")
@click.option("--yes", is_flag=True, help="Apply the force pulse without asking.")
@FULLSCREEN
@click.option("--json", "as_json", is_flag=True)
def devices_check(scene_file, device_names, seconds, view, yes, fullscreen, as_json):
    """Calibration, both styluses live, buttons, a gentle force pulse: exit 1 with the fix if anything is wrong."""
    from sim.devices.check import check_rig
    from sim.scene import build_scene

    scene = build_scene(scene_file).with_device("openhaptics")
    scene.device_names = device_names
    shown = None
    if view == "window":
        from sim.view import open_view

        shown = open_view("window", scene, fullscreen=fullscreen)
    elif fullscreen:
        raise click.UsageError("--fullscreen needs --view window")
    try:
        confirm = (lambda q: True) if yes else (lambda q: click.confirm(q, default=False, err=True))
        report = check_rig(scene, seconds, view=shown, confirm=confirm, say=lambda m: click.echo(m, err=True))
    finally:
        if shown is not None:
            shown.close()
    if as_json:
        _print_json(report)
    else:
        for d in report["devices"]:
            click.echo(f"{d['name']}: " + ("not found" if not d["found"] else
                       f"calibrated {'yes' if d.get('calibrated') else 'no'}, moved {d.get('moved_mm', 0):.0f} mm, "
                       f"button {'seen' if d.get('button_seen') else 'not pressed'}, pulse {d.get('pulse_n', 0):.2f} N"))
    if report["problems"]:
        raise click.ClickException("; ".join(report["problems"]))


# -- study management ----------------------------------------------------------------------

DB = click.option("--db", envvar="STUDYCTL_DB", show_envvar=True, required=True, type=click.Path(dir_okay=False, path_type=Path),
                  help="Study database; required unless the STUDYCTL_DB environment variable names one.")
JSON = click.option("--json", "as_json", is_flag=True, help="Machine-readable output (JSON).")


@cli.group(cls=_Group)
def protocol():
    """Study protocol files."""


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
    click.echo(f"{file}: ok ({p.name}: {len(p.conditions)} conditions, {len(p.questions)} questions, "
               f"{p.trials_per_condition} trials per condition, target {p.target_participants} participants)")


@cli.group(cls=_Group)
def study():
    """Study databases."""


@study.command("init")
@click.option("--protocol", "protocol_file", type=click.Path(dir_okay=False, path_type=Path), default=None,
              show_default="the shipped protocols/brain_pull_2015.toml")
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


@cli.group(cls=_Group)
def participants():
    """Participants (pseudonymous codes)."""


DRY_RUN = click.option("--dry-run", is_flag=True, help="Check and show what would be done; write nothing.")


def _done(out: dict, text: str, as_json: bool = False) -> None:
    if as_json:
        _print_json(out)
        return
    click.echo(("dry run, nothing written: would have " if out.get("dry_run") else "") + text)


@participants.command("add")
@click.argument("code")
@click.option("--age", type=click.IntRange(0, 120), default=None)
@click.option("--name", default=None, help="Kept in a separate table that no export or report includes.")
@click.option("--contact", default=None, help="Kept in a separate table that no export or report includes.")
@click.option("--synthetic", is_flag=True, help="A SYNTHETIC participant (run only with `session run --synthetic`).")
@DB
@DRY_RUN
@JSON
def participants_add(code, age, name, contact, synthetic, db, dry_run, as_json):
    """Register a participant under a pseudonymous CODE."""
    from studyctl.study import add_participant

    out = add_participant(db, code, age, name, contact, synthetic=synthetic, dry_run=dry_run)
    _done(out, f"added {out['code']}" + (" (SYNTHETIC)" if synthetic else ""), as_json)


@participants.command("import")
@click.argument("csv_file", type=click.Path(dir_okay=False, path_type=Path))
@DB
@DRY_RUN
@JSON
def participants_import(csv_file, db, dry_run, as_json):
    """Register participants from a CSV (code, then optional age, name, contact): all or none.
    UTF-8 with or without BOM, ',' or ';' separated, headers in any case."""
    from studyctl.study import import_participants

    out = import_participants(db, csv_file, dry_run=dry_run)
    _done(out, f"imported {out['imported']} participants", as_json)


def _listing(rows: list[dict], as_json: bool, db, what: str, columns: list[str]) -> None:
    if as_json:
        _print_json(rows)
    elif not rows:
        click.echo(f"{db}: no {what} yet")
    else:
        _table(rows, f"{len(rows)} {what}", columns)


def _table(rows: list[dict], title: str, columns: list[str]) -> None:
    from rich.table import Table

    t = Table(title=title)
    for c in columns:
        t.add_column(c)
    for r in rows:
        t.add_row(*("-" if r[c] is None else str(r[c]) for c in columns))
    _console().print(t)


@participants.command("list")
@DB
@click.option("--json", "as_json", is_flag=True)
def participants_list(db, as_json):
    """Every participant (codes only, never names): kind, consent, slot, session, answers."""
    from studyctl.participants import list_participants

    _listing(list_participants(db), as_json, db, "participants", ["code", "kind", "age", "consent", "slot", "session", "answers", "withdrawn"])


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
    _done(out, f"withdrawn {code}: {out['sessions']} sessions and {out['answers']} answers {out['data']}"
          + (f", {out['traces']} trace files deleted" if out["traces"] else "") + "; contact details deleted", as_json)


@participants.command("contacts")
@DB
@click.option("--out", "out_file", required=True, type=OutFile((".csv",)), help="A new CSV file (never overwritten).")
@JSON
def participants_contacts(db, out_file, as_json):
    """EXPERIMENTER ONLY: names and contact details (the identifying table) to a CSV marked as such."""
    from studyctl.participants import export_contacts

    out = export_contacts(db, out_file)
    if as_json:
        _print_json(out)
        return
    click.echo(f"wrote {out['file']}: IDENTIFYING names and contacts of {out['participants']} participants (readable by you only)")


@cli.group("schedule", cls=_Group, invoke_without_command=True)
@click.option("--db", envvar="STUDYCTL_DB", show_envvar=True, type=click.Path(dir_okay=False, path_type=Path),
              help="Study database; required unless the STUDYCTL_DB environment variable names one.")
@click.option("--start", help="First day, YYYY-MM-DD (today or later).")
@click.option("--end", help="Last day, YYYY-MM-DD.")
@click.option("--hours", default="09:00-17:00", show_default=True)
@click.option("--session-minutes", type=click.IntRange(5, 480), default=45, show_default=True)
@click.option("--availability", type=click.Path(dir_okay=False, path_type=Path), default=None, help="CSV: code,date,start,end.")
@click.option("--ics", type=OutFile((".ics",)), default=None, help="Write an iCalendar file (.ics).")
@click.option("--json", "as_json", is_flag=True)
@DRY_RUN
@click.pass_context
def schedule_cmd(ctx, db, start, end, hours, session_minutes, availability, ics, as_json, dry_run):
    """Give each waiting participant a slot on the rig and a counterbalanced order
    (`schedule cancel CODE` frees a slot; scheduling again gives a new one)."""
    if ctx.invoked_subcommand is not None:
        return
    for name, value in (("--db", db), ("--start", start), ("--end", end)):
        if value is None:
            raise click.UsageError(f"Missing option '{name}'.")
    from studyctl.study import schedule_study

    rows = schedule_study(db, start, end, hours, session_minutes, availability, ics, dry_run=dry_run)
    if as_json:
        _print_json(rows)
        return
    from rich.table import Table

    with_slot = len([r for r in rows if r["slot_start"]])
    t = Table(title=("DRY RUN, nothing stored: " if dry_run else "") + f"Schedule ({with_slot} of {len(rows)} participants have a slot)")
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


@cli.command("status", cls=click.Command)
@DB
@click.option("--json", "as_json", is_flag=True)
def status_cmd(db, as_json):
    """Where the study stands: participants, sessions by state, progress to the target N, who is next."""
    from studyctl.participants import status

    out = status(db)
    if as_json:
        _print_json(out)
        return
    p, c = out["participants"], out["complete"]
    click.echo(f"{out['study']}: {c['persons']} of {out['target_participants']} people complete"
               + (f" (and {c['synthetic']} SYNTHETIC)" if c["synthetic"] else ""))
    click.echo(f"participants: {p['persons']} people ({p['consented']} consented, {p['withdrawn']} withdrawn), {p['synthetic']} synthetic")
    click.echo("sessions: " + (", ".join(f"{n} {k}" for k, n in sorted(out["sessions"].items())) or "none yet"))
    click.echo(f"answers: {out['answers']}")
    click.echo("next: " + ("; ".join(f"{r['code']} {r['slot_start'].replace('T', ' ')}" for r in out["next"]) or "nobody scheduled"))


@cli.group(cls=_Group)
def session():
    """Run sessions."""


@session.command("run")
@DB
@click.option("--participant", required=True)
@click.option("--device", type=click.Choice(["simulated", "mouse", "openhaptics"]), default="simulated", show_default=True,
              help="mouse: pilot a session without hardware (needs --view window).")
@click.option("--synthetic", is_flag=True, help="A synthetic participant answers (data labelled synthetic).")
@click.option("--resume", is_flag=True, help="Continue an interrupted session after its last committed trial.")
@click.option("--time-scale", type=Finite(min=0.0, max=1000.0), default=None, help="1 = real time (default for people); synthetic default 0 = as fast as possible.")
@click.option("--view", type=click.Choice(["none", "window"]), default=None,
              help="The participant view (default: window for a person in real time, else none).")
@click.option("--answers", "answer_with", type=click.Choice(["terminal", "window"]), default="terminal", show_default=True,
              help="Where a person answers the questionnaire (window: keys and the mouse; free text stays in the terminal).")
@click.option("--seed", type=int, default=None, help="A synthetic participant's seed  [default: 0; on --resume, the session's]")
@FULLSCREEN
@DEVICES
@JSON
def session_run(db, participant, device, synthetic, resume, time_scale, view, answer_with, seed, fullscreen, device_names, as_json):
    """Training, then each condition in the assigned order: trials, then the questionnaire."""
    from studyctl.session import run_session

    if view is None:
        view = "window" if not synthetic and (time_scale is None or time_scale > 0) else "none"
    if fullscreen and view != "window":
        raise click.UsageError("--fullscreen needs --view window")
    out = run_session(db, participant, device, synthetic, resume, time_scale, seed=seed, progress=lambda m: click.echo(m, err=True),
                      view=view, answer_with=answer_with, device_names=device_names, fullscreen=fullscreen)
    if as_json:
        _print_json(out)
        return
    click.echo(f"session {out['session']} of {out['participant']} complete: conditions {' > '.join(out['order'])}, {out['answers']} answers"
               + (" (SYNTHETIC)" if out["synthetic"] else ""))


@session.command("list")
@DB
@click.option("--json", "as_json", is_flag=True)
def session_list(db, as_json):
    """Every session: participant, state, device, person or synthetic, trials and answers."""
    from studyctl.participants import list_sessions

    _listing(list_sessions(db), as_json, db, "sessions", ["session", "code", "status", "device", "kind", "started_at", "finished_at", "trials", "answers"])


cli.add_command(_Group("sessions", commands={"list": session_list}, help="Alias: `sessions list` is `session list`.", hidden=True))


@cli.command("replay", cls=click.Command)
@DB
@click.option("--session", "session_id", type=click.IntRange(min=1), required=True)
@click.option("--trial", type=click.IntRange(min=1), required=True, help="The session's K-th trial, in the order run (1 = the first).")
@click.option("--view", type=click.Choice(["none", "window"]), default="none", show_default=True, help="window: play it back in real time.")
@click.option("--frames", "frames_dir", type=OutDir(), default=None, help="Write pictures, the force plot and the trace.")
@FULLSCREEN
@click.option("--json", "as_json", is_flag=True)
def replay_cmd(db, session_id, trial, view, frames_dir, fullscreen, as_json):
    """Play a stored trial back: its recorded hand motion through the same model and scene."""
    from studyctl.replay import replay_trial

    if fullscreen and view != "window":
        raise click.UsageError("--fullscreen needs --view window")
    out = replay_trial(db, session_id, trial, view=view, frames_dir=frames_dir, fullscreen=fullscreen)
    if as_json:
        _print_json(out)
        return
    from rich.table import Table

    t = Table(title=f"replay of session {session_id}, trial {trial} (condition {out['label']}, {out['model']})")
    t.add_column("measure")
    t.add_column("value", justify="right")
    t.add_row("ticks", str(out["ticks"]))
    t.add_row("mode", out["mode"])
    t.add_row("largest force difference from the recording (N)", "-" if out["max_force_difference_n"] is None else f"{out['max_force_difference_n']:.3g}")
    if frames_dir is not None:
        t.add_row("pictures", f"{out['frames']} in {frames_dir}")
    _console().print(t)


@cli.command("synth", cls=click.Command)
@DB
@click.option("--participants", type=click.IntRange(1, 1000), required=True, help="How many synthetic participants (1..1000).")
@click.option("--seed", type=int, default=0, show_default=True)
@click.option("--jobs", type=click.IntRange(1, 64), default=1, show_default=True, help="Sessions run in parallel processes.")
@click.option("--protocol", "protocol_file", type=click.Path(dir_okay=False, path_type=Path), default=None,
              help="Create the database for this protocol if it does not exist  [default: the shipped protocols/brain_pull_2015.toml]")
@JSON
def synth_cmd(db, participants, seed, jobs, protocol_file, as_json):
    """Run whole sessions with SYNTHETIC participants on the simulator (labelled synthetic)."""
    from studyctl.synthetic import run_synthetic_study

    out = _with_progress("synthetic sessions", lambda p: run_synthetic_study(db, participants, seed, jobs, protocol_file, progress=p))
    if as_json:
        _print_json(out | {"synthetic": True})
        return
    click.echo(f"ran {out['participants']} SYNTHETIC sessions (seed {seed}, {jobs} jobs) in {out['seconds']:.1f} s")


def _model_name(value):
    """Models are spelt plate_spring in files; plate-spring (the subcommand's spelling) is accepted too."""
    return None if value is None else value.replace("-", "_")


def _range(ctx, param, value):
    try:
        a, b = (int(x) for x in value.split("..")) if ".." in value else (int(value), int(value))
    except ValueError:
        raise click.BadParameter(f"{value!r} is not a number or a range such as 12..60") from None
    if not 3 <= a <= b <= 1000:
        raise click.BadParameter(f"{value!r}: need 3 <= from <= to <= 1000")
    return a, b


@cli.command("plan", cls=click.Command)
@click.option("--participants", "span", default=None, callback=lambda c, p, v: None if v is None else _range(c, p, v),
              help="N, or a range of N such as 12..60  [default: 12..60; with --null 35]")
@click.option("--step", type=click.IntRange(1, 100), default=6, show_default=True)
@click.option("--simulations", type=click.IntRange(10, 100000), default=200, show_default=True)
@click.option("--protocol", "protocol_file", type=click.Path(dir_okay=False, path_type=Path),
              default=DEFAULT_PROTOCOL, show_default="the shipped protocols/brain_pull_2015.toml")
@click.option("--seed", type=click.IntRange(0, 2**32 - 1), default=0, show_default=True)
@click.option("--pilots", type=click.IntRange(1, 50), default=4, show_default=True, help="Synthetic pilot runs per model.")
@click.option("--plot", "plot_file", type=OutFile((".png", ".svg", ".pdf")), default=None, help="Write the power curves (PNG, SVG or PDF).")
@click.option("--null", "null", is_flag=True, help="The observer's fairness test: one model under every label; false-positive rates.")
@click.option("--model", "null_model", default=None, help="With --null: the model to repeat  [default: the protocol's first condition]")
@click.option("--json", "as_json", is_flag=True)
def plan_cmd(span, step, simulations, protocol_file, seed, pilots, plot_file, null, null_model, as_json):
    """Monte Carlo power under the SYNTHETIC model, to choose N: of the protocol's primary
    analysis and of each question's test (Cochran's Q, Friedman, the multinomial); with --null,
    the false-positive rate of each when every condition is one model."""
    from analysis.kinds import primary
    from analysis.plan import plot_power, power_table
    from studyctl.protocol import load_protocol

    protocol = load_protocol(protocol_file)
    if null:
        ctx = click.get_current_context()
        for name, opt in (("step", "--step"), ("plot_file", "--plot")):
            if ctx.get_parameter_source(name) is not click.core.ParameterSource.DEFAULT:
                raise InputError(f"{opt}: not with --null (it reports false-positive rates at one N)")
        _plan_null(protocol, span, simulations, seed, pilots, null_model, as_json)
        return
    if null_model is not None:
        raise InputError("--model: only with --null")
    span = span or (12, 60)
    ns = list(range(span[0], span[1] + 1, step))
    table = _with_progress("simulated studies", lambda p: power_table(protocol, ns, simulations, seed, pilots, progress=p))
    if plot_file:
        plot_power(table, plot_file)
    if as_json:
        _print_json({"synthetic": True, "primary": primary(protocol), "rows": table.to_dict(orient="records")})
        return
    from rich.table import Table

    names = list(dict.fromkeys(table["item"]))
    wide = table.pivot(index="n", columns="item", values="power")[names]
    t = Table(title=f"SYNTHETIC power (p < 0.05), {simulations} simulated studies per N; primary: {primary(protocol)['text']}")
    t.add_column("N", justify="right")
    for q in names:
        t.add_column(q, justify="right")
    for n, row in wide.iterrows():
        t.add_row(str(n), *(f"{v:.2f}" for v in row))
    _console().print(t)
    if plot_file:
        click.echo(f"plot: {plot_file}")


def _plan_null(protocol, span, simulations, seed, pilots, model, as_json) -> None:
    from analysis.kinds import primary
    from analysis.plan import null_table

    if span is not None and span[0] != span[1]:
        raise InputError("--participants: with --null give one N (e.g. 35), not a range")
    if model is not None:
        model = _model_name(model)
        if model not in protocol.conditions:
            raise InputError(f"--model: {model!r} is not a condition of {protocol.name}; allowed: {', '.join(protocol.conditions)}")
    n = span[0] if span else 35
    table = _with_progress("simulated studies", lambda p: null_table(protocol, model, n, simulations, seed, pilots, progress=p))
    if as_json:
        _print_json({"synthetic": True, "null": True, "model": table["model"].iloc[0], "participants": n, "primary": primary(protocol),
                     "items": table[["item", "false_positive_rate", "mc_error", "simulations", "alpha"]].to_dict(orient="records")})
        return
    from rich.table import Table

    t = Table(title=f"SYNTHETIC null test: {table['model'].iloc[0]} under every label, N = {n}, {simulations} simulated studies")
    for c in ("question", "false-positive rate", "alpha", "Monte Carlo s.e."):
        t.add_column(c, justify="right" if c != "question" else "left")
    for _, r in table.iterrows():
        t.add_row(r["item"], f"{r['false_positive_rate']:.3f}", f"{r['alpha']:.2f}", f"{r['mc_error']:.3f}")
    _console().print(t)


@cli.group(cls=_Group)
def report():
    """Reports made from a study database."""


HOLM = click.option("--holm", "holm_scope", type=click.Choice(["family", "question"]), default="family", show_default=True,
                    help="Holm over every pairwise test of every question (family), or within each question.")


@report.command("table1")
@DB
@HOLM
@click.option("--format", "fmt", type=click.Choice(["md", "csv", "latex", "html", "json"]), default="md", show_default=True)
@click.option("--out", "out_file", type=OutFile(), default=None)
@click.option("--accuracy", "accuracy_file", type=click.Path(exists=True, dir_okay=False, path_type=Path), default=None,
              help="accuracy.json from `studyctl bench accuracy --out`: add its table (md, html) and Pareto plot (html).")
@click.option("--stability", "stability_file", type=click.Path(exists=True, dir_okay=False, path_type=Path), default=None,
              help="stability.json from `studyctl bench stability --out`: add its heat map and unstable cases (md, html).")
def report_table1(db, holm_scope, fmt, out_file, accuracy_file, stability_file):
    """The seed paper's Table 1 with Wilson intervals, Cochran's Q and deformation times
    (html: one self-contained file with the statistics and plots)."""
    from analysis import table1

    if _no_answers(db, fmt == "json"):
        return
    accuracy = _load_bench(accuracy_file, "accuracy", "rows") if accuracy_file else None
    stability = _load_bench(stability_file, "stability", "cases") if stability_file else None
    if fmt == "md":
        text = table1.markdown(db, holm_scope)
        if accuracy:
            from analysis.accuracy import markdown

            text += "\n## Model error against run time\n\n" + markdown(accuracy)
        if stability:
            from analysis.stability import markdown as stability_md

            text += "\n## Numerical stability\n\n" + stability_md(stability)
    elif fmt == "latex":
        from analysis.report import latex

        text = latex(db, holm_scope)
    elif fmt == "html":
        from analysis.report import html

        text = html(db, accuracy=accuracy, stability=stability, holm_scope=holm_scope)
    elif fmt == "csv":  # the flag and N travel with the table
        facts = table1.study_facts(db)
        text = table1.rates(db).assign(participants=facts["participants"], synthetic=facts["synthetic"]).to_csv(index=False)
    else:
        from analysis.stats import study_stats

        r, q = table1.rates(db), table1.cochran(db)
        text = json.dumps(jsonable({"facts": table1.study_facts(db), "rates": r.to_dict(orient="records"),
                                     "cochran": q.to_dict(orient="records"), "kinds": study_stats(db, r, q, holm_scope)["kinds"],
                                     "deformation": table1.deformation(db).to_dict(orient="records")}), indent=2)
    if out_file:
        Path(out_file).write_text(text)
        click.echo(f"wrote {out_file}")
    else:
        click.echo(text, nl=False)


def _no_answers(db, as_json: bool) -> bool:
    """An empty study: say so (exit 0) instead of tables of 0/0 and NaN; nothing is written."""
    from analysis.table1 import incomplete_text, study_facts

    facts = study_facts(db)
    if facts["participants"]:
        return False
    incomplete = facts["incomplete_participants"]
    message = "no answers yet" if not incomplete else "no participant has answered every question for every model yet"
    if as_json:
        _print_json({"facts": facts, "message": message})
        return True
    flag = "SYNTHETIC DATA. " if facts["synthetic"] else ""
    if facts["mixed_source_participants"]:
        flag += f"WARNING: {', '.join(facts['mixed_source_participants'])} answered both as a person and synthetically. "
    listed = "; incomplete: " + incomplete_text(facts) if incomplete else ""
    click.echo(f"{flag}{facts['study']}: {message}{listed}; nothing to report")
    return True


def _load_bench(path: Path, kind: str, key: str) -> dict:
    """A bench's JSON (`studyctl bench KIND --out DIR` writes DIR/KIND.json)."""
    try:
        data = json.loads(path.read_text())
    except (OSError, ValueError) as exc:
        raise click.ClickException(f"{path}: not a `studyctl bench {kind}` result ({exc})") from None
    if not isinstance(data, dict) or not {key, "meta"} <= set(data):
        raise click.ClickException(f"{path}: not a `studyctl bench {kind}` result (needs {key} and meta; write one with `studyctl bench {kind} --out DIR`)")
    return data


@report.command("plots")
@DB
@click.option("--out", "out_dir", required=True, type=OutDir(), help="A folder (made if missing) for the PNG and SVG files.")
@JSON
def report_plots(db, out_dir, as_json):
    """Rates with intervals, deformation times, and force traces against the converged reference (PNG and SVG)."""
    from analysis.report import write_plots

    if _no_answers(db, as_json):
        return
    files = write_plots(db, out_dir)
    if as_json:
        _print_json({"out": str(out_dir), "files": [str(f) for f in files]})
        return
    click.echo(f"wrote {len(files)} files to {out_dir}")


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
    from analysis.stats import study_stats
    from analysis.table1 import _gee_line, incomplete_text

    if _no_answers(db, as_json):
        return
    out = study_stats(db, holm_scope=holm_scope)
    if as_json:
        _print_json(out)
        return
    flag = " (SYNTHETIC DATA)" if out["facts"]["synthetic"] else ""
    click.echo(f"{out['facts']['study']}: N = {out['facts']['participants']}{flag}")
    from analysis.kinds import primary_line

    kinds = out["kinds"]
    click.echo(primary_line(out))
    for item, v in out["items"].items():
        pairs = ", ".join(f"{p['a']}-{p['b']} p_holm {p['p_holm']:.3g}" for p in v["pairs"])
        click.echo(f"{item}: Q = {v['cochran_q']:.2f}, p = {v['p_value']:.3g}; {pairs}")
    for item, v in kinds["ratings"].items():
        fr = v["friedman"]
        pairs = ", ".join(f"{p['a']}-{p['b']} p_holm {p['p_holm']:.3g}" for p in v["pairs"])
        friedman = (f"Friedman chi2 = {fr['statistic']:.2f}, p = {fr['p_value']:.3g}, W = {fr['kendall_w']:.2f}"
                    if fr["statistic"] == fr["statistic"] else "two conditions: the Wilcoxon pair is the test")
        click.echo(f"{item}: {friedman}; {pairs}")
    for v in kinds["scores"].values():
        t = v["mixed_model"]["model_test"]
        means = ", ".join(f"{m} {c['mean']:.1f}" for m, c in v["conditions"].items())
        test = (f"mixed model F({t['df']}, {t['df_denominator']}) = {t['f']:.2f}, p = {t['p_value_f']:.3g}" if t["f"] == t["f"]
                else "mixed model: not estimable (" + "; ".join(v["mixed_model"]["problems"] or ["no fit"]) + ")")
        click.echo(f"{v['label']}: {means}; {test}")
    for item, v in kinds["choices"].items():
        shares = ", ".join(f"{m} {s['count']}" for m, s in v["shares"].items())
        click.echo(f"{item}: {shares}; {v['overall']['test']} p = {v['overall']['p_value']:.3g}")
    if out["facts"]["incomplete_participants"]:
        click.echo("left out (incomplete): " + incomplete_text(out["facts"]))
    gee = _gee_line(out["gee"], kinds["primary"]["analysis"] == "logistic_gee")
    if gee and kinds["primary"]["analysis"] != "logistic_gee":  # the primary's own line is printed first
        click.echo(gee.replace("`", ""))
    for row in out["deformation"]["rows"]:
        click.echo(f"deformation time, {row['model']}: {row['mean_ms']:.2f} +- {row['sd_ms']:.2f} ms over {row['n_participants']} participants "
                   f"({out['deformation']['label']})")


@report.command("published")
@click.option("--table", "table_file", type=click.Path(dir_okay=False, path_type=Path), default=PAPER_TABLE,
              show_default="the seed paper's Table 1, data/paper_table1.csv")
@click.option("--json", "as_json", is_flag=True)
def report_published(table_file, as_json):
    """Check a published Table 1: printed rates against their counts, and what counts allow."""
    from analysis.stats import published

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


@cli.group(cls=_Group)
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
    from studyctl.study import import_answers

    out = import_answers(db, csv_file, dry_run=dry_run)
    _done(out, f"imported {out['imported']} answers", as_json)


@answers.command("correct")
@DB
@click.option("--participant", required=True)
@click.option("--model", default="", callback=lambda c, p, v: _model_name(v),
              help="The condition the answer is about, e.g. fem; left out for a question asked once at the end.")
@click.option("--item", required=True, help="The question's id, e.g. natural.")
@click.option("--trial", type=int, default=None, help="The trial (0-based) of a question asked after every trial.")
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


@cli.command("export", cls=click.Command)
@DB
@click.option("--format", "fmt", type=click.Choice(["csv", "parquet"]), default="csv", show_default=True)
@click.option("--out", "out_dir", required=True, type=OutDir(), help="A folder (made if missing) for one file per table.")
@JSON
def export_cmd(db, fmt, out_dir, as_json):
    """Export the pseudonymous tables (never the identifying one)."""
    from studyctl.study import export

    files = export(db, out_dir, fmt)
    if as_json:
        _print_json({"out": str(out_dir), "format": fmt, "files": [str(f) for f in files]})
        return
    click.echo(f"wrote {len(files)} files to {out_dir}")


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
