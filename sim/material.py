"""The brain's material: a scene's `[material]` and the material files it names.

A material file (TOML) holds a finite-strain law (`sim.hyperelastic`) in its
`[material]` table and where it came from in `[provenance]` (the data file's SHA-256, the
region, the fit); `studyctl calibrate material --out` writes one. A scene's `[material]` names
the law by `file`, or inline (`law`, `mu`, `alpha` ...), or neither: the shipped human cortex
(`DEFAULT_MATERIAL`). The linear models (the linear and corotational FEM, the mass-spring)
keep `young` and `poisson`: `poisson` is theirs (default 0.45: their elements lock above it,
docs/fem.md), and `young`, unless the scene gives it, is the law's small-strain limit
E = 2 mu (1 + nu) with the law's shear modulus mu (docs/material.md).
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

from brainsim_assets import path as _asset
from sim.errors import ParameterError
from sim.hyperelastic import ALPHA_RANGE, BULK_RATIO, BULK_RATIO_RANGE, LAWS, Hyperelastic
from sim.models.base import POISSON_MAX, POISSON_MIN
from sim.tomlfile import TomlFileError, read_toml
from sim.tomltable import TableReader

DEFAULT_MATERIAL = _asset("protocols/materials/human_cortex.toml")
DEFAULT_POISSON = 0.45  # the linear models' (docs/material.md)
LAW_KEYS = ("law", "mu", "mu1", "mu2", "alpha", "bulk_ratio")
MU_RANGE = (0.0, 1.0e9)  # Pa per term


def read_law(r: TableReader) -> Hyperelastic | None:
    """The law in a table (a material file's [material], or a scene's inline): `law` and its
    parameters under their own names; None (its problems recorded) when refused."""
    name = r.string("law", choices=LAWS)
    if name is None:
        return None
    ratio = r.number("bulk_ratio", default=BULK_RATIO, lo=BULK_RATIO_RANGE[0], hi=BULK_RATIO_RANGE[1])
    wrong = {"neo-hookean": ("mu1", "mu2", "alpha"), "mooney-rivlin": ("mu", "alpha"), "ogden": ("mu1", "mu2")}[name]
    for key in wrong:
        if key in r.data:
            r.error(key, f"not a parameter of the {name} law; its parameters: "
                    + {"neo-hookean": "mu", "mooney-rivlin": "mu1, mu2", "ogden": "mu, alpha (lists, one per term)"}[name])
    if name == "neo-hookean":
        mu, alpha = r.number("mu", lo=MU_RANGE[0], hi=MU_RANGE[1], lo_open=True), 2.0
        mu, alpha = (None, None) if mu is None else ((mu,), (alpha,))
    elif name == "mooney-rivlin":
        m1, m2 = r.number("mu1", lo=MU_RANGE[0], hi=MU_RANGE[1]), r.number("mu2", lo=MU_RANGE[0], hi=MU_RANGE[1])
        mu, alpha = (None, None) if m1 is None or m2 is None else ((m1, m2), (2.0, -2.0))
    else:
        mu, alpha = r.numbers("mu", lo=MU_RANGE[0], hi=MU_RANGE[1]), r.numbers("alpha", lo=ALPHA_RANGE[0], hi=ALPHA_RANGE[1])
        if mu is not None and alpha is not None and len(mu) != len(alpha):
            r.error("alpha", f"{len(alpha)} exponent(s) for {len(mu)} mu term(s); allowed: one alpha per mu")
            mu = None
    if mu is None or alpha is None or ratio is None:
        return None
    if any(a == 0.0 for a in alpha):
        r.error("alpha", "0 is not an exponent; allowed: non-zero values")
        return None
    if not sum(mu) > 0.0:
        r.error("mu" if name != "mooney-rivlin" else "mu1", "the terms' sum (the shear modulus) must be > 0 Pa")
        return None
    return Hyperelastic(name, tuple(mu), tuple(alpha), float(ratio))


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
class MaterialSpec:
    """The tissue: its finite-strain law (the reference's and the observer's truth's, sim/material.py)
    and the linear models' modulus and Poisson ratio (`young` given, or the law's small-strain limit)."""

    young: float  # Pa, the linear models'
    poisson: float  # the linear models'
    density: float  # kg/m3
    law: Hyperelastic | None = None
    law_source: str = ""  # the material file's path, or "inline"
    young_given: bool = True  # False: young = 2 mu (1 + poisson) of the law


def material_spec(material: TableReader) -> MaterialSpec:
    """A scene's [material] (its problems recorded on the reader)."""
    law, source = scene_law(material)
    poisson = material.number("poisson", default=DEFAULT_POISSON, lo=POISSON_MIN, hi=POISSON_MAX, hi_open=True)
    given = "young" in material.data
    young = material.number("young", lo=0.0, lo_open=True) if given else None
    if not given and law is not None and poisson is not None:
        young = law.young(poisson)
    return MaterialSpec(young=young, poisson=poisson, density=material.number("density", default=1040.0, lo=0.0, lo_open=True),
                        law=law, law_source=source, young_given=given)


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
