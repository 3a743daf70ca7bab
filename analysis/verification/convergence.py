"""Richardson extrapolation and Roache's grid convergence index from two or three meshes with
any refinement ratios (Celik et al. 2008, J. Fluids Eng. 130: 078001), with a conservative
fallback for oscillatory or diverging sequences."""

from __future__ import annotations

import math

import numpy as np

GCI_FS3 = 1.25  # Roache's factor of safety, three meshes with a reasonable observed order
GCI_FS_FALLBACK = 3.0  # two meshes, or an order that cannot be trusted: with the assumed order
ASSUMED_ORDER = 2.0
ORDER_RANGE = (0.5, 4.0)  # observed orders outside this are not trusted (P2: 2 for the energy norm's square... up to 4 for smooth functionals)


def _observed_order(e21: float, e32: float, r21: float, r32: float) -> float:
    """Celik et al. (2008) eq. 3: p from  p ln r21 = ln|e32/e21| + ln((r21^p - s)/(r32^p - s)),
    s = sign(e32/e21); solved by bisection on [1e-3, 30] (reduces to ln(e32/e21)/ln r for r21 = r32)."""
    s = math.copysign(1.0, e32 / e21)
    ratio = math.log(abs(e32 / e21))

    def g(p):
        a, b = r21**p - s, r32**p - s
        if a <= 0 or b <= 0:
            return math.nan
        return p * math.log(r21) - ratio - math.log(a / b)

    if abs(r21 - r32) < 1e-12 * r21:
        return ratio / math.log(r21)
    lo, hi = 1e-3, 30.0
    glo, ghi = g(lo), g(hi)
    if not (math.isfinite(glo) and math.isfinite(ghi)) or glo * ghi > 0:
        # no bracket: the fixed-point iteration of Celik's procedure
        p = ratio / math.log(r21)
        for _ in range(200):
            a, b = r21**p - s, r32**p - s
            if a <= 0 or b <= 0:
                return math.nan
            p_new = abs(ratio + math.log(a / b)) / math.log(r21)
            if abs(p_new - p) < 1e-14:
                return p_new
            p = p_new
        return p
    for _ in range(200):
        mid = 0.5 * (lo + hi)
        gm = g(mid)
        if gm == 0 or hi - lo < 1e-15:
            return mid
        if gm * glo > 0:
            lo, glo = mid, gm
        else:
            hi = mid
    return 0.5 * (lo + hi)


def richardson(f1: float, f2: float, f3: float, h1: float, h2: float, h3: float, fs: float = GCI_FS3,
               order_range: tuple[float, float] = ORDER_RANGE, assumed_order: float = ASSUMED_ORDER) -> dict:
    """Observed order, Richardson-extrapolated value and Roache's GCI from three meshes,
    1 finest (h1 < h2 < h3), any ratios r21 = h2/h1, r32 = h3/h2.

    - Monotone convergence (0 < R < 1, R = (f2 - f1)/(f3 - f2)) with an observed order p in
      `order_range`: ``f_ext = f1 + (f1 - f2)/(r21^p - 1)``, ``GCI = fs |(f1 - f2)/f1| /
      (r21^p - 1)`` (fs = 1.25), band ``f1 (1 +- GCI)``.
    - Otherwise (oscillatory R < 0, diverging R > 1, p outside the range, or f1 = f2 = f3
      within rounding): no extrapolation (f_ext = f1) and a conservative band: the larger of
      the GCI with fs = 3 and the `assumed_order`, and the largest spread |f_i - f1| / |f1|.
    Returns a dict: p (observed, NaN when undefined), p_used, f_ext, gci (relative), band
    (lo, hi), status ("monotone", "oscillatory", "diverging", "order out of range",
    "converged"), r21, r32, R, fs, extrapolated (bool).
    """
    if not (h1 < h2 < h3):
        raise ValueError(f"richardson: need h1 < h2 < h3 (finest first), got {h1:g}, {h2:g}, {h3:g}")
    r21, r32 = h2 / h1, h3 / h2
    e21, e32 = f2 - f1, f3 - f2
    scale = max(abs(f1), abs(f2), abs(f3), 1e-300)
    out = {"r21": r21, "r32": r32, "f1": f1, "f2": f2, "f3": f3}
    if abs(e21) <= 1e-13 * scale and abs(e32) <= 1e-13 * scale:
        return out | {"status": "converged", "R": math.nan, "p": math.nan, "p_used": math.nan, "fs": fs, "f_ext": f1,
                      "gci": 0.0, "band": (f1, f1), "extrapolated": False}
    R = e21 / e32 if e32 != 0 else math.inf
    p = math.nan
    if 0 < R < 1:
        p = _observed_order(e21, e32, r21, r32)
        status = "monotone" if order_range[0] <= p <= order_range[1] else "order out of range"
    elif R < 0:
        status = "oscillatory"
    else:
        status = "diverging"
    if status == "monotone":
        f_ext = f1 + (f1 - f2) / (r21**p - 1.0)
        gci = fs * abs(e21 / f1) / (r21**p - 1.0)
        out |= {"p_used": p, "fs": fs, "extrapolated": True}
    else:
        f_ext = f1
        gci = max(GCI_FS_FALLBACK * abs(e21 / f1) / (r21**assumed_order - 1.0),
                  max(abs(f2 - f1), abs(f3 - f1)) / abs(f1))
        out |= {"p_used": assumed_order, "fs": GCI_FS_FALLBACK, "extrapolated": False}
    return out | {"status": status, "R": R, "p": p, "f_ext": f_ext, "gci": gci, "band": (f1 - gci * abs(f1), f1 + gci * abs(f1))}


def richardson2(f1: float, f2: float, h1: float, h2: float, order: float = ASSUMED_ORDER, fs: float = GCI_FS_FALLBACK) -> dict:
    """Two meshes (1 finest): no observed order; Richardson with the assumed `order` and
    Roache's two-mesh factor of safety fs = 3."""
    if not h1 < h2:
        raise ValueError(f"richardson2: need h1 < h2 (finest first), got {h1:g}, {h2:g}")
    r21 = h2 / h1
    d = r21**order - 1.0
    f_ext = f1 + (f1 - f2) / d
    gci = fs * abs((f2 - f1) / f1) / d
    return {"r21": r21, "r32": math.nan, "f1": f1, "f2": f2, "f3": math.nan, "status": "two meshes", "R": math.nan,
            "p": math.nan, "p_used": order, "fs": fs, "f_ext": f_ext, "gci": gci,
            "band": (f1 - gci * abs(f1), f1 + gci * abs(f1)), "extrapolated": True}


def converge(forces, hs) -> dict:
    """`richardson` (three meshes) or `richardson2` (two) on forces ordered like hs (any order)."""
    order = np.argsort(hs)
    f = [float(forces[i]) for i in order]
    h = [float(hs[i]) for i in order]
    if len(f) == 3:
        return richardson(*f, *h)
    if len(f) == 2:
        return richardson2(*f, *h)
    raise ValueError(f"converge: need two or three meshes, got {len(f)}")
