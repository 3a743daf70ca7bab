"""The truth at the bench's speeds (analysis/verification/truth_in_time.py) on the shipped pulls in
time of the quick bench's 20 mm mesh: assembled from the solves as the docs say, decided only
within the data's rates, and the hands' rates far beyond them."""

import math

import numpy as np
import pytest

from analysis.verification import truth_band
from analysis.verification.accuracy import quick_config, sample_displacements
from analysis.verification.pulls_in_time import data_rates, reached, record_times, shipped_rheology
from analysis.verification.tissue_pulls import RECORD_XS
from analysis.verification.truth_in_time import (
    MESH_TRANSFER_REL,
    QUASI_STATIC,
    TIME_STEP_REL,
    bench_speeds,
    truth_in_time,
)
from sim.errors import ParameterError
from sim.perception import force_jnd
from sim.pulls import make_pulls, scene_with
from sim.pulls import test_pulls as held_out_pulls


def test_a_speed_not_known_is_refused_with_the_allowed_ones():
    with pytest.raises(ParameterError, match="'slow'; allowed: quasi-static, typical, fast"):
        bench_speeds(["slow"])
    qs, typical = bench_speeds([QUASI_STATIC, "typical"])
    assert qs.speed_m_s is None and qs.holds_s == ()
    assert typical.speed_m_s == pytest.approx(0.0141561, rel=1e-5) and typical.holds_s == (0.25, 0.5, 1.0, 2.0)


@pytest.fixture(scope="module")
def quick_in_time():
    cfg = quick_config()
    scene = scene_with(cfg.scene)
    pulls = make_pulls(scene) + held_out_pulls(scene, cfg.test_places)
    xs = sample_displacements(cfg)
    static = truth_band.truth_samples(cfg.scene, pulls, xs, cfg.reference_sizes_mm, jobs=1)
    out = {}
    for sp in bench_speeds(("typical", "fast")):
        out[sp.name] = truth_in_time(cfg.scene, scene, static, pulls, xs, sp, max(cfg.reference_sizes_mm))
    return static, pulls, xs, out


def test_the_truth_in_time_is_the_solve_with_the_timeless_mesh_correction(quick_in_time):
    """Each force is the shipped solve's times the grey matter's equilibrium modulus times the
    timeless truth's extrapolated force over its coarsest mesh's; a hold carries its ramp's end;
    the band adds the time step's share and the borrowed correction's."""
    from analysis.verification.pulls_in_time import HOLDS_S, MAX_DT_S, pull_in_time_key_of, stored_pull_in_time

    static, pulls, xs, out = quick_in_time
    mu = shipped_rheology()[0].equilibrium.shear_modulus
    law_mu = scene_with(quick_config().scene).spec.material.law.shear_modulus
    for name, (cells, meta) in out.items():
        assert meta["pulls_solved"] == len(pulls)  # shipped for every quick pull
        sp = bench_speeds([name])[0]
        for p in pulls:
            solve = stored_pull_in_time(pull_in_time_key_of((str(quick_config().scene), p, 20.0, sp.speed_m_s, RECORD_XS, HOLDS_S, MAX_DT_S)))
            rows = cells[p.name]
            assert len(rows) == len(xs) + len(HOLDS_S)
            coarse = np.asarray(static["refs"]["pulls"][p.name]["force_per_pa"])[0]
            for k, c in enumerate(rows):
                ramp = min(k, len(xs) - 1)
                s = static["pulls"][p.name][ramp]
                if not math.isfinite(s["force_n"]):
                    assert not math.isfinite(c["force_n"])
                    continue
                rec = int(np.argmin(np.abs(RECORD_XS - xs[ramp]))) if k < len(xs) else len(RECORD_XS) + k - len(xs)
                want = np.asarray(solve["force_per_pa"][rec]) * mu * s["force_n"] / (np.linalg.norm(coarse[ramp]) * law_mu)
                assert np.allclose(c["force"], want, rtol=1e-12)
                assert c["time_s"] == pytest.approx(xs[ramp] / sp.speed_m_s + (sp.holds_s[k - len(xs)] if k >= len(xs) else 0.0), rel=1e-9)
                assert c["band_rel"] == pytest.approx(math.sqrt(s["band_rel"] ** 2 + TIME_STEP_REL**2 + MESH_TRANSFER_REL**2), nan_ok=True)


def test_nothing_is_decided_at_the_hands_speeds_for_the_rate_and_the_record_says_so(quick_in_time):
    """The measured finding the bench rests on: at 14 and 18 mm/s nearly all of every sample's
    force power comes from points straining faster than the data's fastest rate, and the median
    rate is tens of times the data's; so no sample is decided, each for its rate."""
    _, _, _, out = quick_in_time
    fastest = max(data_rates())
    for cells, meta in out.values():
        flat = [c for rows in cells.values() for c in rows if math.isfinite(c["force_n"])]
        assert flat and not any(c["decided"] for c in flat)
        for c in flat:
            assert c["rate_share_outside"] > 0.99
            limit = float(force_jnd(np.array(c["force_n"])))
            assert c["left_by"] == "rates beyond the data's" and f"at most {limit:.0%} here" in c["reason"]
        ramp = [c["strain_rate_per_s"] for c in flat if c["hold_s"] == 0.0]
        assert min(ramp) > 30 * fastest
        assert meta["decided"] == 0 and meta["left_by"]["rates beyond the data's"] == len(flat)
        # at a person's pace the tissue pushes back harder than the timeless truth says, and relaxes in a hold
        assert meta["over_timeless"][0] > 1.2
        for rows in cells.values():
            held = [c["force_n"] for c in rows if c["hold_s"] > 0]
            assert np.all(np.diff(held) < 0) and held[0] < rows[len(rows) - 5]["force_n"]


def test_a_bench_that_stops_short_of_12_mm_has_no_truth_for_its_holds(quick_in_time):
    """The solves hold at 12 mm: a bench whose last sample is 2 mm gets its ramp samples and no
    hold truth (not the 12 mm hold's forces), said so."""
    static, pulls, _, _ = quick_in_time
    cfg = quick_config()
    scene = scene_with(cfg.scene)
    short = np.array([0.002])
    small = truth_band.truth_samples(cfg.scene, pulls[:1], short, cfg.reference_sizes_mm, jobs=1)
    sp = bench_speeds(["typical"])[0]
    cells, meta = truth_in_time(cfg.scene, scene, small, pulls[:1], short, sp, 20.0)
    ramp, holds = cells[pulls[0].name][0], cells[pulls[0].name][1:]
    assert math.isfinite(ramp["force_n"]) and ramp["time_s"] == pytest.approx(0.002 / sp.speed_m_s)
    assert len(holds) == 4 and all(not math.isfinite(c["force_n"]) and "hold at 12 mm" in c["reason"] for c in holds)
    assert meta["left_by"]["no solve"] == 4


@pytest.mark.parametrize("stop, where", [(10, "stopped at 5 mm, 0.353 s from rest (diverging)"),
                                         (len(RECORD_XS) + 2, "stopped at 12 mm, 1.35 s from rest (diverging)")])
def test_a_pull_in_time_that_stopped_has_no_truth_beyond_where_it_got(quick_in_time, monkeypatch, stop, where):
    """A solve that stopped (as some anterior pulls do on the 8 mm mesh), on the ramp or in a hold,
    is shipped with the records it reached: the samples up to there are as before, those beyond
    have no truth, each saying where and when it stopped, and the record names the pull. Whether
    it stopped is read from its records, not its account."""
    import analysis.verification.truth_in_time as tit

    static, pulls, xs, out = quick_in_time
    cfg = quick_config()
    real = tit.stored_pull_in_time

    def stopped(key):
        s = dict(real(key))
        for part in ("force_per_pa", "rate_share_outside", "strain_rate_per_s"):
            s[part] = np.array(s[part], dtype=np.float64)
            s[part][stop:] = np.nan
        s["meta"] = {k: v for k, v in s["meta"].items() if k != "converged"} | {"reason": "diverging"}
        return s

    monkeypatch.setattr(tit, "stored_pull_in_time", stopped)
    p = pulls[0]
    sp = bench_speeds(["typical"])[0]
    cells, meta = truth_in_time(cfg.scene, scene_with(cfg.scene), static, [p], xs, sp, 20.0)
    last = stop - 1
    assert meta["pulls_stopped"] == {p.name: {"mm": pytest.approx(RECORD_XS[min(last, len(RECORD_XS) - 1)] * 1e3),
                                              "s": pytest.approx(record_times(RECORD_XS, sp.speed_m_s)[0][last]),
                                              "reason": "diverging"}}
    gone = 0
    for k, (c, before) in enumerate(zip(cells[p.name], out["typical"][0][p.name], strict=True)):
        rec = int(np.argmin(np.abs(RECORD_XS - xs[k]))) if k < len(xs) else len(RECORD_XS) + k - len(xs)
        if rec < stop:
            assert c["left_by"] != "no solve"
            assert c["force_n"] == before["force_n"] or not math.isfinite(before["force_n"])
        else:
            gone += 1
            assert not math.isfinite(c["force_n"]) and c["left_by"] == "no solve" and where in c["reason"]
    assert gone and meta["left_by"]["no solve"] == gone


def test_reached_reads_the_last_record_with_a_force():
    times, x = record_times(RECORD_XS, 0.01)
    f = np.ones((len(times), 3))
    assert reached({"force_per_pa": f, "x_m": x, "times_s": times}) == (12.0, pytest.approx(times[-1]))
    f[len(RECORD_XS) + 1:] = np.nan  # stopped in the second hold: 12 mm, but 0.25 s into the hold
    assert reached({"force_per_pa": f, "x_m": x, "times_s": times}) == (12.0, pytest.approx(1.2 + 0.25))
    f[3:] = np.nan
    assert reached({"force_per_pa": f, "x_m": x, "times_s": times}) == (pytest.approx(1.5), pytest.approx(0.15))
    f[:] = np.nan
    assert reached({"force_per_pa": f, "x_m": x, "times_s": times}) == (0.0, 0.0)
