"""Table 1 of the seed paper from a study database, with the statistics it left out.

Tidy DataFrames with stable column names (documented in docs/analysis.md):

- `rates(db)`: one row per item and model: ``item, question, model, yes, no, n, rate,
  wilson_low, wilson_high`` (Wilson 95% interval);
- `cochran(db)`: one row per item: ``item, cochran_q, df, p_value, n_complete`` (participants
  who answered the item for every model);
- `deformation(db)`: one row per model: ``model, n_trials, mean_ms, sd_ms, median_ms, p95_ms``.
"""

from __future__ import annotations

import sqlite3

import numpy as np
import pandas as pd


def _connect(db) -> sqlite3.Connection:
    from studyctl.store import connect_read

    return connect_read(db)


def _query(db, sql: str) -> pd.DataFrame:
    con = _connect(db)
    try:
        return pd.read_sql_query(sql, con)
    finally:
        con.close()


def answers_wide(answers: pd.DataFrame, item: str, models: list[str]) -> pd.DataFrame:
    """0/1 answers to one item: a row per participant who answered it for every model."""
    wide = answers[answers["item"] == item].pivot(index="code", columns="model", values="answer")
    return wide.reindex(columns=models).dropna()


def _protocol(db):
    from studyctl.store import Store

    store = Store(db, mode="read")
    try:
        return store.protocol()
    finally:
        store.close()


def wilson(yes: int, n: int, alpha: float = 0.05) -> tuple[float, float]:
    from statsmodels.stats.proportion import proportion_confint

    if n == 0:
        return (float("nan"), float("nan"))
    lo, hi = proportion_confint(yes, n, alpha=alpha, method="wilson")  # the default is the normal interval
    return float(lo), float(hi)


def rates(db) -> pd.DataFrame:
    protocol = _protocol(db)
    counts = _query(db, "select item, model, sum(answer) as yes, count(*) as n from answers group by item, model")
    text = {q.id: q.text for q in protocol.questions}
    rows = []
    for q in protocol.items:
        for m in protocol.conditions:
            c = counts[(counts["item"] == q) & (counts["model"] == m)]
            yes = int(c["yes"].iloc[0]) if len(c) else 0
            n = int(c["n"].iloc[0]) if len(c) else 0
            lo, hi = wilson(yes, n)
            rows.append({"item": q, "question": text[q], "model": m, "yes": yes, "no": n - yes, "n": n,
                         "rate": yes / n if n else float("nan"), "wilson_low": lo, "wilson_high": hi})
    return pd.DataFrame(rows, columns=["item", "question", "model", "yes", "no", "n", "rate", "wilson_low", "wilson_high"])


def cochran(db) -> pd.DataFrame:
    from statsmodels.stats.contingency_tables import cochrans_q

    protocol = _protocol(db)
    answers = _query(db, "select code, model, item, answer from answers")
    rows = []
    for q in protocol.items:
        wide = answers_wide(answers, q, list(protocol.conditions))
        if len(wide) >= 2 and len(protocol.conditions) >= 2:
            r = cochrans_q(wide.to_numpy(dtype=int))
            q_stat, p = float(r.statistic), float(r.pvalue)
            if not np.isfinite(q_stat):  # every participant answered alike across models
                q_stat, p = 0.0, 1.0
            rows.append({"item": q, "cochran_q": q_stat, "df": len(protocol.conditions) - 1, "p_value": p, "n_complete": len(wide)})
        else:
            rows.append({"item": q, "cochran_q": float("nan"), "df": len(protocol.conditions) - 1, "p_value": float("nan"), "n_complete": len(wide)})
    return pd.DataFrame(rows, columns=["item", "cochran_q", "df", "p_value", "n_complete"])


def deformation(db) -> pd.DataFrame:
    protocol = _protocol(db)
    lat = _query(db, "select model, value from latency where measure = 'deformation_ms'")
    rows = []
    for m in protocol.conditions:
        v = lat.loc[lat["model"] == m, "value"].to_numpy()
        rows.append({"model": m, "n_trials": len(v), "mean_ms": float(v.mean()) if len(v) else float("nan"),
                     "sd_ms": float(v.std(ddof=1)) if len(v) > 1 else float("nan"),
                     "median_ms": float(np.median(v)) if len(v) else float("nan"),
                     "p95_ms": float(np.percentile(v, 95)) if len(v) else float("nan")})
    return pd.DataFrame(rows, columns=["model", "n_trials", "mean_ms", "sd_ms", "median_ms", "p95_ms"])


def study_facts(db) -> dict:
    protocol = _protocol(db)
    con = _connect(db)
    try:
        n = con.execute("select count(distinct code) from answers").fetchone()[0]
        # counted from the answers' own source, not from a participant flag that could drift
        synthetic = con.execute("select count(distinct code) from answers where source = 'synthetic'").fetchone()[0]
        mixed = [r[0] for r in con.execute(
            "select code from answers group by code having sum(source = 'synthetic') > 0 and sum(source != 'synthetic') > 0 order by code")]
    finally:
        con.close()
    return {"study": protocol.name, "participants": n, "synthetic_participants": synthetic, "mixed_source_participants": mixed,
            "synthetic": synthetic > 0,
            "design": f"within-subject, {len(protocol.conditions)} models, {protocol.counterbalancing} counterbalancing"}


def item_rows(r, q, models):
    """Per question, in table order: (item, question text, its rate row for each of `models`,
    its Cochran's Q row). The Markdown, LaTeX and HTML tables all render these."""
    for item, g in r.groupby("item", sort=False):
        g = g.set_index("model")
        yield item, g["question"].iloc[0], [g.loc[m] for m in models], q[q["item"] == item].iloc[0]


def markdown(db) -> str:
    """Table 1 as Markdown: counts, rate [Wilson 95%] per model, Cochran's Q per item, and the
    deformation-time row, headed by N, the design and a synthetic-data flag."""
    from analysis.stats import study_stats

    facts, r, q, d = study_facts(db), rates(db), cochran(db), deformation(db)
    pairs = {item: v["pairs"] for item, v in study_stats(db, r, q)["items"].items()}
    models = list(d["model"])
    flag = "SYNTHETIC DATA (simulated participants): not evidence about people. " if facts["synthetic"] else ""
    if facts["mixed_source_participants"]:
        flag += f"WARNING: {', '.join(facts['mixed_source_participants'])} answered both as a person and synthetically. "
    lines = [
        f"**Table 1: {facts['study']}.** {flag}N = {facts['participants']} participants; {facts['design']}.",
        "",
        "| Question | " + " | ".join(f"{m}: yes/no, rate [95% CI]" for m in models) + " | Cochran's Q (p) | McNemar p, Holm |",
        "|---|" + "---|" * len(models) + "---|---|",
    ]
    for item, question, rows, qrow in item_rows(r, q, models):
        cells = [f"{row['yes']}/{row['no']}, {row['rate']:.1%} [{row['wilson_low']:.1%}, {row['wilson_high']:.1%}]" for row in rows]
        mc = "; ".join(f"{p['a']}-{p['b']} {p['p_holm']:.3g}" for p in pairs.get(item, []))
        lines.append(f"| {question} | " + " | ".join(cells) + f" | {qrow['cochran_q']:.2f} ({qrow['p_value']:.3g}) | {mc} |")
    cells = [f"{row['mean_ms']:.2f} +- {row['sd_ms']:.2f} (median {row['median_ms']:.2f}, p95 {row['p95_ms']:.2f})" for _, row in d.iterrows()]
    lines.append("| Time for real-time deformation of the model, ms | " + " | ".join(cells) + " | | |")
    lines += ["", "Rates with Wilson 95% intervals; Cochran's Q across the models for participants who answered all of them; "
              "pairwise exact McNemar tests, Holm-adjusted."]
    return "\n".join(lines) + "\n"
