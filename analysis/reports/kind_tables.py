"""The statistics of every kind of answer beyond yes/no (analysis.statistics.kinds.kind_stats) as report
tables and sentences: per rating item, score and choice its table, the questions asked once at
the end, the logistic GEE and the primary analysis in words."""

from __future__ import annotations

import numpy as np

from analysis.reports.formatting import p_value, rate_interval
from analysis.reports.table import Table
from analysis.statistics.faults import is_withheld
from analysis.statistics.kind_results import KindStats
from analysis.statistics.result_records import EndRate, Friedman, GeeFit, OrdinalGeeFit, RankPair, Summary
from analysis.statistics.study_results import LogisticGee, StudyStats
from sim.text import counted


def _p(x) -> str:  # the shared p-value, with n/a where a test gave none
    return p_value(x, missing="n/a")


def _rho_text(fit: GeeFit) -> str:
    """A GEE's exchangeable working correlation, or why there is none (never a bare nan)."""
    rho = fit.working_correlation
    # a fit flagged not estimable or not converged gives a number that means nothing: its reason instead,
    # the same one the sentence's NOT ESTIMABLE OR NOT CONVERGED names
    if fit.estimable and fit.converged and rho is not None and np.isfinite(rho):
        return f"{rho:.2f}"
    why = fit.problems or (["no convergence"] if not fit.converged else ["the fit gave none"])
    return "not estimated: " + "; ".join(why)


def gee_line(gee: LogisticGee, primary: bool = True) -> str:
    """The logistic GEE across the yes/no questions as a sentence: the primary analysis unless
    the protocol has rating items (analysis.statistics.kinds.primary)."""
    c = gee.composite
    if not c or not c.pairs:
        return ""
    pairs = "; ".join(f"{p.b} vs {p.a} OR {p.odds_ratio:.2f} [{p.ci_low:.2f}, {p.ci_high:.2f}], p_Holm {p_value(p.p_holm)}"
                      if p.estimable else f"{p.b} vs {p.a} not estimable" for p in c.pairs)
    return (f"{'Primary analysis, all questions' if primary else 'Across the yes/no questions'}: logistic GEE `{c.formula}`, participants as clusters, exchangeable "
            f"working correlation ({_rho_text(c)}), robust standard errors"
            f"{'' if c.converged else ' (NOT ESTIMABLE OR NOT CONVERGED: ' + '; '.join(c.problems or ['no convergence']) + ')'}: {pairs}.")


def primary_line(st: StudyStats) -> str:
    """The protocol's primary analysis and its result, as a sentence."""

    k = st.kinds
    what = k.primary
    if what.analysis == "ordinal_gee":
        return ordinalgee_line(k.ordinal_gee)
    if what.analysis == "logistic_gee":
        return gee_line(st.gee).replace("`", "")
    if what.analysis == "mixed_model" and what.items[0] in k.scores:
        v = k.scores[what.items[0]]
        pairs = "; ".join(f"{p.b} - {p.a} {p.difference:+.2f}{_ci(p.ci_low, p.ci_high, '{:+.2f}')}, "
                          f"p_Holm {_p(p.p_holm_primary)}" if p.estimable else f"{p.b} - {p.a} not estimable"
                          for p in v.pairs)
        holm = "one pair: no Holm correction" if len(v.pairs) == 1 else "Holm over its " + counted(len(v.pairs), "pair")
        return f"Primary analysis: {what.text}: {pairs} ({holm})."
    if what.analysis == "choice" and what.items[0] in k.choices:
        ov = k.choices[what.items[0]].overall
        return (f"Primary analysis: {what.text}: not tested ({ov.reason})." if ov.reason else
                f"Primary analysis: {what.text}: p = {_p(ov.p_value)} ({ov.test}).")
    return f"Primary analysis: {what.text}: not computed."


def _ci(lo, hi, fmt="{:.2f}") -> str:
    return "" if lo is None or not (np.isfinite(lo) and np.isfinite(hi)) else f" [{fmt.format(lo)}, {fmt.format(hi)}]"


def _friedman_cell(fr: Friedman, with_w: bool = False) -> str:
    if not np.isfinite(fr.statistic):
        return f"n/a ({fr.reason or 'not run'})"
    w = f", W {fr.kendall_w:.2f}{_ci(fr.kendall_w_low, fr.kendall_w_high)}" if with_w and np.isfinite(fr.kendall_w) else ""
    return f"{fr.statistic:.2f} ({_p(fr.p_value)}){w}"


def _mean_cell(c: Summary, fmt: str) -> str:
    """A mean with its interval, or with why it has none."""
    if not c.n:
        return "n/a (no values)"
    ci = _ci(c.ci_low, c.ci_high, fmt)
    return fmt.format(c.mean) + (ci or (f" ({c.ci_reason})" if c.ci_reason else ""))


def _rank_pair_cell(p: RankPair) -> str:
    """A Wilcoxon pair: its Holm p and rank-biserial r [CI], or why it was not tested."""
    r = "" if not np.isfinite(p.rank_biserial) else f"r {p.rank_biserial:.2f}{_ci(p.rb_ci_low, p.rb_ci_high)}"
    if not np.isfinite(p.p_value):
        return f"{p.a}-{p.b} not tested: {p.reason or 'not run'}" + (f" ({r})" if r else "")
    warn = f"; {p.warning}" if p.warning else ""
    return f"{p.a}-{p.b} {_p(p.p_holm)} ({r}{warn})"


def ordinalgee_line(res: OrdinalGeeFit | None) -> str:
    """The primary analysis of the ratings, as a sentence."""
    if not res or not res.pairs:
        return ""
    pairs = "; ".join(f"{p.b} vs {p.a} OR {p.odds_ratio:.2f}{_ci(p.ci_low, p.ci_high)}, p_Holm {_p(p.p_holm)}"
                      if p.estimable else f"{p.b} vs {p.a} not estimable" for p in res.pairs)
    state = "" if res.converged else " (NOT ESTIMABLE OR NOT CONVERGED: " + "; ".join(res.problems or ["no convergence"]) + ")"
    return (f"Primary analysis, all rating items: proportional-odds GEE {res.formula}, participants as clusters, "
            f"{res.working_dependence} working dependence, {res.covariance}{state}: {pairs} "
            "(odds of a higher rating with the second condition).")


def kind_tables(kinds: KindStats, models: list[str], scope: str) -> list[Table]:
    """The tables of every kind beyond yes/no: what the Markdown, LaTeX and HTML reports render alike."""
    out = []
    if kinds.ratings:
        rows = []
        for v in kinds.ratings.values():
            cells = [f"{c.median:g} [{c.q1:g}, {c.q3:g}]" for c in (v.conditions[m] for m in models)]
            pairs = "; ".join(_rank_pair_cell(p) for p in v.pairs) or "n/a (one condition)"
            rows.append([v.question, *cells, _friedman_cell(v.friedman, with_w=True), pairs])
        points = sorted({v.points for v in kinds.ratings.values()})
        out.append(Table(title="Ratings", columns=["Question", *(f"{m}: median [IQR]" for m in models), "Friedman chi2 (p), Kendall's W [95% CI]",
                                                  f"Wilcoxon p, {scope} (rank-biserial r [95% CI])"], rows=rows,
                    notes=f"{'/'.join(map(str, points))}-point ratings (1 = the low anchor). Friedman across the conditions (tie-corrected); "
                            "Wilcoxon signed-rank pairs; interval of r: BCa bootstrap over participants, of W: percentile bootstrap (W is bounded at 0, where BCa fails). "
                            + ordinalgee_line(kinds.ordinal_gee)))
    if kinds.scores:
        rows = []
        for v in kinds.scores.values():
            cells = [_mean_cell(c, "{:.1f}") for c in (v.conditions[m] for m in models)]
            test = v.mixed_model.model_test
            pairs = "; ".join(f"{p.b}-{p.a} {p.difference:+.1f}{_ci(p.ci_low, p.ci_high, '{:+.1f}')}, p {_p(p.p_holm)}"
                              if p.estimable else f"{p.b}-{p.a} not estimable" for p in v.pairs)
            rows.append([v.label, *cells, f"F({test.df}, {test.df_denominator}) = {test.f:.2f} ({_p(test.p_value_f)})"
                         if np.isfinite(test.f) else f"n/a ({test.reason or 'not estimable'})",
                         pairs or "n/a (one condition)", _friedman_cell(v.friedman)])
        out.append(Table(title="Scores", columns=["Score", *(f"{m}: mean [95% CI]" for m in models), "Mixed model: condition (p)",
                                                 f"Difference [95% CI], p {scope}", "Friedman chi2 (p)"], rows=rows,
                    notes="Linear mixed model (REML) answer ~ condition + period + (1 | participant): the condition's Wald F test and "
                            "pairwise differences (t intervals, between-within df); Friedman as the non-parametric check. SUS: Brooke (1996), 0-100; "
                            "raw NASA-TLX: the mean of its six subscales, 0-100 (Hart 2006)."))
    for v in kinds.choices.values():
        ov = v.overall
        rows = [[m, f"{s.count}", rate_interval(s.share, s.wilson_low, s.wilson_high, 0)] for m, s in v.shares.items()]
        pairs = "; ".join(f"{p.a}-{p.b} {p.n_a}:{p.n_b}, " + (f"not tested ({p.reason})" if is_withheld(p.reason) else f"p {_p(p.p_holm)}")
                          for p in v.pairs)
        out.append(Table(title=f"Choice: {v.question}", columns=["Condition", "Chosen by", "Share [Wilson 95%]"], rows=rows,
                    notes=(f"{ov.test}: not tested ({ov.reason}); " if ov.reason else
                           f"{ov.test}: p = {_p(ov.p_value)} (chi2 = {ov.statistic:.2f}, {ov.df} df; equal chances); ")
                          + f"exact binomial pairs, {scope}: {pairs}."))
    if kinds.session:
        rows = []
        for v in kinds.session.values():
            if isinstance(v, EndRate):
                rows.append([v.question, f"{v.yes}/{v.n} yes, {rate_interval(v.rate, v.wilson_low, v.wilson_high, 0)}"])
            else:
                rows.append([v.question, f"mean {_mean_cell(v, '{:.2f}')}, median {v.median:g} [{v.q1:g}, {v.q3:g}]"
                             if v.n else "no answers"])
        out.append(Table(title="Asked once at the end", columns=["Question", "Answers"], rows=rows,
                    notes="About the whole session, not one condition: described, not tested."))
    return out
