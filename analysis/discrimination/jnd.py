"""The discrimination task's report (`studyctl report jnd`; a section of `report table1`):
per participant and condition the psychometric fit and Weber fraction with its parametric-
bootstrap interval (analysis/discrimination/psychometric.py), per condition the geometric mean, across
conditions the group test, the QUEST+ posterior where it ran, and for synthetic participants
their generating Weber fraction beside the estimate (so recovery can be read off).

`jnd_results(study)` returns one JSON-able dict; `markdown` and `html` print it. Keys:

- ``facts``: study, participants, synthetic, task (method, trials, reference, question), function;
- ``weber``: one row per participant and condition: code, condition, n_trials, weber, ci_low,
  ci_high, lapse, slope, converged, p_correct, quest_estimate (QUEST+ only), generating_weber
  (synthetic only);
- ``conditions``: per condition: n, geometric mean Weber fraction with a 95% interval (t on logs),
  median, and for synthetic studies the median absolute relative error against the generating
  values and the intervals' coverage of them;
- ``group``: analysis.discrimination.weber_groups.group_test across conditions (None with one condition);
- ``faults`` (only where a trial had a fault or safety event): per condition its
  analysis.statistics.faults.ConditionEvents over the task's trials (a trial counts when either interval had
  one). A condition whose trials are mostly faults is withheld: its summary's numbers are NaN with
  the ``reason``, the group's omnibus tests are not run (``withheld``: condition -> reason, first
  in ``problems``), and its pairs are not tested; the other conditions' pairs are tested among
  themselves.
"""

from __future__ import annotations

import dataclasses
import itertools
import json
import math

import numpy as np
import pandas as pd
from scipy import stats

from analysis.discrimination.pooled import POOLED_MIN, pooled_webers
from analysis.discrimination.psychometric import DEFAULT_FUNCTION, LAPSE_MAX, N_BOOT, weber_table
from analysis.discrimination.weber_groups import group_test
from analysis.statistics.faults import any_events, condition_events, withheld
from analysis.statistics.methods import study_methods
from analysis.statistics.table1 import study_facts
from analysis.statistics.withhold import interval_reason
from analysis.study.study_snapshot import data_flag

GM_WARN_BELOW = 5  # participants: below this a geometric mean's t interval is said to be wide


def trials(study, task: int = 0) -> pd.DataFrame:
    """One task's trials, tidy: code, condition, trial, stimulus (the increment), correct."""
    d = study.discrimination
    d = d[d["task"] == task]
    return pd.DataFrame({"code": d["code"], "condition": d["model"], "trial": d["trial"], "stimulus": d["delta"].astype(float),
                         "correct": d["correct"].astype(int)}).reset_index(drop=True)


def _quest_estimates(study, task: int) -> dict:
    """(code, condition) -> the procedure's own estimate after its last trial."""
    d = study.discrimination
    d = d[d["task"] == task].sort_values("trial")
    out = {}
    for (code, cond), g in d.groupby(["code", "model"]):
        state = json.loads(g["state"].iloc[-1]) if isinstance(g["state"].iloc[-1], str) else {}
        if "estimate" in state:
            out[(code, cond)] = float(state["estimate"])
    return out


def jnd_results(study, task: int = 0, n_boot: int | None = None, seed: int = 0) -> dict:
    protocol = study.protocol
    spec = protocol.tasks[task]
    t = trials(study, task)
    d = study.discrimination
    synthetic_codes = d.loc[d["source"] == "synthetic", "code"].nunique()
    person_codes = d.loc[d["source"] != "synthetic", "code"].nunique()
    synthetic = synthetic_codes > 0
    kwargs = {} if n_boot is None else {"n_boot": n_boot}
    table = weber_table(t, seed=seed, **kwargs) if len(t) else pd.DataFrame()
    facts = {"study": protocol.name, "participants": int(t["code"].nunique()) if len(t) else 0, "synthetic": synthetic,
             "flag": data_flag(person_codes, synthetic_codes),
             "fit": {"function": DEFAULT_FUNCTION, "axis": "ln ln(1 + delta) (the log of the log stiffness ratio)",
                     "slope": "held: the two-interval observer's, from its threshold", "lapse_max": LAPSE_MAX,
                     "interval": f"parametric bootstrap, percentile, {kwargs.get('n_boot', N_BOOT)} refits"},
             "task": {"kind": spec.kind, "parameter": spec.parameter, "method": spec.method, "rule": spec.rule if spec.method == "staircase" else None,
                      "trials": spec.trials, "reference": spec.reference, "question": spec.question, "range": [spec.low, spec.high]}}
    # the methods as `report text` writes them, N the participants with discrimination trials
    methods = study_methods(study, dataclasses.replace(study_facts(study), participants=facts["participants"], synthetic=synthetic,
                                                       synthetic_participants=synthetic_codes, person_participants=person_codes))
    if not len(table):
        return {"facts": facts, "weber": [], "conditions": [], "group": None, "methods": methods}
    table = table.merge(pooled_webers(t), on=["code", "condition"], how="left")
    facts["pooled"] = (f"each participant's Weber fraction pooled with the condition's others (hierarchical: ln weber normal over the "
                       f"participants, flat priors on its mean and spread, the observer's likelihood; {POOLED_MIN} or more participants a condition)")
    table["p_correct"] = [float(t[(t["code"] == r.code) & (t["condition"] == r.condition)]["correct"].mean()) for r in table.itertuples()]
    if spec.method == "quest+":
        quest = _quest_estimates(study, task)
        table["quest_estimate"] = [quest.get((r.code, r.condition), math.nan) for r in table.itertuples()]
    traits = study.traits
    generating = traits[traits["trait"] == "stiffness_weber"].set_index("code")["value"] if len(traits) else pd.Series(dtype=float)
    if synthetic and len(generating):
        table["generating_weber"] = [float(generating.get(c, math.nan)) for c in table["code"]]
    order = [c for c in protocol.conditions if c in set(table["condition"])]
    events = condition_events(order, task_events(study, task))
    held = withheld(events)
    conds = [_withhold_summary(_condition_summary(table[table["condition"] == c], c), held.get(c)) for c in order]
    group = _group(table, order, held) if len(order) >= 2 else None
    return ({"facts": facts, "weber": table.to_dict(orient="records"), "conditions": conds, "group": group, "methods": methods}
            | ({"faults": list(events)} if any_events(events) else {}))


def task_events(study, task: int) -> pd.DataFrame:
    """The task's trials' servo events as analysis.statistics.faults reads them: code, model, trial, events."""
    d = study.discrimination
    d = d[d["task"] == task]
    return pd.DataFrame({"code": d["code"], "model": d["model"], "trial": d["trial"],
                         "events": d["events"] if "events" in d else None}).reset_index(drop=True)


SUMMARY_CLAIMS = ("geometric_mean", "gm_low", "gm_high", "median", "recovery_median_abs_rel_error", "recovery_coverage",
                  "recovery_pooled_median_abs_rel_error", "recovery_pooled_coverage")


def _withhold_summary(summary: dict, reason: str | None) -> dict:
    """A withheld condition's summary: its Weber fractions describe the fault, not the model, so
    no mean, interval or recovery figure is claimed of it; the reason instead."""
    if reason is None:
        return summary
    return ({k: v for k, v in summary.items() if k not in ("gm_warning", "gm_reason")}
            | {k: math.nan for k in SUMMARY_CLAIMS if k in summary} | {"reason": reason})


def _group(table: pd.DataFrame, order: list[str], held: dict) -> dict:
    """The group test, or where a condition is withheld: no omnibus test (it would compare the
    fault), the pairs of the conditions kept tested among themselves, the others with the reason."""
    if not any(c in held for c in order):
        return group_test(table, conditions=order)
    kept = [c for c in order if c not in held]
    base = group_test(table[table["condition"].isin(kept)], conditions=kept) if len(kept) >= 2 else None
    base = base or {}
    untested = "; ".join(base.get("problems") or [])  # why the kept conditions' pairs were not tested, if they were not
    tested = {(p["a"], p["b"]): p | ({"reason": untested} if untested else {}) for p in base.get("pairs") or []}
    pairs = [tested.get((a, b)) or {"a": a, "b": b, "n": 0, "reason": held.get(a) or held[b]} for a, b in itertools.combinations(order, 2)]
    return {"conditions": order, "n_participants": base.get("n_participants", 0), "excluded": base.get("excluded", []),
            "n_not_converged": base.get("n_not_converged", 0), "estimable": False,
            "problems": [held[c] for c in order if c in held] + (base.get("problems") or []), "mixed_model": None, "friedman": None,
            "pairs": pairs, "withheld": {c: held[c] for c in order if c in held}}


def _condition_summary(rows: pd.DataFrame, condition: str) -> dict:
    w = rows["weber"].to_numpy(dtype=float)
    w = w[np.isfinite(w) & (w > 0)]
    out = {"condition": condition, "n": int(len(w)), "geometric_mean": math.nan, "gm_low": math.nan, "gm_high": math.nan,
           "median": float(np.median(w)) if len(w) else math.nan}
    if len(w):
        out["geometric_mean"] = float(np.exp(np.log(w).mean()))
    if len(w) >= 2 and np.ptp(w) > 0:
        lw = np.log(w)
        half = stats.t.ppf(0.975, len(w) - 1) * lw.std(ddof=1) / math.sqrt(len(w))
        out |= {"gm_low": float(np.exp(lw.mean() - half)), "gm_high": float(np.exp(lw.mean() + half))}
        if len(w) < GM_WARN_BELOW:
            out["gm_warning"] = f"N = {len(w)}: a t interval on {len(w) - 1} df is wide; {GM_WARN_BELOW} or more narrow it"
    else:
        out["gm_reason"] = interval_reason(w) if len(w) else "no fit"
    if "generating_weber" in rows:
        g = rows["generating_weber"].to_numpy(dtype=float)
        ok = np.isfinite(g) & np.isfinite(rows["weber"].to_numpy(dtype=float))
        if ok.any():
            est = rows["weber"].to_numpy(dtype=float)[ok]
            out["recovery_median_abs_rel_error"] = float(np.median(np.abs(est - g[ok]) / g[ok]))
            out["recovery_coverage"] = float(np.mean((rows["ci_low"].to_numpy(dtype=float)[ok] <= g[ok]) & (g[ok] <= rows["ci_high"].to_numpy(dtype=float)[ok])))
        pooled = rows["weber_pooled"].to_numpy(dtype=float) if "weber_pooled" in rows else np.full(len(rows), np.nan)
        okp = np.isfinite(g) & np.isfinite(pooled)
        if okp.any():
            out["recovery_pooled_median_abs_rel_error"] = float(np.median(np.abs(pooled[okp] - g[okp]) / g[okp]))
            out["recovery_pooled_coverage"] = float(np.mean((rows["pooled_low"].to_numpy(dtype=float)[okp] <= g[okp])
                                                            & (g[okp] <= rows["pooled_high"].to_numpy(dtype=float)[okp])))
    return out



