"""The location-aware plate-spring model (beyond the paper): its law worked by hand, the field's
interpolation, and the shipped field's fit to this brain."""

import numpy as np
import pytest

from analysis.verification.field_fit import interpolate
from sim.errors import ParameterError
from sim.laws import RadialTable, TensorTable
from sim.models.plate_spring import PlateSpring, PlateSpringModel, load_params
from sim.pulls import scene_with
from sim.scene import DEFAULT_SCENE
from sim.stiffness_field import FIELD_FILE, load_field, mesh_digest

PARAMS = DEFAULT_SCENE.parents[1] / "models" / "plate_spring_located.toml"


@pytest.fixture(scope="module")
def scene():
    return scene_with(DEFAULT_SCENE)


def test_tensor_law_by_hand():
    stack = PlateSpring(load_params(PARAMS))
    k0 = stack.force(1e-7) / 1e-7
    S = np.array([[40.0, 5.0, 0.0], [5.0, 20.0, 0.0], [0.0, 0.0, 30.0]])  # N/m
    law = TensorTable(list(stack._x0), list(stack._f0), list(stack._slope), k0, tuple(S.ravel()))
    radial = RadialTable(list(stack._x0), list(stack._f0), list(stack._slope))
    for d in ([0.004, 0.0, 0.0], [0.0, 0.012, 0.003], [0.01, -0.01, 0.02]):
        d = np.array(d)
        x = np.linalg.norm(d)
        want = -(stack.force(x) / (k0 * x)) * S @ d
        assert np.allclose(law.force(tuple(d)), want, rtol=1e-12)
        # an isotropic S = k0 I is the paper's radial law
        iso = TensorTable(list(stack._x0), list(stack._f0), list(stack._slope), k0, tuple((k0 * np.eye(3)).ravel()))
        assert np.allclose(iso.force(tuple(d)), radial.force(tuple(d)), rtol=1e-12)
    assert law.force((0.0, 0.0, 0.0)) == (0.0, 0.0, 0.0)


def test_located_model_uses_the_field_at_the_grasped_vertex(scene):
    mesh = scene.mesh
    params = load_params(PARAMS)
    field = np.zeros((len(mesh.vertices), 3, 3))
    field[:] = np.eye(3) * 0.01  # 0.01 N/m per pascal everywhere ...
    v = mesh.nearest_vertex(scene.spec.hands[0].start)
    field[v] = np.diag([0.02, 0.01, 0.005])  # ... but stiffer along x at the grasp
    model = PlateSpringModel(mesh, params, "located", field)
    c = model.grasp(scene.spec.hands[0].start, 0)
    assert c.vertex == v
    d = np.array([0.01, 0.01, 0.0])
    x = np.linalg.norm(d)
    f = np.array(model.force(c, tuple(d)))
    want = -(model.stack.force(x) / (model.k0 * x)) * params.E * field[v] @ d
    assert np.allclose(f, want, rtol=1e-12)
    assert f[0] == pytest.approx(2 * f[1])  # the direction follows the field, not the pull
    # the drawn deformation is the paper's (the grasp follows the hand)
    surf = model.deformation([c], [d])
    assert np.allclose(surf[v], d)
    with pytest.raises(ParameterError, match="needs a stiffness field"):
        PlateSpringModel(mesh, params, "located")


def test_interpolation_reproduces_a_constant_field_and_its_sites(scene):
    mesh = scene.mesh
    sites = np.array([0, 5, 40, 10242, 10250])
    K = np.stack([np.eye(3) * (k + 1) for k in range(len(sites))])
    out = interpolate(mesh, sites, np.stack([np.eye(3)] * len(sites)))
    assert np.allclose(out, np.eye(3))  # every vertex: a convex combination of identities
    out = interpolate(mesh, sites, K)
    for s, k in zip(sites, K):  # a site with no other site within reach keeps its own value
        d = np.linalg.norm(mesh.vertices[sites] - mesh.vertices[s], axis=1)
        same = mesh.labels[sites] == mesh.labels[s]
        if np.sum((d < 0.008) & same) == 1:
            assert np.allclose(out[s], k)
    assert np.all(np.linalg.eigvalsh(out) > 0)


def test_shipped_field_belongs_to_this_brain_and_is_stiffness(scene, tmp_path):
    K = load_field(FIELD_FILE, scene.mesh)
    assert K.shape == (len(scene.mesh.vertices), 3, 3)
    ev = np.linalg.eigvalsh(K)
    assert np.all(ev > 0)  # SPD everywhere
    # per pascal of the law's shear modulus mu (small strain, Poisson 0.490 from kappa = 50 mu):
    # the softest direction (a tangent pull) gives the bench's small-strain forces, K ~ 2e-3..3e-2
    # N/m per Pa; along the normal, a uniform pressure on a 5 mm disc of a half-space has
    # K = 3 pi^2 a E / (16 (1 - nu^2)) = 0.036 N/m per Pa of mu, which the free surface's median
    # stays under (the brain is softer than a half-space away from the clamp); near the clamp,
    # stiffer, but finite
    from sim.scene import clamp_limit

    axis, limit = clamp_limit(scene)
    free = scene.mesh.vertices[:, axis] > limit + 0.015  # where the bench grasps
    assert 1.5e-3 < np.median(ev[free, 0]) < 3e-2
    assert np.median(ev[free, -1]) < 0.036
    assert np.all(ev[:, -1] < 10.0)
    with np.load(FIELD_FILE) as z:
        assert str(z["mesh_digest"]) == mesh_digest(scene.mesh)
        assert float(z["size_mm"]) == 8.0
    # a field made for another surface is refused, naming the file
    other = tmp_path / "other.npz"
    with np.load(FIELD_FILE) as z:
        data = {k: z[k] for k in z.files} | {"mesh_digest": "0" * 16}
    np.savez(other, **data)
    with pytest.raises(ParameterError, match="other.npz: made for another surface mesh"):
        load_field(other, scene.mesh)
    (tmp_path / "junk.npz").write_bytes(b"not a zip")
    with pytest.raises(ParameterError, match="junk.npz: not a stiffness field"):
        load_field(tmp_path / "junk.npz", scene.mesh)
