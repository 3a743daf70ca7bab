"""The plate-spring soft-tissue model of Zhang et al. (2015), Eqs. (1)-(19).

See docs/plate_spring.md for the equations, the gaps the paper leaves and how they are
resolved here. Everything is SI (m, N, Pa, s).

Two variants:

- ``paper``: layer j >= 2 consumes ``F_j = 48 E I_j x_c1 / (delta L_j^3)`` (Eq. 9), so the
  deformation X(F) jumps at layer transitions (forwards or backwards).
- ``continuous``: every layer consumes its DCL capacity ``n_j x_c1 Pc_j``; X(F) is continuous,
  piecewise linear and strictly increasing. The default for rendering.

The haptic direction (displacement in, force out) inverts X(F): ``force(X) = min{F >= 0 :
X(F) >= X}``. Both variants are precomputed into one table of linear segments over X, so a
servo tick is a binary search and a multiply-add.
"""

from __future__ import annotations

import bisect
import dataclasses
import math
from collections.abc import Sequence
from dataclasses import asdict, dataclass, fields
from pathlib import Path

import numpy as np

from sim.errors import ParameterError
from sim.laws import RadialTable, TensorTable
from sim.models.base import Contact
from sim.models.builtin import PLATE_SPRING_VARIANTS, PlateSpringBase
from sim.stiffness_field import FIELD_FILE, load_field
from sim.tomlfile import TomlFileError, read_toml
from sim.tomltable import REQUIRED

VARIANTS = ("paper", "continuous")  # of the stack
MODEL_VARIANTS = PLATE_SPRING_VARIANTS  # of the tissue model: "located" is the continuous stack with a stiffness field
HAPTIC_PERIOD_S = 1e-3  # 1 kHz servo rate: the T of Eq. (18)

# The paper bounds B by "b <= B <= b + 0.1" with no unit; we read the 0.1 as millimetres
# (plates are millimetre-scale on a brain; 0.1 m would be wider than the organ).
B_SLACK_M = 1e-4
# Upper bounds of the stack's values, wide but physical (a value beyond is a slip of units):
# plates and their deflection of millimetres, at most 0.1 m (wider than the organ); the plates'
# modulus (the stack's own, not the tissue's) at most 1e12 Pa, stiffer than steel; Eq. (9)'s
# coefficient (1 in the paper's reading) up to 1e3; a layer's delay (Eq. 17) at most 1 s and its
# ratio at most 10 (the servo's period is 1 ms); the paper's 6 layers, the stability sweep's 60,
# at most 1000.
PARAM_MOST = {"b": 0.1, "h1": 0.1, "l1": 0.1, "x_c1": 0.1, "E": 1e12, "delta": 1e3, "t1": 1.0, "omega": 10.0}
MAX_LAYERS = 1000

_FLOAT_KEYS = ("b", "h1", "l1", "alpha", "q", "B", "E", "x_c1", "delta", "t1", "omega")
_KEYS = ("b", "h1", "l1", "alpha", "q", "layers", "B", "E", "x_c1", "delta", "t1", "omega")


@dataclass(frozen=True)
class PlateSpringParams:
    """Parameters of the stack (SI units). Validated on construction."""

    b: float  # plate width, m
    h1: float  # first-layer thickness, m
    l1: float  # first-layer plate length, m
    alpha: float  # thickness ratio between layers, [1, 2]
    q: float  # length ratio between successive plates, [1, 1.5]
    layers: int  # number of layers N, >= 1
    B: float  # hoop width, [b, b + 0.1 mm]
    E: float  # elastic modulus of the plates, Pa
    x_c1: float  # given deflection of one plate, m
    delta: float = 1.0  # the undefined coefficient of Eq. (9), dimensionless
    t1: float = 1e-4  # delay of the first layer, s
    omega: float = 1.0  # delay ratio between layers

    def __post_init__(self) -> None:
        for name, unit in (("b", "m"), ("h1", "m"), ("l1", "m"), ("E", "Pa"), ("x_c1", "m"), ("delta", ""), ("t1", "s"), ("omega", "")):
            _check_positive(name, getattr(self, name), unit, PARAM_MOST[name])
        _check_range("alpha", self.alpha, 1.0, 2.0)
        _check_range("q", self.q, 1.0, 1.5)
        if isinstance(self.layers, bool) or not isinstance(self.layers, int) or not 1 <= self.layers <= MAX_LAYERS:
            raise ParameterError(f"layers: {self.layers!r} is out of range; allowed: an integer in 1..{MAX_LAYERS}")
        _check_range("B", self.B, self.b, self.b + B_SLACK_M, unit="m", note=" (b <= B <= b + 0.1 mm)")
        # Eq. (1) needs 2 L_i > 0.6 B; L_1 = l1 is the shortest equivalent length (q >= 1).
        if not 2.0 * self.l1 > 0.6 * self.B:
            raise ParameterError(
                f"B: {self.B:g} m is out of range; Eq. (1) needs 2*L_i > 0.6*B for every layer, "
                f"so B < {2.0 * self.l1 / 0.6:.6g} m with l1 = {self.l1:g} m"
            )

    @classmethod
    def from_mapping(cls, data: dict, source: str = "parameters") -> PlateSpringParams:
        """Build from a mapping (e.g. a parsed TOML file), with errors naming `source`."""
        unknown = sorted(set(data) - set(_KEYS))
        if unknown:
            raise ParameterError(f"{source}: unknown key {unknown[0]!r}; allowed keys: {', '.join(_KEYS)}")
        missing = [k for k in _KEYS if k not in data]
        if missing:
            raise ParameterError(f"{source}: missing key {missing[0]!r}; required keys: {', '.join(_KEYS)}")
        values: dict = {}
        for key in _FLOAT_KEYS:
            v = data[key]
            if isinstance(v, bool) or not isinstance(v, (int, float)):
                raise ParameterError(f"{source}: {key}: {v!r} is not a number")
            values[key] = float(v)
        layers = data["layers"]
        if isinstance(layers, bool) or not isinstance(layers, int):
            raise ParameterError(f"{source}: layers: {layers!r} is not an integer; allowed: an integer >= 1")
        values["layers"] = layers
        try:
            params = cls(**values)
            for variant in VARIANTS:  # the derived layer table must be finite too
                PlateSpring(params, variant)
        except ParameterError as exc:
            raise ParameterError(f"{source}: {exc}") from None
        return params

    def as_dict(self) -> dict:
        return asdict(self)


def _check_positive(name: str, value: float, unit: str, most: float) -> None:
    if not (math.isfinite(value) and value > 0.0):
        raise ParameterError(f"{name}: {value!r} is out of range; allowed: a finite number > 0 {unit}".rstrip())
    if value > most:
        raise ParameterError(f"{name}: {value!r} is out of range; allowed: (0, {most:g}] {unit}".rstrip())


def _check_range(name: str, value: float, lo: float, hi: float, unit: str = "", note: str = "") -> None:
    if not (math.isfinite(value) and lo <= value <= hi):
        raise ParameterError(f"{name}: {value!r} is out of range; allowed: [{lo:g}, {hi:g}] {unit}".rstrip() + note)


def load_params(path: str | Path) -> PlateSpringParams:
    """Read a parameter file (TOML, top-level keys in SI units)."""
    path = Path(path)
    try:
        data, _ = read_toml(path)
    except TomlFileError as exc:
        raise ParameterError(str(exc)) from None
    return PlateSpringParams.from_mapping(data, source=str(path))


@dataclass(frozen=True)
class Solution:
    """The stack under a tension F (Eqs. 12, 13, 19)."""

    force: float
    dcl: int  # deformation cut-off layer M, 1-based
    deformation: float  # X
    layer_deformation: tuple[float, ...]  # X_i for i = 1..N (0 beyond the DCL)
    plate_deformation: float  # X_M / n_M
    overstretched: bool  # the DCL's plates deflect more than x_c1
    saturated: bool  # M = N and overstretched: beyond what N layers model


@dataclass(frozen=True)
class Jump:
    """A discontinuity of X(F) at the transition from layer `layer` to `layer + 1`."""

    layer: int
    force: float  # S_{M+1}: where the transition happens
    x_before: float  # lim X(F) from below
    x_after: float  # X at the transition, C_{M+1}

    @property
    def size(self) -> float:
        return self.x_after - self.x_before

    @property
    def kind(self) -> str:
        return "forward" if self.size > 0 else "backward"


class PlateSpring:
    """The layered stack: precomputed layer table, X(F), its inverse, delay budget."""

    def __init__(self, params: PlateSpringParams, variant: str = "continuous"):
        if variant not in VARIANTS:
            raise ParameterError(f"variant: {variant!r} is not one of {', '.join(VARIANTS)}")
        self.params = params
        self.variant = variant
        p = params
        n_layers = p.layers
        i = np.arange(1, n_layers + 1, dtype=np.float64)
        self.n = 2 * i - 1  # plates per layer
        with np.errstate(over="ignore", invalid="ignore", divide="ignore"):
            self.L = _equivalent_lengths(p.l1, p.q, n_layers)  # Eq. (2)
            self.H = p.h1 * p.alpha ** (i - 1)  # Eq. (5)
            self.I = p.b * self.H**3 / 12.0  # Eq. (4)
            self.P = 3.0 * p.E * self.I / self.L**3  # Eq. (3)
            self.Pc = (2 * self.L / (2 * self.L - 0.6 * p.B)) ** 3 * self.P  # Eq. (1)
            if variant == "paper":
                F = 48.0 * p.E * self.I * p.x_c1 / (p.delta * self.L**3)  # Eq. (9)
                F[0] = p.x_c1 * self.Pc[0]  # Eq. (6)
            else:
                F = self.n * p.x_c1 * self.Pc
            self.F = F  # force consumed by a fully stretched layer
            self.S = np.concatenate(([0.0], np.cumsum(F)[:-1]))  # S_M, tension where layer M starts
            self.C = p.x_c1 * (i - 1) ** 2  # C_M = x_c1 * (n_1 + ... + n_{M-1})
            self.t = p.t1 * p.omega ** (i - 1)  # Eq. (17)
            self.T = np.cumsum(self.t)  # Eq. (18)
        self._check_finite()
        self._build_inverse()

    # -- construction -------------------------------------------------------------------
    def _check_finite(self) -> None:
        arrays = (self.L, self.H, self.I, self.P, self.Pc, self.F, self.S)
        ok = all(np.all(np.isfinite(a)) and np.all(a > 0) for a in (self.L, self.H, self.I, self.P, self.Pc, self.F))
        ok = ok and all(np.all(np.isfinite(a)) for a in arrays)
        if not ok:
            top = _max_valid_layers(self.params, self.variant)
            raise ParameterError(
                f"layers: {self.params.layers} is out of range for these parameters; allowed: 1..{top} "
                f"(with q = {self.params.q:g} and alpha = {self.params.alpha:g}, q**(layers**2) or alpha**layers "
                "overflows the layer table)"
            )

    def _build_inverse(self) -> None:
        """Segments over X: on [x0[k], x0[k+1]) the force is f0[k] + slope[k] * (X - x0[k])."""
        x0: list[float] = []
        f0: list[float] = []
        slope: list[float] = []
        jumps: list[Jump] = []
        reached = 0.0  # the largest X already attained at a smaller force
        N = self.params.layers
        for m in range(N):
            c, s, k = float(self.C[m]), float(self.S[m]), float(self.Pc[m])
            x_sup = math.inf if m == N - 1 else c + float(self.F[m]) / k
            if m > 0:
                prev_sup = float(self.C[m - 1]) + float(self.F[m - 1]) / float(self.Pc[m - 1])
                if not math.isclose(prev_sup, c, rel_tol=1e-9, abs_tol=1e-15):
                    jumps.append(Jump(layer=m, force=s, x_before=prev_sup, x_after=c))
            if c > reached:  # a forward gap: X values no force reaches until S_M
                x0.append(reached)
                f0.append(s)
                slope.append(0.0)
                reached = c
            if x_sup > reached:
                x0.append(reached)
                f0.append(s + (reached - c) * k)
                slope.append(k)
                reached = x_sup
        self._x0, self._f0, self._slope = x0, f0, slope
        self.jumps: tuple[Jump, ...] = tuple(jumps)
        # Beyond this X the last layer is over-stretched (saturated stack).
        self.capacity_x = float(self.C[-1] + self.n[-1] * self.params.x_c1)
        self.capacity_f = float(self.S[-1] + self.F[-1])

    # -- force in, deformation out ---------------------------------------------------------
    def deformation(self, force: float) -> Solution:
        """Deformation of the stack under tension `force` (N): Eqs. (12), (13), (19)."""
        F = _as_float("force", force)
        if F < 0:
            raise ParameterError(f"force: {F:g} is out of range; allowed: >= 0 N")
        m = int(np.searchsorted(self.S, F, side="right"))  # DCL, 1-based: largest M with S_M <= F
        idx = m - 1
        x_m = (F - float(self.S[idx])) / float(self.Pc[idx])
        x = float(self.C[idx]) + x_m
        n_m = float(self.n[idx])
        layer_def = [float(self.n[j] * self.params.x_c1) for j in range(idx)] + [x_m]
        layer_def += [0.0] * (self.params.layers - m)
        over = x_m / n_m > self.params.x_c1 * (1 + 1e-12)
        return Solution(
            force=F,
            dcl=m,
            deformation=x,
            layer_deformation=tuple(layer_def),
            plate_deformation=x_m / n_m,
            overstretched=bool(over),
            saturated=bool(over and m == self.params.layers),
        )

    # -- displacement in, force out (the haptic direction) --------------------------------
    def force(self, displacement: float) -> float:
        """min{F >= 0 : X(F) >= displacement} for a displacement magnitude in metres."""
        x = _as_float("displacement", displacement)
        if x < 0:
            raise ParameterError(f"displacement: {x:g} is out of range; allowed: >= 0 m")
        return self.force_fast(x)

    def force_fast(self, x: float) -> float:
        """The per-tick path: no validation, x >= 0 assumed."""
        k = bisect.bisect_right(self._x0, x) - 1
        return self._f0[k] + self._slope[k] * (x - self._x0[k])

    def segments(self) -> list[tuple[float, float, float]]:
        """The inverse table: (x_start, force_at_start, slope) per segment."""
        return list(zip(self._x0, self._f0, self._slope))

    def layer_split(self, x: float) -> np.ndarray:
        """Per-layer deformation when the stack is stretched by X (layers fill in order)."""
        caps = self.n * self.params.x_c1
        before = self.C
        out = np.clip(x - before, 0.0, caps)
        out[-1] = max(x - before[-1], 0.0)  # the last layer takes any over-stretch
        return out

    # -- tables -------------------------------------------------------------------------
    def layers_in_budget(self, period: float = HAPTIC_PERIOD_S) -> int:
        """Largest i with T_i < period (Eq. 18); 0 if even the first layer does not fit."""
        return int(np.sum(self.T < period))

    def layer_table(self) -> list[dict]:
        rows = []
        for j in range(self.params.layers):
            rows.append(
                {
                    "layer": j + 1,
                    "plates": int(self.n[j]),
                    "length_m": float(self.L[j]),
                    "thickness_m": float(self.H[j]),
                    "inertia_m4": float(self.I[j]),
                    "stiffness_n_per_m": float(self.P[j]),
                    "corrected_stiffness_n_per_m": float(self.Pc[j]),
                    "consumed_force_n": float(self.F[j]),
                    "start_force_n": float(self.S[j]),
                    "start_deformation_m": float(self.C[j]),
                    "delay_s": float(self.t[j]),
                    "cumulative_delay_s": float(self.T[j]),
                    "fits_haptic_period": bool(self.T[j] < HAPTIC_PERIOD_S),
                }
            )
        return rows

    def ring_radii(self) -> np.ndarray:
        """Outer radius of the surface ring of each layer: cumulative equivalent lengths."""
        return np.cumsum(self.L)


def _as_float(name: str, value) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float, np.floating, np.integer)):
        raise ParameterError(f"{name}: {value!r} is not a number")
    v = float(value)
    if not math.isfinite(v):
        raise ParameterError(f"{name}: {v!r} is out of range; allowed: a finite number")
    return v


def _equivalent_lengths(l1: float, q: float, n_layers: int) -> np.ndarray:
    """Eq. (2): mean of l1*q**k for k = (i-1)**2 .. i**2 - 1, in closed form."""
    i = np.arange(1, n_layers + 1, dtype=np.float64)
    n = 2 * i - 1
    if q == 1.0:
        return np.full(n_layers, l1)
    lq = math.log(q)
    # sum_{k=a}^{a+n-1} q^k = q^a (q^n - 1) / (q - 1), with expm1 for q near 1
    return l1 * np.exp((i - 1) ** 2 * lq) * np.expm1(n * lq) / (n * math.expm1(lq))


def _max_valid_layers(params: PlateSpringParams, variant: str) -> int:
    top = 0
    for n in range(1, params.layers):
        try:
            PlateSpring(_replace_layers(params, n), variant)
        except ParameterError:
            break
        top = n
    return top


def _replace_layers(params: PlateSpringParams, n: int) -> PlateSpringParams:
    values = {f.name: getattr(params, f.name) for f in fields(params)}
    values["layers"] = n
    return PlateSpringParams(**values)


# -- the tissue model on a surface mesh ---------------------------------------------------


@dataclass(frozen=True)
class _ContactField:
    vertices: np.ndarray  # indices of surface vertices within the stack's outer ring
    distance: np.ndarray  # their geodesic (edge-path) distance from the grasp vertex, m


class PlateSpringModel(PlateSpringBase):
    """The plate-spring model under the tissue-model contract.

    Grasp: snap to the nearest surface vertex and precompute the geodesic distances of the
    vertices within the stack's outer ring (Dijkstra on mesh edges, cut at that radius).
    Force: the inverse X(F) along the hand displacement. Deformation: layer k occupies the
    surface ring between ring radii R_{k-1} and R_k; the displacement along the pull falls
    linearly across each ring from the deformation of layers k..N to that of layers k+1..N,
    so the grasp point moves by X, the field is continuous and nothing beyond R_N moves.
    Two contacts superpose.
    """

    name = "plate_spring"

    def __init__(self, mesh, params: PlateSpringParams, variant: str = "continuous", field=None):
        """`variant` "located" (beyond the paper, `analysis.verification.field_fit`): the continuous stack's curve
        gives the shape, `field` ((n, 3, 3) stiffness per pascal at every vertex, scaled by the
        stack's E, the tissue's modulus) the size and direction of the force at the grasp."""
        if variant not in MODEL_VARIANTS:
            raise ParameterError(f"variant: {variant!r} is not one of {', '.join(MODEL_VARIANTS)}")
        if variant == "located" and field is None:
            raise ParameterError("variant: 'located' needs a stiffness field (`field` in the scene)")
        self.mesh = mesh
        self.variant = variant
        self.stack = PlateSpring(params, "continuous" if variant == "located" else variant)
        self.field = field
        self.k0 = self.stack.force(1e-7) / 1e-7 if field is not None else math.nan
        self.radii = np.concatenate(([0.0], self.stack.ring_radii()))
        self._out = np.zeros_like(mesh.vertices)
        self._touched: list[np.ndarray] = []
        self.frame_flops = math.nan  # the last frame's counted work
        mesh.prepare_queries()  # build search structures now, not inside the first grasp

    def grasp(self, point: Sequence[float], hand: int = 0) -> Contact:
        v = self.mesh.nearest_vertex(point)
        idx, dist = self.mesh.geodesic_within(v, float(self.radii[-1]))
        anchor = tuple(float(c) for c in self.mesh.vertices[v])
        normal = tuple(float(c) for c in self.mesh.vertex_normals[v])
        if self.field is not None:
            S = self.stack.params.E * self.field[v]
            law = TensorTable(list(self.stack._x0), list(self.stack._f0), list(self.stack._slope), float(self.k0),
                              tuple(float(c) for c in S.ravel()))
        else:
            law = RadialTable(list(self.stack._x0), list(self.stack._f0), list(self.stack._slope))
        return Contact(hand=hand, vertex=int(v), point=anchor, normal=normal, data=_ContactField(idx, dist), law=law)

    def with_stiffness(self, scale: float) -> PlateSpringModel:
        """This model with the plates' modulus E times `scale`: every spring constant and layer
        force is linear in E (Eqs. 3, 6, 9) and the layer lengths are not, so every force
        scales by `scale` and the deformation is unchanged (the discrimination task's stimulus)."""
        params = dataclasses.replace(self.stack.params, E=self.stack.params.E * float(scale))
        return PlateSpringModel(self.mesh, params, self.variant, self.field)

    def profile(self, x: float) -> np.ndarray:
        """Displacement magnitude at the ring borders R_0..R_N for a stack stretched by x."""
        layer = self.stack.layer_split(x)
        # D_k = sum of layers k..N, then 0 beyond the last ring
        return np.concatenate((np.cumsum(layer[::-1])[::-1], [0.0]))

    def deformation(self, contacts: Sequence[Contact], displacements) -> np.ndarray:
        out = self._out
        # counted work (studyctl/synthetic/observer.py): per patch vertex, interpolation and the
        # multiply-add along the pull, and the stack's split per layer (not the zeroing of the
        # last frame's patches: that depends on what ran before, and the count must not)
        self.frame_flops = 0.0
        for idx in self._touched:
            out[idx] = 0.0
        self._touched = []
        for contact, d in zip(contacts, displacements):
            d = np.asarray(d, dtype=np.float64)
            x = float(np.linalg.norm(d))
            if not (x > 0.0 and math.isfinite(x)):
                continue
            f = contact.data
            # profile(x)[0] == x: the grasp point follows the hand exactly
            mag = np.interp(f.distance, self.radii, self.profile(x))
            self.frame_flops += 12 * len(f.vertices) + 20 * len(self.radii)
            out[f.vertices] += mag[:, None] * (d / x)
            self._touched.append(f.vertices)
        return out


def build(mesh, options: dict, scene=None) -> PlateSpringModel:
    """Construct from a scene's plate-spring options (`sim.models.builtin.PlateSpringOptions`, as a dict)."""
    field = None
    if options["variant"] == "located":
        field = load_field(options["field"] or FIELD_FILE, mesh)
    return PlateSpringModel(mesh, options["params"], options["variant"], field)


# -- the scene reader's parameters (sim.models.builtin.PlateSpringBase.read_options) --------------

def params_file(table, path: Path | None):
    """The plate-spring parameter file a scene names, its problems named by that file's lines."""
    if path is None:
        return None
    if not path.is_file():
        return table.error("params", f"{path} does not exist" if not path.exists() else f"{path} is not a file")
    try:
        data, loc = read_toml(path)
    except TomlFileError as exc:
        table.problems.append((path, 0, str(exc)))
        return None
    return params_table(type(table)(path, data, "", loc, table.problems))


def params_table(r):
    """PlateSpringParams from a table (a parameter file or an inline table): unknown, missing
    and non-numeric keys are all reported; then the first value out of range (the checks of
    PlateSpringParams, some of which relate several keys)."""
    keys = tuple(f.name for f in dataclasses.fields(PlateSpringParams))
    r.keys(keys)
    values, missing = {}, [key for key in keys if key not in r.data]
    if missing:
        r.error("", f"missing key{'s' if len(missing) > 1 else ''} {', '.join(missing)}; required: {', '.join(keys)}")
    ok = not missing
    for key in keys:
        v = values[key] = r.data.get(key, REQUIRED)
        if v is REQUIRED:
            continue
        if key == "layers" and (isinstance(v, bool) or not isinstance(v, int)):
            r.error(key, f"{v!r} is not an integer")
        elif key != "layers" and (isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v)):
            r.error(key, f"{v!r} is not a finite number")
        else:
            continue
        ok = False
    if not ok:
        return None
    try:
        return PlateSpringParams.from_mapping(values, source="")
    except ParameterError as exc:
        message = str(exc).removeprefix(": ")
        key, sep, rest = message.partition(": ")
        if sep and key in keys:
            r.error(key, rest)
        else:
            r.error("", message)
        return None
