"""Construct-validity statistics (issue 32, item 4) against independent computations: pingouin's
Kruskal-Wallis (its own H) and Mann-Whitney (its rank-biserial correlation), a direct pairwise
count for Cliff's delta, statsmodels for Holm, known parameters for the learning curves, the mixed
model and the classifier. Inputs: tidy tables in analysis.validity.metrics' format, built here."""

import itertools
import math

import numpy as np
import pandas as pd
import pytest

from analysis.statistics.stats import holm
from analysis.validity import groups as v
from analysis.validity.metrics import COLUMNS

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
    assert row["value"].item() == pytest.approx(one["value"].mean())
    assert row["n_values"].item() == 6
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
    assert list(res.kruskal.columns) == v.KRUSKAL_COLUMNS
    assert list(res.pairs.columns) == v.PAIR_COLUMNS
    assert len(res.kruskal) == 4
    assert len(res.pairs) == 12
    assert len(res.descriptives) == 12
    d = scores.assign(group=scores["code"].map(groups))
    for _, k in res.kruskal.iterrows():
        sub = d[(d["metric"] == k["metric"]) & (d["condition"] == k["condition"])]
        ref = pg.kruskal(data=sub, dv="value", between="group")
        assert k["H"] == pytest.approx(ref["H"].item(), rel=1e-10)
        assert k["p"] == pytest.approx(ref["p_unc"].item(), rel=1e-10)
        assert k["df"] == ref["ddof1"].item() == 2
    for _, r in res.pairs.iterrows():
        sub = d[(d["metric"] == r["metric"]) & (d["condition"] == r["condition"])]
        a, b = sub.loc[sub["group"] == r["a"], "value"].to_numpy(), sub.loc[sub["group"] == r["b"], "value"].to_numpy()
        ref = pg.mwu(a, b, alternative="two-sided")
        assert r["U"] == pytest.approx(ref["U_val"].item())
        assert r["p"] == pytest.approx(ref["p_val"].item(), rel=1e-10)
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
    assert (sn["cliffs_delta"] > 0.5).all()
    assert (sn["p_holm"] < 0.05).all()


def _wy_reference(scores, groups, order, n_perm, seed):
    """Westfall-Young step-down min-p written plainly: every permutation of the participants'
    labels (group_tests' stream, v.permutation_indices), scipy's kruskal / mannwhitneyu
    (method="asymptotic") per test, then the step-down by loops. Returns (kw p_wy, pair p_wy,
    kw raw permutation p, pair raw permutation p) in group_tests' row order."""
    from scipy import stats

    d = scores.assign(group=scores["code"].map(groups))
    d = d[d["group"].isin(order)]
    codes = sorted(d["code"].unique())
    perms = v.permutation_indices(len(codes), n_perm, seed)
    maps = [dict(zip(codes, [groups[c] for c in codes]))]
    maps += [{c: groups[codes[j]] for c, j in zip(codes, row)} for row in perms]

    def kw_p(sub, labels):
        xs = [sub.loc[labels == g, "value"].to_numpy() for g in order]
        xs = [x for x in xs if len(x)]
        if len(xs) < 2 or np.ptp(sub["value"]) == 0:
            return np.nan
        return stats.kruskal(*xs).pvalue

    def mwu_p(sub, labels, a, b):
        x, y = sub.loc[labels == a, "value"].to_numpy(), sub.loc[labels == b, "value"].to_numpy()
        if not len(x) or not len(y):
            return np.nan
        return stats.mannwhitneyu(x, y, alternative="two-sided", method="asymptotic").pvalue

    kw, pairs = [], []  # per permutation (row 0: observed), the p of every test
    for mp in maps:
        kw_row, pair_row = [], []
        for _, sub in d.groupby(["metric", "condition"], sort=True):
            labels = sub["code"].map(mp)
            kw_row.append(kw_p(sub, labels))
            for a, b in itertools.combinations(order, 2):
                pair_row.append(mwu_p(sub, labels, a, b))
        kw.append(kw_row)
        pairs.append(pair_row)

    def step_down(rows):
        obs, perm = rows[0], rows[1:]
        fam = sorted((i for i in range(len(obs)) if not np.isnan(obs[i])), key=lambda i: obs[i])
        out, single, running = [np.nan] * len(obs), [np.nan] * len(obs), 0.0
        for j, i in enumerate(fam):
            hits = 0
            for row in perm:
                q = min(1.0 if np.isnan(row[k]) else row[k] for k in fam[j:])
                hits += q <= obs[i] * (1 + v.WY_TOLERANCE)
            running = max(running, (1 + hits) / (len(perm) + 1))
            out[i] = running
            single[i] = (1 + sum(1.0 if np.isnan(row[i]) else row[i] <= obs[i] * (1 + v.WY_TOLERANCE) for row in perm)) / (len(perm) + 1)
        return np.array(out), np.array(single)

    (kw_wy, kw_single), (pair_wy, pair_single) = step_down(kw), step_down(pairs)
    return kw_wy, pair_wy, kw_single, pair_single


def _wy_example():
    """Three groups of 6, two conditions, ties (values rounded), one participant without one
    metric, and a metric the neurosurgeons lack (its observed tests have 2 groups, permutations
    3)."""
    m, groups = make_metrics({"student": {"path_length": 7.0, "sparc": -4.0, "force": 1.0},
                              "resident": {"path_length": 6.5, "sparc": -3.5, "force": 1.0},
                              "neurosurgeon": {"path_length": 5.5, "sparc": -3.0, "force": 1.0}},
                             n_per_group=6, conditions=("linear", "fem"), seed=5)
    s = v.participant_scores(m).assign(value=lambda d: d["value"].round(1))
    s = s[~((s["code"] == "STU01") & (s["metric"] == "sparc"))]
    s = s[~(s["code"].str.startswith("NEU") & (s["metric"] == "force"))]
    return s, groups


def test_westfall_young_matches_a_brute_force_reference():
    scores, groups = _wy_example()
    res = v.group_tests(scores, groups, ORDER, n_boot=20, seed=7, n_perm=150)
    kw_wy, pair_wy, kw_single, pair_single = _wy_reference(scores, groups, ORDER, 150, 7)
    assert list(res.kruskal.columns) == [*v.KRUSKAL_COLUMNS[:v.KRUSKAL_COLUMNS.index("p_holm") + 1], "p_wy",
                                         *v.KRUSKAL_COLUMNS[v.KRUSKAL_COLUMNS.index("p_holm") + 1:]]
    assert list(res.pairs.columns) == [*v.PAIR_COLUMNS[:v.PAIR_COLUMNS.index("p_holm") + 1], "p_wy",
                                       *v.PAIR_COLUMNS[v.PAIR_COLUMNS.index("p_holm") + 1:]]
    np.testing.assert_allclose(res.kruskal["p_wy"], kw_wy, rtol=0, atol=1e-12)
    np.testing.assert_allclose(res.pairs["p_wy"], pair_wy, rtol=0, atol=1e-12)
    # the neurosurgeons' missing metric: its pairs with them are not tested, nor in the family
    force = res.pairs[res.pairs["metric"] == "force"]
    assert force.loc[force["b"] == "neurosurgeon", "p_wy"].isna().all()
    assert force.loc[force["b"] != "neurosurgeon", "p_wy"].notna().all()
    assert (res.kruskal.loc[res.kruskal["metric"] == "force", "k"] == 2).all()
    # min-p with the observed labelling counted: never below a test's own permutation p, nor 1 / (B + 1)
    for got, single in ((res.kruskal["p_wy"], kw_single), (res.pairs["p_wy"], pair_single)):
        ok = got.notna().to_numpy()
        assert (got[ok] >= single[ok] - 1e-12).all()
        assert (got[ok] >= 1 / 151).all()
        assert (got[ok] <= 1).all()
    # step-down monotone: a smaller raw p never gets a larger adjusted p
    k = res.kruskal.sort_values("p")
    assert k["p_wy"].is_monotonic_increasing
    # n_perm = 0: today's tables, no p_wy
    plain = v.group_tests(scores, groups, ORDER, n_boot=20, seed=7)
    assert list(plain.kruskal.columns) == v.KRUSKAL_COLUMNS
    assert list(plain.pairs.columns) == v.PAIR_COLUMNS
    pd.testing.assert_frame_equal(plain.pairs, res.pairs.drop(columns="p_wy"))
    pd.testing.assert_frame_equal(plain.kruskal, res.kruskal.drop(columns="p_wy"))


def test_westfall_young_vectorised_p_equals_scipy_on_the_observed_data():
    from scipy import stats

    scores, groups = _wy_example()
    d = scores.assign(group=scores["code"].map(groups))
    for _, sub in d.groupby(["metric", "condition"]):
        x = sub["value"].to_numpy(float)
        lab = sub["group"].map({g: i for i, g in enumerate(ORDER)}).to_numpy()[None, :]
        xs = [x[lab[0] == i] for i in range(3) if (lab[0] == i).any()]
        assert v._kruskal_p(x, lab, 3)[0] == pytest.approx(stats.kruskal(*xs).pvalue, rel=1e-12)
        for a, b in itertools.combinations(range(3), 2):
            if (lab[0] == a).any() and (lab[0] == b).any():
                ref = stats.mannwhitneyu(x[lab[0] == a], x[lab[0] == b], method="asymptotic").pvalue
                assert v._mannwhitney_p(x, lab, a, b)[0] == pytest.approx(ref, rel=1e-12)


def test_westfall_young_is_not_fooled_by_duplicated_metrics():
    # one metric five times over: Holm multiplies its p by 5, Westfall-Young (which permutes the
    # labels alike for all five) gives each the single test's permutation p
    m, groups = make_metrics({"student": {"x": 0.9}, "resident": {"x": 0.0}, "neurosurgeon": {"x": 0.0}}, n_per_group=10, seed=17)
    one = v.participant_scores(m)
    five = pd.concat([one.assign(metric=f"x{i}") for i in range(5)], ignore_index=True)
    r1 = v.group_tests(one, groups, ORDER, n_boot=20, n_perm=400)
    r5 = v.group_tests(five, groups, ORDER, n_boot=20, n_perm=400)
    p_single = r1.kruskal["p_wy"].item()
    assert 0.01 < r1.kruskal["p"].item() < 0.05
    assert p_single < 0.05
    assert r5.kruskal["p_wy"].tolist() == pytest.approx([p_single] * 5, abs=1e-15)
    assert r5.kruskal["p_holm"].tolist() == pytest.approx([5 * r1.kruskal["p"].item()] * 5)
    assert (r5.kruskal["p_holm"] > 0.05).all()  # Holm loses it, Westfall-Young does not
    for pair, g in r1.pairs.groupby(["a", "b"]):
        dup = r5.pairs[(r5.pairs["a"] == pair[0]) & (r5.pairs["b"] == pair[1])]
        # a family of 3 pairs x 5 copies: each pair's p_wy as in the family of its 3 pairs alone
        assert dup["p_wy"].tolist() == pytest.approx([g["p_wy"].item()] * 5, abs=1e-15)


def test_westfall_young_floor_under_a_clear_group_effect():
    m, groups = make_metrics({"student": {"path_length": 20.0, "sparc": 0.0}, "resident": {"path_length": 10.0, "sparc": 0.0},
                              "neurosurgeon": {"path_length": 0.0, "sparc": 0.0}}, n_per_group=8, seed=2)
    res = v.group_tests(v.participant_scores(m), groups, ORDER, n_boot=20, n_perm=200, seed=3)
    assert res.kruskal["p_wy"].min() == pytest.approx(1 / 201)
    assert res.pairs["p_wy"].min() == pytest.approx(1 / 201)
    assert res.kruskal.set_index("metric").loc["path_length", "p_wy"] == pytest.approx(1 / 201)
    assert np.isnan(v.westfall_young([np.nan, 0.2], np.full((5, 2), 0.5))[0])  # untested: not in the family
    assert v.westfall_young([np.nan, 0.2], np.full((5, 2), 0.5))[1] == pytest.approx(1 / 6)


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
    assert np.isnan(res.kruskal["H"].item())  # not tested: no variation
    assert np.isnan(res.pairs["cliffs_delta"].item())
    assert res.pairs["reason"].item() == "every value is 1: no variation to rank"


TRUTH = {"student": (10.0, 4.0, 0.5), "neurosurgeon": (6.0, 3.0, 1.2)}  # y0, plateau, rate


def _curve_metrics(noise, seed):
    def curve(g, t0):
        return float(v.exp_plateau(t0 + 1, *TRUTH[g]))
    return make_metrics({"student": {"time": 0.0}, "neurosurgeon": {"time": 0.0}}, n_per_group=12, trials=10,
                        sd=noise, curve=curve, seed=seed, hands=("right",))


def test_learning_curve_recovers_rate_and_plateau_without_noise():
    res = v.learning_curves(*_curve_metrics(0.0, 0), ["student", "neurosurgeon"], n_boot=50, seed=1)
    assert list(res.columns) == v.CURVE_COLUMNS
    assert len(res) == 2
    for _, r in res.iterrows():
        assert (r["y0"], r["plateau"], r["rate"]) == pytest.approx(TRUTH[r["group"]], rel=1e-6)
        assert r["n_boot_ok"] == r["n_boot"] == 50
        assert r["n_participants"] == 12
        assert r["n_trials"] == 10


def test_learning_curve_intervals_cover_the_truth_with_noise():
    """Participants' levels scatter (sd 0.15) and so do their trials: over 4 studies x 2 groups the
    95% bootstrap intervals cover the true plateau and rate (at least 7 of 8 each)."""
    res = pd.concat([v.learning_curves(*_curve_metrics(0.15, seed), ["student", "neurosurgeon"], n_boot=200, seed=1)
                     for seed in range(4)])
    truth = pd.DataFrame([TRUTH[g] for g in res["group"]], columns=["y0", "plateau", "rate"], index=res.index)
    assert ((res["plateau_low"] <= truth["plateau"]) & (truth["plateau"] <= res["plateau_high"])).sum() >= 7
    assert ((res["rate_low"] <= truth["rate"]) & (truth["rate"] <= res["rate_high"])).sum() >= 7
    assert (res["n_boot_ok"] >= 190).all()
    assert np.allclose(res["rate"], truth["rate"], rtol=0.1)
    assert np.allclose(res["plateau"], truth["plateau"], atol=0.2)


def test_learning_curve_fit_fails_cleanly():
    assert v.fit_learning_curve([1, 2], [3.0, 2.0]) is None  # too few trials
    assert v.fit_learning_curve([1, 2, 3, 4], [1.0, 2.0, 4.0, 8.0]) is None  # growing: no plateau


def test_mixed_model_recovers_the_group_effect():
    m, groups = make_metrics({"student": {"time": 10.0}, "neurosurgeon": {"time": 6.0}}, n_per_group=10,
                             conditions=("fem", "linear"), trials=4, sd=0.5, seed=2)
    res = v.mixed_model(m, groups, ["student", "neurosurgeon"])
    assert list(res.fixed.columns) == v.FIXED_COLUMNS
    assert res.skipped.empty
    t = res.fixed.set_index("term")
    g = t.loc["group[neurosurgeon]"]
    assert g["coef"] == pytest.approx(-4.0, abs=2.5 * g["se"])
    assert g["p"] < 1e-6
    c = t.loc["condition[linear]"]  # planted: +0.5 in the second condition
    assert c["coef"] == pytest.approx(0.5, abs=3 * c["se"])
    assert {"Intercept", "trial"} <= set(t.index)
    one = v.mixed_model(m[m["condition"] == "fem"], groups)
    assert one.fixed.empty
    assert "one condition" in one.skipped["reason"].item()


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
    assert set(undirected.scorecard["position"]) == {"above", "below"}
    assert not undirected.scorecard["proficient"].any()


def test_classifier_separates_distinct_groups():
    m, groups = make_metrics({"student": {"a": 0.0, "b": 0.0, "c": 0.0}, "resident": {"a": 5.0, "b": -5.0, "c": 0.0},
                              "neurosurgeon": {"a": 10.0, "b": 0.0, "c": 5.0}}, n_per_group=6, trials=1, seed=4)
    res = v.classify(v.participant_scores(m), groups, ORDER, n_permutations=30, seed=0)
    # every permutation scores below the true labels: p at its floor 1 / (n_permutations + 1)
    assert res.accuracy >= 0.94
    assert res.balanced_accuracy >= 0.94
    assert res.p_value == pytest.approx(1 / 31)
    assert res.n == 18
    assert res.n_permutations == 30
    assert res.chance == pytest.approx(1 / 3)
    assert res.confusion.to_numpy().trace() == round(res.accuracy * 18)
    assert list(res.confusion.index) == ORDER
    assert list(res.table().columns)[:3] == ["n", "n_features", "accuracy"]


def test_classifier_at_chance_when_groups_are_identical():
    same = {"a": 0.0, "b": 0.0, "c": 0.0}
    m, groups = make_metrics({"student": same, "neurosurgeon": same}, n_per_group=8, trials=1, seed=7)
    res = v.classify(v.participant_scores(m), groups, ["student", "neurosurgeon"], n_permutations=60, seed=0)
    assert res.accuracy <= 0.65
    assert res.p_value > 0.05


def test_an_invariant_metric_is_not_tested_and_says_why():
    """A metric every participant scores alike (e.g. a count that is 0 throughout): no
    Kruskal-Wallis, no Mann-Whitney, no Cliff's delta: null with the reason, not p = 1 and a
    collapsed [0, 0]; each test names itself; Holm counts only the tests run."""
    scores, groups = _scores()
    flat = scores[scores["metric"] == "path_length"].assign(metric="grasp_losses", value=0.0)
    res = v.group_tests(pd.concat([scores, flat], ignore_index=True), groups, ORDER, n_boot=50)
    kw = res.kruskal.set_index(["metric", "condition"])
    row = kw.loc[("grasp_losses", "fem")]
    assert math.isnan(row["p"])
    assert math.isnan(row["p_holm"])
    assert row["reason"] == "every value is 0: no variation to rank"
    assert set(res.kruskal["test"]) == {v.KRUSKAL}
    assert set(res.pairs["test"]) == {v.MANN_WHITNEY}
    pairs = res.pairs[res.pairs["metric"] == "grasp_losses"]
    assert pairs["p"].isna().all()
    assert pairs["cliffs_delta"].isna().all()
    assert pairs["reason"].notna().all()
    tested = res.kruskal[res.kruskal["reason"].isna()]
    from analysis.statistics.stats import holm

    assert np.allclose(tested["p_holm"], holm(tested["p"]))  # the family: the tests run
