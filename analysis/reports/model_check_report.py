"""`studyctl model check`'s words: each stage's one-line summary as the check goes, and the
scorecard as Markdown (analysis.verification.model_check.check_model makes the card)."""

from __future__ import annotations

from analysis.reports.accuracy_tables import within_text
from analysis.reports.formatting import shown
from analysis.reports.table import Table, markdown_grid
from analysis.verification.model_check import STAGES

_OK = {True: "yes", False: "**no**", None: "not run"}


def _speed_text(row: dict) -> str:
    """"typical (14.2 mm/s)": the truth's speed and the hand's (a card made before speeds: quasi-static)."""
    v = row.get("speed_m_s")
    return f"{row.get('speed', 'quasi-static')}" + (f" (hand {v * 1e3:.3g} mm/s)" if v else "")


def _held(result) -> str:
    rows = result[0]
    skipped = sum(r["ok"] is None for r in rows)
    return f"{sum(r['ok'] is True for r in rows)} of {len(rows)} checks held" + (f", {skipped} not run" if skipped else "")


def stage_summary(key: str, result) -> str:
    """A finished stage's result in one line, as the check prints it."""
    if key == "contract":
        return _held(result)
    if key == "budgets":
        return f"{sum(b['ok'] for b in result)} of {len(result)} within"
    if key == "stability":
        return ", ".join(f"{v} {k}" for k, v in result["counts"].items())
    return ", ".join(f"{x['calibration']} {within_text(x)} within the JND" if x["n_test"] else f"{x['calibration']}: no decided sample"
                     for x in result["rows"])


def scorecard_md(card: dict) -> str:
    """The scorecard as Markdown."""
    src = f"{card['distribution']} {card['version']}" if card["distribution"] else "the Python path"
    lines = [f"# Model check: {card['model']}", "", f"{card['description']} (`{card['class']}`, from {src}; model API {card['api_version']}).",
             f"Scene: {card['scene']}.", "", "## Contract", ""]
    lines += markdown_grid(Table(columns=["check", "ok", "detail"],
                                 rows=[[r["check"], _OK[r["ok"]], r["detail"]] for r in card["contract"]]))
    if card["budgets"]:
        lines += ["", "## Budgets (this machine, 99th percentile per call)", ""]
        lines += markdown_grid(Table(columns=["budget", "p99", "median", "limit", "ok"],
                                     rows=[[b["budget"], f"{b['value']:.3g}", f"{b['median']:.3g}", f"{b['limit']:g}", "yes" if b["ok"] else "**no**"]
                                           for b in card["budgets"]]))
    if card.get("stability"):
        s = card["stability"]
        lines += ["", "## Stability (quick sweep)", "", ", ".join(f"{v} {k}" for k, v in s["counts"].items())
                  + ("; the safety layer held (no NaN, nothing above the peak force sent)" if s["safety_held"] else "; **the safety layer let a NaN or an over-limit force through**"),
                  ""]
        lines += markdown_grid(Table(columns=["case", "outcome", "reason"],
                                     rows=[[f"{r['model']} {r['case']}", r["outcome"], r["reason"][:100]] for r in s["cases"]]))
    if card.get("accuracy"):
        a = card["accuracy"]
        lines += ["", f"## Accuracy against the tissue truth ({a['reference']}{', quick' if a['quick'] else ''})", ""]
        lines += markdown_grid(Table(
            columns=["setting", "speed", "calibration", "scale", "within the JND (95% CI), decided test samples", "truth extrapolated / undecided",
                     "error where extrapolated (not a verdict)", "frame ms"],
            rows=[[r["setting"], _speed_text(r), r["calibration"], shown(r["scale"], ".3g"),
                   within_text(r) if r["n_test"]
                   else "none: the truth is decided at no held-out sample",
                   f"{r.get('extrapolated', 0)} / {r.get('truth_undecided', 0)}", shown(r.get("force_error_extrapolated"), ".1%"),
                   f"{r['frame_ms']:.3g}"] for r in a["rows"]]))
    lines += ["", "## Verdict", ""]
    if card.get("interrupted"):
        lines += [f"INTERRUPTED during {STAGES[card['interrupted']]}: the stages above finished, the rest were not run.", ""]
    if card.get("interrupted") in ("contract", "budgets"):
        lines += ["No verdict: the contract and the budgets did not finish."]
    else:
        lines += [f"- VIOLATION {v}" for v in card["violations"]] or ["The model keeps the contract and its budgets on this machine."]
    if card.get("skipped"):
        lines.append(f"\n{card['skipped']}.")
    return "\n".join(lines) + "\n"
