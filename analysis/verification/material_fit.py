"""Fitting the finite-strain laws to tissue data (`studyctl calibrate material`).

Each law (`sim.hyperelastic`: neo-Hookean, Mooney-Rivlin, one- and two-term Ogden) is fitted
to every loading mode its data files hold together: uniaxial tension and compression (nominal
stress; the law's own volumetric part, kappa = bulk_ratio mu, and free lateral faces: the same
closed form the FEM's cube tests hold the FEM to) and simple shear (the shear stress, J = 1:
`shear_stress`). One file: least squares on the stress (Pa). Several files: each file's
residuals divided by the RMS of its data, so that every file counts alike whatever its stress
scale. Each mode's error is reported, and each mode's error when the law is fitted without it
(leave one mode out: how well the others predict it). The shear
moduli are bounded below by 0 (a negative term is unstable). Ogden's exponents are started
from a grid (the objective has several minima) and the best kept.

Per law: the parameters with 95% intervals from the Jacobian at the optimum (the
covariance s^2 (J^T J)^-1, t quantile; the data points are points of a mean curve, not
independent measurements, so read these as the precision of the fit to that curve), the RMS
error relative to the data's RMS, overall and per mode, and AICc and BIC. The law chosen is
the one of lowest AICc among those whose parameters are identified (every interval finite
and narrower than the value itself); the others are reported beside it.

Odd data are said, not fitted silently: rows repeated exactly (same region, strain and stress)
are counted once, and the count merged is reported (a copy pasted twice is not a second
measurement, and would narrow the intervals); a data set given twice (the same file, or a copy
of its rows) is refused; rows that are not one smooth curve (kPa and Pa mixed, a scatter about
their neighbours far beyond a measured mean curve's) are refused before any fit; a region whose stresses are all zero, and a fit
no law explains (R^2 <= 0 for the chosen law: no better than the data's mean), are refused; a
region of more than `MAX_POINTS` points is refused before any fit (bin or thin the curve: the
fit's time grows with the points, and a mean curve needs a few hundred at most).
"""

from __future__ import annotations

import hashlib
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from scipy.optimize import least_squares
from scipy.stats import t as student_t

from analysis.errors import InputError
from analysis.study.csvfiles import read_csv
from brainsim_assets import path as _asset
from sim.hyperelastic import BULK_RATIO, Hyperelastic, mooney_rivlin, neo_hookean, ogden, uniaxial
from sim.material import load_material

DATA_FILE = _asset("data/brain_tissue_uniaxial_budday2017.csv")
SHEAR_FILE = _asset("data/brain_tissue_shear_budday2017.csv")
# a file's loading mode, from its columns
MODES = {"uniaxial": ("stretch", "nominal_stress_kpa"), "shear": ("shear_strain", "shear_stress_kpa")}
SHEAR_BAND = (0.1, 0.2)  # |shear strain| where a law's worst relative shear error is reported
FIT_LAWS = ("neo-hookean", "mooney-rivlin", "ogden", "ogden-2")
ALPHA_STARTS = (-30.0, -20.0, -10.0, -4.0, 4.0, 10.0)
MAX_POINTS = 1000  # of one file's region, after merging repeated rows: a mean curve needs a few hundred
# Rows that are not one curve. The shipped curves' neighbours differ by at most 2.2x (next to the
# zero crossing), kPa among Pa by 1000x: a row 100x off both its neighbours is a unit mixed in.
UNIT_JUMP = 100.0
# The scatter about the neighbours' line, over the stresses' RMS: the shipped curves 0.8..2.6%,
# thinned to 11 points (their bend then counts) 7%, rows alternating kPa and Pa 97..112%.
SCATTER_MAX = 0.3
SCATTER_MIN_POINTS = 10


class MaterialDataError(InputError):
    """A tissue data file that cannot be fitted (named file, row and field)."""


@dataclass(frozen=True)
class Curve:
    path: str
    sha256: str
    region: str
    x: np.ndarray  # stretch (uniaxial) or shear strain (shear)
    stress: np.ndarray  # nominal (uniaxial) or shear (shear), Pa
    mode: str = "uniaxial"
    duplicates: int = 0  # rows that repeated an earlier row exactly, counted once

    @property
    def stretch(self) -> np.ndarray:
        return self.x

    def modes(self) -> np.ndarray:
        """Each point's mode: tension, compression (uniaxial) or shear."""
        if self.mode == "shear":
            return np.full(len(self.x), "shear")
        return np.where(self.x > 1.0, "tension", "compression")


def read_curve(path, region: str) -> Curve:
    """The rows of `region` in a CSV of one loading mode, read from its columns: region, stretch,
    nominal_stress_kpa (uniaxial) or region, shear_strain, shear_stress_kpa (simple shear); read
    strictly (`analysis.study.csvfiles.read_csv`): a bad cell is named by its line and column."""
    p = Path(path)
    allowed = ("region",) + tuple(c for cols in MODES.values() for c in cols)
    rows = read_csv(p, allowed, ("region",))
    header = set(rows[0][1]) if rows else set()
    found = [m for m, cols in MODES.items() if set(cols) <= header]
    for cols in MODES.values():  # half a mode's columns: name the missing one
        if len(found) == 0 and any(c in header for c in cols):
            missing = next(c for c in cols if c not in header)
            raise MaterialDataError(f"{p}: no {missing!r} column; a file is region, " + " or region, ".join(", ".join(c) for c in MODES.values()))
    if len(found) != 1:
        raise MaterialDataError(f"{p}: the columns must be region, then " + " or ".join(", ".join(c) for c in MODES.values())
                                + f" (one loading mode a file); found {', '.join(sorted(header)) or 'none'}")
    mode = found[0]
    xcol, ycol = MODES[mode]
    regions = sorted({r["region"] for _, r in rows if r["region"]})
    mine = [(line, r) for line, r in rows if r["region"] == region]
    if not mine:
        raise MaterialDataError(f"{p}: region {region!r} has no rows; regions there: {', '.join(regions) or 'none'}")
    ranges = {"stretch": (0.2, 5.0), "shear_strain": (-5.0, 5.0), "nominal_stress_kpa": (-1e6, 1e6), "shear_stress_kpa": (-1e6, 1e6)}
    values = {xcol: [], ycol: []}
    for line, r in mine:
        for col in (xcol, ycol):
            lo, hi = ranges[col]
            try:
                v = float(r[col])
            except ValueError:
                v = math.nan
            if not (math.isfinite(v) and lo <= v <= hi):
                raise MaterialDataError(f"{p}:{line}: {col}: {r[col][:20]!r} is out of range; allowed: a number in {lo:g}..{hi:g}")
            values[col].append(v)
    first = {}  # exact repeats counted once, the first kept, in order, with its line
    for (line, _), pair in zip(mine, zip(values[xcol], values[ycol])):
        first.setdefault(pair, line)
    pairs = list(first)
    duplicates = len(mine) - len(pairs)
    if len(pairs) > MAX_POINTS:
        raise MaterialDataError(f"{p}: region {region!r} has {len(pairs)} points; allowed: at most {MAX_POINTS} a file "
                                "(bin or thin the curve, e.g. a mean stress per strain step)")
    x, stress = np.array([a for a, _ in pairs]), np.array([b for _, b in pairs]) * 1e3
    if not np.any(stress != 0.0):
        raise MaterialDataError(f"{p}: region {region!r}: every {ycol} is 0; there is nothing to fit")
    _check_one_curve(p, region, xcol, ycol, x, stress, list(first.values()))
    if mode == "uniaxial" and ((x < 1).sum() < 2 or (x > 1).sum() < 2):
        raise MaterialDataError(f"{p}: region {region!r} needs at least two points in tension and two in compression")
    if mode == "shear" and (np.abs(x) > 0).sum() < 2:
        raise MaterialDataError(f"{p}: region {region!r} needs at least two points at a non-zero shear strain")
    return Curve(str(p), hashlib.sha256(p.read_bytes()).hexdigest(), region, x, stress, mode, duplicates)


def _check_one_curve(p: Path, region: str, xcol: str, ycol: str, x: np.ndarray, y: np.ndarray, lines: list[int]) -> None:
    """Refuse rows that are not one smooth curve (before any fit: a law fitted to them reads a
    mix as a modulus): a row `UNIT_JUMP` times above or below both its neighbours of the same
    sign (by strain), which is kPa and Pa mixed; else a scatter about the neighbours' line over
    `SCATTER_MAX` of the stresses' RMS."""
    order = np.argsort(x, kind="stable")
    ys = y[order]
    for i in range(1, len(ys) - 1):
        a, b, c = ys[i - 1], ys[i], ys[i + 1]
        if a * b > 0 and b * c > 0:
            up, down = min(abs(b / a), abs(b / c)), min(abs(a / b), abs(c / b))
            if max(up, down) >= UNIT_JUMP:
                j, k = order[i - 1], order[i]
                raise MaterialDataError(
                    f"{p}: region {region!r}: {ycol} jumps {max(up, down):.3g}x between neighbouring rows and back (line {lines[j]}: "
                    f"{y[j] / 1e3:g} at {xcol} {x[j]:g}; line {lines[k]}: {y[k] / 1e3:g} at {x[k]:g}): kPa and Pa mixed? "
                    "give every row in kPa; nothing fitted")
    scatter = curve_scatter(x, y)
    if scatter > SCATTER_MAX:
        raise MaterialDataError(
            f"{p}: region {region!r}: the rows scatter about their neighbours by {scatter:.0%} of the stresses' RMS; allowed: at most "
            f"{SCATTER_MAX:.0%} (a measured mean curve is smooth: the shipped curves scatter by under 3%); mixed units, or two "
            "data sets in one? nothing fitted")


def curve_scatter(x: np.ndarray, y: np.ndarray) -> float:
    """The rows' scatter over the stresses' RMS: the larger of the replicates' spread at one
    strain and the mean curve's noise about the line through each point's neighbours (as a noise
    sigma, whatever the spacing); 0 for fewer than `SCATTER_MIN_POINTS` strains, whose
    neighbours' line measures the curve's bend, not its scatter."""
    xs, ys = np.asarray(x, float), np.asarray(y, float)
    ux = np.unique(xs)
    if len(ux) < SCATTER_MIN_POINTS:
        return 0.0
    mean = np.array([ys[xs == v].mean() for v in ux])
    within = float(np.sqrt(np.mean((ys - mean[np.searchsorted(ux, xs)]) ** 2)))
    w = (ux[1:-1] - ux[:-2]) / (ux[2:] - ux[:-2])
    off = mean[1:-1] - (mean[:-2] + w * (mean[2:] - mean[:-2]))
    between = float(np.sqrt(np.mean(off**2) / np.mean(1.0 + w**2 + (1.0 - w) ** 2)))
    return max(within, between) / float(np.sqrt(np.mean(ys**2)))


def shear_stretch(gamma) -> np.ndarray:
    """The larger in-plane principal stretch of simple shear by `gamma` (>= 1 for gamma >= 0):
    sqrt(1 + gamma^2 / 4) + gamma / 2; the other is its inverse, the third 1."""
    g = np.asarray(gamma, dtype=np.float64)
    return np.sqrt(1.0 + 0.25 * g * g) + 0.5 * g


def shear_stress(law: Hyperelastic, gamma) -> np.ndarray:
    """The shear stress (Pa) of simple shear F = I + gamma e1 (x) e2, in closed form: principal
    stretches l1 = sqrt(1 + gamma^2 / 4) + gamma / 2, l2 = 1 / l1, l3 = 1 (J = 1: no volumetric
    part), tau = (s1 - s2) / (l1 + l2) with s1 - s2 = sum_p (2 mu_p / alpha_p)(l1^a_p - l2^a_p)
    (the Cauchy stress rotated to the shear plane; the first Piola-Kirchhoff's 12 entry is the
    same). The tests' `simple_shear` (tests/helpers.py) gives the whole tensor by an eigendecomposition."""
    l1 = shear_stretch(gamma)
    l2 = 1.0 / l1
    return sum(2.0 * m / a * (l1**a - l2**a) for m, a in zip(law.mu, law.alpha)) / (l1 + l2)


def principal_stretch_range(curves: list[Curve]) -> tuple[float, float]:
    """The principal stretches the data's loading states cover: a uniaxial test's axial stretch
    and its lateral one (the incompressible limit, l^-1/2), simple shear's l1 and 1/l1 (l3 = 1).
    A law is measured inside this range and extrapolated outside it."""
    ends = []
    for c in curves:
        if c.mode == "shear":
            l1 = shear_stretch(np.abs(c.x))
            ends += [l1.max(), (1.0 / l1).min()]
        else:
            ends += [c.x.min(), c.x.max(), (c.x ** -0.5).min(), (c.x ** -0.5).max()]
    return float(min(ends)), float(max(ends))


def _predict(law: Hyperelastic, curve: Curve) -> np.ndarray:
    return shear_stress(law, curve.x) if curve.mode == "shear" else uniaxial(law, curve.x)[0]


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


def _mu_start(curves: list[Curve]) -> float:
    """A start for mu from the small-strain slope: dP/dlambda = 3 mu (uniaxial, incompressible),
    dtau/dgamma = mu (shear)."""
    for c in curves:
        near = np.abs(c.x - (0.0 if c.mode == "shear" else 1.0)) <= (0.051 if c.mode == "shear" else 0.031)
        if near.sum() >= 2:
            slope = float(np.polyfit(c.x[near] - (0.0 if c.mode == "shear" else 1.0), c.stress[near], 1)[0])
            return max(slope / (1.0 if c.mode == "shear" else 3.0), 1.0)
    return 1000.0


def _solve(curves: list[Curve], name: str, bulk_ratio: float, weights: list[float], keep: list[np.ndarray]):
    """The best least-squares optimum over the law's starts, on the kept points of each curve
    (residuals times each curve's weight); None when no start gives a finite one."""
    def residual(x):
        law = _law(name, x, bulk_ratio)
        return np.concatenate([(_predict(law, c) - c.stress)[k] * w for c, w, k in zip(curves, weights, keep)])

    best = None
    for x0, bounds in _starts(name, _mu_start(curves)):
        try:
            r = least_squares(residual, x0, bounds=bounds, x_scale="jac", xtol=1e-12, ftol=1e-12, gtol=1e-12, max_nfev=4000)
        except ValueError:  # a start whose law over/underflows
            continue
        if np.all(np.isfinite(r.fun)) and (best is None or r.cost < best.cost):
            best = r
    return best


def _rms_rel(res: np.ndarray, y: np.ndarray) -> float:
    return float(np.sqrt(np.mean(res**2)) / np.sqrt(np.mean(y**2))) if len(y) else math.nan


def fit_law(curves, name: str, bulk_ratio: float = BULK_RATIO) -> dict:
    """One law's least-squares fit to the curves (one `Curve` or several, each of one mode):
    parameters, intervals, each mode's error, each mode's error when fitted without it, criteria."""
    curves = [curves] if isinstance(curves, Curve) else list(curves)
    # one file: the stress in Pa as it is; several: each file's residuals over its data's RMS
    weights = [1.0] if len(curves) == 1 else [1.0 / float(np.sqrt(np.mean(c.stress**2))) for c in curves]
    everything = [np.ones(len(c.x), bool) for c in curves]
    best = _solve(curves, name, bulk_ratio, weights, everything)
    if best is None:
        raise MaterialDataError(f"{curves[0].path}: the {name} law could not be fitted to region {curves[0].region!r} from any start "
                                "(its stresses over- or underflow there)")
    x, res = best.x, best.fun
    n, k = len(res), len(x)
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
    y = np.concatenate([c.stress for c in curves])
    modes = np.concatenate([c.modes() for c in curves])
    pa = np.concatenate([_predict(law, c) - c.stress for c in curves])  # the residuals in Pa, whatever the weights
    identified = bool(np.all(np.isfinite(half)) and np.all(half < np.abs(x)) and not any(at_bound))
    spread = float(np.sum((y - y.mean()) ** 2))
    r2 = 1.0 - float(np.sum(pa**2)) / spread if spread > 0.0 else math.nan
    aicc = n * math.log(rss / n) + 2 * k + (2 * k * (k + 1) / (n - k - 1) if n - k - 1 > 0 else math.inf)
    present = [m for m in ("tension", "compression", "shear") if (modes == m).any()]
    out = {"law": name, "parameters": dict(zip(_names(name), (float(v) for v in x))),
           "ci95": {p: [float(v - h), float(v + h)] for p, v, h in zip(_names(name), x, half)},
           "material": law.params(), "shear_modulus_pa": law.shear_modulus,
           "rms_rel": _rms_rel(pa, y), **{f"rms_rel_{m}": _rms_rel(pa[modes == m], y[modes == m]) for m in present},
           **({"rms_rel_uniaxial": _rms_rel(pa[modes != "shear"], y[modes != "shear"])} if "shear" in present and len(present) > 1 else {}),
           "rms_pa": float(np.sqrt(np.mean(pa**2))), "r2": r2, "aicc": aicc, "bic": n * math.log(rss / n) + k * math.log(n),
           "identified": identified, "at_bound": any(at_bound), "n": n, "k": k,
           "residuals_pa": pa.tolist()}
    if any(c.mode == "shear" for c in curves):
        out["shear_worst_rel"] = law_errors(law, curves)["shear_worst_rel"]
    if len(present) > 1:  # each mode predicted by a fit to the others
        out["left_out"] = {}
        for m in present:
            keep = [c.modes() != m for c in curves]
            alone = _solve(curves, name, bulk_ratio, weights, keep)
            if alone is None:
                out["left_out"][m] = math.nan
                continue
            other = _law(name, alone.x, bulk_ratio)
            held = np.concatenate([(_predict(other, c) - c.stress)[c.modes() == m] for c in curves])
            out["left_out"][m] = _rms_rel(held, y[modes == m])
    return out


def law_of(fit: dict) -> Hyperelastic:
    """The law of one of `fit_material`'s rows."""
    return _law(fit["law"], np.array(list(fit["parameters"].values())), fit["material"]["bulk_ratio"])


def _check_given_once(curves: list[Curve]) -> None:
    """Refuse a data set given twice (the same file, by another path or a link, or a copy of its
    rows): fitted as twice the points, it would narrow every interval. Files of one mode that
    share half the smaller one's rows are one data set."""
    for k, later in enumerate(curves):
        for earlier in curves[:k]:
            if later.mode != earlier.mode:
                continue
            shared = len(set(zip(later.x, later.stress)) & set(zip(earlier.x, earlier.stress)))
            if 2 * shared >= min(len(later.x), len(earlier.x)):
                raise MaterialDataError(f"{later.path}: the same rows as {earlier.path} ({shared} of {len(later.x)}); "
                                        "give each data set once")


def fit_material(paths, region: str = "cortex", laws=FIT_LAWS, bulk_ratio: float = BULK_RATIO, progress=None) -> dict:
    """Fit every law in `laws` to `region` of the data files (one path or several, each of one
    loading mode, fitted together); choose by AICc among identified fits. `progress(done,
    total)` is called once the data are read (done 0) and after each law. Raises MaterialDataError when the chosen law explains
    nothing (R^2 <= 0, or not finite)."""
    paths = [paths] if isinstance(paths, (str, Path)) else list(paths)
    curves = [read_curve(p, region) for p in paths]
    _check_given_once(curves)
    fits = []
    if progress is not None:  # the data read: the first law starts (its stage can be said before its wait)
        progress(0, len(laws))
    for name in laws:
        fits.append(fit_law(curves, name, bulk_ratio))
        if progress is not None:
            progress(len(fits), len(laws))
    candidates = [f for f in fits if f["identified"]] or fits
    chosen = min(candidates, key=lambda f: f["aicc"])
    if not (math.isfinite(chosen["r2"]) and chosen["r2"] > 0.0 and math.isfinite(chosen["rms_rel"])):
        what = f"R^2 {chosen['r2']:.3g}" if math.isfinite(chosen["r2"]) else "the stresses do not vary"
        raise MaterialDataError(f"{', '.join(str(p) for p in paths)}: region {region!r}: no law explains these data (the chosen "
                                f"{chosen['law']}: {what}, no better than the data's mean); nothing fitted")
    warning = None if chosen["identified"] else (f"no law's parameters are identified by these data; {chosen['law']} has the lowest "
                                                 "AICc, but its intervals are wide or a parameter is at its bound")
    files = [{"path": c.path, "sha256": c.sha256, "region": region, "mode": c.mode, "points": len(c.x), "duplicates_merged": c.duplicates,
              ("stretch_range" if c.mode == "uniaxial" else "shear_strain_range"): [float(c.x.min()), float(c.x.max())]} for c in curves]
    modes = "uniaxial tension and compression" if all(c.mode == "uniaxial" for c in curves) else \
        " and ".join(sorted({"uniaxial tension and compression" if c.mode == "uniaxial" else "simple shear" for c in curves}, reverse=True))
    weighting = "on the stress (Pa)" if len(curves) == 1 else "each file's residuals divided by its data's RMS"
    keys = [k for k in chosen if k.startswith("rms_rel") or k in ("shear_worst_rel", "left_out", "shear_modulus_pa")]
    return {"law": chosen["material"]["law"], **{k: v for k, v in chosen["material"].items() if k != "law"}, "warning": warning,
            "fit": chosen["law"], **{k: chosen[k] for k in keys},
            "laws": fits, "data": files[0], "files": files,
            # where the law is measured: a state whose principal stretches leave this range is extrapolation
            "principal_stretch_range": list(principal_stretch_range(curves)),
            "method": (f"least squares {weighting}, {modes} together; uniaxial loading with free lateral faces, simple shear in "
                       f"closed form (J = 1); nearly incompressible (kappa = {bulk_ratio:g} mu); chosen by AICc among identified fits")}


def material_data(material_path) -> tuple[list[Path], str]:
    """The data files a material file's law was fitted to (its provenance's `data`, and
    `data_shear` for a fit across modes: beside the material file, else among the shipped data)
    and the region; raises MaterialDataError naming what is missing."""
    try:
        _, prov = load_material(Path(material_path))
    except Exception as exc:  # an inline law, a missing file: no provenance to follow
        raise MaterialDataError(f"{material_path}: the material's provenance cannot be read ({type(exc).__name__})") from None
    names = [prov.get("data")] + [v for k, v in prov.items() if k.startswith("data_") and isinstance(v, str)]
    if not names[0] or not prov.get("region"):
        raise MaterialDataError(f"{material_path}: the material file names no data file and region")
    paths = []
    for name in names:
        found = next((p for p in (Path(material_path).parent / name, _asset(f"data/{name}")) if p.exists()), None)
        if found is None:
            raise MaterialDataError(f"{material_path}: the material's data file {name} is not beside it nor shipped")
        paths.append(found)
    return paths, str(prov["region"])


def law_errors(law: Hyperelastic, curves: list[Curve]) -> dict:
    """A law's errors on data curves: the uniaxial RMS relative to the data's RMS and the worst
    relative shear error over `SHEAR_BAND` (NaN where the curves hold no such mode)."""
    uni = [c for c in curves if c.mode == "uniaxial"]
    shear = [c for c in curves if c.mode == "shear"]
    out = {"rms_rel_uniaxial": math.nan, "shear_worst_rel": math.nan}
    if uni:
        res = np.concatenate([_predict(law, c) - c.stress for c in uni])
        out["rms_rel_uniaxial"] = _rms_rel(res, np.concatenate([c.stress for c in uni]))
    if shear:
        band = [(np.abs(c.x) >= SHEAR_BAND[0] - 1e-12) & (np.abs(c.x) <= SHEAR_BAND[1] + 1e-12) for c in shear]
        rel = np.concatenate([np.abs(shear_stress(law, c.x[b]) / c.stress[b] - 1.0) for c, b in zip(shear, band)])
        out["shear_worst_rel"] = float(rel.max()) if len(rel) else math.nan
    return out


def fitted_range(material_path) -> tuple[tuple[float, float] | None, str]:
    """The principal stretches a material file's law was fitted to (`material_data`'s files, for
    its region). (None, why) when they cannot be found or read."""
    try:
        paths, region = material_data(material_path)
        curves = [read_curve(p, region) for p in paths]
    except InputError as exc:
        return None, str(exc)
    return principal_stretch_range(curves), f"{', '.join(p.name for p in paths)}, region {region}"


def chosen_material(rep: dict, region: str, command: str) -> tuple[Hyperelastic, dict]:
    """The law `fit_material` chose and its provenance for a material file: the data files and
    their SHA-256, the published source when they are the shipped ones, the fit's method, errors
    (left-out ones too) and 95% intervals, and the `command` that made it."""
    chosen = next(f for f in rep["laws"] if f["law"] == rep["fit"])
    shipped = {Path(DATA_FILE).name, Path(SHEAR_FILE).name}
    prov = {"data": Path(rep["data"]["path"]).name, "sha256": rep["data"]["sha256"], "region": region,
            **{f"data_{f['mode']}": Path(f["path"]).name for f in rep["files"][1:]},
            **{f"sha256_{f['mode']}": f["sha256"] for f in rep["files"][1:]},
            "source": "Budday et al. 2017, Acta Biomaterialia 48:319-340 (as tabulated by Linka et al. 2023)"
            if all(Path(f["path"]).name in shipped for f in rep["files"]) else "",
            "fit": rep["method"], **{k: v for k, v in rep.items() if k.startswith("rms_rel") or k == "shear_worst_rel"},
            **{f"left_out_rms_rel_{m}": v for m, v in (rep.get("left_out") or {}).items()},
            **{f"ci95_{k}": v for k, v in chosen["ci95"].items()}, "command": command}
    return law_of(chosen), prov
