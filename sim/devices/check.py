"""Before a participant arrives: find the configured OpenHaptics devices and check the rig.

`list_devices` opens each candidate name once and reports what the library says of it.
`check_rig` runs the scene's devices in the servo process for a few seconds (the participant
view shows both styluses, if asked): calibration (with the inkwell guidance), both styluses
moving, buttons, faults; then, once the experimenter confirms, a short gentle force pulse on
each device. Every problem comes back with its fix.
"""

from __future__ import annotations

import glob
import math
import os
from pathlib import Path

import numpy as np

from sim.devices.openhaptics import (
    HD_CALIBRATION_AUTO,
    HD_CALIBRATION_ENCODER_RESET,
    HD_CALIBRATION_INKWELL,
    HD_INVALID_HANDLE,
    HD_SUCCESS,
    HDError,
    flush_errors,
    load_library,
    nominal_limits,
)
from sim.run import Pacing, run_scene
from sim.servo.messages import Pulse
from sim.servo.process import ServoProcess

CONFIG_DIRS = ("$GTDD_HOME/config", "~/.3dsystems/config", "/usr/share/3DSystems/config", "/etc/3DSystems/config")
PULSE_N = 0.5
PULSE_S = 0.2


def candidate_names(names=()) -> list[str]:
    """The names to try: those given, those the vendor's configuration tool saved (one file per
    device in its config folders), and "Default Device"."""
    out = list(names)
    for d in CONFIG_DIRS:
        folder = os.path.expanduser(os.path.expandvars(d))
        if "$" in folder:
            continue
        out += [Path(f).stem for f in sorted(glob.glob(os.path.join(folder, "*.config")))]
    out.append("Default Device")
    return list(dict.fromkeys(out))


def list_devices(names, library: str | None = None) -> list[dict]:
    """Open and close each named device; what the library reports, or its error."""
    lib = load_library(library)
    out = []
    for name in names:
        flush_errors(lib)  # an old error is not this device's
        handle = lib.hdInitDevice(name.encode())
        err = lib.hdGetError()
        if err.errorCode != HD_SUCCESS or handle == HD_INVALID_HANDLE:
            out.append({"name": name, "found": False, "error": HDError(err.errorCode, err.internalErrorCode).name})
            continue
        lib.hdMakeCurrentDevice(handle)
        peak, cont, styles = nominal_limits(lib)
        lib.hdDisableDevice(handle)
        kinds = [k for bit, k in ((HD_CALIBRATION_AUTO, "auto"), (HD_CALIBRATION_INKWELL, "inkwell"),
                                  (HD_CALIBRATION_ENCODER_RESET, "encoder reset")) if styles & bit]
        out.append({"name": name, "found": True, "peak_force_n": peak, "continuous_force_n": cont, "calibration": kinds})
    return out


def check_rig(scene, seconds: float = 5.0, view=None, confirm=None, say=print) -> dict:
    """Check the scene's real devices (every hand on openhaptics). `confirm(question)` -> bool
    asks the experimenter before the force pulse (None: no pulse). Returns the report; its
    `problems` list is empty when the rig is ready."""
    names = [scene.device_name(i) for i in range(len(scene.spec.hands))]
    listing = list_devices(names)
    problems = [f"{d['name']}: not found ({d['error']}); the configured names are set in the vendor's configuration tool "
                f"(Touch_Setup / PHANToM Configuration): give them with --devices \"NAME1,NAME2\" or device_name in the scene"
                for d in listing if not d["found"]]
    report = {"devices": listing, "problems": problems}
    if problems:
        return report
    notices: list[str] = []

    def caption(phase, left):
        return {"top": "Device check", "center": "Move both styluses and press their buttons",
                "bottom": f"{math.ceil(left)} s"}

    with ServoProcess(scene, 1.0) as sp:
        pacing = Pacing(view=view, caption=caption, notify=lambda n: (notices.append(n), say(n)))
        result = run_scene(scene, duration=seconds, pacing=pacing, servo=sp)
        calibrated = {n.split(":")[0] for n in notices if n.endswith(": calibrated")}
        for i, name in enumerate(names):
            p = result.positions[:, i]
            finite = p[np.isfinite(p).all(axis=1)] if len(p) else p
            moved = float((finite.max(axis=0) - finite.min(axis=0)).max() * 1e3) if len(finite) else 0.0
            entry = report["devices"][i]
            entry.update(calibrated=name in calibrated, moved_mm=moved, button_seen=bool(result.buttons[:, i].any()) if len(p) else False,
                         faults=sorted({e.kind for e in result.events if e.hand == i and e.kind in ("device_fault", "nan_position", "position_jump")}))
            if name not in calibrated:
                problems.append(f"{name}: not calibrated: put the stylus in its inkwell (or move it through the workspace) and run the check again")
            elif moved < 5.0:
                problems.append(f"{name}: the stylus moved {moved:.1f} mm in {seconds:g} s: move it during the check; if it did move, "
                                "check the cable and the device's power")
        report["pacer"] = result.pacer
        if not problems and confirm is not None and confirm(f"apply a gentle {PULSE_N:g} N pulse for {PULSE_S:g} s on each device?"):
            sent = []

            def pulse(sp_) -> None:  # once, on the first frame: device +y (up), in the scene
                if not sent:
                    for i in range(len(names)):
                        frame = scene.device_frame(i)
                        up = np.subtract(frame.to_scene((0.0, 1.0, 0.0)), frame.origin)
                        sp_.send(Pulse(hand=i, force=tuple(float(c) for c in PULSE_N * up), seconds=PULSE_S))
                    sent.append(True)

            def pulse_caption(phase, left):
                return {"top": "Device check", "center": "Force pulse"}

            pulsed = run_scene(scene, duration=1.0, pacing=Pacing(view=view, caption=pulse_caption, on_frame=pulse), servo=sp)
            peaks = np.linalg.norm(pulsed.forces, axis=2).max(axis=0) if len(pulsed.forces) else np.zeros(len(names))
            for i in range(len(names)):
                report["devices"][i]["pulse_n"] = float(peaks[i])
                if peaks[i] < 0.5 * PULSE_N:
                    problems.append(f"{names[i]}: the force pulse was not sent (a safety rule held it: see the events)")
    return report
