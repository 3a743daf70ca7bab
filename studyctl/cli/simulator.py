"""`studyctl sim`: run scenes on the simulator, scripted (`sim run`) or by hand (`sim live`).

Not named sim.py: this module imports the `sim` package, and a sibling of that name would read
as (and, with this folder on sys.path, be) an import of itself."""

from __future__ import annotations

from pathlib import Path

import click

from sim.scene import DEFAULT_SCENE, MAX_DURATION_S
from studyctl.cli.common import (
    DEVICES,
    FORCE,
    FRAMES_EXPECTED,
    FRAMES_OWN,
    FULLSCREEN,
    Finite,
    OutDir,
    OutFile,
    _console,
    _Group,
    _print_json,
    say_replaced,
    staged,
)
from studyctl.outputs import refuse_existing, refuse_overlap


@click.group(cls=_Group)
def sim():
    """Run scenes on the simulator."""


@sim.command("run")
@click.option("--scene", "scene_file", type=click.Path(dir_okay=False, path_type=Path), default=DEFAULT_SCENE, show_default="protocols/scenes/brain_pull.toml", help="The scene file (TOML).")
@click.option("--model", "model_name", default=None,
              help="A model configured in the scene, e.g. plate_spring or plate-spring  [default: the scene's]")
@click.option("--duration", type=Finite(min=0.0, min_open=True, max=MAX_DURATION_S), default=None, help="Simulated seconds (default: the scene's).")
@click.option("--frames", "frames_dir", type=OutDir(), default=None, help="Write pictures, the force plot and the trace here.")
@click.option("--time-scale", type=Finite(min=0.0, max=1000.0), default=1.0, show_default=True, help="1 = real time; 0 = as fast as possible (lockstep, deterministic).")
@click.option("--view", type=click.Choice(["none", "offscreen", "window"]), default=None,
              help="window: draw the run live in the participant view; offscreen: pictures after the run (--frames); default: the scene's renderer.")
@click.option("--screenshot", type=OutFile((".png",)), default=None, help="With --view window: save the last frame shown (PNG).")
@FORCE
@FULLSCREEN
@click.option("--json", "as_json", is_flag=True, help="Machine-readable statistics.")
def sim_run(scene_file: Path, model_name, duration, frames_dir, time_scale: float, view, screenshot, force, fullscreen, as_json: bool):
    """Scripted simulated Omni hands grasp and pull the brain; the servo loop runs at 1 kHz."""
    from sim.run import run_scene, write_outputs
    from sim.scene import build_scene

    # refused before the run: the two outputs on one path, the folder's trace and force plot (its pictures are
    # checked once drawn), the screenshot; the scene is never an output
    refuse_overlap({"--frames": (frames_dir, FRAMES_OWN), "--screenshot": (screenshot, False)})
    inputs = {"--scene": scene_file}
    target = staged(frames_dir, force, folder=True, expect=FRAMES_EXPECTED, inputs=inputs, option="--frames", own=FRAMES_OWN)
    replaced = refuse_existing([screenshot], force, inputs=inputs, option="--screenshot") if screenshot is not None else []
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
    if target:
        with target as tmp:  # the pictures, plot and trace all or none
            if as_json:
                stats["frames"] = write_outputs(result, scene, tmp)
            else:
                from rich.progress import Progress

                with Progress(transient=True) as progress:
                    task = progress.add_task("rendering frames", total=max(len(result.snapshots), 1))
                    stats["frames"] = write_outputs(result, scene, tmp, progress=lambda k, n: progress.update(task, completed=k))
        stats["frames_dir"] = str(frames_dir)
    if replaced:
        click.echo(f"--force: overwrote {replaced[0]}", err=True)
    say_replaced(target)
    if screenshot is not None:
        stats["screenshot"] = str(screenshot)
    if as_json:
        _print_json(stats)
    else:
        _print_run(stats)


@sim.command("live")
@click.option("--scene", "scene_file", type=click.Path(dir_okay=False, path_type=Path), default=DEFAULT_SCENE, show_default="protocols/scenes/brain_pull.toml", help="The scene file (TOML).")
@click.option("--model", "model_name", default=None,
              help="A model configured in the scene, e.g. plate_spring or plate-spring  [default: the scene's]")
@click.option("--device", type=click.Choice(["mouse", "simulated", "openhaptics"]), default="mouse", show_default=True, help="What moves the hand.")
@click.option("--duration", type=Finite(min=0.0, min_open=True, max=MAX_DURATION_S), default=600.0, show_default=True, help="Seconds at most; Q, Escape or closing the window ends it sooner.")
@click.option("--screenshot", type=OutFile((".png",)), default=None, help="Save the last frame shown (PNG).")
@FORCE
@FULLSCREEN
@DEVICES
@click.option("--json", "as_json", is_flag=True, help="Machine-readable statistics.")
def sim_live(scene_file: Path, model_name, device, duration, screenshot, force, fullscreen, device_names, as_json: bool):
    """Open the participant view and pull the brain (mouse: grasp under the cursor, drag, wheel)."""
    from sim.live import run_view
    from sim.scene import build_scene

    if screenshot is not None and refuse_existing([screenshot], force, inputs={"--scene": scene_file}, option="--screenshot"):
        click.echo(f"--force: overwrites {screenshot}", err=True)
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
    for line in s.get("over_budget", []):  # the model's calls slower than their budget (docs/models.md)
        click.echo(line)
    seen = set()
    for f in s.get("faults", []):  # why a model_fault or nan_force zeroed the force: the table only counts them
        line = f["detail"] if f["hand"] is None else f"{f['detail']} ({f['hand']} hand)"
        if line not in seen:
            seen.add(line)
            click.echo(line)
