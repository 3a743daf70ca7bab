"""Finite viscoelastic laws for brain tissue: an equilibrium (long-time) hyperelastic law
(`sim.hyperelastic`) and Maxwell branches, each a one-term isochoric Ogden energy with a
relaxation time (docs/viscoelastic.md):

    S(t) = S_inf(C(t)) + sum_k Q_k(t),   dQ_k/dt + Q_k / tau_k = d/dt S_k(C(t)),

S_k the second Piola-Kirchhoff isochoric stress of branch k's energy 2 mu_k/alpha_k^2 (sum lb^alpha_k - 3)
(Simo 1987; Holzapfel 1996: the convolution form FEBio's and Abaqus's finite-strain Prony series
use). At rest Q = 0; held still, Q decays and the stress is S_inf's: the long-time limit is the
equilibrium law exactly. At small strain the law is the standard linear solid with shear moduli
mu_inf and mu_k and times tau_k.

A step of length dt updates Q exactly for S_k linear in time within the step (Taylor, Pister and
Goudreau 1970): Q_(n+1) = e^-h Q_n + g (S_k(C_(n+1)) - S_k(C_n)), h = dt/tau, g = (1 - e^-h)/h:
unconditionally stable, second order, exact for a ramp of S_k. Inside the step the stress is
S_inf + g S_k (a hyperelastic law with branch moduli g mu_k) plus the history stress
e^-h Q_n - g S_k(C_n), constant in the step: the FEM's Newton tangent is exact.

A rheology file (`read_rheology`) is a material file whose `[material]` is the equilibrium law,
with a `[viscous]` table of branches: `mu` (Pa), `alpha`, `tau` (s), one entry per branch.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from sim.errors import ParameterError
from sim.hyperelastic import ALPHA_RANGE, MU_RANGE, Hyperelastic
from sim.tomlfile import TomlFileError, read_toml
from sim.tomltable import TableReader

TAU_RANGE = (1e-4, 1e5)  # s: from a fast polymer's to hours; brain's are seconds (Budday et al. 2017)
VISCOUS_KEYS = ("mu", "alpha", "tau")


@dataclass(frozen=True)
class Branch:
    """One Maxwell branch: a one-term isochoric Ogden energy (mu Pa, alpha) relaxing in tau s."""

    mu: float
    alpha: float
    tau: float

    def __post_init__(self):
        lo, hi = MU_RANGE
        if not lo < self.mu <= hi:
            raise ParameterError(f"viscous mu: {self.mu!r} is out of range; allowed: ({lo:g}, {hi:g}] Pa")
        lo, hi = ALPHA_RANGE
        if not (lo <= self.alpha <= hi and self.alpha != 0.0):
            raise ParameterError(f"viscous alpha: {self.alpha!r} is out of range; allowed: [{lo:g}, {hi:g}], not 0")
        lo, hi = TAU_RANGE
        if not lo <= self.tau <= hi:
            raise ParameterError(f"viscous tau: {self.tau!r} is out of range; allowed: [{lo:g}, {hi:g}] s")


@dataclass(frozen=True)
class Viscoelastic:
    """A finite viscoelastic law: the equilibrium law and its Maxwell branches."""

    equilibrium: Hyperelastic
    branches: tuple[Branch, ...]

    @property
    def instantaneous_shear_modulus(self) -> float:
        """Pa: the small-strain shear modulus of a step (no time to relax), mu_inf + sum mu_k."""
        return self.equilibrium.shear_modulus + sum(b.mu for b in self.branches)

    def ramp_shear_modulus(self, duration: float) -> float:
        """Pa: the small-strain secant shear modulus at the end of a constant-rate ramp of
        `duration` s: mu_inf + sum mu_k (tau_k / T)(1 - e^(-T/tau_k)) (the standard linear solid)."""
        out = self.equilibrium.shear_modulus
        for b in self.branches:
            h = duration / b.tau
            out += b.mu * (-math.expm1(-h) / h if h > 0 else 1.0)
        return out

    def describe(self) -> str:
        parts = ", ".join(f"mu {b.mu:.4g} Pa, alpha {b.alpha:.4g}, tau {b.tau:.4g} s" for b in self.branches)
        return f"{self.equilibrium.describe()} + branches ({parts})"


def step_factors(tau: np.ndarray, dt: float) -> tuple[np.ndarray, np.ndarray]:
    """(e^-h, (1 - e^-h)/h) for h = dt/tau (arrays broadcast); dt = 0: (1, 1), an instant step."""
    tau = np.asarray(tau, dtype=np.float64)
    h = dt / tau
    decay = np.exp(-h)
    with np.errstate(divide="ignore", invalid="ignore"):
        gain = np.where(h > 0, -np.expm1(-h) / np.where(h > 0, h, 1.0), 1.0)
    return decay, gain


def isochoric_stress(F: np.ndarray, mu, alpha) -> np.ndarray:
    """The second Piola-Kirchhoff stress (..., 3, 3) of the isochoric Ogden energy
    2 mu/alpha^2 (sum lb^alpha - 3) at deformation gradients F (..., 3, 3); mu and alpha broadcast
    against F's leading shape. In C's eigenbasis: s_a = 2 mu/alpha J^(-alpha/3) (c_a^(alpha/2 - 1)
    - mean_b(c_b^(alpha/2)) / c_a), the compiled element pass's (`hyperelastic_kernels._iso_point`)."""
    C = np.swapaxes(F, -1, -2) @ F
    c, N = np.linalg.eigh(C)
    J = np.linalg.det(F)
    mu, alpha = np.asarray(mu, dtype=np.float64)[..., None], np.asarray(alpha, dtype=np.float64)[..., None]
    pw = c ** (0.5 * alpha)
    s = 2.0 * mu / alpha * J[..., None] ** (-alpha / 3.0) * (pw / c - pw.mean(axis=-1, keepdims=True) / c)
    return (N * s[..., None, :]) @ np.swapaxes(N, -1, -2)


def read_rheology(path) -> tuple[Viscoelastic, dict]:
    """A rheology file's (law, provenance): `[material]` the equilibrium law (`sim.material.read_law`),
    `[viscous]` the branches (`mu`, `alpha`, `tau` lists, one entry each per branch). ParameterError
    naming the file, line and key when refused."""
    from sim.material import LAW_KEYS, read_law  # the material module reads scenes, which may name rheology files

    path = Path(path)
    problems: list = []
    try:
        data, loc = read_toml(path)
    except TomlFileError as exc:
        raise ParameterError(str(exc)) from None
    root = TableReader(path, data, "", loc, problems)
    root.keys(("material", "viscous", "provenance"))
    law = read_law(root.table("material", allowed=LAW_KEYS))
    v = root.table("viscous", allowed=VISCOUS_KEYS)
    mu = v.numbers("mu", lo=0.0, hi=MU_RANGE[1])
    alpha = v.numbers("alpha", lo=ALPHA_RANGE[0], hi=ALPHA_RANGE[1])
    tau = v.numbers("tau", lo=TAU_RANGE[0], hi=TAU_RANGE[1])
    branches: tuple = ()
    if mu is not None and alpha is not None and tau is not None:
        if not len(mu) == len(alpha) == len(tau) >= 1:
            v.error("tau", f"{len(mu)} mu, {len(alpha)} alpha and {len(tau)} tau; allowed: one of each per branch, at least one branch")
        else:
            try:
                branches = tuple(Branch(float(m), float(a), float(t)) for m, a, t in zip(mu, alpha, tau))
            except ParameterError as exc:
                v.error("mu", str(exc))
    if problems or law is None or not branches:
        raise ParameterError("; ".join(text for _, _, text in problems) or f"{path}: no law")
    prov = data.get("provenance", {})
    return Viscoelastic(law, branches), prov if isinstance(prov, dict) else {}
