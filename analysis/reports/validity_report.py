"""The construct-validity report (`studyctl report validity`): a study's
performance metrics (analysis/validity/metrics.py) compared between its participant groups with
analysis/validity/groups.py, beside its face-validity ratings per group.

`validity_report(study, ...)` reads one study snapshot (analysis/study/study_snapshot.py) and returns a dict of tidy
DataFrames and numbers; `markdown`, `html` and `to_json` render it. The groups are each
participant's value of the protocol's `design.groups` field, in the field's order; the most
expert group is its last value. Participant fields of kind `text` are never read; integer and
number fields are described per group, nothing else of a participant is. A condition whose
trials are mostly model faults (analysis/statistics/faults.py) is shown in the faults table and described,
but no test reads its metrics (`faults` in the dict only where a trial had a fault or safety event).
"""

from __future__ import annotations

import html as _html
import json
from collections.abc import Callable
from dataclasses import replace

import numpy as np
import pandas as pd
from scipy import stats

from analysis.errors import StudyError
from analysis.reports.fault_tables import events_table
from analysis.reports.formatting import PAGE_END, figure_png, p_value, page_head
from analysis.reports.plots import OTHER_COLORS, _plt
from analysis.reports.table import Table, html_grid, latex_tables, markdown_grid
from analysis.statistics.faults import any_events, condition_events, involving, withheld
from analysis.statistics.stats import holm
from analysis.study import instruments
from analysis.study.fields import FieldKind
from analysis.study.questions import Kind
from analysis.study.study_snapshot import Study, data_flag
from analysis.validity import groups as v
from analysis.validity.metrics import UNITS, metrics_table, study_goals
from sim.jsonable import jsonable

DEFAULT_PERMUTATIONS = 100
DEFAULT_GROUP_PERMUTATIONS = 1000  # the group tests' Westfall-Young adjustment (its cost: docs/analysis.md)
DEFAULT_BOOTSTRAP = 200

SESSION = ""  # the condition of an answer given once at the end of the session
BAND = (5.0, 95.0)  # the expert benchmark's band (percentiles of the expert group)

# where better performance lies, for the scorecards' "better"/"worse" (None: no direction; a
# scorecard then says "above"/"below" the expert band)
BETTER = {
    "target_reached": "higher", "time_to_target": "lower", "final_error": "lower", "overshoot": "lower",
    "peak_force": "lower", "time_above_limit": "lower", "impulse_above_limit": "lower",
    "duration": "lower", "path_length": "lower", "path_ratio": "lower", "sparc": "higher",
}

RATING_COLUMNS = ["item", "question", "condition", "group", "n", "median", "q1", "q3", "iqr", "mean"]
RATING_TEST_COLUMNS = ["item", "question", "condition", "k", "n", "H", "df", "p", "p_holm"]
FIELD_COLUMNS = ["field", "group", "n", "median", "q1", "q3"]
GROUP_COLUMNS = ["group", "n_registered", "n_with_metrics"]
STEPS = 7


class NoGroupsError(StudyError):
    """The study has no participant groups (no design.groups): there is nothing to compare."""


def _metric_base(name: str) -> str:
    return name.split(":", 1)[0]


def _unit(name: str) -> str:
    return UNITS.get(_metric_base(name), "")


def _kruskal(vals: list[np.ndarray]) -> tuple[float, float]:
    """H and p of Kruskal-Wallis across the non-empty groups (NaN when fewer than two, or every value alike)."""
    present = [x for x in vals if len(x)]
    if len(present) < 2 or np.ptp(np.concatenate(present)) == 0:
        return float("nan"), float("nan")
    res = stats.kruskal(*present)
    return float(res.statistic), float(res.pvalue)


def _describe(x: np.ndarray) -> dict:
    if not len(x):
        return {"n": 0, "median": np.nan, "q1": np.nan, "q3": np.nan, "iqr": np.nan, "mean": np.nan}
    q1, med, q3 = np.percentile(x, [25, 50, 75])
    return {"n": int(len(x)), "median": float(med), "q1": float(q1), "q3": float(q3), "iqr": float(q3 - q1), "mean": float(np.mean(x))}


# ---------------------------------------------------------------- reading

def study_groups(study: Study) -> tuple[pd.Series, list[str], pd.DataFrame]:
    """Each participant's group (code -> value of the design.groups field), the groups in the
    field's order, and the integer and number fields as a tidy table (code, field, value). Text
    fields are dropped here, before anything else sees them."""
    protocol = study.protocol
    if not protocol.groups or protocol.group_field is None:
        raise NoGroupsError(f"{study.path}: the study has no participant groups (its protocol sets no design.groups naming a "
                            "[fields.NAME] choice); a construct-validity report compares groups")
    field = protocol.group_field
    numeric = {f.name for f in protocol.fields if f.kind in (FieldKind.INTEGER, FieldKind.NUMBER) and f.name != field.name}
    groups, rows = {}, []
    for code, stored in study.fields.groupby("code", sort=False):
        values = dict(zip(stored["field"], stored["value"]))
        if values.get(field.name) is not None:
            groups[code] = str(values[field.name])
        rows += [{"code": code, "field": k, "value": float(x)} for k, x in values.items() if k in numeric and x is not None]
    return pd.Series(groups, dtype=object), list(field.values), pd.DataFrame(rows, columns=["code", "field", "value"])


# ---------------------------------------------------------------- face validity

def rating_scores(protocol, answers: pd.DataFrame) -> tuple[pd.DataFrame, dict[str, str]]:
    """One value per participant, rating and condition (code, item, condition, value): every
    Likert and VAS question that is not an instrument's item (its mean over the trials when asked
    after each trial), and each instrument's score (SUS, raw NASA-TLX; per condition, or once
    for the session: condition ""). Free-text answers are never read. Returns the table and each
    item's text."""
    rows, text = [], {}
    for q in protocol.questions:
        if q.instrument is not None or q.kind not in (Kind.LIKERT, Kind.VAS):
            continue
        text[q.id] = q.text
        sel = answers[answers["item"] == q.id].assign(value=lambda d: pd.to_numeric(d["answer"], errors="coerce")).dropna(subset=["value"])
        for (code, model), g in sel.groupby(["code", "model"], sort=True):
            rows.append({"code": code, "item": q.id, "condition": model, "value": float(g["value"].mean())})
    for name, _when in protocol.instruments:
        items = [q.id for q in instruments.questions(name)]
        text[name] = instruments.SCORES.get(name, name)
        sel = answers[answers["item"].isin(items)].assign(value=lambda d: pd.to_numeric(d["answer"], errors="coerce")).dropna(subset=["value"])
        scored = []
        for (code, model, _trial), g in sel.groupby(["code", "model", "trial"], sort=True):
            by_item = dict(zip(g["item"], g["value"].astype(float)))
            if len(by_item) == len(items):
                scored.append({"code": code, "condition": model, "score": instruments.score(name, by_item)})
        for (code, model), g in pd.DataFrame(scored, columns=["code", "condition", "score"]).groupby(["code", "condition"], sort=True):
            rows.append({"code": code, "item": name, "condition": model, "value": float(g["score"].mean())})
    return pd.DataFrame(rows, columns=["code", "item", "condition", "value"]), text


def ratings_by_group(scores: pd.DataFrame, text: dict[str, str], groups: pd.Series, order: list[str]) -> tuple[pd.DataFrame, pd.DataFrame]:
    """Per rating (and instrument score) and condition: each group's n, median, IQR and mean
    (RATING_COLUMNS), and Kruskal-Wallis across the groups with Holm over every rating and
    condition tested (RATING_TEST_COLUMNS)."""
    s = scores.assign(group=scores["code"].map(groups))
    s = s[s["group"].isin(order)]
    desc, tests = [], []
    for (item, condition), d in s.groupby(["item", "condition"], sort=False):
        vals = [d.loc[d["group"] == g, "value"].to_numpy(float) for g in order]
        for g, x in zip(order, vals):
            desc.append({"item": item, "question": text.get(item, item), "condition": condition, "group": g} | _describe(x))
        H, p = _kruskal(vals)
        k = sum(1 for x in vals if len(x))
        tests.append({"item": item, "question": text.get(item, item), "condition": condition, "k": k, "n": int(sum(map(len, vals))),
                      "H": H, "df": k - 1, "p": p})
    t = pd.DataFrame(tests, columns=RATING_TEST_COLUMNS[:-1])
    t["p_holm"] = holm(t["p"]) if len(t) else pd.Series(dtype=float)
    return pd.DataFrame(desc, columns=RATING_COLUMNS), t[RATING_TEST_COLUMNS]


# ---------------------------------------------------------------- the report

def _trial_points(metrics: pd.DataFrame, groups: pd.Series, order: list[str]) -> pd.DataFrame:
    """Per metric, condition, group and trial (1-based): the mean over the group's participants
    of their mean over hands (what the learning curves are fitted to)."""
    t = v._trial_means(metrics).assign(group=lambda d: d["code"].map(groups))
    t = t[t["group"].isin(order)]
    out = t.groupby(["metric", "condition", "group", "trial"], sort=True)["value"].agg(["mean", "count"]).reset_index()
    out["trial"] = out["trial"] + 1
    return out.rename(columns={"count": "n"})


def _with_wy(columns: list[str]) -> list[str]:
    """`columns` with p_wy after p_holm (group_tests' columns with n_perm > 0)."""
    i = columns.index("p_holm") + 1
    return columns[:i] + ["p_wy"] + columns[i:]


def validity_report(study: Study, permutations: int = DEFAULT_PERMUTATIONS, bootstrap: int = DEFAULT_BOOTSTRAP, seed: int = 0,
                    progress: Callable[[int, int], None] | None = None,
                    group_permutations: int = DEFAULT_GROUP_PERMUTATIONS) -> dict:
    """The construct-validity report of `study` (analysis/study/study_snapshot.py's snapshot). `permutations`:
    of the classifier's permutation test; `group_permutations`: of the group tests' Westfall-Young
    adjustment (`p_wy`, analysis.validity.groups.group_tests' n_perm); `bootstrap`: replicates of Cliff's delta's intervals and
    of the learning curves'; `seed`: of every resampling. `progress(done, STEPS)` after each step.
    Raises NoGroupsError for a study without design.groups."""
    step = progress or (lambda k, n: None)
    protocol = study.protocol
    groups, order, fields = study_groups(study)
    expert = order[-1]
    synthetic_codes = set(study.synthetic_codes)
    answers = study.answers
    metrics = metrics_table(study, study_goals(study))
    step(1, STEPS)
    synthetic_codes |= set(metrics.loc[metrics["synthetic"].astype(bool), "code"])
    measured = set(metrics["code"])
    ungrouped = sorted(measured - set(groups.index))
    metrics = metrics[metrics["code"].isin(set(groups.index))]
    scores = v.participant_scores(metrics)
    conditions = sorted(metrics["condition"].unique().tolist())
    counts = pd.DataFrame([{"group": g, "n_registered": int((groups == g).sum()),
                            "n_with_metrics": int(groups[groups.index.isin(measured)].eq(g).sum())} for g in order], columns=GROUP_COLUMNS)
    fdesc = []
    f = fields.assign(group=fields["code"].map(groups))
    for name in dict.fromkeys(f["field"]):
        for g in order:
            d = _describe(f.loc[(f["field"] == name) & (f["group"] == g), "value"].to_numpy(float))
            fdesc.append({"field": name, "group": g, "n": d["n"], "median": d["median"], "q1": d["q1"], "q3": d["q3"]})
    n_boot = max(int(bootstrap), 1)
    events = condition_events(list(protocol.conditions), study.trial_events)
    held = withheld(events)
    # a withheld condition's metrics were measured while the participant felt the fault: no test reads them
    tested, tested_metrics = scores[~scores["condition"].isin(held)], metrics[~metrics["condition"].isin(held)]
    tested_conditions = sorted(tested_metrics["condition"].unique().tolist())

    n_wy = max(int(group_permutations), 1)
    tests = v.group_tests(tested, groups, order, n_boot=n_boot, seed=seed, n_perm=n_wy) if len(tested) else None
    tests = _with_withheld(tests, scores[scores["condition"].isin(held)], groups, order, held)
    step(2, STEPS)
    if len(tested_conditions) >= 2:
        mm = v.mixed_model(tested_metrics, groups, order)
        mixed = {"reason": None, "fixed": mm.fixed, "skipped": mm.skipped}
    else:
        why = (involving(conditions, held) if len(conditions) >= 2 else
               f"one condition ({conditions[0]}): no condition effect to model; the groups are compared by the tests above"
               if conditions else "no metrics yet")
        mixed = {"reason": why,
                 "fixed": pd.DataFrame(columns=v.FIXED_COLUMNS), "skipped": pd.DataFrame(columns=["metric", "reason"])}
    step(3, STEPS)
    curves = v.learning_curves(metrics, groups, order, n_boot=n_boot, seed=seed) if len(metrics) else pd.DataFrame(columns=v.CURVE_COLUMNS)
    step(4, STEPS)
    better = {m: BETTER[_metric_base(m)] for m in scores["metric"].unique() if _metric_base(m) in BETTER}
    try:
        prof = v.proficiency(scores, groups, expert, better=better, band=BAND)
        proficiency = {"reason": None, "benchmark": prof.benchmark, "scorecard": prof.scorecard, "summary": prof.summary}
    except ValueError as e:
        proficiency = {"reason": str(e), "benchmark": pd.DataFrame(columns=v.BENCHMARK_COLUMNS),
                       "scorecard": pd.DataFrame(columns=v.SCORECARD_COLUMNS), "summary": pd.DataFrame(columns=v.SUMMARY_COLUMNS)}
    step(5, STEPS)
    try:
        c = v.classify(tested, groups, order, n_permutations=int(permutations), seed=seed)
        classifier = {"reason": None, "n": c.n, "n_features": len(c.features), "features": list(c.features), "accuracy": c.accuracy,
                      "balanced_accuracy": c.balanced_accuracy, "chance": c.chance, "p_value": c.p_value,
                      "n_permutations": c.n_permutations, "groups": list(c.confusion.index),
                      "confusion": c.confusion.to_numpy().tolist(), "predictions": c.predictions}
    except ValueError as e:
        classifier = {"reason": str(e)}
    step(6, STEPS)
    rscores, rtext = rating_scores(protocol, answers)
    ratings, rating_tests = ratings_by_group(rscores, rtext, groups, order)
    step(7, STEPS)
    in_groups = groups[groups.isin(order)]
    synthetic = sorted(synthetic_codes & set(in_groups.index) | synthetic_codes & measured)
    persons = sorted((set(in_groups.index) | measured) - synthetic_codes)
    return {
        "study": protocol.name, "synthetic": bool(synthetic), "synthetic_participants": len(synthetic), "person_participants": len(persons),
        "note": data_flag(len(persons), len(synthetic)),
        "group_field": protocol.groups, "groups": order, "expert": expert,
        "participants": int(len(in_groups)), "participants_with_metrics": int(len(set(in_groups.index) & measured)),
        "ungrouped_with_metrics": ungrouped, "conditions": conditions,
        "trials": int(metrics["trial"].max()) + 1 if len(metrics) else 0,
        "metrics": sorted(scores["metric"].unique().tolist()), "units": {m: _unit(m) for m in scores["metric"].unique()},
        "settings": {"permutations": int(permutations), "group_permutations": n_wy, "bootstrap": n_boot, "seed": int(seed),
                     "band": list(BAND)},
        "group_counts": counts, "fields": pd.DataFrame(fdesc, columns=FIELD_COLUMNS),
        "scores": scores.assign(group=scores["code"].map(groups)),
        "kruskal": tests.kruskal if tests else pd.DataFrame(columns=_with_wy(v.KRUSKAL_COLUMNS)),
        "pairs": tests.pairs if tests else pd.DataFrame(columns=_with_wy(v.PAIR_COLUMNS)),
        "descriptives": tests.descriptives if tests else pd.DataFrame(columns=v.DESCRIPTIVE_COLUMNS),
        "mixed_model": mixed, "learning_curves": curves, "trial_means": _trial_points(metrics, groups, order) if len(metrics) else
        pd.DataFrame(columns=["metric", "condition", "group", "trial", "mean", "n"]),
        "proficiency": proficiency, "classifier": classifier, "ratings": ratings, "rating_tests": rating_tests,
    } | ({"faults": list(events)} if any_events(events) else {})


WITHHELD_NUMBERS = ("H", "U", "p", "p_holm", "p_wy", "cliffs_delta", "delta_low", "delta_high")


def _with_withheld(tests, scores: pd.DataFrame, groups: pd.Series, order: list[str], held: dict):
    """The group tests with the withheld conditions' rows added, described (their groups'
    medians) but not tested: no statistic, no p, the reason; in (metric, condition) order."""
    if not len(scores):
        return tests
    out = v.group_tests(scores, groups, order, n_boot=1, seed=0)
    mark = {"kruskal": out.kruskal, "pairs": out.pairs}
    for (name, frame), columns in zip(mark.items(), (v.KRUSKAL_COLUMNS, v.PAIR_COLUMNS)):
        frame = frame.assign(**{k: np.nan for k in WITHHELD_NUMBERS if k in frame.columns or k == "p_wy"})
        mark[name] = frame.assign(reason=frame["condition"].map(held))[_with_wy(columns)]
    if tests is None:
        return replace(out, **mark)
    return replace(tests, **{name: pd.concat([getattr(tests, name), f[getattr(tests, name).columns]], ignore_index=True)
                             .sort_values(["metric", "condition"], kind="stable").reset_index(drop=True) for name, f in mark.items()},
                   descriptives=pd.concat([tests.descriptives, out.descriptives], ignore_index=True)
                   .sort_values(["metric", "condition"], kind="stable").reset_index(drop=True))


# ---------------------------------------------------------------- rendering

def _records(obj):
    """DataFrames (also nested in dicts) as lists of records."""
    if isinstance(obj, pd.DataFrame):
        return obj.to_dict(orient="records")
    if isinstance(obj, dict):
        return {k: _records(x) for k, x in obj.items()}
    return obj


def to_json(rep: dict) -> str:
    """The report as JSON (NaN as null); `scores` (every participant's value) included."""
    return json.dumps(jsonable(_records(rep)), indent=2) + "\n"


def _g(x, fmt: str = "{:.3g}") -> str:
    return "-" if x is None or (isinstance(x, float) and not np.isfinite(x)) or pd.isna(x) else fmt.format(x)


def _ci(lo, hi) -> str:
    return f"[{_g(lo)}, {_g(hi)}]"


def _cond(c: str) -> str:
    return "whole session" if c == SESSION else c


def title(rep: dict) -> str:
    kind = " (MIXED DATA)" if rep["synthetic"] and rep.get("person_participants") else " (SYNTHETIC DATA)" if rep["synthetic"] else ""
    return f"Construct validity: {rep['study']}{kind}"


def header_lines(rep: dict) -> list[str]:
    counts = ", ".join(f"{r['group']} {r['n_with_metrics']}" for r in rep["group_counts"].to_dict(orient="records"))
    s = rep["settings"]
    lines = [f"N = {rep['participants_with_metrics']} participants with metrics in {len(rep['groups'])} groups of "
             f"{rep['group_field']} ({counts}); {len(rep['conditions'])} condition{'' if len(rep['conditions']) == 1 else 's'} "
             f"({', '.join(rep['conditions']) or 'none'}), "
             f"up to {rep['trials']} trials each; {len(rep['metrics'])} metrics (docs/metrics.md). "
             f"Expert group: {rep['expert']}. {s['group_permutations']} permutations of the group tests' labels, "
             f"{s['permutations']} of the classifier's, {s['bootstrap']} bootstrap replicates, seed {s['seed']}."]
    if not rep["participants_with_metrics"]:
        lines.append("No participant with a group has a trial with a stored trace yet: nothing to compare.")
    if rep["ungrouped_with_metrics"]:
        lines.append(f"Left out (no {rep['group_field']} value): {', '.join(rep['ungrouped_with_metrics'])}.")
    return lines


def _section(title: str, text: str, columns: list, rows: list) -> Table:
    return Table(columns=columns, rows=rows, title=title, notes=text)


def sections(rep: dict) -> list[Table]:
    """The report's sections, each a table (a section of text alone has no columns), its text the
    notes: what md, LaTeX and html all render."""
    order, out = rep["groups"], []
    fields = rep["fields"]
    cols = ["group", "registered", "with metrics"] + [f"{f}: median [IQR] (n)" for f in dict.fromkeys(fields["field"])]
    rows = []
    for r in rep["group_counts"].to_dict(orient="records"):
        cells = [r["group"], r["n_registered"], r["n_with_metrics"]]
        for f in dict.fromkeys(fields["field"]):
            d = fields[(fields["field"] == f) & (fields["group"] == r["group"])].iloc[0]
            cells.append(f"{_g(d['median'])} {_ci(d['q1'], d['q3'])} ({d['n']})")
        rows.append(cells)
    out.append(_section("Participants", f"Groups: the {rep['group_field']} field (design.groups), in the protocol's order; integer and number "
                "fields described per group; text fields are never analysed.", cols, rows))
    faults = events_table(list(rep.get("faults") or []))
    if faults is not None:  # only where a trial had one: a study without keeps its report as it was
        out.append(replace(faults, notes=faults.notes + " A withheld condition's metrics are described, never tested: no group "
                           "comparison, mixed model or classifier reads them."))

    kw, pairs, desc = rep["kruskal"], rep["pairs"], rep["descriptives"]
    cols = ["metric", "unit", "condition"] + [f"{g}: median [IQR]" for g in order] + ["H", "p", "p_holm", "p_wy"]
    rows = []
    for k in kw.to_dict(orient="records"):
        d = desc[(desc["metric"] == k["metric"]) & (desc["condition"] == k["condition"])].set_index("group")
        meds = [f"{_g(d.loc[g, 'median'])} {_ci(d.loc[g, 'q1'], d.loc[g, 'q3'])}" if g in d.index else "-" for g in order]
        tested = not isinstance(k.get("reason"), str)
        rows.append([k["metric"], _unit(k["metric"]), k["condition"], *meds, _g(k["H"]) if tested else "-",
                     p_value(k["p"], decimals=True) if tested else f"not tested: {k['reason']}", p_value(k["p_holm"], decimals=True), p_value(k["p_wy"], decimals=True)])
    n_kw = int(kw["p"].notna().sum())
    out.append(_section("Group comparisons", f"Kruskal-Wallis across the groups per metric and condition (each participant's mean over trials "
                f"and hands); p_holm: Holm over the family of the {n_kw} Kruskal-Wallis tests run (a metric with no variation, or "
                "values in fewer than two groups, is not tested and not in the family); p_wy: Westfall-Young step-down min-p over the same family, "
                f"{rep['settings']['group_permutations']} permutations of the participants' group labels (keeps the correlation "
                "between the metrics, which makes Holm conservative).", cols, rows))
    rows = [[r["metric"], r["condition"], f"{r['a']} vs {r['b']}", _g(r["U"]), p_value(r["p"], decimals=True), p_value(r["p_holm"], decimals=True), p_value(r["p_wy"], decimals=True),
             f"{_g(r['cliffs_delta'], '{:.2f}')} [{_g(r['delta_low'], '{:.2f}')}, {_g(r['delta_high'], '{:.2f}')}]"]
            if not isinstance(r.get("reason"), str) else [r["metric"], r["condition"], f"{r['a']} vs {r['b']}", "-", f"not tested: {r['reason']}", "-", "-", "-"]
            for r in pairs.to_dict(orient="records")]
    n_pairs = int(pairs["p"].notna().sum())
    out.append(_section("Pairwise comparisons", f"Two-sided Mann-Whitney U for every pair of groups; p_holm: Holm over the family of the "
                f"{n_pairs} pairwise tests run (metrics x conditions x pairs); p_wy: Westfall-Young step-down min-p over the same "
                "family (the same permutations; raw p from the normal approximation); Cliff's delta of the first group over the second "
                f"(positive: higher values in the first) with its bootstrap percentile 95% interval ({rep['settings']['bootstrap']} "
                "replicates, participants resampled within each group).",
                ["metric", "condition", "pair", "U", "p", "p_holm", "p_wy", "Cliff's delta [95% CI]"], rows))

    mm = rep["mixed_model"]
    if mm["reason"]:
        out.append(_section("Mixed model", f"Not fitted: {mm['reason']}.", [], []))
    else:
        rows = [[r["metric"], r["term"], _g(r["coef"]), _g(r["se"]), _g(r["z"]), p_value(r["p"], decimals=True), "yes"] if r["converged"] else
                [r["metric"], r["term"], "-", "-", "-", "not tested: the fit did not converge", "NO"]
                for r in mm["fixed"].to_dict(orient="records")]
        rows += [[r["metric"], "not fitted: " + r["reason"], "", "", "", "", ""] for r in mm["skipped"].to_dict(orient="records")]
        out.append(_section("Mixed model", "Per metric, value ~ group + condition + trial with a random intercept per participant "
                    f"(statsmodels MixedLM, REML; references: {order[0]} and the first condition alphabetically); Wald p, not adjusted.",
                    ["metric", "term", "coef", "se", "z", "p", "converged"], rows))

    def curve_ci(lo, hi) -> str:  # an interval of fewer than two distinct replicates says nothing
        return _ci(lo, hi) if lo == lo and hi == hi and hi > lo else "(no interval)"

    rows = [[r["metric"], r["condition"], r["group"], r["n_participants"], _g(r["y0"]), f"{_g(r['plateau'])} {curve_ci(r['plateau_low'], r['plateau_high'])}",
             f"{_g(r['rate'])} {curve_ci(r['rate_low'], r['rate_high'])}", f"{r['n_boot_ok']}/{r['n_boot']}"]
            if r["plateau"] == r["plateau"] else [r["metric"], r["condition"], r["group"], r["n_participants"], "-", "no fit", "no fit",
                                                  f"{r['n_boot_ok']}/{r['n_boot']}"]
            for r in rep["learning_curves"].to_dict(orient="records")]
    out.append(_section("Learning curves", "Per metric, condition and group: the group's mean per trial fitted with y = plateau + (y0 - plateau) "
                "exp(-rate (trial - 1)); 95% percentile intervals of plateau and rate from bootstrap replicates resampling the group's "
                "participants (fits that failed are dropped: ok/replicates). No fit (-): fewer than 3 trials, no convergence, a step "
                f"(rate above {v.MAX_RATE:.2f}: half the approach within a quarter of a trial) or a rate too slow for half the approach to "
                "lie within the trials observed.",
                ["metric", "condition", "group", "n", "y0", "plateau [95% CI]", "rate per trial [95% CI]", "ok"], rows))

    prof = rep["proficiency"]
    if prof["reason"]:
        out.append(_section("Proficiency", f"No benchmark: {prof['reason']}.", [], []))
    else:
        lo, hi = rep["settings"]["band"]
        rows = [[r["metric"], r["condition"], r["n_expert"], _g(r["median"]), _ci(r["low"], r["high"]),
                 r["better"] if isinstance(r["better"], str) else "-"]
                for r in prof["benchmark"].to_dict(orient="records")]
        out.append(_section("Proficiency benchmark", f"The expert group ({rep['expert']}): its median per metric and the band from its "
                    f"{lo:g}th to {hi:g}th percentile; better: where better performance lies (-: no direction).",
                    ["metric", "condition", "experts", "median", f"band [{lo:g}th, {hi:g}th]", "better"], rows))
        rows = [[r["code"], r["group"], r["condition"], f"{r['n_proficient']}/{r['n_metrics']}", f"{r['fraction_proficient']:.0%}"]
                for r in prof["summary"].to_dict(orient="records")]
        out.append(_section("Scorecards", "Every other participant against the benchmark: a metric is at proficiency when inside the band or "
                    "beyond it on the better side (the per-metric scorecard is in the JSON).",
                    ["participant", "group", "condition", "metrics at proficiency", "fraction"], rows))

    c = rep["classifier"]
    if c.get("reason"):
        out.append(_section("Expertise classification", f"Not run: {c['reason']}.", [], []))
    else:
        text = (f"Group from a participant's {c['n_features']} metric scores (median imputation, standardisation, L2 logistic "
                f"regression, balanced class weights), leave-one-participant-out over {c['n']} participants: accuracy "
                f"{c['accuracy']:.1%} (balanced {c['balanced_accuracy']:.1%}; the largest group's share {c['chance']:.1%}), "
                f"permutation p = {p_value(c['p_value'], decimals=True)} ({c['n_permutations']} permutations of the groups). Below the largest group's "
                "share is what leave-one-out gives groups that do not differ (each left-out participant shifts the training groups "
                "against its own); read the permutation p, not the distance from chance. Confusion (rows: true group):")
        rows = [[g] + list(r) for g, r in zip(c["groups"], c["confusion"])]
        out.append(_section("Expertise classification", text, ["true \\ predicted", *c["groups"]], rows))

    rt, rd = rep["rating_tests"], rep["ratings"]
    if not len(rt):
        out.append(_section("Face validity ratings", "The protocol asks no rating question and has no instrument.", [], []))
    else:
        rows = []
        for t in rt.to_dict(orient="records"):
            d = rd[(rd["item"] == t["item"]) & (rd["condition"] == t["condition"])].set_index("group")
            cells = [f"{_g(d.loc[g, 'median'])} {_ci(d.loc[g, 'q1'], d.loc[g, 'q3'])} ({d.loc[g, 'n']})" for g in order]
            rows.append([t["question"], _cond(t["condition"]), *cells, _g(t["H"]), p_value(t["p"], decimals=True), p_value(t["p_holm"], decimals=True)])
        out.append(_section("Face validity ratings", "Per rating question (its mean over trials when asked after each trial) and instrument "
                    "score (SUS, 0-100), per group: median [IQR] (n), every participant who answered; Kruskal-Wallis across the groups, "
                    f"p_holm: Holm over the family of all {len(rt)} ratings and scores.",
                    ["question", "condition", *[f"{g}: median [IQR] (n)" for g in order], "H", "p", "p_holm"], rows))
    return out


def markdown(rep: dict) -> str:
    lines = [f"# {title(rep)}", ""]
    if rep["note"]:
        lines += [f"**{rep['note']}** {rep['synthetic_participants']} synthetic participants.", ""]
    lines += header_lines(rep) + [""]
    for t in sections(rep):
        lines += [f"## {t.title}", "", t.notes, ""]
        if t.columns:
            lines += markdown_grid(t) + [""]
    return "\n".join(lines)


def latex(rep: dict) -> str:
    """The report's tables as LaTeX (analysis/reports/table.py), each section's text its caption; the
    title, the synthetic note and the header lines as a comment and the first caption's start."""
    lead = " ".join([rep["note"] + f" {rep['synthetic_participants']} synthetic participants." if rep["note"] else "",
                     *header_lines(rep)]).strip()
    ts = [t for t in sections(rep) if t.columns]
    if ts:
        ts[0] = replace(ts[0], notes=f"{title(rep)}. {lead} {ts[0].notes}")
    return latex_tables(ts, "tab:validity")


# ---------------------------------------------------------------- html and its plots

def metric_figure(rep: dict, metric: str):
    """One metric: per condition, a box plot per group with every participant's score as a point,
    and the groups' learning curves (trial means and the fitted curve)."""
    plt = _plt()
    order, conditions = rep["groups"], rep["conditions"]
    colors = {g: OTHER_COLORS[k % len(OTHER_COLORS)] for k, g in enumerate(order)}
    s = rep["scores"][rep["scores"]["metric"] == metric]
    tm = rep["trial_means"][rep["trial_means"]["metric"] == metric]
    lc = rep["learning_curves"][rep["learning_curves"]["metric"] == metric]
    fig, axes = plt.subplots(len(conditions), 2, figsize=(10, 3.4 * len(conditions)), dpi=80, squeeze=False)
    rng = np.random.default_rng(0)  # horizontal jitter only
    unit = _unit(metric)
    for (bx, cx), cond in zip(axes, conditions):
        data = [s[(s["condition"] == cond) & (s["group"] == g)]["value"].to_numpy(float) for g in order]
        bx.boxplot([d if len(d) else [np.nan] for d in data], tick_labels=order, showfliers=False, widths=0.5)
        for j, (g, d) in enumerate(zip(order, data)):
            bx.scatter(j + 1 + rng.uniform(-0.12, 0.12, len(d)), d, s=14, color=colors[g], alpha=0.8, zorder=3)
        bx.set_ylabel(f"{metric} ({unit})" if unit else metric)
        bx.set_title(f"{cond}: participants' means per group", fontsize=9)
        for g in order:
            p = tm[(tm["condition"] == cond) & (tm["group"] == g)]
            cx.plot(p["trial"], p["mean"], "o", ms=4, color=colors[g], label=g)
            f = lc[(lc["condition"] == cond) & (lc["group"] == g)]
            if len(f) and np.isfinite(f["rate"].iloc[0]) and len(p):
                x = np.linspace(p["trial"].min(), p["trial"].max(), 100)
                cx.plot(x, v.exp_plateau(x, f["y0"].iloc[0], f["plateau"].iloc[0], f["rate"].iloc[0]), color=colors[g], lw=1.3)
        cx.set_xlabel("trial")
        cx.set_title(f"{cond}: learning curves (group mean per trial, fitted)", fontsize=9)
        cx.legend(fontsize=7)
        for ax in (bx, cx):
            ax.grid(alpha=0.3)
    fig.suptitle(("SYNTHETIC DATA: " if rep["synthetic"] else "") + metric, fontsize=11)
    fig.tight_layout()
    return fig


def html(rep: dict) -> str:
    """One self-contained HTML file: the sections' tables and, per metric, a figure (box and
    strip plots per group, learning curves) inlined as base64 PNG."""
    esc = _html.escape
    parts = [page_head(title(rep)),
             f"<h1>{esc(title(rep))}</h1>"]
    if rep["note"]:
        parts.append(f'<p class="synthetic">{esc(rep["note"])} {rep["synthetic_participants"]} synthetic participants.</p>')
    parts += [f"<p>{esc(line)}</p>" for line in header_lines(rep)]
    for t in sections(rep):
        parts.append(f"<h2>{esc(t.title)}</h2><p>{esc(t.notes)}</p>")
        if t.columns:
            parts.append(html_grid(t))
    if rep["metrics"]:
        parts.append("<h2>Metrics per group and learning curves</h2>")
        for m in rep["metrics"]:
            img = figure_png(metric_figure(rep, m), _plt().close)
            parts.append(f'<figure><img alt="{esc(m)}" src="data:image/png;base64,{img}"><figcaption>{esc(m)}</figcaption></figure>')
    parts.append(PAGE_END)
    return "\n".join(parts)
