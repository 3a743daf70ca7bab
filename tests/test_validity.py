"""Construct-validity statistics (issue 32, item 4) against independent computations: pingouin's
Kruskal-Wallis (its own H) and Mann-Whitney (its rank-biserial correlation), a direct pairwise
count for Cliff's delta, statsmodels for Holm, known parameters for the learning curves, the mixed
model and the classifier. Inputs: tidy tables in analysis.metrics' format, built here."""

import numpy as np
import pandas as pd
import pytest

from analysis import validity as v
from analysis.metrics import COLUMNS
from analysis.stats import holm

ORDER = ["student", "resident", "neurosurgeon"]


def make_metrics(means: dict, n_per_group=8, conditions=("linear",), trials=3, hands=("left", "right"),
                 sd=1.0, seed=0, curve=None, both=None) -> tuple[pd.DataFrame, pd.Series]:
    """Tidy metrics: `means` group -> metric -> mean (a participant's level: mean + N(0, sd)); every
    trial and hand scatters by sd / 4 around it. `curve(group, trial0)`: added per trial.
    `both`: metric -> group -> mean of a bimanual (hand "both") metric."""
    rng = np.random.default_rng(seed)
    rows, groups = [], {}
    for g, ms in means.items():
        for i in range(n_per_group):
            code = f"{g[:3].upper()}{i:02d}"
            groups[code] = g
            level = {m: mu + rng.normal(0, sd) for m, mu in ms.items()}
            for ci, c in enumerate(conditions):
                for t in range(trials):
                    extra = curve(g, t) if curve else 0.0
                    for h in hands:
                        for m in ms:
                            rows.append([code, True, c, t, h, m, level[m] + 0.5 * ci + extra + rng.normal(0, sd / 4), "1"])
                    for m, gm in (both or {}).items():
                        rows.append([code, True, c, t, "both", m, gm[g] + rng.normal(0, 0.05), "1"])
    return pd.DataFrame(rows, columns=COLUMNS), pd.Series(groups)


def test_participant_scores_average_trials_and_hands_and_keep_both_rows():
    m, _ = make_metrics({"student": {"path_length": 5.0}}, n_per_group=2, trials=3,
                        both={"force_ratio": {"student": 0.7}, "path_length": {"student": 99.0}})
    s = v.participant_scores(m)
    assert list(s.columns) == v.SCORE_COLUMNS
    one = m[(m["code"] == "STU00") & (m["hand"] != "both") & (m["metric"] == "path_length")]
    row = s[(s["code"] == "STU00") & (s["metric"] == "path_length")]
    assert row["value"].item() == pytest.approx(one["value"].mean()) and row["n_values"].item() == 6
    assert set(s["metric"]) == {"path_length", "path_length:both", "force_ratio"}
    assert s.loc[(s["code"] == "STU00") & (s["metric"] == "force_ratio"), "n_values"].item() == 3
    med = v.participant_scores(m, how="median")
    assert med.loc[(med["code"] == "STU00") & (med["metric"] == "path_length"), "value"].item() == pytest.approx(one["value"].median())


def _scores():
    m, groups = make_metrics({"student": {"path_length": 8.0, "sparc": -4.0}, "resident": {"path_length": 6.5, "sparc": -3.5},
                              "neurosurgeon": {"path_length": 5.0, "sparc": -3.0}}, n_per_group=9, conditions=("linear", "fem"),
                             seed=3)
    return v.participant_scores(m), groups


def test_group_tests_match_pingouin_and_direct_counts():
    pg = pytest.importorskip("pingouin")
    scores, groups = _scores()
    res = v.group_tests(scores, groups, ORDER, n_boot=500)
    assert list(res.kruskal.columns) == v.KRUSKAL_COLUMNS and list(res.pairs.columns) == v.PAIR_COLUMNS
    assert len(res.kruskal) == 4 and len(res.pairs) == 12 and len(res.descriptives) == 12
    d = scores.assign(group=scores["code"].map(groups))
    for _, k in res.kruskal.iterrows():
        sub = d[(d["metric"] == k["metric"]) & (d["condition"] == k["condition"])]
        ref = pg.kruskal(data=sub, dv="value", between="group")
        assert k["H"] == pytest.approx(ref["H"].item(), rel=1e-10) and k["p"] == pytest.approx(ref["p_unc"].item(), rel=1e-10)
        assert k["df"] == ref["ddof1"].item() == 2
    for _, r in res.pairs.iterrows():
        sub = d[(d["metric"] == r["metric"]) & (d["condition"] == r["condition"])]
        a, b = sub.loc[sub["group"] == r["a"], "value"].to_numpy(), sub.loc[sub["group"] == r["b"], "value"].to_numpy()
        ref = pg.mwu(a, b, alternative="two-sided")
        assert r["U"] == pytest.approx(ref["U_val"].item()) and r["p"] == pytest.approx(ref["p_val"].item(), rel=1e-10)
        assert r["cliffs_delta"] == pytest.approx(ref["RBC"].item(), abs=1e-12)
        count = sum(int(x > y) - int(x < y) for x in a.tolist() for y in b.tolist()) / (len(a) * len(b))  # Cliff's delta, by hand
        assert r["cliffs_delta"] == pytest.approx(count, abs=1e-12)
        assert r["delta_low"] <= r["cliffs_delta"] <= r["delta_high"]
        assert r["median_a"] == pytest.approx(np.median(a))
    # Holm over the whole family (all metrics, conditions and pairs), not per metric
    assert res.pairs["p_holm"].tolist() == pytest.approx(holm(res.pairs["p"]))
    assert res.kruskal["p_holm"].tolist() == pytest.approx(holm(res.kruskal["p"]))
    # the planted ordering: students' paths longer than the neurosurgeons'
    sn = res.pairs[(res.pairs["a"] == "student") & (res.pairs["b"] == "neurosurgeon") & (res.pairs["metric"] == "path_length")]
    assert (sn["cliffs_delta"] > 0.5).all() and (sn["p_holm"] < 0.05).all()


def test_cliffs_delta_with_ties_and_its_interval():
    a, b = [1, 2, 2, 3, 5], [2, 2, 4, 0]
    assert v.cliffs_delta(a, b) == pytest.approx(sum(np.sign(x - y) for x in a for y in b) / 20)
    lo, hi = v.cliffs_delta_interval(a, b, seed=1)
    assert -1 <= lo <= v.cliffs_delta(a, b) <= hi <= 1
    assert (lo, hi) == v.cliffs_delta_interval(a, b, seed=1)  # seeded
    assert v.cliffs_delta_interval([1, 2, 3], [7, 8, 9]) == (-1.0, -1.0)  # complete separation


def test_holm_matches_statsmodels():
    from statsmodels.stats.multitest import multipletests

    p = [0.01, 0.04, 0.03, 0.005, 0.2, 0.04]
    assert holm(p) == pytest.approx(multipletests(p, method="holm")[1].tolist())


def test_group_tests_constant_metric_gives_nan_not_error():
    m, groups = make_metrics({"student": {"x": 1.0}, "neurosurgeon": {"x": 1.0}}, n_per_group=4, sd=0.0)
    res = v.group_tests(v.participant_scores(m), groups, ["student", "neurosurgeon"], n_boot=50)
    assert np.isnan(res.kruskal["H"].item()) and res.pairs["cliffs_delta"].item() == 0.0


TRUTH = {"student": (10.0, 4.0, 0.5), "neurosurgeon": (6.0, 3.0, 1.2)}  # y0, plateau, rate


def _curve_metrics(noise, seed):
    def curve(g, t0):
        return float(v.exp_plateau(t0 + 1, *TRUTH[g]))
    return make_metrics({"student": {"time": 0.0}, "neurosurgeon": {"time": 0.0}}, n_per_group=12, trials=10,
                        sd=noise, curve=curve, seed=seed, hands=("right",))


def test_learning_curve_recovers_rate_and_plateau_without_noise():
    res = v.learning_curves(*_curve_metrics(0.0, 0), ["student", "neurosurgeon"], n_boot=50, seed=1)
    assert list(res.columns) == v.CURVE_COLUMNS and len(res) == 2
    for _, r in res.iterrows():
        assert (r["y0"], r["plateau"], r["rate"]) == pytest.approx(TRUTH[r["group"]], rel=1e-6)
        assert r["n_boot_ok"] == r["n_boot"] == 50 and r["n_participants"] == 12 and r["n_trials"] == 10


def test_learning_curve_intervals_cover_the_truth_with_noise():
    """Participants' levels scatter (sd 0.15) and so do their trials: over 4 studies x 2 groups the
    95% bootstrap intervals cover the true plateau and rate (at least 7 of 8 each)."""
    res = pd.concat([v.learning_curves(*_curve_metrics(0.15, seed), ["student", "neurosurgeon"], n_boot=200, seed=1)
                     for seed in range(4)])
    truth = pd.DataFrame([TRUTH[g] for g in res["group"]], columns=["y0", "plateau", "rate"], index=res.index)
    assert ((res["plateau_low"] <= truth["plateau"]) & (truth["plateau"] <= res["plateau_high"])).sum() >= 7
    assert ((res["rate_low"] <= truth["rate"]) & (truth["rate"] <= res["rate_high"])).sum() >= 7
    assert (res["n_boot_ok"] >= 190).all()
    assert np.allclose(res["rate"], truth["rate"], rtol=0.1) and np.allclose(res["plateau"], truth["plateau"], atol=0.2)


def test_learning_curve_fit_fails_cleanly():
    assert v.fit_learning_curve([1, 2], [3.0, 2.0]) is None  # too few trials
    assert v.fit_learning_curve([1, 2, 3, 4], [1.0, 2.0, 4.0, 8.0]) is None  # growing: no plateau


def test_mixed_model_recovers_the_group_effect():
    m, groups = make_metrics({"student": {"time": 10.0}, "neurosurgeon": {"time": 6.0}}, n_per_group=10,
                             conditions=("fem", "linear"), trials=4, sd=0.5, seed=2)
    res = v.mixed_model(m, groups, ["student", "neurosurgeon"])
    assert list(res.fixed.columns) == v.FIXED_COLUMNS and res.skipped.empty
    t = res.fixed.set_index("term")
    g = t.loc["group[neurosurgeon]"]
    assert g["coef"] == pytest.approx(-4.0, abs=2.5 * g["se"]) and g["p"] < 1e-6
    c = t.loc["condition[linear]"]  # planted: +0.5 in the second condition
    assert c["coef"] == pytest.approx(0.5, abs=3 * c["se"])
    assert {"Intercept", "trial"} <= set(t.index)
    one = v.mixed_model(m[m["condition"] == "fem"], groups)
    assert one.fixed.empty and "one condition" in one.skipped["reason"].item()


def test_proficiency_benchmark_and_scorecard():
    scores = pd.DataFrame({"code": ["E1", "E2", "E3", "E4", "E5", "S1", "S1", "S2", "S2", "E1", "E2", "E3", "E4", "E5"],
                           "condition": "c",
                           "metric": ["path_length"] * 5 + ["path_length", "sparc", "path_length", "sparc"] + ["sparc"] * 5,
                           "value": [1.0, 2.0, 3.0, 4.0, 5.0, 0.5, -9.0, 9.0, -1.0, -5.0, -4.0, -3.0, -2.0, -1.5],
                           "n_values": 1})
    groups = pd.Series({"E1": "neurosurgeon", "E2": "neurosurgeon", "E3": "neurosurgeon", "E4": "neurosurgeon",
                        "E5": "neurosurgeon", "S1": "student", "S2": "student"})
    res = v.proficiency(scores, groups, "neurosurgeon", {"path_length": "lower", "sparc": "higher"}, band=(25, 75))
    b = res.benchmark.set_index("metric")
    assert (b.loc["path_length", "median"], b.loc["path_length", "low"], b.loc["path_length", "high"]) == (3.0, 2.0, 4.0)
    card = res.scorecard.set_index(["code", "metric"])["position"].to_dict()
    assert card == {("S1", "path_length"): "better", ("S1", "sparc"): "worse",
                    ("S2", "path_length"): "worse", ("S2", "sparc"): "better"}
    assert res.summary.set_index("code")["fraction_proficient"].to_dict() == {"S1": 0.5, "S2": 0.5}
    undirected = v.proficiency(scores, groups, "neurosurgeon")
    assert set(undirected.scorecard["position"]) == {"above", "below"} and not undirected.scorecard["proficient"].any()


def test_classifier_separates_distinct_groups():
    m, groups = make_metrics({"student": {"a": 0.0, "b": 0.0, "c": 0.0}, "resident": {"a": 5.0, "b": -5.0, "c": 0.0},
                              "neurosurgeon": {"a": 10.0, "b": 0.0, "c": 5.0}}, n_per_group=6, trials=1, seed=4)
    res = v.classify(v.participant_scores(m), groups, ORDER, n_permutations=30, seed=0)
    # every permutation scores below the true labels: p at its floor 1 / (n_permutations + 1)
    assert res.accuracy >= 0.94 and res.balanced_accuracy >= 0.94 and res.p_value == pytest.approx(1 / 31)
    assert res.n == 18 and res.n_permutations == 30 and res.chance == pytest.approx(1 / 3)
    assert res.confusion.to_numpy().trace() == round(res.accuracy * 18)
    assert list(res.confusion.index) == ORDER and list(res.table().columns)[:3] == ["n", "n_features", "accuracy"]


def test_classifier_at_chance_when_groups_are_identical():
    same = {"a": 0.0, "b": 0.0, "c": 0.0}
    m, groups = make_metrics({"student": same, "neurosurgeon": same}, n_per_group=8, trials=1, seed=7)
    res = v.classify(v.participant_scores(m), groups, ["student", "neurosurgeon"], n_permutations=60, seed=0)
    assert res.accuracy <= 0.65 and res.p_value > 0.05
