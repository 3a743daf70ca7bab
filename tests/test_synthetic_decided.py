"""The synthetic observer judges accuracy only on decided truth: a made truth along one path
(records at 0, 1, 2 and 3 mm, decided at the first three, force 40 N/m x the stretch) and made
traces of one hand pulling along it."""

import dataclasses
import math
from types import SimpleNamespace

import numpy as np
import pytest

from analysis.study.trace_files import Trace
from analysis.verification.truth import Truth
from sim.servo.loop import Event
from studyctl.synthetic.observer import (
    P_WITHIN_PERFECT,
    ObserverParams,
    ObserverTraits,
    features,
    judged_time,
    summarise,
)
from tests.helpers import p_yes

MEDIAN = ObserverTraits(weber=0.10, prior=1.0, latency_ms=40.0, vibration=1.0, bias=0.0)
EVERY_TICK = ObserverParams(sample_every=1)  # every tick a sample: counts by hand
K = 40.0  # N/m: 0.02 N, the judged force, at 0.5 mm
S = np.array([0.0, 0.001, 0.002, 0.003])
E = np.array([1.0, 0.0, 0.0])
MESH = SimpleNamespace(vertices=np.zeros((8, 3)))
TRUTH = Truth(vertices=np.array([5, 7]), path=np.array([0, 0]), transfer=np.stack([np.eye(3)] * 2), s=S, direction=E[None],
              force_per_pa=(K * S[:, None] * E)[None], stiffness_per_pa=np.stack([K * np.eye(3)] * len(S))[None], mu=1.0, digest="",
              grasp_radius=0.005, band_rel=np.array([[0.0, 0.0, 0.0, 0.3]]), path_band=np.array([[0.0, 0.05, 0.05, 0.3]]),
              transfer_error=np.array([[0.0, 0.1, 0.1, 0.3]]), path_vertex=np.array([5]),
              path_decided=np.array([[True, True, True, False]]))


def pull(stretch_m, ratio=1.0, vertex=5) -> Trace:
    """The left hand grasping `vertex` at t = 0 and stretched along the path by `stretch_m` (one
    per tick, 1 kHz), rendering `ratio` (per tick, or one for all) times the truth's force; the
    right hand never grasps."""
    x = np.asarray(stretch_m, dtype=np.float64)
    pos = np.zeros((len(x), 2, 3))
    pos[:, 0] = x[:, None] * E
    forces = np.zeros_like(pos)
    forces[:, 0] = -(np.asarray(ratio, dtype=np.float64) * K * x)[:, None] * E
    buttons = np.zeros((len(x), 2), dtype=bool)
    buttons[:, 0] = True
    return Trace(hand_names=["left", "right"], times=np.arange(len(x)) / 1000.0, positions=pos, forces=forces, buttons=buttons,
                 deformation_s=np.zeros(0), events=[Event(0.0, 0, "grasp", f"vertex {vertex}")], frame_flops=np.full(3, 1e4))


def test_the_truth_is_decided_only_between_decided_records_and_off_the_vertex_only_within_a_jnd_band():
    d = np.outer([0.0005, 0.0015, 0.0025, 0.0035, -0.0005], E)
    # 0.5 and 1.5 mm: between decided records; 2.5 mm: next to the undecided 3 mm record; 3.5 mm:
    # past the last record; -0.5 mm: compression, never solved
    assert TRUTH.decided(5, d).tolist() == [True, True, False, False, False]
    # off the vertex the band is the path's and the transfer's error: +-11% at 1.5 mm, within the JND (25% below 0.3 N)
    assert TRUTH.decided(7, d).tolist() == [True, True, False, False, False]
    wide = dataclasses.replace(TRUTH, transfer_error=np.array([[0.0, 0.3, 0.3, 0.3]]))
    assert wide.decided(7, d).tolist() == [True, False, False, False, False]  # +-30% at 1.5 mm: wider than the JND
    # a table that records no decision: decided where it gives no band
    older = dataclasses.replace(TRUTH, path_decided=None, band_rel=np.array([[0.0, 0.0, 0.2, 0.3]]))
    assert older.decided(5, d).tolist() == [True, False, False, False, False]


def test_the_decided_share_of_judged_time_by_hand_count():
    # 0.05, 0.15, ..., 2.95 mm: judged from 0.55 mm (ticks 5..29: 25 samples), decided up to
    # 1.95 mm (ticks 5..19: 15 of them); the right hand held nothing
    counts = judged_time(pull(0.0001 * (np.arange(30) + 0.5)), TRUTH, MESH, EVERY_TICK)
    assert counts[0].tolist() == [25, 15]
    assert counts[1].tolist() == [0, 0]
    # at 100 Hz (the observer's rate) every tenth tick: 10 and 20 judged, 10 decided
    assert judged_time(pull(0.0001 * (np.arange(30) + 0.5)), TRUTH, MESH)[0].tolist() == [2, 1]


def test_a_pull_wholly_on_undecided_truth_judges_nothing():
    stretch = 0.002 + 0.0001 * (np.arange(9) + 0.5)  # 2.05 .. 2.85 mm: past the last decided record
    exact = features([summarise(pull(stretch), TRUTH, MESH, EVERY_TICK)], MEDIAN, EVERY_TICK)
    stiff = features([summarise(pull(stretch, 2.0), TRUTH, MESH, EVERY_TICK)], MEDIAN, EVERY_TICK)
    assert math.isnan(stiff["within_jnd"])
    assert stiff["samples"] == 0
    assert stiff["undecided_samples"] == 9
    # the neutral accuracy term: no force difference changes the answer
    assert p_yes("texture", stiff, MEDIAN) == p_yes("texture", exact, MEDIAN)
    assert p_yes("texture", stiff, MEDIAN) == pytest.approx(1 / (1 + math.exp(-1.0)), abs=1e-12)


def test_a_pull_half_on_decided_truth_is_judged_on_that_half_alone():
    stretch = 0.001 + 0.0001 * (np.arange(20) + 0.5)  # 1.05 .. 1.95 mm decided, 2.05 .. 2.95 mm not
    ratio = np.where(np.arange(20) < 10, 1.0, 4.0)  # exact on the decided half, four times the truth beyond it
    f = features([summarise(pull(stretch, ratio), TRUTH, MESH, EVERY_TICK)], MEDIAN, EVERY_TICK)
    assert f["samples"] == 10
    assert f["undecided_samples"] == 10
    assert f["within_jnd"] == pytest.approx(P_WITHIN_PERFECT, abs=1e-9)  # as a perfect model on decided evidence
    assert f["force_log_ratio"] == pytest.approx(0.0, abs=1e-9)
    # the former rule judged the undecided half against its band too: four times the truth is far outside it (+-30% at most)
    before = features([summarise(pull(stretch, ratio), TRUTH, MESH, EVERY_TICK)], MEDIAN, dataclasses.replace(EVERY_TICK, judge_undecided=True))
    assert before["within_jnd"] < 0.4  # about half of 0.683
