"""The stability sweep's report (`studyctl bench stability`): its counts, the cases that were not
stable, the near-chatter ones, and the files it writes (JSON, Markdown, the heat map)."""

from __future__ import annotations

import json
from pathlib import Path

import pandas as pd

from analysis.reports.plots import stability_heatmap
from analysis.reports.table import Table, markdown_grid
from analysis.verification.stability import CHATTER_REVERSALS, CHATTER_WINDOW_S, NEAR_CHATTER, outcome_grid


def counts_text(result: dict) -> str:
    """The sweep in one sentence: its cases, how many were stable, refused, unstable, and what reached a device."""
    m = result["meta"]
    c = m["counts"]
    return (f"{len(result['cases'])} cases ({'quick' if m['quick'] else 'full'} sweep, {m['resolution_m'] * 1e3:g} mm meshes, "
            f"{m['duration_s']:g} s each): {c['stable']} stable, {c['refused']} refused, {c['unstable']} unstable; "
            f"NaN sent to a device: {m['nan_sent']}, over-limit force sent: {m['over_limit_sent']}.")


def unstable_table(result: dict) -> Table:
    """Every case that was not stable, with when it was caught and why."""
    return Table(columns=["model", "case", "outcome", "at", "reason"],
                 rows=[[r["model"], r["case"], r["outcome"], f"{r['detected_at_s']:.3f} s" if r["detected_at_s"] is not None else "", r["reason"]]
                       for r in result["cases"] if r["outcome"] != "stable"])


def near_chatter_text(result: dict) -> str:
    """The stable cases near the chatter limit, as a sentence ("" when none)."""
    near = [r for r in result["cases"] if r["outcome"] == "stable" and r.get("peak_reversals", 0) >= NEAR_CHATTER]
    if not near:
        return ""
    return (f"Stable but near the chatter limit ({CHATTER_REVERSALS} force reversals within {CHATTER_WINDOW_S * 1e3:g} ms): "
            + ", ".join(f"{r['model']} {r['case']} ({r['peak_reversals']})" for r in near)
            + ". Whether such a contact chatters can turn on the last bits of the arithmetic (the CPU's BLAS kernels).")


def markdown(result: dict) -> str:
    """Counts, then every case that was not stable with its reason."""
    near = near_chatter_text(result)
    return "\n".join([counts_text(result), "", *markdown_grid(unstable_table(result)), *(["", near] if near else [])]) + "\n"


def write_outputs(result: dict, out_dir) -> list[Path]:
    """stability.json, stability.csv, stability.md, heatmap.png and .svg."""

    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    files = [out / "stability.json", out / "stability.csv", out / "stability.md"]
    files[0].write_text(json.dumps(result, indent=2, default=float))
    pd.DataFrame(result["cases"]).drop(columns=["events"]).to_csv(files[1], index=False)
    files[2].write_text(markdown(result))
    for ext in ("png", "svg"):
        stability_heatmap(outcome_grid(result["cases"]), out / f"heatmap.{ext}")
        files.append(out / f"heatmap.{ext}")
    return files
