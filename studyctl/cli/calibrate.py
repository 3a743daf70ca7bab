"""`studyctl calibrate`: fit model parameters to a reference (plate-spring, stiffness field, the
rig's frame times, the synthetic observer's truth)."""

from __future__ import annotations

import json
from pathlib import Path

import click

from analysis.errors import InputError
from sim.scene import DEFAULT_SCENE
from studyctl.cli.common import (
    FORCE,
    Finite,
    OutFile,
    _command_line,
    _console,
    _Group,
    _print_json,
    _with_progress,
    say_replaced,
    staged,
    write_output,
)
from studyctl.outputs import refuse_overlap


@click.group(cls=_Group)
def calibrate():
    """Fit model parameters to a reference."""


@calibrate.command("plate-spring")
@click.option("--scene", "scene_file", type=click.Path(dir_okay=False, path_type=Path), default=DEFAULT_SCENE, show_default="protocols/scenes/brain_pull.toml", help="The scene file (TOML).")
@click.option("--reference", default="converged", show_default=True,
              help="converged (the accuracy bench's reference on its calibration pulls) or a CSV with displacement_m, force_n.")
@click.option("--max-displacement", type=click.FloatRange(min=0.001, max=0.1), default=0.012, show_default=True, help="m, the longest pull.")
@click.option("--samples", type=click.IntRange(3, 100), default=24, show_default=True,
              help="Points per pull (the converged reference: only where the truth is decided).")
@click.option("--out", "out_file", type=OutFile((".toml",)), default=None, help="Write the fitted parameter file (.toml).")
@FORCE
@click.option("--json", "as_json", is_flag=True, help="Machine-readable output (JSON).")
def calibrate_plate_spring(scene_file, reference, max_displacement, samples, out_file, force, as_json):
    """Fit h1, alpha, q and x_c1 (within their bounds) to the reference force-displacement curve."""
    import numpy as np

    from analysis.verification.accuracy import calibration_curve
    from sim.calibrate import fit, read_curve, to_toml
    from sim.scene import load_scene

    inputs = {"--scene": scene_file, "--reference": None if reference == "converged" else Path(reference)}
    target = staged(out_file, force, inputs=inputs)  # refused before the fit
    spec = load_scene(scene_file)
    ps = spec.model_spec("plate_spring")
    if reference == "converged":
        xs, forces, reference = calibration_curve(scene_file, max_displacement * np.arange(1, samples + 1) / samples)
    else:
        xs, forces = read_curve(reference)
    params, rep = fit(ps.options["params"], xs, forces, ps.options["variant"])
    if target:
        write_output(target, to_toml(params, f"Plate-spring parameters fitted by `studyctl calibrate plate-spring` to {reference}\n"
                                             f"({rep['points']} points up to {xs.max() * 1e3:g} mm; {rep['within_jnd']:.0%} within the force JND)\n"
                                             f"Past {xs.max() * 1e3:g} mm no point is fitted: the stack's force there is the fit's extrapolation, not the reference's\n"
                                             "h1, alpha, q and x_c1 are fitted within their bounds; the rest as in the scene's file (E is the stack's own parameter, not the tissue's)"))
    if as_json:
        _print_json(rep | {"reference": reference, "out": str(out_file) if out_file else None})
        return
    f = rep["fitted"]
    click.echo(f"fitted to {reference}: h1 {f['h1']:.5g} m, alpha {f['alpha']:.4g}, q {f['q']:.4g}, x_c1 {f['x_c1']:.5g} m")
    click.echo(f"{rep['within_jnd']:.0%} of {rep['points']} points within the force JND; worst {rep['max_jnd_units']:.2f} JND, rms {rep['rms_jnd_units']:.2f} JND")
    if out_file:
        click.echo(f"wrote {out_file}")


@calibrate.command("material")
@click.option("--data", "data_files", type=click.Path(dir_okay=False, path_type=Path), multiple=True,
              show_default="data/brain_tissue_uniaxial_budday2017.csv",
              help="CSV of one loading mode, read from its columns: region, stretch, nominal_stress_kpa (uniaxial) or region, "
                   "shear_strain, shear_stress_kpa (simple shear; data/brain_tissue_shear_budday2017.csv). Repeat to fit the modes together.")
@click.option("--region", default="cortex", show_default=True, help="The data's region to fit.")
@click.option("--law", "laws", multiple=True, type=click.Choice(["neo-hookean", "mooney-rivlin", "ogden", "ogden-2"]),
              help="Laws to fit (repeat; default: all four).")
@click.option("--bulk-ratio", type=Finite(min=1.0, max=1e4), default=None, show_default="50", help="kappa / mu of the laws.")
@click.option("--out", "out_file", type=OutFile((".toml",)), default=None, help="Write the chosen law as a material file (.toml).")
@FORCE
@click.option("--json", "as_json", is_flag=True, help="Machine-readable output (JSON).")
@click.pass_context
def calibrate_material(ctx, data_files, region, laws, bulk_ratio, out_file, force, as_json):
    """Fit finite-strain laws to tissue data (uniaxial tension and compression, simple shear: each
    file's mode read from its columns, several fitted together), report each mode's error and
    each mode's error when left out of the fit, and choose one law by AICc (docs/material.md)."""
    from analysis.verification.material_fit import DATA_FILE, FIT_LAWS, chosen_material, fit_material
    from sim.hyperelastic import BULK_RATIO
    from sim.material import material_toml

    target = staged(out_file, force, inputs={"--data": list(data_files)})  # refused before the fit
    command = _command_line(ctx)  # the provenance: this command as run
    data_files = list(data_files) or [DATA_FILE]
    laws = laws or FIT_LAWS
    rep = _with_progress(f"fitting {len(laws)} law{'s' if len(laws) != 1 else ''}",
                         lambda p: fit_material(data_files, region, laws, BULK_RATIO if bulk_ratio is None else bulk_ratio, progress=p),
                         stage=lambda k, n: f"calibrate material: fitting {laws[k]} (law {k + 1} of {n})")
    for f in rep["files"]:  # on stderr: a --json document stays clean
        if f["duplicates_merged"]:
            click.echo(f"warning: {f['path']}: {f['duplicates_merged']} row{'s' if f['duplicates_merged'] != 1 else ''} of region "
                       f"{region} repeated an earlier row exactly (same strain and stress) and counted once; "
                       f"{f['points']} points fitted", err=True)
    if out_file:
        law, prov = chosen_material(rep, region, command)
        write_output(target, material_toml(law, prov, f"{region}: {law.describe()}\nWritten by `{command}`."))
    if as_json:
        _print_json({k: v for k, v in rep.items()} | {"out": str(out_file) if out_file else None})
        return
    from rich.table import Table

    spans = "; ".join(f"{f['mode']} {f['points']} points, " + (f"stretch {f['stretch_range'][0]:g}..{f['stretch_range'][1]:g}"
                      if f["mode"] == "uniaxial" else f"shear strain {f['shear_strain_range'][0]:g}..{f['shear_strain_range'][1]:g}")
                      for f in rep["files"])
    modes = [m for m in ("tension", "compression", "shear") if f"rms_rel_{m}" in rep["laws"][0]]
    table = Table(title=f"{region}: {spans}")
    for col in ("law", "parameters [95% CI]", "RMS (rel.)", *modes, *(f"{m} left out" for m in modes if "left_out" in rep["laws"][0]),
                *(("worst shear 0.1-0.2",) if "shear" in modes else ()), "AICc", ""):
        table.add_column(col)
    for f in rep["laws"]:
        pars = "; ".join(f"{k} {v:.4g} [{f['ci95'][k][0]:.3g}, {f['ci95'][k][1]:.3g}]" for k, v in f["parameters"].items())
        note = "chosen" if f["law"] == rep["fit"] else ("" if f["identified"] else "not identified")
        table.add_row(f["law"], pars, f"{f['rms_rel']:.1%}", *(f"{f[f'rms_rel_{m}']:.1%}" for m in modes),
                      *(f"{f['left_out'][m]:.1%}" for m in modes if "left_out" in f),
                      *((f"{f['shear_worst_rel']:.1%}",) if "shear" in modes else ()), f"{f['aicc']:.1f}", note)
    _console().print(table)
    if rep["warning"]:
        click.echo(f"warning: {rep['warning']}")
    if out_file:
        click.echo(f"wrote {out_file}")


@calibrate.command("rheology")
@click.option("--data", "data_files", type=click.Path(dir_okay=False, path_type=Path), multiple=True,
              show_default="data/brain_tissue_uniaxial_budday2017.csv and data/brain_tissue_shear_budday2017.csv",
              help="CSV of one loading mode (as `calibrate material` reads them). Repeat to fit the modes together.")
@click.option("--region", default="cortex", show_default=True, help="The data's region to fit.")
@click.option("--mu-inf", type=Finite(min=1.0, max=1e9), required=True, help="Equilibrium shear modulus (Pa), published.")
@click.option("--mu-1", type=Finite(min=1.0, max=1e9), required=True, help="The Maxwell branch's shear modulus (Pa), published.")
@click.option("--tau-1", type=Finite(min=1e-4, max=1e5), required=True, help="The branch's relaxation time (s), published.")
@click.option("--bulk-modulus", type=Finite(min=1.0, max=1e12), required=True, help="kappa (Pa): the hyperelastic truth's, kept.")
@click.option("--alpha-start", type=Finite(min=-60.0, max=-0.5), default=-20.0, show_default=True, help="Where the exponent's fit starts.")
@click.option("--source", default="", help="The published parameters' source, for the file's provenance.")
@click.option("--out", "out_file", type=OutFile((".toml",)), default=None, help="Write the law as a rheology file (.toml).")
@FORCE
@click.option("--json", "as_json", is_flag=True, help="Machine-readable output (JSON).")
@click.pass_context
def calibrate_rheology(ctx, data_files, region, mu_inf, mu_1, tau_1, bulk_modulus, alpha_start, source, out_file, force, as_json):
    """Complete a finite viscoelastic law of published moduli and relaxation time (one Maxwell
    branch, sim/material.py (Viscoelastic)) with the exponent and the tests' loading rate that fit it to
    tissue curves measured at a finite rate; report each mode's error (docs/viscoelastic.md)."""
    from analysis.verification.material_fit import DATA_FILE, SHEAR_FILE
    from analysis.verification.rheology import fit_rheology, rheology_provenance
    from sim.material import rheology_toml

    target = staged(out_file, force, inputs={"--data": list(data_files)})
    command = _command_line(ctx)
    data_files = list(data_files) or [DATA_FILE, SHEAR_FILE]
    rep = _with_progress("fitting the exponent and the rate",
                         lambda p: fit_rheology(data_files, region, mu_inf, mu_1, tau_1, bulk_modulus, alpha_start, progress=p),
                         stage=lambda k, n: "calibrate rheology: fitting the exponent and the tests' rate")
    law = rep.pop("law")
    if out_file:
        write_output(target, rheology_toml(law, rheology_provenance(rep, data_files, region, source, command),
                                           f"{region}: {law.describe()}\nWritten by `{command}`."))
    if as_json:
        _print_json(rep | {"law": law.describe(), "out": str(out_file) if out_file else None})
        return
    from rich.table import Table

    table = Table(title=f"{region}: {law.describe()}")
    for col in ("fitted", "value [95% CI]"):
        table.add_column(col)
    table.add_row("alpha (both branches)", f"{rep['alpha']:.4g} [{rep['ci95']['alpha'][0]:.4g}, {rep['ci95']['alpha'][1]:.4g}]")
    table.add_row("the tests' strain rate", f"{rep['rate_per_s']:.3g}/s [{rep['ci95']['rate_per_s'][0]:.3g}, {rep['ci95']['rate_per_s'][1]:.3g}]")
    for mode, t in rep["ramp_s"].items():
        table.add_row(f"{mode} ramp", f"{t:.1f} s")
    for mode, e in rep["rms_rel"].items():
        table.add_row(f"{mode} RMS (rel.)", f"{e:.1%}")
    _console().print(table)
    if out_file:
        click.echo(f"wrote {out_file}")


@calibrate.command("field")
@click.option("--scene", "scene_file", type=click.Path(dir_okay=False, path_type=Path), default=DEFAULT_SCENE, show_default="protocols/scenes/brain_pull.toml", help="The scene file (TOML).")
@click.option("--out", "out_file", type=OutFile((".npz",)), default=None, show_default="data/plate_spring_field.npz", help="The stiffness field.")
@click.option("--params-out", type=OutFile((".toml",)), default=None, help="Also write the located stack's curve here.")
@FORCE
@click.option("--formulation", type=click.Choice(["finite-strain", "small-strain"]), default="finite-strain", show_default=True,
              help="The curve: fitted to the finite-strain / small-strain force ratio of the calibration pulls, or straight.")
@click.option("--json", "as_json", is_flag=True, help="Machine-readable output (JSON).")
def calibrate_field(scene_file, out_file, params_out, formulation, force, as_json):
    """The location-aware plate-spring's stiffness field: the reference's 3 x 3 grasp stiffness
    at the ico4 sites of both hemispheres (P2, 8 mm body-fitted mesh, area-mean grasp),
    interpolated to every vertex; with --params-out, the stack's curve too."""
    import contextlib
    import dataclasses

    from analysis.verification import field_fit as field
    from analysis.verification.accuracy import AccuracyConfig, sample_displacements
    from sim.calibrate import to_toml
    from sim.scene import load_scene

    # the shipped field too (the default): refused before the solves unless --force
    refuse_overlap({"--out": (out_file or field.FIELD_FILE, False), "--params-out": (params_out, False)})
    field_target = staged(out_file or field.FIELD_FILE, force, inputs={"--scene": scene_file})
    params_target = staged(params_out, force, inputs={"--scene": scene_file}, option="--params-out")
    # all or none: both are written under temporary names and moved into place only once the
    # shape fit, the second step, has run too
    with params_target or contextlib.nullcontext() as params_tmp, field_target as tmp:
        rep = _with_progress("stiffness field sites", lambda p: field.build_field(scene_file, tmp, progress=p))
        rep["path"] = str(field_target.target)
        if params_out:
            scene = load_scene(scene_file)
            start = scene.model_spec("plate_spring").options["params"]
            xs = sample_displacements(AccuracyConfig())
            params, fit_rep = field.fit_shape(scene_file, start, xs, formulation)
            law = scene.material.law
            params = dataclasses.replace(params, E=law.shear_modulus)  # the field is per pascal of the law's shear modulus
            how = ("a one-layer stack: a straight curve, so the force is E K(v) d, the law's small-strain limit" if formulation == "small-strain" else
                   f"fitted to the mean finite-strain / small-strain force ratio ({', '.join(f'{r:.3f}' for r in fit_rep['finite_over_small_strain'])})\n"
                   f"of the calibration pulls {', '.join(fit_rep['pulls'])} on the {fit_rep['mesh_mm']:g} mm P2 mesh"
                   + (f" ({', '.join(fit_rep['no_reference'])}: no reference)" if fit_rep.get("no_reference") else "")
                   + f"; {fit_rep['within_jnd']:.0%} "
                   "within the JND.\nE is the law's shear modulus (the field is per pascal of it)")
            params_tmp.write_text(to_toml(params, (
                "Plate-spring stack for the location-aware model (variant \"located\"): only the curve's shape matters,\n"
                "the stiffness field (data/plate_spring_field.npz) sets its size and direction at each vertex.\n"
                f"Written by `studyctl calibrate field --params-out FILE --formulation {formulation}`:\n{how}.")), encoding="utf-8")
            rep |= {"params_out": str(params_out), "shape_fit": fit_rep}
    say_replaced(field_target)
    say_replaced(params_target)
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
@FORCE
@click.option("--json", "as_json", is_flag=True, help="Machine-readable output (JSON).")
def calibrate_rig(db, protocol_file, trials, profile_file, out_file, force, as_json):
    """Each condition's deformation time per frame on this machine (the rig), kept with the
    study: its synthetic participants perceive these as latency (studyctl/synthetic/rig.py)."""
    from studyctl.protocol import load_protocol
    from studyctl.store import Store
    from studyctl.synthetic.rig import measure, read_profile, store_profile

    if (db is None) == (protocol_file is None):
        raise InputError("name the study (--db) or, to write a profile only, a protocol (--protocol with --out)")
    if protocol_file is not None and (out_file is None or profile_file is not None):
        raise InputError("--protocol: measures without a study, so it needs --out (and no --profile)")
    # refused before the trials
    target = staged(out_file, force, inputs={"--db": db, "--protocol": protocol_file, "--profile": profile_file})
    if db is not None:
        with Store(db, mode="read") as store:
            protocol = store.protocol()
    else:
        protocol = load_protocol(protocol_file)
    if profile_file is not None:
        profile, source = read_profile(profile_file), f"file {profile_file.name}"
    else:
        profile, source = _with_progress("rig trials", lambda p: measure(protocol, trials, progress=p)), "measured"
    if target:
        write_output(target, json.dumps(profile, indent=2) + "\n")
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
@click.option("--scene", "scene_file", type=click.Path(dir_okay=False, path_type=Path), default=DEFAULT_SCENE, show_default="protocols/scenes/brain_pull.toml", help="The scene file (TOML).")
@click.option("--vertices", default=None, callback=_vertex_ids, help="Surface vertex ids, e.g. 3386,13629  [default: within 10 mm of the scene's hands]")
@click.option("--out", "out_file", type=OutFile((".npz",)), default=None, help="[default: the cache folder, where sessions find it; rebuilt there freely]")
@FORCE
@click.option("--no-check", is_flag=True, help="Skip the transfer check (a direct solve at the farthest place per hand).")
@click.option("--jobs", type=click.IntRange(1, 256), default=None, help="Reference solves at once (default: every core).")
@click.option("--json", "as_json", is_flag=True, help="Machine-readable output (JSON).")
def calibrate_truth(scene_file, vertices, out_file, force, no_check, jobs, as_json):
    """The synthetic observer's truth at grasp places: the converged reference's finite-strain
    path along each hand's pull (the scene's law on the shipped body-fitted 8 / 6 / 4 mm meshes,
    Richardson) and its small-strain transfer to the places around it. Needed for a scene, or
    grasp places, that the shipped table (data/observer_truth.npz) does not cover; the shipped
    scene's paths are shipped solves, another scene's take minutes per pull and mesh."""
    from analysis.verification.truth_table import build_truth
    from studyctl.outputs import refuse_existing

    # a named table and its .json refused before the solves (the cache's is the tool's own); the table is written atomically
    replaced = refuse_existing([out_file, out_file.with_suffix(".json")], force, inputs={"--scene": scene_file}) if out_file else []
    rep = build_truth(scene_file, out_file, vertices, check=not no_check, jobs=jobs, progress=None if as_json else click.echo)
    if replaced:
        click.echo(f"--force: overwrote {', '.join(map(str, replaced))}", err=True)
    if as_json:
        _print_json(rep)
        return
    click.echo(f"wrote {rep['out']}: {rep['vertices']} grasp places on {len(rep['paths'])} paths ({rep['seconds']:.0f} s); path GCI "
               f"median {rep['path_gci_median']:.1%}, max {rep['path_gci_max']:.1%}")
    for c in rep["transfer_checks"]:
        click.echo(f"transfer check {c['hand']}: vertex {c['vertex']}, {c['distance_mm']:.1f} mm from the hand's, largest error "
                   f"{c['error_max']:.1%} (median {c['error_median']:.1%}) on the {c['mesh_mm']:g} mm mesh")
