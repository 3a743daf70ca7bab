"""Geometry of the brain: the surface mesh (`mesh`), body-fitted tetrahedral meshes (`tetmesh`),
points embedded in them (`volume`), the grasp patch (`patch`), and the brain's regions (`regions`:
grey and white matter by FreeSurfer's white surface).

Imports: numpy, scipy, pytetwild, numba (`regions`), and `sim` below it (files, errors); no tissue model.
"""
