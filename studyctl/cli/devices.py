"""`studyctl devices`: find the real haptic devices (OpenHaptics) and check the rig."""

from __future__ import annotations

from pathlib import Path

import click

from sim.scene import DEFAULT_SCENE
from studyctl.cli.common import DEVICES, FULLSCREEN, _console, _Group, _print_json


@click.group(cls=_Group)
def devices():
    """Real haptic devices (OpenHaptics): find them and check the rig before a session."""


@devices.command("list")
@DEVICES
@click.option("--json", "as_json", is_flag=True, help="Machine-readable output (JSON).")
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
@click.option("--scene", "scene_file", type=click.Path(dir_okay=False, path_type=Path), default=DEFAULT_SCENE, show_default="protocols/scenes/brain_pull.toml", help="The scene file (TOML).")
@DEVICES
@click.option("--seconds", type=click.FloatRange(1.0, 600.0), default=5.0, show_default=True, help="How long to watch the styluses.")
@click.option("--view", type=click.Choice(["none", "window"]), default="none", show_default=True, help="window: show both styluses live.")
@click.option("--yes", is_flag=True, help="Apply the force pulse without asking.")
@FULLSCREEN
@click.option("--json", "as_json", is_flag=True, help="Machine-readable output (JSON).")
def devices_check(scene_file, device_names, seconds, view, yes, fullscreen, as_json):
    """Calibration, both styluses live, buttons, a gentle force pulse: exit 1 with the fix if anything is wrong."""
    from sim.devices.check import check_rig
    from sim.scene import build_scene

    scene = build_scene(scene_file).with_device("openhaptics")
    scene.device_names = device_names
    shown = None
    if view == "window":
        from sim.view.window import open_view

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
