"""Rig profiles: each condition's deformation time per frame, measured on the machine that
runs the study, which the synthetic observer perceives as latency (studyctl/synthetic/observer.py).

Without a profile the observer turns each frame's counted work into time with one flop rate
fitted on one machine (`frame_ms`), which can be far from the rig (`python -m bench observer`:
docs/study.md). With one, a synthetic study
predicts the rig it will run on, and stays deterministic (the profile is a fixed number per
configuration, not a timing taken during the session).

A profile is keyed by the configuration's physics (the resolved configuration without the
condition's name, studyctl/conditions.py): the same model and options measured once serve any
condition that runs them. `studyctl calibrate rig` measures one (lockstep trials of each
condition with a synthetic pilot's pull, after a warm-up) and stores it with the study; the
shipped `data/rig_ci.json` (measured on the CI machine) serves studies without their own.
"""

from __future__ import annotations

import json
import math
import platform
from pathlib import Path

import numpy as np

from analysis.errors import InputError, StoreError
from brainsim_assets import path as asset
from sim.errors import InputFileError
from sim.files import DATA_MAX_BYTES, read_input
from sim.run import run_scene
from studyctl.conditions import SOFTWARE_VERSION, condition_configs, condition_scene, config_sha256
from studyctl.store import now
from studyctl.store.rig_profile import has_profile, keep_rows, profile_rows, session_count
from studyctl.synthetic.participant import SyntheticParticipant

SHIPPED = "data/rig_ci.json"


def physics_key(config: dict) -> str:
    """The configuration's hash without the condition's name."""
    return config_sha256({k: v for k, v in config.items() if k != "condition"})


def condition_keys(protocol) -> dict[str, str]:
    """Each condition's physics key (its configuration as the protocol resolves it)."""
    return {c: physics_key(cfg) for c, cfg in condition_configs(protocol, protocol.conditions).items()}


def machine() -> str:
    cpu = ""
    try:
        cpu = next((line.split(":", 1)[1].strip() for line in Path("/proc/cpuinfo").read_text().splitlines()
                    if line.startswith("model name")), "")
    except OSError:
        pass
    return f"{platform.node()}: {cpu or platform.processor() or platform.machine()}"


def measure(protocol, trials: int = 2, progress=None) -> dict:
    """A profile of `protocol`'s conditions on this machine: per condition, `trials` lockstep
    trials (the protocol's trial time, a synthetic pilot's pull) after a 0.5 s warm-up; the
    median and 95th percentile of the deformation time per frame."""
    configs = condition_configs(protocol, protocol.conditions)
    rows = []
    for i, c in enumerate(protocol.conditions):
        scene = condition_scene(protocol, c, "simulated")
        run_scene(scene, duration=0.5, time_scale=0)  # first-frame allocations and caches
        times = []
        for k in range(trials):
            pilot = SyntheticParticipant.draw(f"RIG{k + 1:02d}", 0)
            scene.operators = pilot.operators(scene, k, c)
            try:
                times.append(run_scene(scene, duration=protocol.trial_seconds, time_scale=0).deformation_s * 1e3)
            finally:
                scene.operators = None
            if progress:
                progress(i * trials + k + 1, len(protocol.conditions) * trials)
        ms = np.concatenate(times)
        rows.append({"key": physics_key(configs[c]), "condition": c, "model": configs[c]["model"],
                     "frame_ms_p50": round(float(np.median(ms)), 4), "frame_ms_p95": round(float(np.percentile(ms, 95)), 4), "frames": int(len(ms))})
    return {"machine": machine(), "measured_at": now(), "software_version": SOFTWARE_VERSION, "protocol": protocol.name,
            "trials": trials, "conditions": rows}


def read_profile(path: str | Path) -> dict:
    """A profile file, checked: every entry names its key and a finite positive frame time."""
    path = Path(path)
    try:
        data = json.loads(read_input(path, DATA_MAX_BYTES))
    except InputFileError as exc:
        raise InputError(str(exc)) from None
    except ValueError as exc:
        raise InputError(f"{path}: not JSON ({exc})") from None
    rows = data.get("conditions") if isinstance(data, dict) else None
    if not isinstance(rows, list) or not rows:
        raise InputError(f"{path}: conditions: missing; a rig profile lists conditions (write one with `studyctl calibrate rig --out`)")
    for k, r in enumerate(rows):
        if not isinstance(r, dict) or not isinstance(r.get("key"), str) or len(r["key"]) != 64:
            raise InputError(f"{path}: conditions[{k}].key: missing or not a SHA-256")
        for f in ("frame_ms_p50", "frame_ms_p95"):
            v = r.get(f)
            if not (isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v) and 0 < v < 1e5):
                raise InputError(f"{path}: conditions[{k}].{f}: {v!r} is out of range; allowed: a time in ms, 0 < t < 100000")
    return data


def store_profile(store, profile: dict, source: str) -> int:
    """Keep `profile` with the study in `store` (an open studyctl.store.Store, for writing): one
    row per configuration, replacing an older one. Refused when none of its entries is a
    configuration of the study's conditions, and once sessions have run (their synthetic
    participants perceived the profile they had: a new one would change the later participants alone)."""
    db = store.path
    protocol = store.protocol()
    if not set(condition_keys(protocol).values()) & {r["key"] for r in profile["conditions"]}:
        raise InputError(f"the profile has no entry for the configurations of {db}'s conditions ({', '.join(protocol.conditions)}): "
                         "measure it with `studyctl calibrate rig --db` on the rig")
    ran = session_count(store)
    if ran:
        raise StoreError(f"{db}: {ran} sessions have run with the rig profile they had; a new one would apply to later "
                         "participants only: calibrate before the first session")
    with store.transaction() as conn:
        keep_rows(conn, profile["conditions"], profile, source)
    return len(profile["conditions"])


def frame_times(protocol, store=None) -> dict[str, dict]:
    """Each condition's frame time for the synthetic observer: {condition: {frame_ms, source}},
    from the study's own profile (`store`), else the shipped one. All conditions or none: when
    a profile misses a condition, every condition falls back to the observer's flop model (one
    latency scale for all; a mix would judge conditions on two)."""
    keys = condition_keys(protocol)
    known: dict[str, tuple[float, str]] = {}
    if asset(SHIPPED).exists():
        shipped = read_profile(asset(SHIPPED))
        for r in shipped["conditions"]:
            known[r["key"]] = (float(r["frame_ms_p50"]), f"shipped {SHIPPED} ({shipped.get('machine', '')})")
    if store is not None:
        for r in profile_rows(store):
            known[r["key"]] = (float(r["frame_ms_p50"]), f"{r['source']} ({r['machine']})")
    if not all(k in known for k in keys.values()):
        return {}
    return {c: {"frame_ms": known[k][0], "source": known[k][1]} for c, k in keys.items()}


def keep_shipped(store) -> int:
    """Store the shipped profile's rows for the study's conditions with the study in `store` (an
    open studyctl.store.Store, for writing), once, when it has none of its own (so an export
    says which frame times its synthetic sessions used)."""
    if has_profile(store) or not asset(SHIPPED).exists():
        return 0
    keys = set(condition_keys(store.protocol()).values())
    shipped = read_profile(asset(SHIPPED))
    rows = [r for r in shipped["conditions"] if r["key"] in keys]
    if len(rows) < len(keys):
        return 0
    with store.transaction() as conn:
        keep_rows(conn, rows, shipped, f"shipped {SHIPPED}", verb="ignore")
    return len(rows)
