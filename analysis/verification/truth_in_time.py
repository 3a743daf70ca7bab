"""The truth at each of the accuracy bench's speeds (docs/accuracy.md, In time).

- **quasi-static**: the timeless truth (`truth_band.truth_samples`), the law fitted to curves
  measured at about 0.0024/s: the tissue as the data saw it.
- **typical, fast** (data/pull_speeds.json, the hands' median and 90th-percentile ramp speeds):
  the regional viscoelastic brain pulled at that speed and held (`pulls_in_time`, shipped and
  hash-checked), on the timeless truth's coarsest mesh. Its mesh error is taken to be the
  timeless law's on the same mesh: each force is multiplied by the timeless truth's
  extrapolated force over its coarsest mesh's, and its band is the timeless sample's with the
  time step's share and that borrowed correction's measured error added. A hold sample takes
  the last ramp sample's.
- **Support in time**: a sample is decided only where the timeless sample at its displacement
  is and, as the rule for stretches (`truth_band.decide`), the share of the force's power from quadrature
  points straining faster than the data's fastest rate (`pulls_in_time.rate_support`, the
  largest so far along the pull) is at most the JND fraction at its force.
- A pull in time that stopped (as some anterior pulls do on the 8 mm mesh, in time as in the
  timeless solves) has no truth beyond its last record, and says where it stopped.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass

import numpy as np

from analysis.verification.pulls_in_time import (
    GREY_RHEOLOGY,
    HOLDS_S,
    MAX_DT_S,
    WHITE_RHEOLOGY,
    data_rates,
    pull_in_time_key_of,
    reached,
    shipped_rheology,
    stopped,
    stored_pull_in_time,
)
from analysis.verification.tissue_pulls import RECORD_XS
from analysis.verification.truth_band import MARGINAL_LIMIT, combine, decide
from brainsim_assets import path as _asset
from sim.errors import ParameterError
from sim.material import read_rheology
from sim.perception import force_jnd

QUASI_STATIC = "quasi-static"
SPEED_NAMES = (QUASI_STATIC, "typical", "fast")
# the implicit step's share of a force: halving every step moves the forces by at most 0.39%
# (docs/viscoelastic.md), so the step's own error is about as much again
TIME_STEP_REL = 0.004
# the borrowed mesh correction's own error: over the 18 pulls solved in time and timeless on both
# the 20 and the 8 mm mesh (105 ramp and 64 hold samples a speed), the time solves' 20-over-8 mm
# force ratio is the timeless solves' within a median 1.4% (typical) and 1.6% (fast), a 95th
# percentile 7.2% and 7.4%, at most 11.7% and 11.5% (scripts/check_mesh_correction_in_time.py
# --speed). The larger 95th percentile is assumed for the correction on either bench's coarsest
# mesh at either speed: measured between 20 and 8 mm only
MESH_TRANSFER_REL = 0.074
PULL_SPEEDS = _asset("data/pull_speeds.json")


@dataclass(frozen=True)
class BenchSpeed:
    name: str
    speed_m_s: float | None  # None: quasi-static (the timeless truth)
    holds_s: tuple[float, ...] = ()


def bench_speeds(names) -> list[BenchSpeed]:
    """The bench's speeds by name: quasi-static, and those of data/pull_speeds.json (held `HOLDS_S`)."""
    speeds = json.loads(PULL_SPEEDS.read_text())["speeds"]
    out = []
    for name in names:
        if name == QUASI_STATIC:
            out.append(BenchSpeed(name, None))
        elif name in speeds:
            out.append(BenchSpeed(name, float(speeds[name]["speed_m_s"]), tuple(HOLDS_S)))
        else:
            raise ParameterError(f"speed {name!r}; allowed: {', '.join((QUASI_STATIC, *speeds))}")
    return out


def stored_bench_pull(scene_path, pull, size_mm: float, speed: BenchSpeed) -> dict | None:
    """The pull in time the bench reads for `pull` on the `size_mm` mesh at `speed` (shipped or
    cached, `pulls_in_time.stored_pull_in_time`); None if neither."""
    return stored_pull_in_time(pull_in_time_key_of((str(scene_path), pull, size_mm, speed.speed_m_s, RECORD_XS, speed.holds_s, MAX_DT_S)))


def _missing(cell: dict, why: str) -> dict:
    return cell | {"force": np.full(3, np.nan), "force_n": math.nan, "band_rel": math.nan, "band_half_n": math.nan,
                   "decided": False, "truth": "undecided", "reason": why, "static_force_n": cell["force_n"], "left_by": "no solve"}


def truth_in_time(scene_path, scene, static: dict, pulls, xs, speed: BenchSpeed, size_mm: float, e_ratio: float = 1.0) -> tuple[dict, dict]:
    """Per pull, the samples at `xs` and then each hold at `speed` (`BenchSpeed` with a speed):
    the timeless truth's sample (`static`: `truth_samples`' result, scaled by `e_ratio`) with the
    force, band and verdict in time, `time_s`, `hold_s`, `rate_share_outside`,
    `strain_rate_per_s` and `static_force_n`; and what the truth in time rests on (JSON-ready)."""
    xs = np.asarray(xs, dtype=np.float64)
    records = [int(np.argmin(np.abs(RECORD_XS - x))) for x in xs]
    on_records = bool(np.allclose(RECORD_XS[records], xs, rtol=0, atol=1e-12))
    grey, white = shipped_rheology()
    if scene.spec.material.white_matter is None:
        white = None
    mu = grey.equilibrium.shear_modulus * e_ratio
    why_none = ("the bench's samples are not the pulls in time's records (every 0.5 mm to 12 mm)" if not on_records else
                "the pulls in time have no pia-arachnoid" if scene.spec.material.pia_arachnoid is not None else "")
    law_mu = scene.spec.material.law.shear_modulus * e_ratio
    # the solves hold at 12 mm: a bench that stops short of it has no truth for its holds
    holds_at_end = on_records and records[-1] == len(RECORD_XS) - 1
    rates = "/".join(f"{r:.2g}" for r in data_rates(white is not None))
    out, found, halted = {}, 0, {}
    for p in pulls:
        cells = static["pulls"][p.name]
        solve = None
        if not why_none:
            solve = stored_bench_pull(scene_path, p, size_mm, speed)
        found += solve is not None
        stop = ""
        if solve is not None and stopped(solve):
            (mm, at_s), why = reached(solve), solve["meta"].get("reason") or "no convergence"
            halted[p.name] = {"mm": mm, "s": at_s, "reason": why}
            stop = (f"the pull in time stopped at {mm:g} mm, {at_s:.3g} s from rest ({why}) on the {size_mm:g} mm mesh, "
                    "as the timeless solves of some pulls do")
        coarse = np.asarray(static["refs"]["pulls"][p.name]["force_per_pa"])[0]  # (records of xs, 3): the coarsest mesh, per pascal
        rows = []
        for k in range(len(xs) + len(speed.holds_s)):
            ramp = min(k, len(xs) - 1)
            c = cells[ramp] | {"hold_s": speed.holds_s[k - len(xs)] if k >= len(xs) else 0.0}
            if solve is None or (k >= len(xs) and not holds_at_end):
                rows.append(_missing(c, why_none or (f"no pull in time shipped at {speed.name} speed on the {size_mm:g} mm mesh "
                                                     "(scripts/make_pulls_in_time.py)" if solve is None else
                                                     f"the pulls in time hold at {RECORD_XS[-1] * 1e3:g} mm, not at this bench's last sample")))
                continue
            rec = records[ramp] if k < len(xs) else len(RECORD_XS) + (k - len(xs))
            if not np.isfinite(solve["force_per_pa"][rec]).all():
                rows.append(_missing(c, stop))
                continue
            coarse_n = float(np.linalg.norm(coarse[ramp])) * law_mu
            correction = c["force_n"] / coarse_n if coarse_n > 0 and math.isfinite(c["force_n"]) else math.nan
            vec = np.asarray(solve["force_per_pa"][rec]) * mu * correction
            f = float(np.linalg.norm(vec))
            share, rate = float(solve["rate_share_outside"][rec]), float(solve["strain_rate_per_s"][rec])
            band = combine(combine(c["band_rel"], TIME_STEP_REL), MESH_TRANSFER_REL)
            ok, verdict, why = decide(f, band, c["decided_share"], c["decided_j"], c["decided_on"])
            left_by = "" if ok else "the timeless rules"
            limit = MARGINAL_LIMIT * float(force_jnd(np.array(f))) if math.isfinite(f) else math.nan
            if math.isfinite(f) and not share <= limit:
                ok, verdict, left_by = False, "extrapolated", "rates beyond the data's"
                why = (f"{share:.0%} of the force's power from points straining faster than the data's {rates}/s "
                       f"(median {rate:.2g}/s; at most {limit:.0%} here)")
            rows.append(c | {"force": vec, "force_n": f, "band_rel": band, "band_half_n": band * f, "decided": ok, "truth": verdict,
                             "reason": why, "time_s": float(solve["times_s"][rec]), "rate_share_outside": share, "strain_rate_per_s": rate,
                             "static_force_n": c["force_n"], "mesh_correction": correction, "left_by": left_by})
        out[p.name] = rows
    flat = [c for rows in out.values() for c in rows]
    rates = [c["strain_rate_per_s"] for c in flat if math.isfinite(c.get("strain_rate_per_s", math.nan)) and c["hold_s"] == 0.0]
    ratio = [c["force_n"] / c["static_force_n"] for c in flat if math.isfinite(c["force_n"]) and c["static_force_n"] > 0]
    meta = {"speed": speed.name, "speed_m_s": speed.speed_m_s, "holds_s": list(speed.holds_s), "mesh_mm": size_mm,
            "law": [law.describe() for law in ((grey, white) if white is not None else (grey,))],
            "rheology": {str(f.name): read_rheology(f)[1].get("source", "") for f in (GREY_RHEOLOGY, WHITE_RHEOLOGY)},
            "data_rate_per_s": list(data_rates()), "time_step_rel": TIME_STEP_REL, "mesh_transfer_rel": MESH_TRANSFER_REL,
            "pulls_solved": found, "pulls": len(pulls),
            "pulls_stopped": halted,
            "decided": sum(c["decided"] for c in flat), "samples": len(flat),
            "strain_rate_median_per_s": [float(np.min(rates)), float(np.max(rates))] if rates else None,
            "over_timeless": [float(np.min(ratio)), float(np.max(ratio))] if ratio else None,
            "left_by": {k: sum(c["left_by"] == k for c in flat) for k in ("rates beyond the data's", "the timeless rules", "no solve")}}
    return out, meta
