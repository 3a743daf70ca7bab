"""Geometry of the brain: the surface mesh (`mesh`), body-fitted tetrahedral meshes (`tetmesh`),
points embedded in them (`volume`), and the grasp patch (`patch`).

Imports: numpy, scipy, pytetwild, and `sim` below it (files, errors); no tissue model.
"""
