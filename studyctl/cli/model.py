"""`studyctl model`: inspect and exercise the tissue models (plate-spring, FEM, mass-spring)."""

from __future__ import annotations

import math
from pathlib import Path

import click

from sim.geometry.patch import GRASP_REACH_M, grasp_problem
from sim.models.base import MAX_PULL_M, pull_problem
from sim.scene import DEFAULT_SCENE
from studyctl.cli.common import (
    FORCE,
    Finite,
    OutDir,
    OutFile,
    _console,
    _Group,
    _print_json,
    say_replaced,
    staged,
    write_output,
)
from studyctl.outputs import output_format


@click.group(cls=_Group)
def model():
    """Inspect and exercise the tissue models."""


@model.command("list")
@click.option("--json", "as_json", is_flag=True, help="Machine-readable output.")
def model_list(as_json: bool):
    """The installed tissue models: built in, and registered by other packages under the
    entry-point group brainsim.models. A model that does not load is listed with the cause."""
    from sim.models.registry import describe_installed

    rows, problems = describe_installed()
    if as_json:
        _print_json({"models": rows, "problems": problems})
        return
    from rich.table import Table

    t = Table(title=f"{len(rows)} tissue models")
    for c in ("name", "from", "description", "stiffness scaling"):
        t.add_column(c)
    for r in rows:
        t.add_row(r["name"], r["source"], r["description"], "yes" if r["scales_stiffness"] else "no")
    _console().print(t)
    for p in problems:
        click.echo(f"not loaded: {p}")


@model.command("describe")
@click.argument("name")
@click.option("--json", "as_json", is_flag=True, help="Machine-readable output.")
def model_describe(name: str, as_json: bool):
    """A model's options (units, defaults, bounds), capabilities and where it comes from."""
    from sim.models.registry import describe

    out = describe(name)  # a model that does not load is one line (SimError)
    if as_json:
        _print_json(out)
        return
    from rich.markup import escape
    from rich.table import Table

    click.echo(f"{out['name']}: {out['description']}\nfrom {out['source']} ({out['class']}; model API {out['api_version']})")
    click.echo(f"capabilities: {', '.join(k for k, v in out['capabilities'].items() if v) or 'none beyond the contract'}")
    click.echo(f"material keys a condition may change: {', '.join(out['material_keys']) or 'none'}")
    t = Table(title=escape("options ([models.NAME] in a scene, [conditions.NAME] in a protocol)"))
    for c in ("option", "kind", "unit", "default", "allowed", "meaning"):
        t.add_column(c)
    for o in out["options"]:
        t.add_row(o["name"], o["kind"], o["unit"] or "-", "-" if o["default"] is None else repr(o["default"]), o["allowed"], o["doc"])
    _console().print(t)


@model.command("check")
@click.argument("name")
@click.option("--scene", "scene_file", type=click.Path(dir_okay=False, path_type=Path), default=DEFAULT_SCENE,
              show_default="protocols/scenes/brain_pull.toml", help="The scene the model runs in (its configuration of the model, else the model's defaults).")
@click.option("--quick", is_flag=True, help="The accuracy bench's small configuration (20 and 16 mm reference meshes, two test places).")
@click.option("--contract", "contract_only", is_flag=True, help="The contract and the budgets only (seconds): no stability sweep, no accuracy bench.")
@click.option("--json", "as_json", is_flag=True, help="The scorecard as JSON (default: Markdown).")
@click.option("--out", "out_file", type=OutFile(), default=None, help="Also write the scorecard here (.md or .json).")
@FORCE
def model_check(name: str, scene_file: Path, quick: bool, contract_only: bool, as_json: bool, out_file, force: bool):
    """A model's scorecard: the contract, its time budgets on this machine, the quick stability
    sweep and the accuracy bench against the tissue truth. Stages are reported on stderr as they
    start and end, with an estimate of the time left; Ctrl-C keeps the stages that finished.
    Exits 1 on a violation, 130 when interrupted."""
    import json

    from analysis.reports.model_check_report import scorecard_md
    from analysis.verification.model_check import CheckConfig, CheckInterrupted, check_model
    from sim.jsonable import jsonable
    from sim.models.registry import canonical, model_class

    model_class(name)  # a model that does not load is one line (naming it as typed), before any progress
    name = canonical(name)  # plate-spring is plate_spring
    # refused before the check runs; the scorecard's format is its name's (.md or .json)
    target = staged(out_file, force, inputs={"--scene": scene_file})
    card_format = output_format(out_file, None, ("md", "json"), "md", "model check")

    def emit(card):
        text = json.dumps(jsonable(card), indent=2) if as_json else scorecard_md(card)
        if target:  # whole or not at all: a second Ctrl-C while writing leaves no half card
            write_output(target, json.dumps(jsonable(card), indent=2) if card_format == "json" else scorecard_md(card))
        click.echo(text.rstrip("\n"))

    try:
        with _StageReport(4 if not contract_only else 2) as report:
            card = check_model(name, CheckConfig(scene=scene_file, quick=quick, contract_only=contract_only), progress=report)
    except CheckInterrupted as stop:
        emit(stop.card)
        click.echo(f"Error: model check {name}: {stop}; the scorecard above holds the stages that finished", err=True)
        raise SystemExit(130) from None
    emit(card)
    if card["violations"]:
        raise click.ClickException(f"model {name}: {len(card['violations'])} violation{'s' if len(card['violations']) > 1 else ''} "
                                   "of the model contract (see above)")


@model.command("wheel")
@click.argument("folder", type=click.Path(file_okay=False, exists=True, path_type=Path))
@click.option("--out", "out_dir", type=OutDir(), default=Path("dist"), show_default=True, help="The folder the wheel is written into.")
@FORCE
@click.option("--json", "as_json", is_flag=True, help="Machine-readable output (JSON).")
def model_wheel(folder: Path, out_dir: Path, force: bool, as_json: bool):
    """Build the wheel of a model package (FOLDER holds its pyproject.toml) with the standard
    library alone: offline, where pip cannot fetch setuptools. Install it into any venv with
    `pip install --no-deps WHEEL` (docs/models.md)."""
    from analysis.errors import InputError
    from studyctl.model_wheel import build_wheel

    try:
        out = build_wheel(folder, out_dir, force=force)
    except InputError as exc:
        raise click.ClickException(str(exc)) from None
    say_replaced(out)
    wheel = out.target
    if as_json:
        _print_json({"wheel": str(wheel), "bytes": wheel.stat().st_size})
        return
    click.echo(f"{wheel} ({wheel.stat().st_size / 1e3:.1f} kB)")


class _StageReport:
    """`model check`'s stages on stderr: a line as each starts and ends, a bar with the time
    left on the long ones, and the estimate of the whole once the budgets are measured."""

    def __init__(self, stages: int):
        from rich.console import Console

        self.console, self.stages, self.k, self.bar, self.task = Console(stderr=True, highlight=False), stages, 0, None, None

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self._stop_bar()

    def _stop_bar(self):
        if self.bar is not None:
            self.bar.stop()
            self.bar = None

    def start(self, key: str, title: str) -> None:
        self.k += 1
        self.title = title
        self.console.print(f"[{self.k}/{self.stages}] {title} ...", soft_wrap=True)

    def step(self, k: int, n: int) -> None:
        from rich.progress import (
            BarColumn,
            MofNCompleteColumn,
            Progress,
            TextColumn,
            TimeElapsedColumn,
            TimeRemainingColumn,
        )

        if not self.console.is_terminal:  # a log or a pipe gets the stage lines only
            return
        if self.bar is None:
            self.bar = Progress(TextColumn(f"      {self.title}"), BarColumn(), MofNCompleteColumn(), TimeElapsedColumn(),
                                TextColumn("left"), TimeRemainingColumn(), console=self.console, transient=True)
            self.bar.start()
            self.task = self.bar.add_task("", total=n)
        self.bar.update(self.task, completed=k, total=n)

    def end(self, key: str, seconds: float, result) -> None:
        from analysis.reports.model_check_report import stage_summary

        self._stop_bar()
        self.console.print(f"[{self.k}/{self.stages}] {self.title}: {stage_summary(key, result)} ({seconds:.1f} s)", soft_wrap=True)

    def estimate(self, est: dict) -> None:
        refs = (f", {est['reference_solves']} reference solves neither shipped nor cached (about {est['reference_solves_s']:.0f} s)"
                if est["reference_solves"] else ", the reference solves shipped or cached")
        self.console.print(f"      estimated from this model's measured costs: stability about {est['stability_s']:.0f} s "
                           f"({est['stability_cases']} cases, each with a build as long as the contract's), accuracy about {est['accuracy_s']:.0f} s ({est['pulls']} pulls{refs}); "
                           f"about {est['stability_s'] + est['accuracy_s']:.0f} s to go", soft_wrap=True)


@model.command("plate-spring")
@click.option("--params", "params_file", required=True, type=click.Path(dir_okay=False, path_type=Path), help="Parameter file (TOML, SI units).")
@click.option("--variant", type=click.Choice(["paper", "continuous"]), default="continuous", show_default=True, help="The plate-spring's variant: as printed (paper) or continuous.")
@click.option("--force", "force", type=Finite(), default=None, help="Tension F in newtons, >= 0: print the deformation.")
@click.option("--displacement", "displacement", type=Finite(min=0.0, max=MAX_PULL_M), default=None,
              help=f"Displacement X in metres, 0..{MAX_PULL_M:g} (the longest pull the tissue models are meant for): print the force.")
@click.option("--json", "as_json", is_flag=True, help="Machine-readable output.")
def model_plate_spring(params_file: Path, variant: str, force, displacement, as_json: bool):
    """The paper's plate-spring model: layer table, X(F), or its inverse F(X).

    Without --force or --displacement it prints the layer table, the jumps of X(F) and the
    delay budget.
    """
    from sim.models.plate_spring import HAPTIC_PERIOD_S, PlateSpring, load_params

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
        "delay_budget": {"period_s": HAPTIC_PERIOD_S, "layers_in_budget": stack.layers_in_budget()},
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
    if (problem := grasp_problem(mesh, grasp)) is not None:
        ctx = click.get_current_context()
        raise click.BadParameter(problem, ctx, next(q for q in ctx.command.params if q.name == "grasp"))


@model.command("fem")
@click.option("--scene", "scene_file", type=click.Path(dir_okay=False, path_type=Path), default=DEFAULT_SCENE, show_default="protocols/scenes/brain_pull.toml", help="The scene file (TOML).")
@click.option("--resolution", type=float, default=None, help="Target edge of the body-fitted mesh in millimetres, 3..8 (default: the scene's, else 8; 8, 6 and 4 are shipped).")
@click.option("--formulation", type=click.Choice(["linear", "corotational", "finite-strain", "nodal-pressure"]), default="linear", show_default=True,
              help="finite-strain: the scene's material law (docs/material.md), Newton along the pull; nodal-pressure: the same law "
                   "on linear tetrahedra with averaged nodal volumes, which do not lock (docs/fem.md).")
@click.option("--grasp", required=True, callback=_vector, help=f"Grasp point X,Y,Z in metres, within the grasp reach ({GRASP_REACH_M * 1e3:g} mm) of the brain surface (snapped to it).")
@click.option("--displacement", required=True, callback=_pull, help=f"Displacement DX,DY,DZ of the grasp point in metres, at most {MAX_PULL_M:g} m long.")
@click.option("--steps", type=click.IntRange(1, 200), default=5, show_default=True,
              help="Load steps of the nonlinear solves (finite-strain: the first step is 1/steps of the pull, then adaptive).")
@click.option("--order", type=click.IntRange(1, 2), default=None, help="Element order: 1 linear, 2 quadratic tetrahedra (default: the scene's, else 2; 1 for --formulation corotational and nodal-pressure).")
@click.option("--json", "as_json", is_flag=True, help="Machine-readable output (JSON).")
def model_fem(scene_file: Path, resolution, formulation: str, grasp, displacement, steps: int, order, as_json: bool):
    """Pull the brain once with the finite element model: force, displacement, phase times."""
    from sim.models.fem import static_pull
    from sim.models.fem.linear import LOCKING_POISSON
    from sim.scene import build_scene

    scene = build_scene(scene_file)
    _check_grasp(grasp, scene.mesh)
    stretch_range, source = None, ""
    if formulation == "finite-strain":  # where the law was measured: from its material file's data
        from analysis.verification.material_fit import fitted_range

        law_source = scene.spec.material.law_source
        stretch_range, source = fitted_range(law_source) if law_source not in ("", "inline") else (None, "an inline law names no data")
    pull = static_pull(scene, grasp, displacement, None if resolution is None else resolution / 1e3, formulation, steps, order,
                       stretch_range=stretch_range)
    if as_json:
        extra = {}
        if formulation == "finite-strain":
            extra["support_data"] = source if stretch_range is not None else None
            if stretch_range is None:
                extra["support_unavailable"] = source
        _print_json(pull.as_dict() | extra)
        _check_converged(pull)
        return
    console = _console()
    f = pull.force_n
    console.print(
        f"FEM ({pull.formulation}, {'quadratic' if pull.order == 2 else 'linear'} tetrahedra, {pull.resolution_mm:g} mm: "
        f"{pull.volume['nodes']} corner nodes, {pull.volume['tets']} tetrahedra; "
        f"grasped hemisphere {pull.part['free_dofs']} unknowns)"
    )
    console.print(f"force on the hand: ({f[0]:.4g}, {f[1]:.4g}, {f[2]:.4g}) N, |F| = {pull.force_magnitude_n:.4g} N")
    console.print(f"largest displacement: {pull.max_displacement_m * 1e3:.3f} mm")
    if pull.locking:
        console.print(f"warning: the elements lock at this Poisson ratio (linear tetrahedra from {LOCKING_POISSON[1]:g}, quadratic from {LOCKING_POISSON[2]:g}): "
                      "forces are overestimated; try --order 2")
    if pull.solve is not None:
        s = pull.solve
        console.print(
            f"converged: {'yes' if s.converged else 'NO'}; iterations per load step {list(s.iterations)}; "
            f"final residuals {', '.join(f'{r:.1e}' for r in s.final_residuals if r is not None)}"
            + ("; inverted elements" if s.inverted_elements else "")
        )
        if not s.converged:
            console.print("warning: the solve stopped " + _stopped(s) + "; the force and displacements above are those it reached, "
                          "not the requested pull's")
        if s.support is not None:
            sup = s.support
            lo, hi = sup["stretch_range"]
            console.print(f"support: {sup['energy_share_outside']:.0%} of the stored energy at points with a principal stretch outside "
                          f"{lo:.3g}-{hi:.3g}, the range the law's data cover ({source}): that share rests on the "
                          f"law's extrapolation; principal stretches {sup['principal_stretch_min']:.3g}-{sup['principal_stretch_max']:.3g}, "
                          f"largest |J - 1| {sup['max_abs_j_minus_1']:.3g}")
        elif formulation == "finite-strain" and stretch_range is None and source:
            console.print(f"support: not computed ({source})")
    from rich.table import Table

    t = Table(title="phase times")
    t.add_column("phase")
    t.add_column("ms", justify="right")
    for k, v in pull.times_ms.items():
        t.add_row(k, f"{v:.4g}")
    console.print(t)
    _check_converged(pull)


def _check_converged(pull) -> None:
    """A nonlinear solve that did not converge is a failure (exit status 1), not a result."""
    if pull.converged:
        return
    raise click.ClickException(f"the {pull.formulation} solve stopped {_stopped(pull.solve)}: the force is not the requested pull's; "
                               "try more --steps or a shorter --displacement")


def _stopped(s) -> str:
    """Where a nonlinear solve (sim.models.fem.pull.SolveReport) stopped, and why."""
    frac, n, done = s.completed_fraction, s.load_steps, s.completed_steps
    if frac is not None:
        where = f"at {frac:.0%} of the pull after {done} load step{'s' * (done != 1)}"
    elif done is not None and done < n:
        where = f"after {done} of {n} load steps"
    else:
        where = f"without converging in {n} load step{'s' * (n != 1)}"
    why = s.reason or ("elements inverted" if s.inverted_elements else "")
    return where + (f" ({why})" if why else "")


@model.command("mass-spring")
@click.option("--scene", "scene_file", type=click.Path(dir_okay=False, path_type=Path), default=DEFAULT_SCENE, show_default="protocols/scenes/brain_pull.toml", help="The scene file (TOML).")
@click.option("--resolution", type=float, default=None, help="Target edge of the body-fitted mesh in millimetres, 3..8 (default: the scene's).")
@click.option("--integrator", type=click.Choice(["explicit", "implicit", "local-global"]), required=True, help="The mass-spring's time integrator.")
@click.option("--dt", type=Finite(min=0.0, min_open=True, max=0.1), required=True, help="Step in seconds, (0, 0.1].")
@click.option("--steps", type=click.IntRange(1, 1_000_000), default=100, show_default=True, help="Visual frames to run.")
@click.option("--substep", is_flag=True, help="Split explicit steps above the critical step instead of refusing them.")
@click.option("--grasp", callback=_vector, default=None,
              help=f"Grasp point X,Y,Z in metres, within the grasp reach ({GRASP_REACH_M * 1e3:g} mm) of the brain surface (default: the scene's first hand).")
@click.option("--displacement", callback=_pull, default=None,
              help=f"Hand displacement DX,DY,DZ in metres, at most {MAX_PULL_M:g} m long (default: that hand's pull).")
@click.option("--json", "as_json", is_flag=True, help="Machine-readable output (JSON).")
def model_mass_spring(scene_file, resolution, integrator, dt, steps, substep, grasp, displacement, as_json):
    """Hold a pull on the mass-spring brain and step it: stability, displacement, cost."""
    from sim.models.mass_spring_pull import hold_pull
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
