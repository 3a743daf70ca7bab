"""Tissue models behind one public API (`sim.models.api`), found by `sim.models.registry`:
the built-in plate-spring, FEM and mass-spring (`sim.models.builtin`) and a lab's own,
registered under the entry-point group ``brainsim.models``. A model's module is imported only
when a scene asks for that model. The mass-spring's solvers (`local_global`, `newton_krylov`) and
compiled passes over its springs (`spring_kernels`) sit beside it; the FEM is `sim.models.fem`.

Imports: numpy, scipy, numba and `sim` below it (geometry, laws, linalg); never the servo or the view."""
