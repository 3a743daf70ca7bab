"""Planning a study: Monte Carlo power of the protocol's tests under the synthetic model.

Pilot runs of synthetic participants on the simulator give, per model, the features the answer
model uses (what each model measured); simulated studies of N participants then draw answers
from the answer model and test each question with Cochran's Q across the models. Power is the
fraction of simulated studies with p < alpha. All of it is SYNTHETIC: a planning aid, no data.
"""

from __future__ import annotations

import numpy as np
import pandas as pd


def pilot_features(protocol, pilots: int = 4, seed: int = 0) -> dict[str, list[dict]]:
    from sim.run import run_scene
    from studyctl.session import _scene
    from studyctl.synthetic import SyntheticParticipant, features

    ref = _scene(protocol, "fem", "simulated")
    out: dict[str, list[dict]] = {}
    for model in protocol.conditions:
        scene = _scene(protocol, model, "simulated")
        feats = []
        for k in range(pilots):
            p = SyntheticParticipant.draw(f"PILOT{k + 1:02d}", seed)
            scene.operators = p.operators(scene, 0, model)
            result = run_scene(scene, duration=protocol.trial_seconds, time_scale=0)
            scene.operators = None
            feats.append(features([result], ref.model, ref.mesh))
        out[model] = feats
    return out


def power_table(protocol, ns: list[int], simulations: int = 200, seed: int = 0, pilots: int = 4, alpha: float = 0.05,
                feats: dict | None = None) -> pd.DataFrame:
    """Tidy power table: columns n, item, power, simulations, alpha."""
    from statsmodels.stats.contingency_tables import cochrans_q

    from studyctl.synthetic import p_yes

    feats = feats or pilot_features(protocol, pilots, seed)
    models = list(protocol.conditions)
    rng = np.random.default_rng(seed)
    rows = []
    for n in ns:
        hits = {q: 0 for q in protocol.items}
        for _ in range(simulations):
            bias = rng.normal(0.0, 0.6, n)
            pick = {m: rng.integers(0, len(feats[m]), n) for m in models}
            for q in protocol.items:
                p = np.array([[p_yes(q, feats[m][pick[m][i]], bias[i]) for m in models] for i in range(n)])
                x = (rng.random(p.shape) < p).astype(int)
                if np.all(x == x[:, :1]):  # no participant differs between models: no evidence
                    continue
                if cochrans_q(x).pvalue < alpha:
                    hits[q] += 1
        rows += [{"n": n, "item": q, "power": hits[q] / simulations, "simulations": simulations, "alpha": alpha} for q in protocol.items]
    return pd.DataFrame(rows, columns=["n", "item", "power", "simulations", "alpha"])


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
