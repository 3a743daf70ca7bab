"""Planning a study: Monte Carlo power of the protocol's tests under the synthetic model.

Pilot runs of synthetic participants on the simulator give, per condition, what each trial
offers an observer (studyctl/synthetic/observer.py); simulated studies of N participants, each with
their own perception, then draw answers of every kind from the observer (as synthetic
sessions do, studyctl/synthetic/participant.py) and test them: each question across the conditions with
the test of its kind (Cochran's Q for yes/no, Friedman for ratings and scores (Wilcoxon for two conditions), the exact
multinomial test for a choice), and the protocol's primary analysis (analysis.statistics.kinds.primary:
"primary" rows; it rejects when a pair of conditions differs at Holm-adjusted p < alpha, or
for a choice when the multinomial test does). Power is the fraction of simulated studies
that reject. The null test runs one model under every label: its rejection rate is the
false-positive rate. All of it is SYNTHETIC: a planning aid, no data.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import matplotlib
import matplotlib.pyplot as plt
import numpy as np
import pandas as pd
from statsmodels.stats.contingency_tables import cochrans_q

from analysis.statistics import kinds, scales
from analysis.statistics.kinds import score_names
from analysis.statistics.stats import gee_fit, holm
from analysis.study.questions import NOT_PER_TRIAL, SESSION, Kind
from analysis.verification.truth import load_truth
from sim.linalg import one_thread_pools
from sim.run import run_scene
from sim.sweep import completed, reachable
from studyctl.conditions import condition_scene, scene_itself
from studyctl.schedule import williams
from studyctl.synthetic.observer import DEFAULT, ObserverTraits, features, judged_answer, logit, summarise
from studyctl.synthetic.participant import SyntheticParticipant
from studyctl.synthetic.rig import frame_times


def pilot_summaries(protocol, pilots: int = 4, seed: int = 0, mapping: dict[str, str] | None = None) -> dict[str, list]:
    """Per condition label, `pilots` synthetic pilot trials on the simulator, summarised for
    the observer (studyctl/observer.TrialSummary), with the rig profile's frame time of the
    condition that ran (studyctl/synthetic/rig.py: the shipped one) where it has one. `mapping` (label ->
    model) lets one model play another's condition (the null and swap tests); the pilots' hand
    motions are drawn per label, as a session draws them per condition."""
    mapping = mapping or {}
    rig = frame_times(protocol)
    scenes: dict[str, object] = {}
    truth = load_truth(scene_itself(protocol))  # the scene's own, whatever a condition changes
    out: dict[str, list] = {}
    for label in protocol.conditions:
        model = mapping.get(label, label)
        scene = scenes.get(model) or scenes.setdefault(model, condition_scene(protocol, model, "simulated"))
        out[label] = []
        for k in range(pilots):
            p = SyntheticParticipant.draw(f"PILOT{k + 1:02d}", seed)
            scene.operators = p.operators(scene, 0, label)
            try:
                result = run_scene(scene, duration=protocol.trial_seconds, time_scale=0)
            finally:
                scene.operators = None
            summary = summarise(result, truth, scene.mesh)
            out[label].append(dataclasses.replace(summary, frame_ms=rig[model]["frame_ms"]) if model in rig else summary)
    return out


def _tested(protocol) -> list:
    """The questions `plan` tests one by one: each asked after every condition (instrument items
    through their score), and the choices at the end."""
    return [q for q in protocol.asked("condition") if q.analysed and q.instrument is None] + \
        [q for q in protocol.asked("end") if q.kind == Kind.CHOICE]


def test_names(protocol) -> list[str]:
    """The rows of a power table: each tested question, each score, the primary."""
    return [q.id for q in _tested(protocol)] + score_names(protocol) + ["primary"]


def simulate_study(protocol, summaries: dict[str, list], n: int, rng: np.random.Generator, params=None) -> pd.DataFrame:
    """One simulated study of `n` participants: tidy answers (code, model, item, trial, answer,
    period) to every question asked after a condition and every choice at the end, drawn from
    the observer as a synthetic session draws them; each participant's condition perceived from
    a random pilot trial; Williams orders in turn for the period."""
    params = params or DEFAULT
    labels = list(protocol.conditions)
    orders = williams(len(labels))
    asked = [q for q in protocol.asked("condition") if q.analysed]
    per_trial = [q for q in protocol.asked("trial") if q.analysed and q.kind != Kind.CHOICE]
    choices = [q for q in protocol.asked("end") if q.kind == Kind.CHOICE]

    def draw(q, eta):
        v = judged_answer(q, eta, rng.random, rng.normal)
        return int(v) if q.kind == Kind.YES_NO else v

    rows = []
    for i, z in enumerate(rng.normal(size=(n, 5))):
        traits = ObserverTraits.from_normals(z, params)
        code = f"N{i:04d}"
        feats = {c: features([summaries[c][rng.integers(len(summaries[c]))]], traits, params) for c in labels}
        period = {labels[c]: k for k, c in enumerate(orders[i % len(orders)])}
        for c in labels:
            for q in asked:
                rows.append((code, c, q.id, NOT_PER_TRIAL, draw(q, logit(q, feats[c], traits, params)), period[c]))
            for t in range(protocol.trials_per_condition) if per_trial else ():  # each trial judged on itself
                ft = features([summaries[c][rng.integers(len(summaries[c]))]], traits, params)
                rows += [(code, c, q.id, t, draw(q, logit(q, ft, traits, params)), period[c]) for q in per_trial]
        for q in choices:
            utility = {c: logit(q, feats[c], traits, params) + rng.gumbel() for c in labels}
            rows.append((code, SESSION, q.id, NOT_PER_TRIAL, max(utility, key=utility.get), -1))
    return pd.DataFrame(rows, columns=["code", "model", "item", "trial", "answer", "period"])


def test_study(protocol, answers: pd.DataFrame, primary: bool = True) -> dict[str, float]:
    """The p-value of each of `test_names` on one simulated study (NaN: not computed). Per
    question: Cochran's Q (yes/no), Friedman (ratings, scores), the exact multinomial (choice)."""
    labels = list(protocol.conditions)
    out = {}
    for q in _tested(protocol):
        sel = answers[answers["item"] == q.id]
        if q.kind == Kind.CHOICE:
            out[q.id] = scales.choice_analysis(sel.set_index("code")["answer"], labels)["overall"]["p_value"]
            continue
        x = sel.pivot(index="code", columns="model", values="answer")[labels].to_numpy(float)
        if q.kind == Kind.YES_NO:
            out[q.id] = cochran_p(x.astype(int))
        else:
            out[q.id] = kinds.across_p(x)
    meas = kinds.measures(protocol, answers.drop(columns="period"), answers[["code", "model", "period"]].drop_duplicates())
    for name in kinds.score_names(protocol):
        out[name] = kinds.across_p(kinds._wide(meas, name, labels).to_numpy(float))
    out["primary"] = primary_p(protocol, answers, meas) if primary else float("nan")
    return out


def primary_p(protocol, answers: pd.DataFrame, meas: pd.DataFrame) -> float:
    """The primary analysis's decision as a p-value: the smallest Holm-adjusted p of its pairs
    (ordinal or logistic GEE, mixed model), or the multinomial test's p (choice); 1 when it is
    not estimable (it finds nothing)."""
    what = kinds.primary(protocol)
    labels = list(protocol.conditions)
    if what.analysis == "choice":
        sel = answers[answers["item"] == what.items[0]]
        return scales.choice_analysis(sel.set_index("code")["answer"], labels)["overall"]["p_value"]
    if what.analysis == "ordinal_gee":
        res = scales.ordinal_gee(meas[meas["item"].isin(what.items)], labels, with_item=len(what.items) > 1)
    elif what.analysis == "logistic_gee":
        res = gee_fit(answers[answers["item"].isin(what.items)].astype({"answer": int}), labels, with_item=True)
    elif what.analysis == "mixed_model":
        res = scales.mixed_model(meas[meas["item"] == what.items[0]], labels)
    else:
        return float("nan")
    p = [x["p_value"] if x.get("estimable") and np.isfinite(x["p_value"]) else 1.0 for x in res["pairs"]]
    return min(holm(p)) if p else 1.0


def cochran_p(x: np.ndarray) -> float:
    """Cochran's Q p-value; 1 when no participant differs between conditions (no evidence)."""
    if np.all(x == x[:, :1]):
        return 1.0
    return float(cochrans_q(x).pvalue)


BATCH = 25  # simulated studies per task: each batch has its own random stream, so the tables are
# the same whether the batches run here, in local processes or on a Dask cluster


@dataclass(frozen=True)
class _Batch:
    """One task of a power or null table: `size` simulated studies of `n` participants drawn
    from the stream (seed, n, index)."""

    protocol: object
    summaries: dict
    n: int
    seed: int
    index: int
    size: int
    names: tuple
    alpha: float
    primary: bool


def _rejections(batch: _Batch) -> dict[str, int]:
    """How many of the batch's simulated studies each test rejects at alpha."""
    one_thread_pools()  # the model fits' small BLAS calls: two threads fighting on 2 cores are slower (docs/synthetic.md)
    rng = np.random.default_rng([batch.seed, batch.n, batch.index])
    hits = dict.fromkeys(batch.names, 0)
    for _ in range(batch.size):
        for t, p in test_study(batch.protocol, simulate_study(batch.protocol, batch.summaries, batch.n, rng), batch.primary).items():
            if t in hits:
                hits[t] += p < batch.alpha
    return hits


def _hits(protocol, summaries: dict, ns: list[int], simulations: int, seed: int, names: list[str], alpha: float, primary: bool,
          jobs: int, scheduler: str | None, progress) -> dict[int, dict[str, int]]:
    """Per N, how many of `simulations` studies each test rejects; the batches run where
    `sim.sweep.completed` puts them. `progress(studies done, studies)`."""
    batches = [_Batch(protocol, summaries, n, seed, i, min(BATCH, simulations - start), tuple(names), alpha, primary)
               for n in ns for i, start in enumerate(range(0, simulations, BATCH))]
    out = {n: dict.fromkeys(names, 0) for n in ns}
    done = 0
    for k, hits in completed(_rejections, batches, jobs, scheduler):
        for t, h in hits.items():
            out[batches[k].n][t] += h
        done += batches[k].size
        if progress:
            progress(done, len(ns) * simulations)
    return out


def power_table(protocol, ns: list[int], simulations: int = 200, seed: int = 0, pilots: int = 4, alpha: float = 0.05,
                summaries: dict | None = None, primary: bool = True, progress=None, jobs: int = 1,
                scheduler: str | None = None) -> pd.DataFrame:
    """Tidy power table: columns n, item (a question, a score, or "primary"), power, simulations, alpha.
    The simulated studies run in `jobs` local processes or on the Dask cluster at `scheduler`
    (the pilots here), with the same result."""
    reachable(scheduler)  # before the pilots
    summaries = summaries or pilot_summaries(protocol, pilots, seed)
    names = [t for t in test_names(protocol) if primary or t != "primary"]
    hits = _hits(protocol, summaries, ns, simulations, seed, names, alpha, primary, jobs, scheduler, progress)
    rows = [{"n": n, "item": t, "power": hits[n][t] / simulations, "simulations": simulations, "alpha": alpha} for n in ns for t in names]
    return pd.DataFrame(rows, columns=["n", "item", "power", "simulations", "alpha"])


def null_table(protocol, model: str | None = None, participants: int = 35, simulations: int = 200, seed: int = 0, pilots: int = 4,
               alpha: float = 0.05, summaries: dict | None = None, primary: bool = True, progress=None, jobs: int = 1,
               scheduler: str | None = None) -> pd.DataFrame:
    """The observer's fairness test: one model (default: the protocol's first condition) under
    every label; per question, score and the primary analysis the false-positive rate, which
    should be alpha or below within Monte Carlo error (`mc_error`: its binomial standard error).
    Columns: item, false_positive_rate, mc_error, simulations, alpha, model, participants."""
    model = model or protocol.conditions[0]
    reachable(scheduler)  # before the pilots
    summaries = summaries or pilot_summaries(protocol, pilots, seed, mapping={c: model for c in protocol.conditions})
    # every label draws from all the model's pilot trials: the trials of a condition are a
    # sample of one distribution, whichever label it has (fixed per-label pilots would be a
    # difference between labels that no study has)
    pool = [s for c in protocol.conditions for s in summaries[c]]
    summaries = {c: pool for c in protocol.conditions}
    names = [t for t in test_names(protocol) if primary or t != "primary"]
    hits = _hits(protocol, summaries, [participants], simulations, seed, names, alpha, primary, jobs, scheduler, progress)[participants]
    se = float(np.sqrt(alpha * (1 - alpha) / simulations))
    rows = [{"item": t, "false_positive_rate": hits[t] / simulations, "mc_error": se, "simulations": simulations, "alpha": alpha,
             "model": model, "participants": participants} for t in names]
    return pd.DataFrame(rows, columns=["item", "false_positive_rate", "mc_error", "simulations", "alpha", "model", "participants"])


def plot_power(table: pd.DataFrame, path) -> None:
    matplotlib.use("Agg")

    fig, ax = plt.subplots(figsize=(7.5, 4.2), dpi=100)
    for item, g in table.groupby("item", sort=False):
        ax.plot(g["n"], g["power"], marker="o", ms=3, label=item)
    ax.axhline(0.8, color="0.4", ls="--", lw=0.8)
    ax.set_xlabel("participants")
    ax.set_ylabel(f"power (p < {table['alpha'].iloc[0]:.2g}; primary: Holm-adjusted)")
    ax.set_ylim(0, 1.02)
    ax.set_title(f"SYNTHETIC planning: {table['simulations'].iloc[0]} simulated studies per N", fontsize=10)
    ax.legend(fontsize=7, ncol=3)
    ax.grid(alpha=0.3)
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)
