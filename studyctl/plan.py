"""Planning a study: Monte Carlo power of the protocol's tests under the synthetic model.

Pilot runs of synthetic participants on the simulator give, per condition, what each trial
offers an observer (studyctl/observer.py); simulated studies of N participants, each with
their own perception, then draw answers from the observer and test each question with
Cochran's Q across the conditions. Power is the fraction of simulated studies with p < alpha.
The null test runs one model under every label: its rejection rate is the false-positive rate.
All of it is SYNTHETIC: a planning aid, no data.
"""

from __future__ import annotations

import numpy as np
import pandas as pd


def pilot_summaries(protocol, pilots: int = 4, seed: int = 0, mapping: dict[str, str] | None = None) -> dict[str, list]:
    """Per condition label, `pilots` synthetic pilot trials on the simulator, summarised for
    the observer (studyctl/observer.TrialSummary). `mapping` (label -> model) lets one model
    play another's condition (the null and swap tests); the pilots' hand motions are drawn per
    label, as a session draws them per condition."""
    from sim.run import run_scene
    from studyctl.conditions import scene_itself
    from studyctl.observer import summarise
    from studyctl.session import _scene
    from studyctl.synthetic import SyntheticParticipant
    from studyctl.truth import load_truth

    mapping = mapping or {}
    scenes: dict[str, object] = {}
    truth = load_truth(scene_itself(protocol))  # the scene's own, whatever a condition changes
    out: dict[str, list] = {}
    for label in protocol.conditions:
        model = mapping.get(label, label)
        scene = scenes.get(model) or scenes.setdefault(model, _scene(protocol, model, "simulated"))
        out[label] = []
        for k in range(pilots):
            p = SyntheticParticipant.draw(f"PILOT{k + 1:02d}", seed)
            scene.operators = p.operators(scene, 0, label)
            try:
                result = run_scene(scene, duration=protocol.trial_seconds, time_scale=0)
            finally:
                scene.operators = None
            out[label].append(summarise(result, truth, scene.mesh))
    return out


def simulate_answers(protocol, summaries: dict[str, list], n: int, rng: np.random.Generator, params=None) -> dict[str, np.ndarray]:
    """One simulated study of `n` participants: per question, answers (n, conditions) drawn
    from the observer, each participant's condition perceived from a random pilot trial."""
    from studyctl.observer import DEFAULT, ObserverTraits, features, p_yes

    params = params or DEFAULT
    labels = list(protocol.conditions)
    traits = [ObserverTraits.from_normals(z, params) for z in rng.normal(size=(n, 5))]
    feats = [[features([summaries[c][rng.integers(len(summaries[c]))]], t, params) for c in labels] for t in traits]
    return {q: (rng.random((n, len(labels))) < np.array([[p_yes(q, f, t, params) for f in row] for row, t in zip(feats, traits)])).astype(int)
            for q in protocol.items}


def cochran_p(x: np.ndarray) -> float:
    """Cochran's Q p-value; 1 when no participant differs between conditions (no evidence)."""
    from statsmodels.stats.contingency_tables import cochrans_q

    if np.all(x == x[:, :1]):
        return 1.0
    return float(cochrans_q(x).pvalue)


def power_table(protocol, ns: list[int], simulations: int = 200, seed: int = 0, pilots: int = 4, alpha: float = 0.05,
                summaries: dict | None = None) -> pd.DataFrame:
    """Tidy power table: columns n, item, power, simulations, alpha."""
    summaries = summaries or pilot_summaries(protocol, pilots, seed)
    rng = np.random.default_rng(seed)
    rows = []
    for n in ns:
        hits = {q: 0 for q in protocol.items}
        for _ in range(simulations):
            for q, x in simulate_answers(protocol, summaries, n, rng).items():
                hits[q] += cochran_p(x) < alpha
        rows += [{"n": n, "item": q, "power": hits[q] / simulations, "simulations": simulations, "alpha": alpha} for q in protocol.items]
    return pd.DataFrame(rows, columns=["n", "item", "power", "simulations", "alpha"])


def null_table(protocol, model: str | None = None, participants: int = 35, simulations: int = 200, seed: int = 0, pilots: int = 4,
               alpha: float = 0.05, summaries: dict | None = None) -> pd.DataFrame:
    """The observer's fairness test: one model (default: the protocol's first condition) under
    every label; per question the false-positive rate of Cochran's Q, which should be alpha
    within Monte Carlo error (`mc_error`: its binomial standard error).
    Columns: item, false_positive_rate, mc_error, simulations, alpha, model, participants."""
    model = model or protocol.conditions[0]
    summaries = summaries or pilot_summaries(protocol, pilots, seed, mapping={c: model for c in protocol.conditions})
    # every label draws from all the model's pilot trials: the trials of a condition are a
    # sample of one distribution, whichever label it has (fixed per-label pilots would be a
    # difference between labels that no study has)
    pool = [s for c in protocol.conditions for s in summaries[c]]
    summaries = {c: pool for c in protocol.conditions}
    rng = np.random.default_rng(seed)
    hits = {q: 0 for q in protocol.items}
    for _ in range(simulations):
        for q, x in simulate_answers(protocol, summaries, participants, rng).items():
            hits[q] += cochran_p(x) < alpha
    se = float(np.sqrt(alpha * (1 - alpha) / simulations))
    rows = [{"item": q, "false_positive_rate": hits[q] / simulations, "mc_error": se, "simulations": simulations, "alpha": alpha,
             "model": model, "participants": participants} for q in protocol.items]
    return pd.DataFrame(rows, columns=["item", "false_positive_rate", "mc_error", "simulations", "alpha", "model", "participants"])


def expected_rates(protocol, summaries: dict[str, list], participants: int = 35, simulations: int = 200, seed: int = 0) -> pd.DataFrame:
    """Mean yes rate per condition label and question over simulated studies, with its Monte
    Carlo standard error. Columns: label, item, rate, mc_error."""
    rng = np.random.default_rng(seed)
    labels = list(protocol.conditions)
    acc = {q: [] for q in protocol.items}
    for _ in range(simulations):
        for q, x in simulate_answers(protocol, summaries, participants, rng).items():
            acc[q].append(x.mean(axis=0))
    rows = []
    for q, per in acc.items():
        per = np.array(per)
        for j, label in enumerate(labels):
            rows.append({"label": label, "item": q, "rate": float(per[:, j].mean()), "mc_error": float(per[:, j].std(ddof=1) / np.sqrt(len(per)))})
    return pd.DataFrame(rows, columns=["label", "item", "rate", "mc_error"])


def plot_power(table: pd.DataFrame, path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(7.5, 4.2), dpi=100)
    for item, g in table.groupby("item", sort=False):
        ax.plot(g["n"], g["power"], marker="o", ms=3, label=item)
    ax.axhline(0.8, color="0.4", ls="--", lw=0.8)
    ax.set_xlabel("participants")
    ax.set_ylabel(f"power of Cochran's Q (p < {table['alpha'].iloc[0]:.2g})")
    ax.set_ylim(0, 1.02)
    ax.set_title(f"SYNTHETIC planning: {table['simulations'].iloc[0]} simulated studies per N", fontsize=10)
    ax.legend(fontsize=7, ncol=3)
    ax.grid(alpha=0.3)
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)
