"""Finite-strain hyperelastic laws for brain tissue, nearly incompressible, with a
deviatoric/volumetric split (docs/material.md):

    psi = sum_p 2 mu_p / alpha_p^2 (lb1^alpha_p + lb2^alpha_p + lb3^alpha_p - 3) + U(J),
    U(J) = kappa/4 (J^2 - 1 - 2 ln J)

with lb_i = J^(-1/3) l_i the isochoric principal stretches. This is the convention of Budday
et al. (2017): mu = sum_p mu_p is the small-strain shear modulus, and every term is stable
for mu_p > 0, whatever the sign of alpha_p. The three laws are one family:

- neo-Hookean: one term, alpha = 2 (psi = mu/2 (Ib1 - 3));
- Mooney-Rivlin: alpha = 2 and -2 (psi = mu1/2 (Ib1 - 3) + mu2/2 (Ib2 - 3));
- Ogden: N terms of free alpha (one term with alpha near -20 follows human brain, Budday
  et al. 2017; Linka et al. 2023).

The volumetric energy U(J) = kappa/4 (J^2 - 1 - 2 ln J) (Simo and Taylor 1982; Abaqus's and
FEBio's convex choice) is convex for every J > 0 (U'' = kappa/2 (1 + 1/J^2)), where the
kappa/2 (ln J)^2 used before is not past J = e; both have U''(1) = kappa, so the
small-strain limit is unchanged. kappa is `bulk_ratio` times mu (`BULK_RATIO`, why in
docs/material.md). The closed-form homogeneous
responses here (uniaxial loading with free lateral faces, simple shear) are what
`studyctl calibrate material` fits and what the cube tests hold the FEM to. SI units.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from sim.errors import ParameterError

LAWS = ("neo-hookean", "mooney-rivlin", "ogden")
# each law's parameters under its own names (a material file's keys, `Hyperelastic.params`)
PARAMETERS = {"neo-hookean": ("mu",), "mooney-rivlin": ("mu1", "mu2"), "ogden": ("mu", "alpha")}
MU_RANGE = (0.0, 1.0e9)  # Pa per term (a negative term is unstable)
# kappa / mu: small-strain Poisson ratio 0.49, the brain-shift models' value (Wittek et al. 2007,
# Miller et al. 2010: nearly incompressible, with the element free of locking); docs/material.md
BULK_RATIO = 50.0
BULK_RATIO_RANGE = (1.0, 1.0e4)
ALPHA_RANGE = (-60.0, 60.0)  # |alpha| above this over/underflows stretches of 0.1..10


@dataclass(frozen=True)
class Hyperelastic:
    """One law: its name, the terms' shear moduli `mu` (Pa) and exponents `alpha`, and kappa / mu."""

    law: str
    mu: tuple[float, ...]
    alpha: tuple[float, ...]
    bulk_ratio: float = BULK_RATIO

    def __post_init__(self):
        for key, message in law_problems(self.law, self.mu, self.alpha, self.bulk_ratio)[:1]:
            raise ParameterError(f"{key}: {message}")

    @property
    def shear_modulus(self) -> float:
        """Pa: the small-strain shear modulus, sum of mu_p."""
        return float(sum(self.mu))

    @property
    def bulk_modulus(self) -> float:
        return self.bulk_ratio * self.shear_modulus

    @property
    def poisson(self) -> float:
        """The small-strain Poisson ratio of kappa and mu: (3 kappa - 2 mu) / (2 (3 kappa + mu))."""
        r = self.bulk_ratio
        return (3.0 * r - 2.0) / (2.0 * (3.0 * r + 1.0))

    def young(self, poisson: float) -> float:
        """The Young's modulus of a linear model with this shear modulus and `poisson`: 2 mu (1 + nu)."""
        return 2.0 * self.shear_modulus * (1.0 + poisson)

    def scaled(self, ratio: float) -> Hyperelastic:
        """The same law with every mu_p times `ratio` (a stiffer or softer brain of the same shape)."""
        return Hyperelastic(self.law, tuple(m * ratio for m in self.mu), self.alpha, self.bulk_ratio)

    def terms(self) -> tuple[np.ndarray, np.ndarray]:
        return np.asarray(self.mu, dtype=np.float64), np.asarray(self.alpha, dtype=np.float64)

    def params(self) -> dict:
        """The law's own parameters under its own names (SI): what a material file and
        `calibrate material --json` hold."""
        if self.law == "neo-hookean":
            out = {"law": self.law, "mu": self.mu[0]}
        elif self.law == "mooney-rivlin":
            out = {"law": self.law, "mu1": self.mu[0], "mu2": self.mu[1]}
        else:
            out = {"law": self.law, "mu": list(self.mu), "alpha": list(self.alpha)}
        return out | {"bulk_ratio": self.bulk_ratio}

    @staticmethod
    def from_params(d: dict) -> Hyperelastic:
        """The law of `params()`'s dictionary."""
        br = float(d.get("bulk_ratio", BULK_RATIO))
        if d["law"] == "neo-hookean":
            return neo_hookean(d["mu"], br)
        if d["law"] == "mooney-rivlin":
            return mooney_rivlin(d["mu1"], d["mu2"], br)
        return ogden(d["mu"], d["alpha"], br)

    def describe(self) -> str:
        terms = ", ".join(f"mu {m:.4g} Pa, alpha {a:.4g}" for m, a in zip(self.mu, self.alpha))
        return f"{self.law} ({terms}; kappa = {self.bulk_ratio:g} mu)"


def neo_hookean(mu: float, bulk_ratio: float = BULK_RATIO) -> Hyperelastic:
    return Hyperelastic("neo-hookean", (float(mu),), (2.0,), float(bulk_ratio))


def mooney_rivlin(mu1: float, mu2: float, bulk_ratio: float = BULK_RATIO) -> Hyperelastic:
    return Hyperelastic("mooney-rivlin", (float(mu1), float(mu2)), (2.0, -2.0), float(bulk_ratio))


def ogden(mu, alpha, bulk_ratio: float = BULK_RATIO) -> Hyperelastic:
    mu, alpha = tuple(float(m) for m in np.atleast_1d(mu)), tuple(float(a) for a in np.atleast_1d(alpha))
    return Hyperelastic("ogden", mu, alpha, float(bulk_ratio))


def law_problems(law: str, mu: Sequence[float], alpha: Sequence[float], bulk_ratio: float) -> list[tuple[str, str]]:
    """What is wrong with a law's parameters: (parameter, message) pairs, at most one per
    parameter, named as the law names them (`params()`: mu, or mu1 and mu2); [] when nothing.
    The one check of a law: `Hyperelastic` raises the first, a material table
    (`sim.material.read_law`) records each at its key's line."""
    if law not in LAWS:
        return [("law", f"{law!r} is not one of {', '.join(LAWS)}")]
    problems, named = [], set()
    names = PARAMETERS[law] if law == "mooney-rivlin" else ("mu",) * len(mu)
    lo, hi = MU_RANGE
    for name, m in zip(names, mu):
        if not lo <= m <= hi and name not in named:  # the first bad term of each parameter
            problems.append((name, f"{m!r} is out of range; allowed: [{lo:g}, {hi:g}] Pa per term"))
            named.add(name)
    if not mu:
        problems.append(("mu", "no term; allowed: at least one"))
    elif not named and not sum(mu) > 0.0:
        problems.append((names[0], "the terms' sum (the shear modulus) must be > 0 Pa"))
    lo, hi = ALPHA_RANGE
    bad_alpha = [a for a in alpha if not (lo <= a <= hi and a != 0.0)]
    if mu and len(alpha) != len(mu):
        problems.append(("alpha", f"{len(alpha)} exponent(s) for {len(mu)} mu term(s); allowed: one alpha per mu"))
    elif bad_alpha:
        a = bad_alpha[0]
        problems.append(("alpha", "0 is not an exponent; allowed: non-zero values" if a == 0.0
                         else f"{a!r} is out of range; allowed: [{lo:g}, {hi:g}]"))
    lo, hi = BULK_RATIO_RANGE
    if not lo <= bulk_ratio <= hi:
        problems.append(("bulk_ratio", f"{bulk_ratio!r} is out of range; allowed: [{lo:g}, {hi:g}] (kappa / mu)"))
    return problems


# -- closed forms in principal stretches ---------------------------------------------------------

def volumetric(kappa: float, J) -> tuple:
    """U(J) = kappa/4 (J^2 - 1 - 2 ln J) and its first two derivatives (arrays broadcast); the
    compiled element pass (`sim.models.fem.hyperelastic_kernels`) writes the same three lines."""
    J = np.asarray(J, dtype=np.float64)
    with np.errstate(divide="ignore", invalid="ignore"):
        return 0.25 * kappa * (J * J - 1.0 - 2.0 * np.log(J)), 0.5 * kappa * (J - 1.0 / J), 0.5 * kappa * (1.0 + 1.0 / (J * J))


def principal_nominal(law: Hyperelastic, l1, l2, l3) -> tuple:
    """The principal nominal (first Piola-Kirchhoff) stresses dpsi/dl_i (Pa) at principal
    stretches (arrays broadcast): (1/l_i) [sum_p (2 mu_p/alpha_p) J^(-alpha_p/3) (l_i^alpha_p -
    (1/3) sum_j l_j^alpha_p) + J U'(J)]."""
    l1, l2, l3 = (np.asarray(x, dtype=np.float64) for x in (l1, l2, l3))
    J = l1 * l2 * l3
    out = [J * volumetric(law.bulk_modulus, J)[1] for _ in range(3)]
    for m, a in zip(law.mu, law.alpha):
        c = 2.0 * m / a * J ** (-a / 3.0)
        pw = (l1**a, l2**a, l3**a)
        mean = (pw[0] + pw[1] + pw[2]) / 3.0
        for i in range(3):
            out[i] = out[i] + c * (pw[i] - mean)
    return tuple(o / li for o, li in zip(out, (l1, l2, l3)))


def uniaxial(law: Hyperelastic, stretch) -> tuple[np.ndarray, np.ndarray]:
    """Uniaxial loading with free lateral faces: (nominal stress along the load, Pa; lateral
    stretch), the lateral stretch solving a zero lateral stress (Newton on its log, to round-off)."""
    lam = np.atleast_1d(np.asarray(stretch, dtype=np.float64))
    t = -0.5 * np.log(lam)  # the incompressible lateral stretch's log: the start
    for _ in range(60):
        lt = np.exp(t)
        f = principal_nominal(law, lam, lt, lt)[1] * lt
        h = 1e-7
        df = (principal_nominal(law, lam, np.exp(t + h), np.exp(t + h))[1] * np.exp(t + h) - f) / h
        step = f / df
        t = t - step
        if np.all(np.abs(step) < 1e-15):
            break
    lt = np.exp(t)
    return principal_nominal(law, lam, lt, lt)[0], lt
