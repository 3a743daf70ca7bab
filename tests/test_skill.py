"""Synthetic participants with skill (issue 32, item 5): `[synthetic.groups.NAME]` parsed and
refused with FILE:LINE, the target-pursuing operator's movement worked analytically, force
restraint against a spring tissue, the old operator unchanged, the profile stored."""

import dataclasses
import math
import sqlite3
from pathlib import Path

import numpy as np
import pytest

from sim.devices.simulated import PullScript, SimulatedOmni, min_jerk
from sim.targets import HandTarget, TargetSpec
from studyctl.protocol import check_protocol
from studyctl.synthetic.participant import CORRECTION_DELAY, CORRECTION_TIME, SyntheticParticipant, pursue
from studyctl.synthetic.skill import KEYS, SkillProfile

ROOT = Path(__file__).resolve().parents[1]
CV = ROOT / "protocols" / "construct_validity.toml"


def _problems(text: str) -> list[str]:
    return check_protocol(CV, text)[1]


def _line(text: str, needle: str) -> int:
    return next(n for n, line in enumerate(text.splitlines(), start=1) if line.startswith(needle))


def test_shipped_profiles_parse_in_the_groups_order_of_skill():
    protocol, problems = check_protocol(CV)
    assert problems == []
    s = protocol.skills
    assert set(s) == {"student", "resident", "neurosurgeon"}
    st, re_, ns = s["student"], s["resident"], s["neurosurgeon"]
    assert st.tremor_mm > re_.tremor_mm > ns.tremor_mm
    assert st.speed < re_.speed < ns.speed
    assert st.overshoot > re_.overshoot > ns.overshoot
    assert st.force_restraint < re_.force_restraint < ns.force_restraint
    assert all(p.spread > 0 and p.learning > 0 for p in s.values())


def test_defaults_and_a_partial_profile():
    text = CV.read_text().split("[synthetic.groups.student]")[0] + "[synthetic.groups.resident]\nspeed = 1.5\n"
    protocol, problems = check_protocol(CV, text)
    assert problems == []
    assert protocol.skills == {"resident": SkillProfile(speed=1.5)}
    d = SkillProfile()
    assert (d.tremor_mm, d.speed, d.overshoot, d.force_restraint, d.learning, d.spread) == (None, 1.0, 0.0, 0.0, 0.0, 0.0)
    assert all(KEYS[k][2] == getattr(d, k) for k in KEYS)
    # no section: no profiles
    assert check_protocol(CV, CV.read_text().split("[synthetic.groups.student]")[0])[0].skills == {}


def test_a_group_that_is_not_a_value_of_the_group_field_is_refused_with_file_line_and_the_values():
    text = CV.read_text().replace("[synthetic.groups.resident]", "[synthetic.groups.surgeon]")
    problems = _problems(text)
    assert problems == [f"{CV}:{_line(text, '[synthetic.groups.surgeon]')}: synthetic.groups.surgeon: not a value of design.groups "
                        "field experience; allowed: student, resident, neurosurgeon"]


def test_profiles_without_design_groups_are_refused():
    text = CV.read_text().replace('groups = "experience"', "")
    problems = _problems(text)
    assert len(problems) == 1
    assert "synthetic.groups: needs design.groups" in problems[0]
    assert problems[0].startswith(f"{CV}:{_line(text, '[synthetic.groups.student]')}:")


@pytest.mark.parametrize("line, message", [
    ("tremor = 0.3", "synthetic.groups.student.tremor: unknown key; allowed: " + ", ".join(KEYS)),
    ("speed = 9", "synthetic.groups.student.speed: 9 is out of range; allowed: [0.25, 4]"),
    ("force_restraint = 1.5", "synthetic.groups.student.force_restraint: 1.5 is out of range; allowed: [0, 1]"),
    ("overshoot = -0.1", "synthetic.groups.student.overshoot: -0.1 is out of range; allowed: [0, 1]"),
    ("spread = \"wide\"", "synthetic.groups.student.spread: 'wide' is not a finite number"),
])
def test_unknown_keys_and_values_out_of_range_are_refused(line, message):
    text = CV.read_text().split("[synthetic.groups.student]")[0] + f"[synthetic.groups.student]\ntremor_mm = 0.3\n{line}\n"
    problems = _problems(text)
    assert problems == [f"{CV}:{_line(text, line)}: {message}"]


def test_a_plateau_needs_learning():
    head = CV.read_text().split("[synthetic.groups.student]")[0] + "[synthetic.groups.student]\ntremor_mm = 0.3\n"
    text = head + "plateau_speed = 1.2\nplateau_overshoot = 0.1\n"
    problems = _problems(text)
    assert problems == [f"{CV}:{_line(text, k)}: synthetic.groups.student.{k}: a plateau needs learning > 0 (trials to halve the gap "
                        f"from {k[8:]} to it)" for k in ("plateau_speed", "plateau_overshoot")]
    text = head.replace("tremor_mm = 0.3\n", "learning = 2\nplateau_tremor_mm = 0.2\n")
    assert _problems(text) == [f"{CV}:{_line(text, 'plateau_tremor_mm')}: synthetic.groups.student.plateau_tremor_mm: needs tremor_mm: "
                               "the group's tremor on the first trial"]


def test_individual_spread_and_learning():
    p = SkillProfile(tremor_mm=0.3, speed=0.8, overshoot=0.4, force_restraint=0.5, learning=2.0,
                     plateau_tremor_mm=0.2, plateau_speed=1.2, plateau_overshoot=0.1, spread=0.3)
    a, b = p.individual("S001", 1), p.individual("S002", 1)
    assert a != b
    assert p.individual("S001", 1) == a
    assert 0 < a.force_restraint < 1
    one = dataclasses.replace(p, spread=0.0).individual("S001", 1)
    assert one.at(0) == (0.3, 0.8, 0.4)
    t, s, o = one.at(2)  # one half-life: half way to the plateau
    assert t == pytest.approx(0.25)
    assert s == pytest.approx(1.0)
    assert o == pytest.approx(0.25)
    assert one.at(1000) == pytest.approx((0.2, 1.2, 0.1))
    # the spread scales the participant's whole curve by one factor per key
    assert a.plateau_speed / a.speed == pytest.approx(1.2 / 0.8)
    assert a.plateau_overshoot / a.overshoot == pytest.approx(0.25)


def _script(**kw):
    return PullScript(start=(0.01, 0.02, 0.03), pull=(0.04, 0.0, 0.0), grasp_at=0.3, pull_start=0.5, pull_time=2.0, release_at=5.5, **kw)


def test_an_overshooting_operator_goes_beyond_the_target_and_back():
    u = (0.6, 0.8, 0.0)
    target = HandTarget(TargetSpec(distance=0.04, tolerance=0.003, hold=0.5, safe_force=0.29), direction=u)
    o = 0.3
    sc = pursue(_script(), target, o)
    start, t1 = np.array(sc.start), sc.pull_start + sc.pull_time
    b0, b1 = t1 + CORRECTION_DELAY, t1 + CORRECTION_DELAY + CORRECTION_TIME * sc.pull_time
    assert (sc.back_start, sc.back_time) == (pytest.approx(b0), pytest.approx(CORRECTION_TIME * sc.pull_time))
    for t in np.linspace(0.0, 8.0, 161):
        expected = 0.04 * ((1 + o) * min_jerk((t - sc.pull_start) / sc.pull_time) - o * min_jerk((t - b0) / (b1 - b0)))
        assert np.allclose(np.array(sc.target(t)) - start, expected * np.array(u), atol=1e-15)
    assert np.allclose(sc.target(t1), start + 0.052 * np.array(u))
    assert np.allclose(sc.target(b1), start + 0.04 * np.array(u))
    assert sc.release_at == pytest.approx(max(5.5, b1 + 0.5 + 1.0))
    assert sc.restraint == 0.0
    assert sc.safe_force == math.inf
    # no overshoot: one movement to the target, no second segment
    plain = pursue(_script(), target, 0.0)
    assert plain.back_start is None
    assert np.allclose(plain.target(10.0), start + 0.04 * np.array(u))


def test_a_script_without_a_second_segment_is_the_old_one():
    old = _script(tremor_m=2e-4, tremor_phase=(0.1, 0.2, 0.3))
    for t in np.linspace(0, 6, 61):
        s = min_jerk((t - 0.5) / 2.0)
        w = 2 * math.pi * 10.0 * t
        x = tuple(a + s * p + 2e-4 * math.sin(w + ph) for a, p, ph in zip(old.start, old.pull, old.tremor_phase))
        assert old.target(t) == x  # bit for bit


def _peak_force_on_a_spring(restraint: float, k_tissue: float = 8.0, overshoot: float = 0.5) -> float:
    """The peak force of a pursuing operator on a tissue that is a spring (N/m) from the grasp,
    at 1 kHz: the force at the target 0.32 N, the limit 0.4 N."""
    target = HandTarget(TargetSpec(distance=0.04, safe_force=0.4), direction=(1.0, 0.0, 0.0))
    sc = pursue(_script(), target, overshoot, restraint)
    dev = SimulatedOmni(sc)
    peak = 0.0
    for n in range(1, 6000):
        p = dev.read(n * 1e-3).position
        f = tuple(-k_tissue * (a - b) for a, b in zip(p, sc.start))
        dev.write_force(f)
        peak = max(peak, math.sqrt(sum(c * c for c in f)))
    return peak


def test_force_restraint_keeps_the_force_under_the_limit_where_no_restraint_passes_it():
    free, held = _peak_force_on_a_spring(0.0), _peak_force_on_a_spring(0.9)
    assert free > 1.15 * 0.4  # the overshoot alone: 60 mm on 8 N/m, less the hand's lag
    assert held < 0.97 * 0.4  # holds back from 90 % of the limit on
    assert _peak_force_on_a_spring(0.9, overshoot=0.0) == pytest.approx(_peak_force_on_a_spring(0.0, overshoot=0.0), rel=1e-12)


def test_old_operator_unchanged_without_a_target_or_profile():
    from sim.devices.simulated import HandImpedance
    from sim.scene import build_scene
    from tests.conftest import SCENE

    scene = build_scene(SCENE)
    assert all(h.target is None for h in scene.spec.hands)
    p = SyntheticParticipant.draw("S001", 3)
    assert p.skill is None
    assert not any(k.startswith("skill_") for k in p.trait_values())
    import random

    rng = random.Random("trial:3:S001:fem:2")  # the operators as they were before skill profiles
    expected = []
    for h in scene.spec.hands:
        base = h.script(scene.mesh)
        s = p.pull_scale * rng.uniform(0.9, 1.1)
        damping = 2 * 0.7 * math.sqrt(p.stiffness * 0.2)
        expected.append(dataclasses.replace(
            base, pull=tuple(s * c for c in base.pull), pull_time=base.pull_time * p.time_scale * rng.uniform(0.9, 1.1),
            tremor_m=p.tremor_m, tremor_hz=p.tremor_hz, tremor_phase=tuple(rng.uniform(0, 2 * math.pi) for _ in range(3)),
            impedance=HandImpedance(mass_kg=0.2, stiffness_n_per_m=p.stiffness, damping_ns_per_m=damping)))
    assert p.operators(scene, 2, "fem") == expected
    # a profile changes the skill alone: every other trait as drawn without it
    q = SyntheticParticipant.draw("S001", 3, SkillProfile(tremor_mm=0.2, speed=2.0))
    assert dataclasses.replace(q, skill=None) == p
    ops = q.operators(scene, 2, "fem")
    assert ops[0].tremor_m == pytest.approx(2e-4)
    assert ops[0].pull_time == pytest.approx(expected[0].pull_time / 2.0)
    assert ops[0].pull == expected[0].pull  # no target: the scene's pull
    assert ops[0].back_start is None
    assert SyntheticParticipant.draw("S001", 3).skill is None


def test_a_synthetic_study_stores_each_participants_profile(tmp_path):
    from studyctl.store import init_study
    from studyctl.synthetic.synth_run import run_synthetic_study

    text = CV.read_text().replace("trials_per_condition = 10 ", "trials_per_condition = 2 ")
    text = text.replace('scene = "scenes/retraction.toml"', f'scene = "{CV.parent / "scenes" / "retraction.toml"}"')
    text = text.replace("training_minutes = 2.0", "training_minutes = 0.0")
    proto = tmp_path / "cv.toml"
    proto.write_text(text)
    db = tmp_path / "s.db"
    init_study(db, proto)
    run_synthetic_study(db, 2, seed=1, protocol_path=proto)
    con = sqlite3.connect(db)
    traits = {(c, t): v for c, t, v in con.execute("select code, trait, value from synthetic_traits")}
    groups = dict(con.execute("select code, value from participant_fields where field = 'experience'").fetchall())
    ticks = con.execute("select trace_ticks from trials order by session_id, trial").fetchall()
    con.close()
    assert groups == {"S001": "student", "S002": "resident"}
    protocol = check_protocol(proto)[0]
    for code, group in groups.items():
        want = protocol.skills[group].individual(code, 1).values()
        assert want
        assert all(traits[(code, k)] == pytest.approx(v) for k, v in want.items())
    assert all(n < 10_000 for (n,) in ticks)  # the targets were held before the 10 s limit
