"""Fitting the finite-strain laws to uniaxial tissue data (`studyctl calibrate material`).

Each law (`sim.hyperelastic`: neo-Hookean, Mooney-Rivlin, one- and two-term Ogden)
is fitted to the nominal stress of uniaxial tension and compression together, by least
squares on the stress (Pa), with the law's own volumetric part (kappa = bulk_ratio mu) and
free lateral faces: the same closed form the FEM's cube tests hold the FEM to. The shear
moduli are bounded below by 0 (a negative term is unstable). Ogden's exponents are started
from a grid (the objective has several minima) and the best kept.

Per law: the parameters with 95% intervals from the Jacobian at the optimum (the
covariance s^2 (J^T J)^-1, t quantile; the data points are points of a mean curve, not
independent measurements, so read these as the precision of the fit to that curve), the RMS
error relative to the data's RMS, overall and per mode, and AICc and BIC. The law chosen is
the one of lowest AICc among those whose parameters are identified (every interval finite
and narrower than the value itself); the others are reported beside it.
"""

from __future__ import annotations

import hashlib
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from brainsim_assets import path as _asset
from sim.hyperelastic import BULK_RATIO, Hyperelastic, mooney_rivlin, neo_hookean, ogden, uniaxial
from studyctl.csvfiles import read_csv
from studyctl.errors import InputError

DATA_FILE = _asset("data/brain_tissue_uniaxial_budday2017.csv")
FIT_LAWS = ("neo-hookean", "mooney-rivlin", "ogden", "ogden-2")
ALPHA_STARTS = (-30.0, -20.0, -10.0, -4.0, 4.0, 10.0)


class MaterialDataError(InputError):
    """A tissue data file that cannot be fitted (named file, row and field)."""


@dataclass(frozen=True)
class Curve:
    path: str
    sha256: str
    region: str
    stretch: np.ndarray
    stress: np.ndarray  # nominal, Pa


def read_curve(path, region: str) -> Curve:
    """The rows of `region` in a CSV with columns region, stretch, nominal_stress_kpa (read
    strictly: `studyctl.csvfiles.read_csv`); a bad cell is named by its line and column."""
    p = Path(path)
    columns = ("region", "stretch", "nominal_stress_kpa")
    rows = read_csv(p, columns, columns)
    regions = sorted({r["region"] for _, r in rows if r["region"]})
    mine = [(line, r) for line, r in rows if r["region"] == region]
    if not mine:
        raise MaterialDataError(f"{p}: region {region!r} has no rows; regions there: {', '.join(regions) or 'none'}")
    values = {c: [] for c in columns[1:]}
    for line, r in mine:
        for col, lo, hi in (("stretch", 0.2, 5.0), ("nominal_stress_kpa", -1e6, 1e6)):
            try:
                v = float(r[col])
            except ValueError:
                v = math.nan
            if not (math.isfinite(v) and lo <= v <= hi):
                raise MaterialDataError(f"{p}:{line}: {col}: {r[col][:20]!r} is out of range; allowed: a number in {lo:g}..{hi:g}")
            values[col].append(v)
    lam, stress = np.array(values["stretch"]), np.array(values["nominal_stress_kpa"]) * 1e3
    if (lam < 1).sum() < 2 or (lam > 1).sum() < 2:
        raise MaterialDataError(f"{p}: region {region!r} needs at least two points in tension and two in compression")
    return Curve(str(p), hashlib.sha256(p.read_bytes()).hexdigest(), region, lam, stress)


def _law(name: str, x: np.ndarray, bulk_ratio: float) -> Hyperelastic:
    if name == "neo-hookean":
        return neo_hookean(x[0], bulk_ratio)
    if name == "mooney-rivlin":
        return mooney_rivlin(x[0], x[1], bulk_ratio)
    if name == "ogden":
        return ogden([x[0]], [x[1]], bulk_ratio)
    return ogden([x[0], x[1]], [x[2], x[3]], bulk_ratio)


def _names(name: str) -> list[str]:
    return {"neo-hookean": ["mu"], "mooney-rivlin": ["mu1", "mu2"], "ogden": ["mu", "alpha"],
            "ogden-2": ["mu1", "mu2", "alpha1", "alpha2"]}[name]


def _starts(name: str, mu0: float) -> list[tuple[np.ndarray, tuple]]:
    """(start, bounds) pairs; alpha bounds keep each term's exponent on its side of 0."""
    if name == "neo-hookean":
        return [(np.array([mu0]), ([0.0], [np.inf]))]
    if name == "mooney-rivlin":
        return [(np.array([mu0 / 2, mu0 / 2]), ([0.0, 0.0], [np.inf, np.inf]))]
    if name == "ogden":
        return [(np.array([mu0, a]), ([0.0, -60.0 if a < 0 else 0.05], [np.inf, -0.05 if a < 0 else 60.0])) for a in ALPHA_STARTS]
    out = []
    for a1 in (-30.0, -20.0, -10.0):
        for a2 in (-4.0, 2.0, 10.0):
            lo2, hi2 = (-60.0, -0.05) if a2 < 0 else (0.05, 60.0)
            out.append((np.array([mu0 / 2, mu0 / 2, a1, a2]), ([0.0, 0.0, -60.0, lo2], [np.inf, np.inf, -0.05, hi2])))
    return out


def fit_law(curve: Curve, name: str, bulk_ratio: float = BULK_RATIO) -> dict:
    """One law's least-squares fit to the curve: parameters, intervals, errors, criteria."""
    from scipy.optimize import least_squares
    from scipy.stats import t as student_t

    lam, y = curve.stretch, curve.stress
    # a start for mu: the small-strain slope, dP/dlambda = 3 mu (incompressible)
    near = np.abs(lam - 1.0) <= 0.031
    mu0 = max(float(np.polyfit(lam[near] - 1.0, y[near], 1)[0]) / 3.0, 1.0) if near.sum() >= 2 else 1000.0

    def residual(x):
        return uniaxial(_law(name, x, bulk_ratio), lam)[0] - y

    best = None
    for x0, bounds in _starts(name, mu0):
        try:
            r = least_squares(residual, x0, bounds=bounds, x_scale="jac", xtol=1e-12, ftol=1e-12, gtol=1e-12, max_nfev=4000)
        except ValueError:  # a start whose law over/underflows
            continue
        if np.all(np.isfinite(r.fun)) and (best is None or r.cost < best.cost):
            best = r
    if best is None:
        raise MaterialDataError(f"{curve.path}: the {name} law could not be fitted to region {curve.region!r} from any start "
                                "(its stresses over- or underflow there)")
    x, res = best.x, best.fun
    n, k = len(y), len(x)
    rss = max(float(np.sum(res**2)), 1e-300)  # an exact fit: no log of zero
    dof = max(n - k, 1)
    J = best.jac
    try:
        cov = np.linalg.inv(J.T @ J) * rss / dof
        half = student_t.ppf(0.975, dof) * np.sqrt(np.clip(np.diag(cov), 0.0, None))
    except np.linalg.LinAlgError:
        half = np.full(k, np.inf)
    at_bound = [bool(np.isclose(v, 0.0)) for v in x[: 1 if name in ("neo-hookean", "ogden") else 2]]
    law = _law(name, x, bulk_ratio)
    rms = lambda sel: float(np.sqrt(np.mean(res[sel] ** 2)) / np.sqrt(np.mean(y[sel] ** 2)))  # noqa: E731
    tension, compression = lam > 1.0, lam < 1.0
    identified = bool(np.all(np.isfinite(half)) and np.all(half < np.abs(x)) and not any(at_bound))
    aicc = n * math.log(rss / n) + 2 * k + (2 * k * (k + 1) / (n - k - 1) if n - k - 1 > 0 else math.inf)
    return {"law": name, "parameters": dict(zip(_names(name), (float(v) for v in x))),
            "ci95": {p: [float(v - h), float(v + h)] for p, v, h in zip(_names(name), x, half)},
            "material": law.params(), "shear_modulus_pa": law.shear_modulus,
            "rms_rel": rms(np.ones(n, bool)), "rms_rel_tension": rms(tension), "rms_rel_compression": rms(compression),
            "rms_pa": float(np.sqrt(rss / n)), "aicc": aicc, "bic": n * math.log(rss / n) + k * math.log(n),
            "identified": identified, "at_bound": any(at_bound), "n": n, "k": k,
            "residuals_pa": res.tolist()}


def law_of(fit: dict) -> Hyperelastic:
    """The law of one of `fit_material`'s rows."""
    return _law(fit["law"], np.array(list(fit["parameters"].values())), fit["material"]["bulk_ratio"])


def fit_material(path, region: str = "cortex", laws=FIT_LAWS, bulk_ratio: float = BULK_RATIO) -> dict:
    """Fit every law in `laws` to `region` of the data file; choose by AICc among identified fits."""
    curve = read_curve(path, region)
    fits = [fit_law(curve, name, bulk_ratio) for name in laws]
    candidates = [f for f in fits if f["identified"]] or fits
    chosen = min(candidates, key=lambda f: f["aicc"])
    warning = None if chosen["identified"] else (f"no law's parameters are identified by these data; {chosen['law']} has the lowest "
                                                 "AICc, but its intervals are wide or a parameter is at its bound")
    return {"law": chosen["material"]["law"], **{k: v for k, v in chosen["material"].items() if k != "law"}, "warning": warning,
            "fit": chosen["law"], "rms_rel": chosen["rms_rel"], "rms_rel_tension": chosen["rms_rel_tension"],
            "rms_rel_compression": chosen["rms_rel_compression"], "shear_modulus_pa": chosen["shear_modulus_pa"],
            "laws": fits,
            "data": {"path": curve.path, "sha256": curve.sha256, "region": region, "points": len(curve.stretch),
                     "stretch_range": [float(curve.stretch.min()), float(curve.stretch.max())]},
            "method": ("least squares on the nominal stress (Pa), tension and compression together; uniaxial loading with free "
                       f"lateral faces, nearly incompressible (kappa = {bulk_ratio:g} mu); chosen by AICc among identified fits")}
