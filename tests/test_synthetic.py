"""Synthetic participants: determinism, dependence on what the simulator measured."""

import sqlite3

import numpy as np
import pytest

from studyctl.synthetic import SyntheticParticipant, latency_category, p_yes, run_synthetic_study
from tests.test_study import fast_protocol


def _content(db):
    con = sqlite3.connect(db)
    answers = con.execute("select code, model, item, answer, session_id, source from answers order by code, model, item").fetchall()
    trials = con.execute("select session_id, model, trial, round(max_force_n, 9) from trials order by session_id, model, trial").fetchall()
    orders = con.execute("select code, conditions from schedule order by code").fetchall()
    return answers, trials, orders


def _latency_categories(db) -> dict:
    """The latency a synthetic participant perceives in each condition: measured wall-clock
    time, so it may differ between runs on a loaded machine (and then so may the answers)."""
    con = sqlite3.connect(db)
    rows = con.execute("select s.code, t.model, avg(t.deformation_ms_mean) from trials t join sessions s on s.id = t.session_id "
                       "group by s.code, t.model").fetchall()
    return {(code, model): latency_category(ms) for code, model, ms in rows}


def test_same_seed_same_database_different_seed_different_answers(tmp_path):
    protocol = fast_protocol(tmp_path, trials=1)
    runs, cats = {}, {}
    for name, seed, jobs in (("a", 7, 1), ("b", 7, 2), ("c", 8, 1)):
        db = tmp_path / f"{name}.db"
        run_synthetic_study(db, 3, seed=seed, jobs=jobs, protocol_path=protocol)
        runs[name] = _content(db)
        cats[name] = _latency_categories(db)
    # same seed: same trials and orders, even in parallel; the same answers wherever the measured
    # latency fell in the same category (two jobs on a loaded 2-core machine can push a model's
    # frame time over a threshold, and a participant would notice that)
    assert runs["a"][1:] == runs["b"][1:]
    same = {key for key in cats["a"] if cats["a"][key] == cats["b"].get(key)}
    assert len(same) >= len(cats["a"]) // 2
    pick = lambda answers: [r for r in answers if (r[0], r[1]) in same]  # noqa: E731
    assert pick(runs["a"][0]) == pick(runs["b"][0])
    assert runs["a"][0] != runs["c"][0]  # another seed: other participants, other answers
    answers = runs["a"][0]
    assert len(answers) == 3 * 3 * 9 and all(r[5] == "synthetic" for r in answers)
    assert len({r[1] for r in runs["a"][2]}) == 3  # three participants, three Williams orders


def test_answers_follow_the_measurements_not_the_model_name():
    fast = {"latency_ms": 1.0, "within_jnd": 0.95, "jitter": 0.0, "events": 0}
    slow = dict(fast, latency_ms=80.0)
    rough = dict(fast, within_jnd=0.1, jitter=0.05, events=2)
    assert latency_category(10) == 0 and latency_category(30) == 1 and latency_category(80) == 2
    assert p_yes("realtime", slow) < p_yes("realtime", fast) - 0.3
    assert p_yes("texture", slow) == pytest.approx(p_yes("texture", fast))  # texture ignores latency
    assert p_yes("stable", rough) < p_yes("stable", fast) - 0.3
    assert p_yes("feedback", rough) < p_yes("feedback", fast)
    assert p_yes("natural", fast, bias=1.0) > p_yes("natural", fast)


def test_motor_model_varies_per_participant_and_trial():
    from sim.scene import build_scene
    from tests.conftest import SCENE

    scene = build_scene(SCENE)
    a, b = SyntheticParticipant.draw("S001", 0), SyntheticParticipant.draw("S002", 0)
    assert a != b and SyntheticParticipant.draw("S001", 0) == a
    pa = a.operators(scene, 0, "fem")
    assert pa[0].tremor_m > 0 and 8 <= pa[0].tremor_hz <= 12
    assert pa[0].pull != a.operators(scene, 1, "fem")[0].pull  # each trial differs a little
    # tremor is in the target: at the end of the pull the hand oscillates about the goal
    t = np.linspace(pa[0].pull_start + pa[0].pull_time + 0.1, pa[0].pull_start + pa[0].pull_time + 0.3, 200)
    xs = np.array([pa[0].target(x)[0] for x in t])
    assert 0.5 * pa[0].tremor_m < xs.std() * np.sqrt(2) < 1.5 * pa[0].tremor_m


def test_plan_power_grows_with_n_and_is_labelled_synthetic(tmp_path):
    import json

    from click.testing import CliRunner

    from studyctl.cli import cli
    from studyctl.plan import power_table
    from studyctl.protocol import load_protocol

    protocol = load_protocol(fast_protocol(tmp_path, trials=1))
    # fixed pilot features: a clearly worse model and two similar ones
    good = {"latency_ms": 1.0, "within_jnd": 0.9, "jitter": 0.0, "events": 0}
    bad = {"latency_ms": 80.0, "within_jnd": 0.2, "jitter": 0.0, "events": 0}
    feats = {"plate_spring": [good], "fem": [good], "mass_spring": [bad]}
    t = power_table(protocol, [6, 24, 48], simulations=100, seed=3, feats=feats)
    assert list(t.columns) == ["n", "item", "power", "simulations", "alpha"]
    rt = t[t["item"] == "realtime"].set_index("n")["power"]
    assert rt[6] < rt[24] <= rt[48] and rt[48] > 0.9  # a large effect: power rises to ~1
    res = CliRunner().invoke(cli, ["plan", "--protocol", str(fast_protocol(tmp_path, trials=1)), "--participants", "12..18",
                                   "--step", "6", "--simulations", "20", "--pilots", "1", "--json", "--plot", str(tmp_path / "p.png")])
    assert res.exit_code == 0, res.output
    out = json.loads(res.output)
    assert out["synthetic"] is True and len(out["rows"]) == 2 * 9 and (tmp_path / "p.png").stat().st_size > 5000
