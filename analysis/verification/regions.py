"""The truth's regions: grey matter (the scene's law) between the pial and the white surface,
white matter (the scene's `[material] white_matter`) inside it, each quadrature point of the P2
reference its own region's law (`sim.geometry.regions`, `sim.models.fem.FiniteStrain`'s
`law_of`), and the regional variants the literature spans (`contrast_members`).

A law per quadrature point on the pial-only meshes puts the interface inside elements; the mesh
study in docs/reference.md (Regions) gives its error against the truth's band.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache

import numpy as np

from analysis.verification.material_fit import fitted_range
from sim.geometry.regions import WHITE, quadrature_regions, white_sha256, white_surfaces
from sim.hyperelastic import Hyperelastic
from sim.material import DEFAULT_MATERIAL, load_material

WHITE_MATTER = DEFAULT_MATERIAL.parent / "human_white_matter.toml"  # Budday 2017 corona radiata
# Jin et al. 2013 (J Biomech 46:2795-2801; human, tension, compression and shear to 50% strain):
# white matter stiffer than grey in compression and shear, corona radiata stiffer than cortex
# in tension and compression. The abstract gives no ratio and the tables were not reachable
# here: the factor is an assumption (docs/reference.md, Regions), a white matter this much
# stiffer than cortex of the cortex's shape.
JIN_WHITE_OVER_GREY = 1.3
_fitted_range = lru_cache(maxsize=32)(fitted_range)  # a key per solve reads the data files once per process


@dataclass(frozen=True)
class RegionalLaw:
    """The grey matter's law and the white matter's (None: one material), with the principal
    stretches each was fitted to (None where its material names no data), and the scale of the
    scene's pia-arachnoid's mu in this variant of the body (1: the scene's; a member of its
    measured spread otherwise; nothing without a pia-arachnoid)."""

    grey: Hyperelastic
    white: Hyperelastic | None = None
    grey_range: tuple[float, float] | None = None
    white_range: tuple[float, float] | None = None
    pac_scale: float = 1.0

    def ranges_pair(self) -> tuple:
        """(grey range, white range): what another variant of the same regions is judged by."""
        return self.grey_range, self.white_range

    def ranges(self):
        """The support's stretch ranges: the grey's alone, or one per law (white falls back on
        the grey's where its material names no data); None without any."""
        if self.grey_range is None:
            return None
        if self.white is None:
            return self.grey_range
        return [self.grey_range, self.white_range or self.grey_range]


def scene_regions(scene, law=None) -> RegionalLaw:
    """The scene's laws: its grey law (or `law`, a `Hyperelastic` replacing it, or a whole
    `RegionalLaw`) and its white matter. A replaced grey law (an ensemble member, solved at unit
    mu: forces scale with mu) takes the white matter scaled along, its ratio to the grey kept, so
    that a member's forces still scale with its mu."""
    if isinstance(law, RegionalLaw):
        return law
    material = scene.spec.material
    grey = law or material.law
    grey_range = _fitted_range(material.law_source)[0] if material.law_source else None
    if material.white_matter is None:
        return RegionalLaw(grey, None, grey_range, None)
    white_range = _fitted_range(material.white_matter_source)[0]
    return RegionalLaw(grey, material.white_matter.scaled(grey.shear_modulus / material.law.shear_modulus), grey_range, white_range)


def region_key(regional: RegionalLaw, shape_key, digits) -> list:
    """What a regional solve adds to its key ([] for one material, so the homogeneous keys stay
    as they were): the white law's shape, its scale over the grey law's (forces are stored per
    pascal of the grey law), its data's range and the white surfaces' hash."""
    if regional.white is None:
        return []
    rng = [digits(r) for r in regional.white_range] if regional.white_range else []
    return [["white", shape_key(regional.white), digits(regional.white.shear_modulus / regional.grey.shear_modulus), rng,
             white_sha256()]]


def regional_system(space, mesh, label: int, regional: RegionalLaw, unit: Hyperelastic):
    """(laws, law_of) for `FiniteStrain` on a hemisphere's mesh: the grey law scaled to `unit`
    and the white law by the same factor (their ratio kept), each quadrature point's region;
    (unit, None) for one material."""
    if regional.white is None:
        return unit, None
    scale = unit.shear_modulus / regional.grey.shear_modulus
    law_of = quadrature_regions(mesh.nodes, mesh.tets, space.element.POINTS, label, white_surfaces())
    return (unit, regional.white.scaled(scale)), (law_of == WHITE).astype(np.int64)


def contrast_members(grey: Hyperelastic, grey_range=None) -> list[dict]:
    """The regional variants the literature spans, each a `RegionalLaw` with its source:
    Budday et al. 2017's corona radiata (about half as stiff as cortex: the chosen), white
    matter as stiff as cortex (one material: the brain before regions), and white matter
    stiffer than cortex as Jin et al. 2013 found (`JIN_WHITE_OVER_GREY`, assumed)."""
    white, _ = load_material(WHITE_MATTER)
    white_range = fitted_range(str(WHITE_MATTER))[0]
    return [
        {"name": "budday-corona-radiata", "chosen": True, "law": RegionalLaw(grey, white, grey_range, white_range),
         "source": "Budday et al. 2017, Acta Biomaterialia 48:319-340, corona radiata rows (data/brain_tissue_*_budday2017.csv), "
                   "one-term Ogden fitted jointly to uniaxial and shear (protocols/materials/human_white_matter.toml)"},
        {"name": "homogeneous", "chosen": False, "law": RegionalLaw(grey, None, grey_range, None),
         "source": "white matter as stiff as cortex: no contrast (the truth before regions; between the two studies' directions)"},
        {"name": "jin-white-stiffer", "chosen": False, "assumed": True, "law": RegionalLaw(grey, grey.scaled(JIN_WHITE_OVER_GREY), grey_range, grey_range),
         "source": f"Jin et al. 2013, J Biomech 46:2795-2801: white matter stiffer than grey in compression and shear; "
                   f"ratio {JIN_WHITE_OVER_GREY:g} assumed (the paper's ratio not found here), the cortex law's shape"},
    ]


def regions_meta(scene) -> dict:
    """The truth's regions: each one's law and where its data come from."""
    material = scene.spec.material
    grey = {"region": "grey matter (the whole brain when there is no white matter)", "law": material.law.params(), "source": material.law_source}
    if material.white_matter is None:
        return {"regions": [grey], "white_matter": None}
    return {"regions": [grey, {"region": "white matter, inside FreeSurfer's fsaverage5 white surface (data/brain_white_fsaverage5.npz)",
                               "law": material.white_matter.params(), "source": material.white_matter_source}],
            "white_matter": material.white_matter_source}


def membrane_meta(scene, members: list) -> dict:
    """The pia-arachnoid's treatment in this truth (docs/reference.md, The pia-arachnoid), and
    the members of its measured spread in the band."""
    pac = scene.spec.material.pia_arachnoid
    if pac is not None:
        return {"treatment": "a membrane on the surface, in every solve; its measured spread of mu in the band", "mu_pa": pac.mu,
                "alpha": pac.alpha, "thickness_m": pac.thickness, "mu_spread": pac.mu_spread, "members": members}
    return {"treatment": "not in this truth, which is the parenchyma's force (a grasp inside an opened pia); measured (Vandemaele et al. 2025, "
                         "human: one-term Ogden mu 0.30 MPa, alpha 37, 0.4 mm), modelled and solved, it multiplies the force of a 5 mm grasp "
                         "on the intact surface by 6-13, with a mesh band of +-30% (left-lateral, 8/6/4 mm) and a measured spread of -23%/+19%, "
                         "together wider than the JND: there no sample would be decided (docs/reference.md, The pia-arachnoid)",
            "source": "protocols/materials/pia_arachnoid_human.toml"}
