"""Finite element tissue model: one core for the haptic model and the reference.

- `p1`, `p2`: the elements (shape functions, quadrature, element stiffness);
- `linear`: small-strain linear elasticity, assembly, the clamp, one factorisation (`LinearFem`);
- `grasp`: the grasp constraint and its condensation;
- `space`: the elements on a mesh with its clamp (`TetSpace`), shared by every solve;
- `finite_strain`: a finite-strain law (`sim.hyperelastic`) on a space (P2, or P2/P0 with a mean dilatation),
  its compiled element pass in `hyperelastic_kernels`;
- `membrane`: a hyperelastic membrane on the body's boundary faces (the pia-arachnoid) and the body with it;
- `newton`: the one Newton solver for finite strain, following a held constraint's path (`hold`), or a
  path in time (`follow`);
- `viscous`: a finite viscoelastic law (`sim.material.Viscoelastic`) on a space, stepped in time;
- `nodal_pressure`: linear tetrahedra that do not lock (the average nodal pressure element) for a
  finite-strain law;
- `corotational`: the stiffness-warping update (P1), its compiled passes in `corotational_kernels`
  (with the 3 x 3 inverse `hyperelastic_kernels` shares);
- `model`: `FemModel` under the tissue-model contract, and `build` from a scene;
- `pull`: one static pull (`studyctl model fem`).

SI units; dof ``3 i + c`` is component c of node i. Imports: numpy, scipy, numba, the CHOLMOD factor
(`sim.linalg`) and `sim` below it.
"""

from sim.hyperelastic import Hyperelastic
from sim.linalg import Factor, SingularSystemError
from sim.models.fem.corotational import corotational_internal_force, corotational_solve, element_rotations
from sim.models.fem.finite_strain import FiniteStrain
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
from sim.models.fem.newton import FollowedPath, HeldPath, NewtonReport, follow, hold
from sim.models.fem.pull import FORMULATIONS, static_pull
from sim.models.fem.space import TetSpace
from sim.models.fem.viscous import ViscoelasticStrain

__all__ = ["ASSEMBLIES", "COROT_FORCE_LIMIT", "DEFAULT_ORDER", "DEFAULT_RESOLUTION", "FORMULATIONS", "LOCKING_POISSON", "Factor",
           "FemContact", "FemModel", "FiniteStrain", "FollowedPath", "HeldPath", "Hyperelastic", "LinearFem", "NewtonReport", "TetSpace", "SingularSystemError", "ViscoelasticStrain", "assemble", "build", "check_material",
           "condense", "constraint_matrix", "corotational_internal_force", "corotational_solve", "element_dofs", "element_rotations",
           "fixed_nodes", "follow", "hold", "lame", "pull_stiffness", "static_pull"]
