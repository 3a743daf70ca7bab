"""Whole runs of the brain scene: lockstep (deterministic) and real time, pictures."""

import json
from types import SimpleNamespace

import numpy as np
import pytest
from click.testing import CliRunner

from sim.run import run_scene, visual_budget_lines, write_outputs
from sim.run_plots import HAND_STYLES
from sim.scene import build_scene
from studyctl.cli import cli
from tests.conftest import SCENE


@pytest.fixture(scope="module")
def lockstep():
    scene = build_scene(SCENE)
    return scene, run_scene(scene, duration=2.0, time_scale=0)


def test_both_hands_grasp_pull_and_feel_the_plate_spring_force(lockstep):
    scene, r = lockstep
    assert len(r.times) == 2000
    assert r.mode == "lockstep"
    kinds = [e.kind for e in r.events]
    assert kinds.count("grasp") == 2
    fmag = np.linalg.norm(r.forces, axis=2)
    assert fmag.max() <= 3.3
    # at the end of the pull (1.7 s) each hand is about 12 mm from its grasp point minus the
    # lag of its impedance; the force sent equals the stack's force at that displacement
    model = scene.model
    k = int(1.9 * 1000)
    for e in (x for x in r.events if x.kind == "grasp"):
        contact_vertex = int(e.detail.split()[1])
        anchor = scene.mesh.vertices[contact_vertex]
        d = np.linalg.norm(r.positions[k, e.hand] - anchor)
        assert 0.008 < d < 0.0125
        assert fmag[k, e.hand] == pytest.approx(model.stack.force(d), rel=1e-9)
    # the force opposes the displacement: the tissue pulls the hand back
    d = r.positions[k, 0] - scene.mesh.vertices[scene.mesh.nearest_vertex(scene.spec.hands[0].start)]
    assert np.dot(d, r.forces[k, 0]) < 0


def test_lockstep_is_deterministic(lockstep):
    scene, r = lockstep
    again = run_scene(build_scene(SCENE), duration=2.0, time_scale=0)
    assert np.array_equal(r.forces, again.forces)
    assert np.array_equal(r.positions, again.positions)


def test_deformation_field_follows_the_hand(lockstep):
    scene, _ = lockstep
    model = scene.model
    mesh = scene.mesh
    c = model.grasp(scene.spec.hands[0].start, 0)
    d = np.array([0.01, 0.0, 0.002])
    u = model.deformation([c], [d])
    assert np.allclose(u[c.vertex], d)  # the grasp point moves with the hand
    moved = np.flatnonzero(np.linalg.norm(u, axis=1) > 0)
    assert set(moved) <= set(c.data.vertices.tolist())  # nothing beyond the outer ring moves
    # magnitude falls with geodesic distance
    mag = np.linalg.norm(u[c.data.vertices], axis=1)
    order = np.argsort(c.data.distance)
    assert np.all(np.diff(mag[order]) <= 1e-12)
    # two contacts superpose; a second call does not keep the first call's field
    c2 = model.grasp(scene.spec.hands[1].start, 1)
    u2 = model.deformation([c, c2], [d, -d]).copy()
    alone = model.deformation([c2], [-d]).copy()
    assert np.allclose(u2, model.deformation([c], [d]) + alone)
    assert np.allclose(model.deformation([], []), 0.0)
    assert mesh.n_vertices == len(u)


def test_realtime_run_goes_through_the_servo_process():
    scene = build_scene(SCENE)
    r = run_scene(scene, duration=0.3, time_scale=1.0)
    s = r.stats()
    assert s["mode"] == "realtime-process"
    assert s["ticks"] == 300
    assert s["tick_interval_us"]["p50"] is not None
    assert s["tick_compute_us"]["p50"] > 0
    assert len(r.intervals_s) == 299
    assert s["started_by"] == "clock"


def test_pictures_and_force_plot(tmp_path):
    scene = build_scene(SCENE)
    r = run_scene(scene, duration=1.2, time_scale=0, snapshots=True)
    n = write_outputs(r, scene, tmp_path)
    assert n == 12
    assert len(list(tmp_path.glob("frame_*.png"))) == 12
    import matplotlib.image as mpimg

    img = mpimg.imread(tmp_path / "frame_0011.png")[..., :3]
    assert img.std() > 0.05  # not blank
    # the deforming region is coloured: hot pixels exist once the pull has started
    hot = (img[..., 0] > 0.8) & (img[..., 2] < 0.3)
    assert hot.sum() > 50
    assert (tmp_path / "force.png").stat().st_size > 10_000
    lines = (tmp_path / "trace.csv").read_text().splitlines()
    assert lines[0] == "t_s,hand,x_m,y_m,z_m,fx_n,fy_n,fz_n,button"
    assert len(lines) == 1 + 2 * 1200


def test_cli_sim_run_json():
    res = CliRunner().invoke(cli, ["sim", "run", "--duration", "0.5", "--time-scale", "0", "--json"])
    assert res.exit_code == 0, res.output
    s = json.loads(res.output)
    for key in ("ticks", "rate_hz", "tick_interval_us", "tick_compute_us", "max_force_n", "deformation_ms", "frames"):
        assert key in s
    assert {"p50", "p99", "max"} <= set(s["tick_interval_us"])
    assert {"p50", "p99"} <= set(s["tick_compute_us"])
    assert s["ticks"] == 500
    assert s["frames"] == 0


def test_cli_unknown_model_is_a_clean_error():
    res = CliRunner().invoke(cli, ["sim", "run", "--model", "rubber", "--duration", "0.1", "--time-scale", "0"])
    assert res.exit_code == 1
    assert res.output.strip().startswith("Error: ")
    assert "models.rubber: not configured" in res.output
    assert len(res.output.strip().splitlines()) == 1


def test_replay_reproduces_a_recorded_run(tmp_path):
    from tests.helpers import localise

    scene = build_scene(SCENE)
    first = run_scene(scene, duration=2.0, time_scale=0)
    from sim.run_plots import write_trace

    write_trace(first, tmp_path / "trace.csv")
    text = localise(SCENE.read_text()).replace('device = "simulated"', f'device = "replay"\ntrace = "{tmp_path / "trace.csv"}"')
    (tmp_path / "replay.toml").write_text(text)
    replay = run_scene(build_scene(tmp_path / "replay.toml"), duration=2.0, time_scale=0)
    # same positions and buttons, so the same grasps and (the recorded hand being passive) the same forces
    assert np.allclose(replay.positions, first.positions, atol=1e-9)
    assert [e.kind for e in replay.events] == [e.kind for e in first.events]
    assert np.allclose(replay.forces, first.forces, atol=1e-6)


def test_replay_of_a_missing_trace_is_a_clean_error(tmp_path):
    from tests.helpers import localise

    text = localise(SCENE.read_text()).replace('device = "simulated"', f'device = "replay"\ntrace = "{tmp_path / "none.csv"}"')
    (tmp_path / "replay.toml").write_text(text)
    res = CliRunner().invoke(cli, ["sim", "run", "--scene", str(tmp_path / "replay.toml"), "--duration", "0.1", "--time-scale", "0"])
    assert res.exit_code == 1
    assert "none.csv: cannot read" in res.output


def test_servo_process_run_matches_the_lockstep_run():
    scene = build_scene(SCENE)
    proc = run_scene(scene, duration=2.0, time_scale=1.0)
    lock = run_scene(build_scene(SCENE), duration=2.0, time_scale=0)
    s = proc.stats()
    assert s["mode"] == "realtime-process"
    assert s["ticks"] == 2000
    assert [e.kind for e in proc.events].count("grasp") == 2
    # same simulated hands, same model: the same vertices are grasped and every force the
    # process rendered lies on the lockstep run's force-displacement curve. (Peak forces are no
    # test: a loaded machine's missed deadlines suspend the force, the hand runs ahead and the
    # force overshoots when it resumes; CI saw a 2.3% higher peak that way.)
    vertices = [[e.detail for e in r.events if e.kind == "grasp"] for r in (proc, lock)]
    assert vertices[0] == vertices[1]
    for h, detail in enumerate(vertices[0]):
        anchor = scene.mesh.vertices[int(detail.split()[-1])]
        curves = []
        for r in (proc, lock):
            t_grasp = min(e.t for e in r.events if e.kind == "grasp" and e.hand == h)
            t = np.arange(len(r.forces)) / 1000.0
            f = np.linalg.norm(r.forces[:, h], axis=1)
            x = np.linalg.norm(r.positions[:, h] - anchor, axis=1)
            keep = (t > t_grasp + 0.06) & (f > 0.0)  # past the grasp ramp, not suspended
            curves.append((x[keep], f[keep]))
        (xp, fp), (xl, fl) = curves
        order = np.argsort(xl)
        inside = (xp > 0.002) & (xp <= xl.max())
        assert inside.sum() > 500
        assert fp[inside] == pytest.approx(np.interp(xp[inside], xl[order], fl[order]), rel=0.02, abs=1e-4)


def test_grasp_collides_with_the_deformed_surface_and_misses_when_far():
    from sim.run import VisualStep
    from sim.servo.loop import Hand

    scene = build_scene(SCENE)
    model, mesh = scene.model, scene.mesh
    hand = Hand(index=0, name="h", device=None, button=True)
    visual = VisualStep(model=model, hands=[hand], events=[])
    v = mesh.nearest_vertex(scene.spec.hands[0].start)
    moved = np.zeros_like(mesh.vertices)
    moved[v] = (0.0, 0.0, 0.03)  # this vertex has been pulled 3 cm up
    visual.last = moved
    hand.grasp_request = tuple(mesh.vertices[v] + moved[v])  # the hand is where the tissue is now
    visual(0.5)
    assert hand.contact is not None
    assert hand.contact.vertex == v
    # a press 5 cm above the surface grasps nothing
    hand2 = Hand(index=1, name="g", device=None, button=True, grasp_request=tuple(mesh.vertices[v] + (0.0, 0.0, 0.08)))
    visual.hands = [hand2]
    visual(0.6)
    assert hand2.contact is None
    assert visual.events[-1].kind == "grasp_missed"


def test_read_to_force_latency_is_reported(lockstep):
    _, r = lockstep
    s = r.stats()["read_to_force_us"]
    assert 0 < s["p50"] <= s["p99"] <= s["max"]


def test_a_built_model_has_done_the_grasps_one_time_work():
    """A run's first grasps were over the budget building what every later grasp reuses."""
    scene = build_scene(SCENE)
    scene.model  # noqa: B018 - the build is what is tested
    assert scene.mesh.queries_prepared


def test_one_slow_grasp_is_not_over_budget():
    """The docs' rule for every call: more than 1% of a run's calls, and at least 3."""
    visual = SimpleNamespace(deformation_s=[0.001] * 100, grasp_s=[0.6, 0.001])
    assert visual_budget_lines(visual) == []


def test_three_slow_grasps_are_over_budget():
    visual = SimpleNamespace(deformation_s=[0.001] * 100, grasp_s=[0.6, 0.3, 0.3])
    assert visual_budget_lines(visual)[0].startswith("over_budget: grasp: 3 of 3 grasps took over 250 ms (worst 600 ms)")


def test_the_second_hands_line_is_drawn_over_the_first_and_both_show_where_they_meet():
    """The left hand's line lay under the right's when they pulled alike."""
    assert HAND_STYLES[1]["zorder"] > HAND_STYLES[0]["zorder"]
    assert HAND_STYLES[0]["lw"] > HAND_STYLES[1]["lw"]  # the one below is the wider: it shows either side
    assert HAND_STYLES[1].get("ls") == "--"
