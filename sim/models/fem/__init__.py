"""Finite element tissue model: one core for the haptic model and the reference.

- `p1`, `p2`: the elements (shape functions, quadrature, element stiffness);
- `linear`: small-strain linear elasticity, assembly, the clamp, one factorisation (`LinearFem`);
- `grasp`: the grasp constraint and its condensation;
- `newton`: the compressible neo-Hookean Newton solver, the element a parameter;
- `corotational`: the stiffness-warping update (P1);
- `model`: `FemModel` under the tissue-model contract, and `build` from a scene;
- `pull`: one static pull (`studyctl model fem`).

SI units; dof ``3 i + c`` is component c of node i.
"""

from sim.linalg import Factor, SingularSystemError
from sim.models.fem.corotational import corotational_internal_force, corotational_solve, element_rotations
from sim.models.fem.grasp import condense, constraint_matrix, pull_stiffness
from sim.models.fem.linear import ASSEMBLIES, LOCKING_POISSON, LinearFem, assemble, check_material, element_dofs, lame
from sim.models.fem.model import (
           COROT_FORCE_LIMIT,
           DEFAULT_ORDER,
           DEFAULT_RESOLUTION,
           FemContact,
           FemModel,
           build,
           fixed_nodes,
)
from sim.models.fem.newton import NewtonReport, neo_hookean_solve
from sim.models.fem.pull import FORMULATIONS, static_pull

__all__ = ["ASSEMBLIES", "COROT_FORCE_LIMIT", "DEFAULT_ORDER", "DEFAULT_RESOLUTION", "FORMULATIONS", "LOCKING_POISSON", "Factor",
           "FemContact", "FemModel", "LinearFem", "NewtonReport", "SingularSystemError", "assemble", "build", "check_material",
           "condense", "constraint_matrix", "corotational_internal_force", "corotational_solve", "element_dofs", "element_rotations",
           "fixed_nodes", "lame", "neo_hookean_solve", "pull_stiffness", "static_pull"]
