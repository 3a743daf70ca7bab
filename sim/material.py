"""The brain's material: a scene's `[material]` and the material files it names.

A material file (TOML) holds a finite-strain law (`sim.hyperelastic`) in its
`[material]` table and where it came from in `[provenance]` (the data file's SHA-256, the
region, the fit); `studyctl calibrate material --out` writes one. A scene's `[material]` names
the law by `file`, or inline (`law`, `mu`, `alpha` ...), or neither: the shipped human cortex
(`DEFAULT_MATERIAL`). The linear models (the linear and corotational FEM, the mass-spring)
keep `young` and `poisson`: `poisson` is theirs (default 0.45: their elements lock above it,
docs/fem.md), and `young`, unless the scene gives it, is the law's small-strain limit
E = 2 mu (1 + nu) with the law's shear modulus mu (docs/material.md).

A rheology file adds Maxwell branches to its `[material]` law (`Viscoelastic`, `read_rheology`):
the finite viscoelastic truth's tissue (docs/viscoelastic.md).
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from brainsim_assets import path as _asset
from sim.errors import ParameterError
from sim.hyperelastic import ALPHA_RANGE, BULK_RATIO, MU_RANGE, PARAMETERS, Hyperelastic, law_problems
from sim.models.base import POISSON_MAX, POISSON_MIN
from sim.tomlfile import TomlFileError, read_toml
from sim.tomltable import TableReader

DEFAULT_MATERIAL = _asset("protocols/materials/human_cortex.toml")
DEFAULT_POISSON = 0.45  # the linear models' (docs/material.md)
LAW_KEYS = ("law", "mu", "mu1", "mu2", "alpha", "bulk_ratio")
# Wide but physical (a value outside is a unit slip or a typo, refused before a solver sees it):
# Young's modulus from softer than any tissue (brain ~1 kPa) to stiffer than cartilage, the span
# the stability sweep runs (analysis/verification/stability.py); a density from a foam's to a
# metal's (brain 1040 kg/m3)
YOUNG_RANGE = (1.0, 1.0e9)  # Pa
MEMBRANE_KEYS = ("law", "mu", "alpha", "thickness", "mu_spread")
MEMBRANE_SPREAD = (0.0, 0.9)  # relative: the measurements' spread of mu, the truth's members at (1 -+ s) mu
MEMBRANE_THICKNESS = (1e-6, 5e-3)  # m: from a basement membrane's to a thick dura's
DENSITY_RANGE = (100.0, 2.0e4)  # kg/m3


def read_law(r: TableReader) -> Hyperelastic | None:
    """The law in a table (a material file's [material], or a scene's inline): `law` and its
    parameters under their own names (`sim.hyperelastic.PARAMETERS`); None (its problems recorded
    at their keys' lines) when refused. Types are read here; the values are checked by
    `sim.hyperelastic.law_problems`, the one check of a law."""
    name = r.string("law")
    ratio = r.number("bulk_ratio", default=BULK_RATIO)
    own = PARAMETERS.get(name)
    for key in ("mu", "mu1", "mu2", "alpha"):
        if own is not None and key in r.data and key not in own:
            r.error(key, f"not a parameter of the {name} law; its parameters: {', '.join(own)}"
                    + (" (lists, one per term)" if name == "ogden" else ""))
    if name == "neo-hookean":
        m = r.number("mu")
        mu, alpha = (None, None) if m is None else ((m,), (2.0,))
    elif name == "mooney-rivlin":
        m1, m2 = r.number("mu1"), r.number("mu2")
        mu, alpha = (None, None) if m1 is None or m2 is None else ((m1, m2), (2.0, -2.0))
    elif name == "ogden":
        mu, alpha = r.numbers("mu"), r.numbers("alpha")
    else:
        mu, alpha = (), ()  # no law, or one `law_problems` refuses by name
    if name is None or mu is None or alpha is None or ratio is None:
        return None
    problems = law_problems(name, mu, alpha, ratio)
    for key, message in problems:
        r.error(key, message)
    return None if problems else Hyperelastic(name, tuple(mu), tuple(alpha), float(ratio))


def material_file(path: Path, problems: list) -> tuple[Hyperelastic | None, dict]:
    """(law, provenance) of a material file; problems recorded as FILE:LINE."""
    try:
        data, loc = read_toml(path)
    except TomlFileError as exc:
        problems.append((path, 0, str(exc)))
        return None, {}
    root = TableReader(path, data, "", loc, problems)
    root.keys(("material", "provenance"))
    law = read_law(root.table("material", allowed=LAW_KEYS))
    prov = data.get("provenance", {})
    return law, prov if isinstance(prov, dict) else {}


def load_material(path) -> tuple[Hyperelastic, dict]:
    """A material file's (law, provenance); ParameterError with every problem otherwise."""
    problems: list = []
    law, prov = material_file(Path(path), problems)
    if problems or law is None:
        raise ParameterError("; ".join(text for _, _, text in problems) or f"{path}: no law")
    return law, prov


def scene_law(material: TableReader) -> tuple[Hyperelastic | None, str]:
    """The law a scene's [material] names (a file, inline, or the shipped default) and where it
    came from (the file's path, or 'inline')."""
    inline = [k for k in LAW_KEYS if k in material.data]
    if "file" in material.data:
        if inline:
            material.error(inline[0], "give the law in the material `file` or inline, not both")
            return None, ""
        path = material.path_value("file")
        if path is None:
            return None, ""
        if not path.is_file():
            material.error("file", f"{path} does not exist" if not path.exists() else f"{path} is not a file")
            return None, ""
        law, _ = material_file(path, material.problems)
        return law, str(path)
    if inline:
        return read_law(material), "inline"
    law, _ = material_file(DEFAULT_MATERIAL, material.problems)
    return law, str(DEFAULT_MATERIAL)


@dataclass(frozen=True)
class MembraneLaw:
    """A membrane on the brain's surface (the pia-arachnoid, `sim.models.fem.membrane`): the
    one-term Ogden law of shear modulus `mu` (Pa) and exponent `alpha`, thickness (m), and the
    measurements' relative spread of mu (`mu_spread`: the truth's band solves (1 - s) and
    (1 + s) times mu; 0, none known)."""

    mu: float
    alpha: float
    thickness: float
    mu_spread: float = 0.0

    def __post_init__(self):
        if not (np.isfinite(self.mu) and self.mu > 0):
            raise ParameterError(f"membrane mu: {self.mu!r} must be a positive modulus (Pa)")
        if not (np.isfinite(self.alpha) and self.alpha != 0):
            raise ParameterError(f"membrane alpha: {self.alpha!r} must be a non-zero number")
        if not (np.isfinite(self.thickness) and self.thickness > 0):
            raise ParameterError(f"membrane thickness: {self.thickness!r} must be a positive length (m)")
        if not (MEMBRANE_SPREAD[0] <= self.mu_spread <= MEMBRANE_SPREAD[1]):
            raise ParameterError(f"membrane mu_spread: {self.mu_spread!r} must lie in {MEMBRANE_SPREAD[0]:g}..{MEMBRANE_SPREAD[1]:g}")

    def scaled(self, factor: float) -> MembraneLaw:
        return MembraneLaw(self.mu * factor, self.alpha, self.thickness, self.mu_spread)

def membrane_file(path: Path, problems: list) -> MembraneLaw | None:
    """A membrane file's law (its `[membrane]`: law = "ogden", mu (Pa), alpha, thickness (m));
    problems recorded as FILE:LINE."""
    try:
        data, loc = read_toml(path)
    except TomlFileError as exc:
        problems.append((path, 0, str(exc)))
        return None
    root = TableReader(path, data, "", loc, problems)
    root.keys(("membrane", "provenance"))
    r = root.table("membrane", allowed=MEMBRANE_KEYS)
    if r.string("law") not in (None, "ogden"):
        r.error("law", "the membrane's law is \"ogden\" (one term)")
    mu = r.number("mu", lo=YOUNG_RANGE[0], hi=YOUNG_RANGE[1], unit="Pa")
    alpha = r.number("alpha", lo=-100.0, hi=100.0)
    t = r.number("thickness", lo=MEMBRANE_THICKNESS[0], hi=MEMBRANE_THICKNESS[1], unit="m")
    spread = r.number("mu_spread", default=0.0, lo=MEMBRANE_SPREAD[0], hi=MEMBRANE_SPREAD[1])
    if alpha == 0:
        r.error("alpha", "must not be 0")
        return None
    return None if mu is None or alpha is None or t is None or spread is None else MembraneLaw(mu, alpha, t, spread)


def scene_membrane(material: TableReader) -> MembraneLaw | None:
    """The membrane a scene's [material] puts on the brain's surface (`pia_arachnoid`, a membrane file), or None."""
    if "pia_arachnoid" not in material.data:
        return None
    path = material.path_value("pia_arachnoid")
    if path is None:
        return None
    if not path.is_file():
        material.error("pia_arachnoid", f"{path} does not exist; allowed: a membrane file (.toml) like protocols/materials/pia_arachnoid_human.toml"
                       if not path.exists() else f"{path} is not a file; allowed: a membrane file (.toml)")
        return None
    return membrane_file(path, material.problems)


@dataclass(frozen=True)
class MaterialSpec:
    """The tissue: its finite-strain law (the reference's and the observer's truth's, sim/material.py)
    and the linear models' modulus and Poisson ratio (`young` given, or the law's small-strain limit)."""

    young: float  # Pa, the linear models'
    poisson: float  # the linear models'
    density: float  # kg/m3
    law: Hyperelastic | None = None
    law_source: str = ""  # the material file's path, or "inline"
    young_given: bool = True  # False: young = 2 mu (1 + poisson) of the law
    # the truth's white matter, inside the white surface (sim/geometry/regions.py); None: homogeneous
    white_matter: Hyperelastic | None = None
    white_matter_source: str = ""  # its material file's path
    pia_arachnoid: MembraneLaw | None = None  # a membrane on the surface (the reference's only)


def white_matter_law(material: TableReader) -> tuple[Hyperelastic | None, str]:
    """The law of the material file a scene's `white_matter` names (optional: absent, the brain
    is one material) and its path."""
    if "white_matter" not in material.data:
        return None, ""
    path = material.path_value("white_matter")
    if path is None:
        return None, ""
    if not path.is_file():
        material.error("white_matter", f"{path} does not exist; allowed: a material file (.toml) like protocols/materials/human_white_matter.toml"
                       if not path.exists() else f"{path} is not a file; allowed: a material file (.toml)")
        return None, ""
    law, _ = material_file(path, material.problems)
    return law, str(path)


def material_spec(material: TableReader) -> MaterialSpec:
    """A scene's [material] (its problems recorded on the reader)."""
    law, source = scene_law(material)
    white, white_source = white_matter_law(material)
    poisson = material.number("poisson", default=DEFAULT_POISSON, lo=POISSON_MIN, hi=POISSON_MAX, hi_open=True)
    given = "young" in material.data
    young = material.number("young", lo=YOUNG_RANGE[0], hi=YOUNG_RANGE[1], unit="Pa") if given else None
    if law is not None and poisson is not None:
        lo, hi = YOUNG_RANGE
        small = law.young(poisson)  # the law's, given young or not: the volume models' reference runs the law itself
        if not lo <= small <= hi:  # a law within its own bounds (a term of 1e-300 Pa) would hang a factorisation as well
            key = "file" if "file" in material.data else next((k for k in ("mu", "mu1") if k in material.data), "")
            material.error(key, f"the law's small-strain Young's modulus 2 mu (1 + poisson) = {small:.3g} Pa is out of range; allowed: "
                                f"[{lo:g}, {hi:g}] Pa (a shear modulus mu in [{lo / (2 + 2 * poisson):.3g}, {hi / (2 + 2 * poisson):.3g}] Pa)")
        elif not given:
            young = small
    return MaterialSpec(young=young, poisson=poisson, density=material.number("density", default=1040.0, lo=DENSITY_RANGE[0], hi=DENSITY_RANGE[1], unit="kg/m3"),
                        law=law, law_source=source, young_given=given, white_matter=white, white_matter_source=white_source,
                        pia_arachnoid=scene_membrane(material))


def _toml_value(v) -> str:
    if isinstance(v, str):
        return json.dumps(v)  # a TOML basic string is a JSON string for this text (no control characters)
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, (list, tuple)):
        return "[" + ", ".join(_toml_value(x) for x in v) + "]"
    return repr(float(v)) if isinstance(v, float) else str(v)


def material_toml(law: Hyperelastic, provenance: dict, header: str = "") -> str:
    """A material file's text: the header as comments, [material], [provenance] (flat values)."""
    lines = [f"# {line}".rstrip() for line in header.splitlines()]
    lines += ["[material]"] + [f"{k} = {_toml_value(v)}" for k, v in law.params().items()]
    lines += ["", "[provenance]"] + [f"{k} = {_toml_value(v)}" for k, v in provenance.items() if v is not None]
    return "\n".join(lines) + "\n"


# -- finite viscoelastic laws --------------------------------------------------------------------
#
# Finite viscoelastic laws for brain tissue (docs/viscoelastic.md): an equilibrium (long-time)
# hyperelastic law (`sim.hyperelastic`) and Maxwell branches in the multiplicative form (Reese and
# Govindjee 1998) of the finite viscoelastic Ogden family Budday et al. 2017 (Acta Biomaterialia
# 60) fitted to human brain (their abstract and parameters were at hand here, not their text):
#
#     psi = psi_inf(F) + sum_k psi_k(F_e,k),   F = F_e,k F_v,k,
#     -1/2 (L_v b_e,k) b_e,k^-1 = 1/(2 eta_k) dev tau_k,   eta_k = mu_k tau_k,
#
# psi_k the isochoric one-term Ogden energy 2 mu_k/alpha_k^2 (sum lb_e^alpha_k - 3) of the branch's
# elastic part, b_e = F_e F_e^T, tau_k its Kirchhoff stress; the flow is isochoric. At small strain
# the law is the standard linear solid with shear moduli mu_inf and mu_k and relaxation times
# tau_k; held still, every branch's stress decays and the long-time limit is the equilibrium law.
#
# A step of dt is implicit, in principal logarithmic stretches (the exponential map of Reese and
# Govindjee 1998): eps_e + dt/(2 eta) tau(eps_e) = eps_trial, unconditionally stable, first
# order in dt (the compiled element pass, `sim.models.fem.hyperelastic_kernels._branch_point`).
#
# A rheology file (`read_rheology`) is a material file whose `[material]` is the equilibrium law,
# with a `[viscous]` table of branches: `mu` (Pa), `alpha`, `tau` (s), one entry per branch.

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

    @property
    def viscosity(self) -> float:
        """Pa s: eta = mu tau, the deviatoric viscosity whose small-strain relaxation time is tau."""
        return self.mu * self.tau


@dataclass(frozen=True)
class Viscoelastic:
    """A finite viscoelastic law: the equilibrium law and its Maxwell branches."""

    equilibrium: Hyperelastic
    branches: tuple[Branch, ...]

    @property
    def instantaneous_shear_modulus(self) -> float:
        """Pa: the small-strain shear modulus of a step (no time to relax), mu_inf + sum mu_k."""
        return self.equilibrium.shear_modulus + sum(b.mu for b in self.branches)

    def scaled(self, ratio: float) -> Viscoelastic:
        """Every modulus times `ratio`, the times kept: the force scales by `ratio` along any history."""
        return Viscoelastic(self.equilibrium.scaled(ratio), tuple(Branch(b.mu * ratio, b.alpha, b.tau) for b in self.branches))

    def describe(self) -> str:
        parts = ", ".join(f"mu {b.mu:.4g} Pa, alpha {b.alpha:.4g}, tau {b.tau:.4g} s" for b in self.branches)
        return f"{self.equilibrium.describe()} + branches ({parts})"


def read_rheology(path) -> tuple[Viscoelastic, dict]:
    """A rheology file's (law, provenance): `[material]` the equilibrium law (`sim.material.read_law`),
    `[viscous]` the branches (`mu`, `alpha`, `tau` lists, one entry each per branch). ParameterError
    naming the file, line and key when refused."""
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
        elif 0.0 in mu:
            v.error("mu", f"0 Pa is not a branch; allowed: ({MU_RANGE[0]:g}, {MU_RANGE[1]:g}] Pa")
        elif 0.0 in alpha:
            v.error("alpha", f"0 is not an exponent; allowed: non-zero values in [{ALPHA_RANGE[0]:g}, {ALPHA_RANGE[1]:g}]")
        else:
            branches = tuple(Branch(float(m), float(a), float(t)) for m, a, t in zip(mu, alpha, tau))
    if problems or law is None or not branches:
        raise ParameterError("; ".join(text for _, _, text in problems) or f"{path}: no law")
    prov = data.get("provenance", {})
    return Viscoelastic(law, branches), prov if isinstance(prov, dict) else {}


def rheology_toml(law: Viscoelastic, provenance: dict, header: str = "") -> str:
    """A rheology file's text: `sim.material.material_toml`'s of the equilibrium law with the
    `[viscous]` table of the branches before its `[provenance]`."""
    text = material_toml(law.equilibrium, provenance, header)
    viscous = "[viscous]\n" + "".join(f"{key} = [{', '.join(repr(float(getattr(b, key))) for b in law.branches)}]\n"
                                      for key in VISCOUS_KEYS) + "\n"
    head, sep, tail = text.partition("[provenance]")
    return head + viscous + sep + tail
