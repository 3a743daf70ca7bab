"""The accuracy bench's tables and files (`analysis.verification.accuracy.run_accuracy`'s result): the
Markdown, LaTeX, CSV and JSON outputs, the Pareto plot, and the held-out samples per displacement
and per force band."""

from __future__ import annotations

import json
import math
from pathlib import Path

import pandas as pd

from analysis.reports.formatting import rate_interval, shown
from analysis.reports.plots import pareto_plot
from analysis.reports.table import Table, latex_tables, markdown_grid
from analysis.verification.accuracy import MIN_DECIDED, QUICK_REASON, RATE_HALF_WIDTH, TARGET_WITHIN, class_best
from analysis.verification.paper import deformation_words
from analysis.verification.tissue_pulls import describe_no_reference
from analysis.verification.truth_in_time import QUASI_STATIC
from sim.jsonable import jsonable
from sim.text import counted


def within_text(r: dict, short: bool = False) -> str:
    """A row's within-JND rate with its interval over the decided samples it is a rate of
    ("84% [75%, 91%] of 77"), or, below `MIN_DECIDED`, the counts and why no rate is given
    (`short`: "1/1, too few (1 < 39)", for a terminal's narrow column)."""
    n, k = r["n_test"], r.get("n_within_jnd", round(r["within_jnd"] * r["n_test"]) if r["n_test"] else 0)
    if n < MIN_DECIDED:
        if short:
            return f"{k}/{n}, too few ({n} < {MIN_DECIDED})"
        return f"{k} of {n} within; no rate: too few decided samples ({n} < {MIN_DECIDED})"
    return f"{rate_interval(r['within_jnd'], r['within_jnd_low'], r['within_jnd_high'], 0)} of {n}"


def error_text(r: dict) -> str:
    """A row's force error over decided samples ("12.0% / 31.0%", mean / max), or, with none
    decided, its error against the truth beyond the data, said so."""
    if r["force_error"] is not None and math.isfinite(r["force_error"]):
        return f"{shown(r['force_error'], '.1%')} / {shown(r['force_error_max'], '.1%')}"
    beyond = r.get("force_error_extrapolated")
    return f"- (beyond the data: {shown(beyond, '.1%')}, not a verdict)" if beyond is not None and math.isfinite(beyond) else "-"


def truth_counts(r: dict) -> str:
    """"decided / extrapolated / undecided" over a row's held-out samples, and those with no reference."""
    none = r.get("no_reference", 0)
    return f"{r['n_test']} / {r['extrapolated']} / {r['truth_undecided']}" + (f" (+{none} without a reference)" if none else "")


def meets_text(b: dict) -> str:
    """A class's "meets target": yes, no, or no verdict (too few decided samples)."""
    return "no verdict" if b["meets_target"] is None else "yes" if b["meets_target"] else "no"


def verdict_rule() -> str:
    return (f"A rate, a verdict or \"meets target\" needs at least {MIN_DECIDED} decided held-out samples (then every Wilson 95% "
            f"interval is at most +-{RATE_HALF_WIDTH:.0%}); below, a row shows its counts only.")


def in_time_words(meta: dict) -> str:
    """What the truth at each speed in time rests on and what it decided (`truth_in_time`'s meta)."""
    out = []
    for name, t in meta["reference"].get("in_time", {}).items():
        left = ", ".join(f"{n} {why}" for why, n in t["left_by"].items() if n)
        rate = t["strain_rate_median_per_s"]
        over = t["over_timeless"]
        halted = ", ".join(f"{pull} at {h['mm']:g} mm, {h['s']:.3g} s ({h['reason']})" for pull, h in t.get("pulls_stopped", {}).items())
        out.append(f"At the {name} speed ({t['speed_m_s'] * 1e3:.3g} mm/s, held {', '.join(f'{h:g}' for h in t['holds_s'])} s) the truth is the "
                   f"viscoelastic brain ({'; '.join(t['law'])}) on the {t['mesh_mm']:g} mm mesh, {t['pulls_solved']} of {t['pulls']} pulls solved: "
                   f"{t['decided']} of {t['samples']} samples decided" + (f" ({left})" if left else "")
                   + (f"; stopped, with no truth beyond: {halted}" if halted else "")
                   + (f"; the tissue's power-weighted median strain rate {rate[0]:.2g} to {rate[1]:.2g}/s against the data's "
                      f"{' and '.join(f'{r:.2g}' for r in t['data_rate_per_s'])}/s (grey, white)" if rate else "")
                   + (f"; forces {over[0]:.2g} to {over[1]:.2g} x the timeless truth's" if over else "") + ".")
    return " ".join(out)


def intro(result: dict) -> str:
    m = result["meta"]
    ref = m["reference"]

    gone = ref.get("no_reference") or []
    lost = sum(g['samples'] for g in gone)
    missing = (f" {counted(lost, 'sample')} {'has' if lost == 1 else 'have'} no reference and {'is' if lost == 1 else 'are'} not judged: "
               f"{describe_no_reference(gone)}.") if gone else ""
    n = ref.get("samples", {})
    ens = "; ".join(f"{e['name']} (uniaxial {e['rms_rel_uniaxial']:.1%}, worst shear {e['shear_worst_rel']:.1%})" for e in ref.get("ensemble", []))
    decided = (f" The truth's laws: {ens}. Within-JND rates are over the held-out samples where the truth is decided "
               f"({ref.get('test_decided', 0)}; over every pull, {n.get('decided', 0)} decided, {n.get('extrapolated', 0)} extrapolated, "
               f"{n.get('undecided', 0)} undecided): {ref.get('decided_rule', '')}.") if n else ""
    return (f"Reference: {ref['setting']} ({ref['formulation']}; band (mesh and law) median {ref['band_rel_median']:.1%}, "
            f"largest {ref['band_rel_max']:.1%}).{decided}{missing} {len(m['calibration_pulls'])} calibration pulls and {len(m['test_pulls'])} held-out test "
            f"pulls to {m['max_pull_m'] * 1e3:g} mm at {m['pull_speed_m_per_s'] * 1e3:g} mm/s, {m['samples_per_pull']} samples each; "
            f"the linear models' E = {m['young_pa'] / 1e3:.3g} kPa (scene: {m['scene_young_pa'] / 1e3:.3g} kPa)" + (" (quick bench)" if m["quick"] else "") + ". "
            + verdict_rule() + (f" The quick bench is a smoke run: it decides nothing ({QUICK_REASON})." if m["quick"] else "")
            + (" " + in_time_words(m) if ref.get("in_time") else ""))


def tables(result: dict) -> list[Table]:
    """The accuracy table (every configuration, raw and calibrated) and each class at its best:
    what the Markdown, the LaTeX and the HTML print."""
    rows = [[r["model"], r["setting"], r["calibration"], r.get("speed", ""), shown(r["scale"], ".3g"),
             error_text(r), within_text(r), truth_counts(r),
             f"{r['within']} / {r['outside']} / {r['undecided']}", f"{r['pulls_within']}/{r['n_test_pulls']}", str(r["unstable_pulls"]),
             f"{shown(r['angle_deg'], '.1f')} / {shown(r['angle_deg_max'], '.1f')} deg", f"{r['tick_us']:.2f} us / {r['frame_ms']:.3g} ms"]
            for r in result["rows"]]
    best = []
    for b in class_best(result["rows"], quick=bool(result["meta"].get("quick"))):
        left = "; ".join(f"{k}: {v}" for k, v in b["left_out"].items()) or "none"
        if b["setting"] is None:
            best.append([b["model"], b.get("speed", ""), b["calibration"], f"none ({b['why']})", "", "", "", "", meets_text(b), left])
            continue
        best.append([b["model"], b.get("speed", ""), b["calibration"], b["setting"],
                     within_text(b), f"{b['force_error']:.1%}",
                     f"{b['pulls_within']}/{b['n_test_pulls']}", f"{b['frame_ms']:.3g} / {b['frame_ms_p99']:.3g} ms",
                     meets_text(b), left])
    return [Table(title="Model error against run time", columns=["model", "setting", "calibration", "speed", "scale", "force error (mean / max)",
                                                                   "within JND [95% CI] of decided", "truth decided / extrapolated / undecided",
                                                                   "within / outside / undecided", "whole pulls within",
                                                                   "unstable pulls", "direction error (mean / max)", "tick / frame"],
                  rows=rows, notes=intro(result)),
            Table(title="Each class at its best", columns=["model", "speed", "calibration", "best setting", "within JND [95% CI] of decided", "force error",
                                                            "whole pulls within", "frame (p50 / p99)", "meets target", "left out"],
                  rows=best, notes=f"The most samples within the JND among the configurations whose frame p99 keeps the budget, "
                                   f"that gave up no pull and that have at least {MIN_DECIDED} decided samples; the target is {TARGET_WITHIN:.0%}.")]


def markdown(result: dict) -> str:
    """The accuracy table as Markdown (test pulls only), with what it was measured against."""
    every, best = tables(result)
    lines = [intro(result), "", *markdown_grid(every)]
    lines += ["", f"Each class at its best (`class_best`: the most samples within the JND among the configurations whose frame p99 keeps "
              f"the budget, that gave up no pull and that have at least {MIN_DECIDED} decided samples; the target is {TARGET_WITHIN:.0%}):", "", *markdown_grid(best)]
    cb = result["meta"].get("coupling_bound")
    if cb:
        lines += ["", f"The mass-spring renders through its hand coupling: the tissue's own forces behind it (an exact model) are within "
                      f"the JND on {cb['scene']:.0%} of the samples at the scene's {cb['scene_n_per_m']:g} N/m and {cb['omni_max']:.0%} at "
                      f"{cb['omni_max_n_per_m']:g} N/m, the stiffest an Omni renders stably at 1 kHz (`coupling_bound`)."]
    for key, by, title in (("by_displacement", "displacement_mm", "displacement (mm)"), ("by_force_band", "force_band", "reference force")):
        lines += ["", f"Held-out samples per {title}: within the JND / decided (extrapolated, undecided):", "",
                  *markdown_grid(breakdown_table(result[key], by))]
    lines += ["", f"Seed paper, deformation time per frame on its 2014 PC: {deformation_words()}."]
    return "\n".join(lines) + "\n"


def breakdown_table(rows: list[dict], by: str) -> Table:
    """`analysis.verification.accuracy.breakdown`'s rows as a table: one row per configuration, speed and calibration,
    one column per group ("k/n (e, u)")."""
    groups = list(dict.fromkeys(r[by] for r in rows))
    if by == "displacement_mm":
        groups.sort()
    table: dict = {}
    for r in rows:
        table.setdefault((r["model"], r["setting"], r.get("speed", ""), r["calibration"]), {})[r[by]] = r
    cols = ["model", "setting", "speed", "calibration"] + [f"{g:g}" if isinstance(g, float) else str(g) for g in groups]
    out = []
    for (model, setting, speed, calibration), cells in table.items():
        out.append([model, setting, speed, calibration] + [f"{c['within']}/{c['decided']} ({c['extrapolated']}, {c['undecided']})" if (c := cells.get(g)) else ""
                                                    for g in groups])
    return Table(columns=cols, rows=out)


def pareto_rows(result: dict) -> list[dict]:
    """What the Pareto plot shows: the raw rows against the timeless truth (every speed's frame
    costs the same; at the hands' speeds the truth is not decided)."""
    return [r for r in result["rows"] if r["calibration"] == "raw" and r.get("speed", QUASI_STATIC) == QUASI_STATIC]


def write_outputs(result: dict, out_dir) -> list[Path]:
    """accuracy.json, accuracy.csv, samples.csv, accuracy.md, accuracy.tex (its tables as LaTeX), pareto.png and .svg."""

    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    files = [out / "accuracy.json", out / "accuracy.csv", out / "samples.csv", out / "accuracy.md"]
    files[0].write_text(json.dumps(jsonable(result), indent=2))
    pd.DataFrame(result["rows"]).to_csv(files[1], index=False)
    pd.DataFrame(result["samples"]).to_csv(files[2], index=False)
    files[3].write_text(markdown(result))
    files.append(out / "accuracy.tex")
    files[4].write_text(latex_tables(tables(result), "tab:accuracy"))
    for ext in ("png", "svg"):
        pareto_plot(pareto_rows(result), out / f"pareto.{ext}", reference=result["meta"]["reference"]["setting"])
        files.append(out / f"pareto.{ext}")
    return files
