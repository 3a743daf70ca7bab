"""Calibration of the plate-spring model to a reference force-displacement curve.

"The model is parameterized and thus can be adapted to simulate different organs" (seed
paper): fit h1, alpha, q and x_c1 within their bounds so that the plate-spring force at a set of
displacements matches a reference: the converged FEM reference on the accuracy bench's
calibration pulls (`analysis.verification.accuracy.calibration_curve`, through `studyctl calibrate
plate-spring`) or a measured curve from a CSV (displacement_m, force_n). Residuals are in
units of the force JND (`sim.perception`), so the report says directly how many samples a person could tell apart.
"""

from __future__ import annotations

import csv
import dataclasses
import math
from pathlib import Path

import numpy as np
from scipy.optimize import least_squares

from sim.errors import InputFileError, ParameterError
from sim.files import DATA_MAX_BYTES, check_input
from sim.models.plate_spring import B_SLACK_M, PlateSpring, PlateSpringParams
from sim.perception import force_jnd


def read_curve(path) -> tuple[np.ndarray, np.ndarray]:
    path = Path(path)
    xs, fs = [], []
    try:
        check_input(path, DATA_MAX_BYTES)
    except InputFileError as exc:
        raise ParameterError(str(exc)) from None
    try:
        with open(path, newline="") as fh:
            reader = csv.DictReader(fh)
            if not {"displacement_m", "force_n"} <= set(reader.fieldnames or []):
                raise ParameterError(f"{path}: need columns displacement_m, force_n")
            for line, row in enumerate(reader, start=2):
                try:
                    x, f = float(row["displacement_m"]), float(row["force_n"])
                except ValueError:
                    raise ParameterError(f"{path}: line {line}: not a number") from None
                if not (x > 0 and f > 0 and math.isfinite(x) and math.isfinite(f)):
                    raise ParameterError(f"{path}: line {line}: displacement and force must be > 0")
                xs.append(x)
                fs.append(f)
    except OSError as exc:
        raise ParameterError(f"{path}: cannot read: {exc.strerror}") from None
    if len(xs) < 3:
        raise ParameterError(f"{path}: need at least 3 points")
    return np.array(xs), np.array(fs)


FIT = ("h1", "alpha", "q", "x_c1")
BOUNDS = {"h1": (1e-4, 0.05), "alpha": (1.0, 2.0), "q": (1.0, 1.5), "x_c1": (1e-4, 0.02)}


def fit(params: PlateSpringParams, xs: np.ndarray, forces: np.ndarray, variant: str = "continuous") -> tuple[PlateSpringParams, dict]:
    def build(v):
        values = dataclasses.asdict(params) | {"h1": math.exp(v[0]), "alpha": float(v[1]), "q": float(v[2]), "x_c1": math.exp(v[3])}
        values["B"] = min(max(values["B"], values["b"]), values["b"] + B_SLACK_M)
        return PlateSpringParams(**values)

    def residual(v):
        try:
            stack = PlateSpring(build(v), variant)
        except ParameterError:
            return np.full(len(xs), 1e3)
        f = np.array([stack.force(x) for x in xs])
        return (f - forces) / (force_jnd(forces) * forces)

    lo = [math.log(BOUNDS["h1"][0]), 1.0, 1.0, math.log(BOUNDS["x_c1"][0])]
    hi = [math.log(BOUNDS["h1"][1]), 2.0, 1.5, math.log(BOUNDS["x_c1"][1])]
    v0 = [math.log(params.h1), params.alpha, params.q, math.log(params.x_c1)]
    v0 = [min(max(a, lo_i + 1e-9), hi_i - 1e-9) for a, lo_i, hi_i in zip(v0, lo, hi)]
    best = None
    for start in (v0, [v0[0] - 1.0, 1.0 + 1e-6, 1.0 + 1e-6, v0[3]]):  # the given parameters, and a linear stack
        sol = least_squares(residual, start, bounds=(lo, hi), x_scale="jac")
        if best is None or sol.cost < best.cost:
            best = sol
    fitted = build(best.x)
    r = residual(best.x)
    return fitted, {
        "variant": variant, "points": len(xs),
        "within_jnd": float(np.mean(np.abs(r) <= 1.0)), "max_jnd_units": float(np.max(np.abs(r))),
        "rms_jnd_units": float(np.sqrt(np.mean(r**2))),
        "fitted": {k: getattr(fitted, k) for k in FIT},
    }


def to_toml(params: PlateSpringParams, header: str) -> str:
    lines = [f"# {line}" for line in header.splitlines()]
    lines += [f"{k} = {v!r}" for k, v in dataclasses.asdict(params).items()]
    return "\n".join(lines) + "\n"
