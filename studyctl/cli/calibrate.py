"""`studyctl calibrate`: fit model parameters to a reference (plate-spring, stiffness field, the
rig's frame times, the synthetic observer's truth)."""

from __future__ import annotations

import json
from pathlib import Path

import click

from sim.scene import DEFAULT_SCENE
from studyctl.cli.common import OutFile, _Group, _print_json, _with_progress
from studyctl.errors import InputError


@click.group(cls=_Group)
def calibrate():
    """Fit model parameters to a reference."""


@calibrate.command("plate-spring")
@click.option("--scene", "scene_file", type=click.Path(dir_okay=False, path_type=Path), default=DEFAULT_SCENE, show_default="protocols/scenes/brain_pull.toml")
@click.option("--reference", default="converged", show_default=True,
              help="converged (the accuracy bench's reference on its calibration pulls) or a CSV with displacement_m, force_n.")
@click.option("--formulation", type=click.Choice(["linear", "neo-hookean"]), default="linear", show_default=True,
              help="The reference's formulation (neo-hookean: solved on the 8 mm mesh, about 2 minutes per pull the first time).")
@click.option("--max-displacement", type=click.FloatRange(min=0.001, max=0.1), default=0.024, show_default=True, help="m, the longest pull.")
@click.option("--samples", type=click.IntRange(3, 100), default=6, show_default=True, help="Points per pull.")
@click.option("--out", "out_file", type=OutFile((".toml",)), default=None, help="Write the fitted parameter file (.toml).")
@click.option("--json", "as_json", is_flag=True)
def calibrate_plate_spring(scene_file, reference, formulation, max_displacement, samples, out_file, as_json):
    """Fit h1, alpha, q and x_c1 (within their bounds) to the reference force-displacement curve."""
    import numpy as np

    from analysis.accuracy import calibration_curve
    from sim.calibrate import fit, read_curve, to_toml
    from sim.scene import load_scene
    from sim.tetmesh import SHIPPED_MM

    spec = load_scene(scene_file)
    ps = spec.model_spec("plate_spring")
    if reference == "converged":
        nonlinear = max(SHIPPED_MM) if formulation == "neo-hookean" else None
        xs, forces, reference = calibration_curve(scene_file, max_displacement * np.arange(1, samples + 1) / samples, nonlinear)
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
    from studyctl.store import Store

    if (db is None) == (protocol_file is None):
        raise InputError("name the study (--db) or, to write a profile only, a protocol (--protocol with --out)")
    if protocol_file is not None and (out_file is None or profile_file is not None):
        raise InputError("--protocol: measures without a study, so it needs --out (and no --profile)")
    if db is not None:
        with Store(db, mode="read") as store:
            protocol = store.protocol()
    else:
        protocol = load_protocol(protocol_file)
    if profile_file is not None:
        profile, source = read_profile(profile_file), f"file {profile_file.name}"
    else:
        profile, source = _with_progress("rig trials", lambda p: measure(protocol, trials, progress=p)), "measured"
    if out_file is not None:
        Path(out_file).write_text(json.dumps(profile, indent=2) + "\n")
    if db is not None:  # opened for writing after the measuring, as before: a study that cannot be written still gets --out
        with Store(db) as store:
            store_profile(store, profile, source)
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
    stiffness (the shipped body-fitted 8 / 6 / 4 mm meshes, Richardson). Needed for a scene, or grasp
    places, that the shipped table (data/observer_truth.npz) does not cover."""
    from analysis.truth import build_truth

    rep = build_truth(scene_file, out_file, vertices, progress=None if as_json else click.echo)
    if as_json:
        _print_json(rep)
        return
    click.echo(f"wrote {rep['out']}: {rep['vertices']} grasp places ({rep['seconds']:.0f} s); GCI median {rep['gci_median']:.1%}, "
               f"max {rep['gci_max']:.1%}")
