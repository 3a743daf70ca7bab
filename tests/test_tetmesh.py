"""The shipped body-fitted meshes (sim/geometry/tetmesh.py, data/brain_tets*.{npz,json}): one geometry,
checked against its provenance, used by the FEM, the mass-spring and the reference alike."""

import json
import shutil

import numpy as np
import pytest

from sim.errors import MeshError
from sim.geometry.tetmesh import (
    PROVENANCE,
    SHIPPED_MM,
    TEST_MM,
    body_volume,
    content_hash,
    enclosed_volume,
    hemisphere_surface,
    mesh_hemisphere,
)
from sim.geometry.volume import tet_volumes
from sim.models.fem import build as build_fem
from sim.models.mass_spring import build as build_ms
from sim.pulls import scene_with
from sim.scene import DEFAULT_SCENE


@pytest.fixture(scope="module")
def scene():
    return scene_with(DEFAULT_SCENE)


def test_every_shipped_mesh_matches_its_provenance(scene):
    prov = json.loads(PROVENANCE.read_text())
    assert sorted({m["target_edge_mm"] for m in prov["meshes"]}) == sorted(SHIPPED_MM + TEST_MM)
    for entry in prov["meshes"]:
        v, t, _ = hemisphere_surface(scene.mesh, entry["hemisphere"])
        m = mesh_hemisphere(v, t, entry["target_edge_mm"] * 1e-3)
        assert m.source == "shipped"
        assert content_hash(m.nodes, m.tets) == entry["sha256"]
        vol = tet_volumes(m.nodes, m.tets)
        assert np.all(vol > 0)  # positively oriented, none degenerate
        # the boundary follows the pial surface within the envelope (0.1 x the edge): the volume
        # error shrinks with the size (1% at 8 mm)
        assert abs(vol.sum() / enclosed_volume(v, t) - 1) < 0.01 * entry["target_edge_mm"] / 8.0
        assert len(m.tets) == entry["tets"]
        assert len(m.nodes) == entry["nodes"]


def test_a_damaged_shipped_mesh_is_refused_by_name(scene, tmp_path, monkeypatch):
    import sim.geometry.tetmesh as tm

    src = tm.shipped_file(8.0)
    with np.load(src) as z:
        arrays = {k: z[k] for k in z.files}
    arrays["nodes_0"] = arrays["nodes_0"].copy()
    arrays["nodes_0"][5, 0] += 1e-6
    np.savez(tmp_path / src.name, **arrays)
    shutil.copy(PROVENANCE, tmp_path / PROVENANCE.name)
    monkeypatch.setattr(tm, "_asset", lambda rel: tmp_path / rel.split("/")[-1])
    monkeypatch.setattr(tm, "PROVENANCE", tmp_path / PROVENANCE.name)
    v, t, _ = hemisphere_surface(scene.mesh, 0)
    with pytest.raises(MeshError, match=r"brain_tets_8mm\.npz: hemisphere 0: content hash differs"):
        mesh_hemisphere(v, t, 0.008)


def test_fem_mass_spring_and_reference_share_one_geometry(scene):

    volume = body_volume(scene.mesh, 0.008)
    fem = build_fem(scene.mesh, {"resolution": 0.008, "order": 1}, scene)
    ms = build_ms(scene.mesh, dict(scene.spec.model_spec("mass_spring").options) | {"resolution": 0.008}, scene)
    for model in (fem, ms):
        assert np.array_equal(model.volume.nodes, volume.nodes)
        assert np.array_equal(model.volume.tets, volume.tets)
    v, t, _ = hemisphere_surface(scene.mesh, 1)
    right = mesh_hemisphere(v, t, 0.008)  # what analysis/verification/reference.py meshes the right hemisphere with
    assert np.array_equal(volume.nodes[volume.component == 1], right.nodes)
