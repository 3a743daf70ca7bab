"""The methods and results paragraphs of a study, written from the results that `studyctl report
stats --json` prints (analysis.statistics.study_results.StudyStats: its `methods` and its statistics), never
from numbers retyped: each number in the text is a value of that JSON at the printed precision, in APA 7 style (p = .066, p < .001,
no leading zero for values that cannot exceed 1, two decimals for test statistics, 95% CI [a, b]).
Synthetic data is said first; a statistic the reports withhold is withheld here with the same
reason. Markdown, or LaTeX through analysis/reports/latex.py's escaping."""

from __future__ import annotations

import json
import math
import numbers
from collections.abc import Mapping

from analysis.discrimination.jnd import jnd_results
from analysis.reports import latex
from analysis.reports.fault_tables import events_text
from analysis.statistics.faults import ConditionEvents
from analysis.statistics.kind_results import KindStats
from analysis.statistics.methods import StudyMethods
from analysis.statistics.result_records import EndSummary
from analysis.statistics.study_results import StudyStats
from analysis.statistics.study_stats import study_stats
from analysis.study.questions import LATENCY_MEASURES, Kind
from analysis.study.study_snapshot import Study
from sim.jsonable import jsonable
from sim.text import counted

KIND_WORDS = {Kind.YES_NO: "yes/no question", Kind.LIKERT: "rating", Kind.VAS: "visual analogue scale", Kind.CHOICE: "choice among the conditions"}
WHEN_WORDS = {"condition": "after each condition", "trial": "after each trial", "end": "once, after the last condition"}
SIGNIFICANT = 0.05  # which pairwise tests the results name (after Holm); the rest are counted


def _finite(x) -> bool:
    return isinstance(x, numbers.Real) and not isinstance(x, bool) and x == x and abs(x) != float("inf")


def p_text(p) -> str | None:
    """'p = .066', 'p < .001' (APA 7), or None when there is no p."""
    if not _finite(p):
        return None
    return "p < .001" if p < 0.0005 else "p = " + f"{p:.3f}".lstrip("0")


def unit(x, decimals: int = 2) -> str:
    """A value that cannot exceed 1 in magnitude, without its leading zero (W = .07, r = -.31)."""
    s = f"{x:.{decimals}f}"
    return s.replace("0.", ".", 1)


def pct(x) -> str:
    return f"{100 * x:.1f}%"


def sig(x, digits: int = 3) -> str:
    """`digits` significant digits, without an exponent (deformation times of 0.00418 ms)."""
    if x == 0:
        return "0"
    decimals = max(digits - 1 - math.floor(math.log10(abs(x))), 0)
    return f"{x:.{decimals}f}"


def _names(xs) -> str:
    xs = list(xs)
    if not xs:
        return "none"
    return xs[0] if len(xs) == 1 else ", ".join(xs[:-1]) + (", and " if len(xs) > 2 else " and ") + xs[-1]


def _pairs_text(pairs, describe, what: str, family: str) -> str:
    """The pairs (analysis/statistics/result_records.py) significant after Holm, each described; the others
    counted; untested ones with why."""
    tested = [p for p in pairs if _finite(p.p_value)]
    untested = [p for p in pairs if not _finite(p.p_value)]
    shown = [p for p in tested if _finite(p.p_holm) and p.p_holm < SIGNIFICANT]
    out = []
    if shown:
        out.append(f"{what} differing after Holm's correction ({family}): "
                   + "; ".join(f"{describe(p)}, {p_text(p.p_value)}, Holm-corrected {p_text(p.p_holm)}"
                               for p in shown) + ".")
    elif tested:
        out.append(f"No {what.lower()} differed after Holm's correction ({family}).")
    for p in untested:
        out.append(f"{p.a} vs {p.b} was not tested: {p.reason or 'not estimable'}.")
    return " ".join(out)


def _participants(m: StudyMethods, flag: str) -> str:
    p = m.participants
    who = ("synthetic participants simulated by the platform, not people" if p.synthetic_participants and not p.person_participants
           else "people" if not p.synthetic_participants
           else f"{counted(p.person_participants, 'person')} and {counted(p.synthetic_participants, 'synthetic participant')}, pooled")
    asked = m.procedure.questions or m.procedure.instruments
    did = "answered every question for every condition" if asked else "took part in the discrimination task"
    text = (f"{flag + ' ' if flag else ''}N = {counted(p.n, 'participant')} {did} "
            f"(target {p.target}; ages {p.age_min} to {p.age_max} eligible); they were {who}.")
    if p.excluded:
        k = len(p.excluded)
        text += (f" Excluded from every analysis for incomplete answers: {k} participant{'' if k == 1 else 's'} ("
                 + "; ".join(f"{x.code}: {x.answers} of {x.of} answers" for x in p.excluded) + ").")
    else:
        text += " No participant was excluded."
    if p.groups:
        text += (f" Participants were grouped by {p.groups.field}: "
                 + ", ".join(f"{v} (n = {n})" for v, n in p.groups.counts.items()) + ".")
    return text


def _design(m: StudyMethods) -> str:
    d = m.design
    if d.n_conditions == 1:
        text = f"Every participant ran one condition ({d.conditions[0]})."
    else:
        text = (f"A within-subject design compared {counted(d.n_conditions, 'condition')} ({_names(d.conditions)}), their order "
                f"counterbalanced ({d.counterbalancing}).")
    if d.trials_per_condition:
        text += (f" Each condition was run for {counted(d.trials_per_condition, 'trial')} of {d.trial_seconds:g} s, with {d.rest_seconds:g} s "
                 f"of rest between trials")
        text += "; a trial ended when its targets were reached." if d.trial_end == "targets" else "."
    if d.training_minutes:
        text += f" Training lasted {d.training_minutes:g} min."
    return text


def _apparatus(m: StudyMethods) -> str:
    a = m.apparatus
    text = ("Sessions ran with " + _names([f"{x.device} devices ({counted(x.sessions, 'session')}{', synthetic' if x.synthetic else ''})"
                                           for x in a.devices])) if a.devices else "No session has finished"
    if a.software_versions:
        text += f", on {_names(a.software_versions)}"
    text += "."
    if a.servo_rate_hz and a.visual_rate_hz:
        text += (f" The haptic servo loop ran at {_names([f'{x:g}' for x in a.servo_rate_hz])} Hz and the visual loop at "
                 f"{_names([f'{x:g}' for x in a.visual_rate_hz])} Hz.")
    for c in a.models:
        if not c.model:
            text += f" Condition {c.condition} recorded no configuration."
            continue
        options = ", ".join(f"{k} {v:g}" if _finite(v) else f"{k} {v}" for k, v in c.options.items())
        material = []
        if c.law:
            material.append(f"the {c.law} law")
        if _finite(c.young_pa):
            material.append(f"Young's modulus {sig(c.young_pa)} Pa")
        if _finite(c.poisson):
            material.append(f"Poisson's ratio {c.poisson:g}")
        src = c.source
        origin = (f" of the package {src.package} {src.version}" if src and not src.builtin and src.package
                  else f" ({src.target}, from the Python path)" if src and not src.builtin else " built into brainsim-study")
        text += (f" Condition {c.condition} ran the {c.model} model{origin}" + (f" ({options})" if options else "")
                 + (f" on the mesh {c.mesh}" if c.mesh else "") + (f", with {_names(material)}" if material else "") + ".")
    for r in a.latency:
        text += (f" Measured {LATENCY_MEASURES.get(r.measure, r.measure)} with {r.model}: mean {sig(r.mean)} over {counted(r.trials, 'trial')} "
                 f"(range {sig(r.lowest)} to {sig(r.highest)}).")
    return text


def _procedure(m: StudyMethods) -> str:
    pr = m.procedure
    parts = []
    for q in pr.questions:
        scale = ""
        if q.kind == Kind.LIKERT:
            scale = f" on a {q.points}-point scale from “{q.anchors[0]}” to “{q.anchors[1]}”"
        elif q.kind == Kind.VAS and q.anchors:
            scale = f" from “{q.anchors[0]}” to “{q.anchors[1]}”"  # KIND_WORDS names the scale
        parts.append(f"“{q.text}” ({KIND_WORDS.get(q.kind, q.kind)}{scale}, asked {WHEN_WORDS.get(q.when, q.when)})")
    text = ("Participants answered " + "; ".join(parts) + ".") if parts else ""
    for ins in pr.instruments:
        text += f" They completed the {ins.title} ({ins.source}; {ins.items} items) {WHEN_WORDS.get(ins.when, ins.when)}."
    for t in pr.tasks:
        text += (f" A {t.kind} task on {t.parameter} ran {t.trials} trials per condition by {t.method}, asking “{t.question}” "
                 f"after two {t.interval_seconds:g} s intervals, the comparison's increment over the reference from {t.low:g} to "
                 f"{t.high:g} (relative).")
    return text.strip()


def _analysis(m: StudyMethods) -> str:
    an = m.analysis
    level = f"{100 * an.ci_level:g}%"
    several = m.design.n_conditions > 1
    text = f"The primary analysis was planned as a {an.primary_text}." if an.primary_text else ""
    if m.procedure.tasks:
        text += (" Discrimination: each participant's Weber fraction per condition from a psychometric fit, and the conditions' "
                 "geometric means with t intervals on ln Weber fraction" + (", compared by a linear mixed model, the Friedman test and "
                                                                             "Holm-corrected pairs." if several else "."))
    for k in an.kinds:
        word = KIND_WORDS[k.kind].capitalize()
        text += (f" {word} answers were compared across the conditions by {k.omnibus} and between pairs of conditions by "
                 f"{k.pairs}, and described by {k.describe}." if several
                 else f" {word} answers were described by {k.describe}; with one condition, nothing was compared.")
    scope = (f"over the family of all {an.holm_family} pairwise tests run" if an.holm == "family"
             else "within each question's pairwise tests")
    if an.holm_family:
        text += f" Pairwise p-values were corrected by Holm's method {scope}."
    groups = m.participants.groups
    if groups:
        text += (f" The comparison between the {groups.field} groups (construct validity) is reported separately "
                 "(`studyctl report validity`), not here.")
    text += (" Only complete cases were analysed; intervals are "
             f"{level}. Software: " + ", ".join(f"{k} {v}" for k, v in an.software.items()) + ".")
    return text.strip()


def _yes_no(st: StudyStats, family: str) -> list[str]:
    out = []
    for v in st.items.values():
        rates = "; ".join(f"{m} {pct(r.rate)} ({r.yes} yes, {r.no} no, 95% CI [{pct(r.wilson_low)}, {pct(r.wilson_high)}])"
                          for m, r in v.rates.items())
        p = p_text(v.p_value)
        cochran = (f"Cochran's Q({v.df}) = {v.cochran_q:.2f}, {p}" if p
                   else f"Cochran's Q was not tested ({v.reason or 'not estimable'})")
        out.append(f"“{v.question}”: yes with {rates}; {cochran}. "
                   + _pairs_text(v.pairs, lambda p: f"{p.a} vs {p.b}, {p.n01} and {p.n10} discordant answers", "Pairs", family))
    return out


def _gee(fit, what: str, family: str, n_conditions: int) -> str:
    """A GEE's sentence (analysis.statistics.result_records.GeeFit or OrdinalGeeFit; None when not fitted)."""
    if not fit:
        return f"The {what} was not made: " + ("one condition: nothing to compare." if n_conditions < 2 else "no answers to fit.")
    if not fit.estimable or not fit.converged:
        return f"The {what} was not reported: {'; '.join(fit.problems) or 'it did not converge'}."
    head = f"The {what} ({fit.formula}) included {counted(fit.n_participants, 'participant')} and {counted(fit.n_answers, 'answer')}."
    return head + " " + _pairs_text(fit.pairs, lambda p: f"{p.b} relative to {p.a}, OR = {p.odds_ratio:.2f}, 95% CI [{p.ci_low:.2f}, {p.ci_high:.2f}]",
                                    "Condition pairs", family)


def _ratings(kinds: KindStats, family: str) -> list[str]:
    out = []
    for v in kinds.ratings.values():
        medians = "; ".join(f"{m} Mdn = {c.median:g} (IQR {c.q1:g} to {c.q3:g})" for m, c in v.conditions.items())
        fr = v.friedman
        p = p_text(fr.p_value)
        w_ci = (f", 95% CI [{unit(fr.kendall_w_low)}, {unit(fr.kendall_w_high)}]" if _finite(fr.kendall_w_low)
                else " (no interval)")
        friedman = (f"Friedman χ²({fr.df}) = {fr.statistic:.2f}, {p}, Kendall's W = {unit(fr.kendall_w)}{w_ci}" if p
                    else f"the Friedman test was not made: {fr.reason or 'not estimable'}")
        out.append(f"“{v.question}” (n = {v.n}): {medians}; {friedman}. "
                   + _pairs_text(v.pairs, lambda p: f"{p.a} over {p.b}, rank-biserial r = {unit(p.rank_biserial)}", "Pairs", family))
    return out


def _scores(kinds: KindStats, family: str) -> list[str]:
    out = []
    for v in kinds.scores.values():
        means = "; ".join(f"{m} M = {c.mean:.2f}" for m, c in v.conditions.items() if _finite(c.mean))
        mm = v.mixed_model
        problems, test = mm.problems, mm.model_test
        p = p_text(test.p_value_f)
        if problems or not p:
            model = f"the mixed model was not reported: {'; '.join(problems) or 'not estimable'}."
        else:
            model = (f"linear mixed model, F({test.df:g}, {test.df_denominator:g}) = {test.f:.2f}, {p}. "
                     + _pairs_text(v.pairs, lambda p: f"{p.b} minus {p.a}, {p.difference:.2f}, 95% CI [{p.ci_low:.2f}, {p.ci_high:.2f}]",
                                   "Pairs", family))
        out.append(f"{v.label} (n = {v.n}): {means}; {model}".strip())
    return out


def _choices(kinds: KindStats, family: str) -> list[str]:
    out = []
    for v in kinds.choices.values():
        shares = "; ".join(f"{m} {pct(s.share)} ({s.count} of {v.n})" for m, s in v.shares.items() if _finite(s.share))
        o = v.overall
        p = p_text(o.p_value)
        # the chi-square statistic with its own p; the exact test's p on its own
        overall = (f"{o.test}, χ²({o.df}) = {o.statistic:.2f}, {p}" if p and o.test.startswith("chi-square")
                   else f"{o.test}, {p}" if p else "no test of the shares was made" + (f" ({o.reason})" if o.reason else ""))
        out.append(f"“{v.question}”: chosen {shares}; {overall}. "
                   + _pairs_text(v.pairs, lambda p: f"{p.a} vs {p.b}, {p.n_a} and {p.n_b} choices", "Pairs", family))
    return out


def _session(kinds: KindStats) -> list[str]:
    """The questions asked once per session (an instrument's score at the end)."""
    out = []
    for s in kinds.session.values():
        if not isinstance(s, EndSummary) or not _finite(s.mean):  # a yes/no question's rate is not a mean
            continue
        ci = (f", 95% CI [{s.ci_low:.2f}, {s.ci_high:.2f}]" if _finite(s.ci_low)
              else f" (no interval: {s.ci_reason})" if s.ci_reason else "")
        sd = f", SD = {s.sd:.2f}" if _finite(s.sd) else ""
        out.append(f"{s.question} (n = {s.n}): M = {s.mean:.2f}{sd}{ci}; Mdn = {s.median:g}.")
    return out


def _deformation(st: StudyStats) -> str:
    d = st.deformation
    rows = "; ".join(f"{r.model} {sig(r.mean_ms)} ms (SD {sig(r.sd_ms)} over {r.n_participants} participants' means, "
                     f"{counted(r.n_trials, 'trial')})" if _finite(r.sd_ms)
                     else f"{r.model} {sig(r.mean_ms)} ms ({counted(r.n_trials, 'trial')})" for r in d.rows if _finite(r.mean_ms))
    return f"Deformation time per frame, a {d.label}: {rows}." if rows else ""


def study_text(study: Study, holm_scope: str = "family", fmt: str = "md") -> str:
    """The methods and results of `study` as Markdown (`fmt` "md"), LaTeX ("latex") or JSON, written
    from the results `report stats --json` prints for it (same `holm_scope`); for a study that
    only discriminates (tasks, no questions), from the object `report jnd --json` prints."""
    if study.protocol.tasks and not study.protocol.questions:
        res = jnd_results(study)
        st = jsonable(res) | {"methods": res["methods"]}  # the methods stay their record
    else:
        st = study_stats(study, holm_scope=holm_scope)
    if fmt == "json":  # for machines: the same paragraphs under their headings
        return json.dumps({"sections": [{"heading": h, "paragraphs": [p for p in ps if p]} for h, ps in sections(st)]}, indent=2,
                          ensure_ascii=False) + "\n"
    return latex_text(st) if fmt == "latex" else markdown(st)


def _discrimination(res: dict) -> list[str]:
    """The Weber fraction per condition and the group test (`report jnd --json`)."""
    f = res["facts"]
    out = [f"Each participant's Weber fraction was fitted by a {f['fit']['function']} psychometric function on {f['fit']['axis']} "
           f"(slope {f['fit']['slope']}; lapse at most {f['fit']['lapse_max']:g}; interval: {f['fit']['interval']})."]
    if res.get("faults"):  # before the Weber fractions: a withheld condition's reason is said there
        out.append(events_text([ConditionEvents(**e) for e in res["faults"]]))
    for c in res["conditions"]:
        if c.get("reason"):
            out.append(f"{c['condition']}: no Weber fraction is reported ({c['reason']}).")
            continue
        if not _finite(c.get("geometric_mean")):
            out.append(f"{c['condition']}: no Weber fraction (no fit).")
            continue
        ci = (f", 95% CI [{pct(c['gm_low'])}, {pct(c['gm_high'])}]" if _finite(c.get("gm_low"))
              else f" ({c.get('gm_reason') or 'no interval'})")
        warn = f"; {c['gm_warning']}" if c.get("gm_warning") else ""
        out.append(f"{c['condition']} (n = {c['n']}): geometric mean Weber fraction {pct(c['geometric_mean'])}{ci}, "
                   f"median {pct(c['median'])}{warn}.")
    g = res.get("group")
    if g:
        mm, fr = g.get("mixed_model") or {}, g.get("friedman") or {}
        parts = []
        if p_text(mm.get("p")) and mm.get("converged", True):
            parts.append(f"a linear mixed model of ln Weber fraction, likelihood-ratio χ²({mm['df']}) = {mm['chi2']:.2f}, {p_text(mm['p'])}")
        if p_text(fr.get("p")):
            parts.append(f"the Friedman test, χ²({fr['df']}) = {fr['statistic']:.2f}, {p_text(fr['p'])}")
        problems = "; ".join(g.get("problems") or [])
        text = (f"Across the conditions ({counted(g['n_participants'], 'participant')}): " + " and ".join(parts) + "." if parts
                else f"The conditions were not compared: {problems or 'not estimable'}.")
        shown = [p for p in g.get("pairs") or [] if _finite(p.get("p_holm")) and p["p_holm"] < SIGNIFICANT]
        text += (" Pairs differing after Holm's correction: " + "; ".join(
            f"{p['a']} vs {p['b']}, ratio {p['ratio']:.2f}, 95% CI [{p['ratio_low']:.2f}, {p['ratio_high']:.2f}], t({p['df']}) = "
            f"{p['t']:.2f}, {p_text(p['p'])}, Holm-corrected {p_text(p['p_holm'])}" for p in shown) + "."
                 if shown else " No pair of conditions differed after Holm's correction." if g.get("pairs") else "")
        out.append(text)
    return out


def sections(st: StudyStats | Mapping) -> list[tuple[str, list[str]]]:
    """(heading, paragraphs) of the methods and results, from a study's results `st`, or from
    the `report jnd --json` object of a study that only discriminates."""
    if isinstance(st, Mapping):  # a discrimination study (`report jnd --json`)
        m, flag = st["methods"], st["facts"]["flag"]
        results = ([flag] if flag else []) + (_discrimination(st) if st["weber"] else ["No discrimination trials yet."])
        return [("Participants", [_participants(m, flag)]), ("Design", [_design(m)]), ("Apparatus", [_apparatus(m)]),
                ("Procedure", [_procedure(m)]), ("Analysis", [_analysis(m)]), ("Results", results)]
    m, flag, kinds = st.methods, st.facts.flag, st.kinds
    family = (f"family of {m.analysis.holm_family}" if st.holm == "family" else "within each question")
    results = [flag] if flag else []
    results.append(events_text(st.faults))  # before any test: a withheld condition's tests say why below
    n = m.design.n_conditions
    if kinds.primary.analysis == "logistic_gee":
        results.append(_gee(st.gee.composite, "logistic GEE across the yes/no questions", "their own family", n))
    elif kinds.primary.analysis == "ordinal_gee":
        results.append(_gee(kinds.ordinal_gee, "proportional-odds GEE across the rating items", "their own family", n))
    results += _yes_no(st, family) + _ratings(kinds, family) + _scores(kinds, family) + _choices(kinds, family) + _session(kinds)
    if m.procedure.tasks:
        results.append("The discrimination task's results (Weber fractions) are reported by `studyctl report jnd`, not here.")
    results.append(_deformation(st))
    return [("Participants", [_participants(m, flag)]), ("Design", [_design(m)]), ("Apparatus", [_apparatus(m)]),
            ("Procedure", [_procedure(m)]), ("Analysis", [_analysis(m)]), ("Results", [r for r in results if r])]


def markdown(st: StudyStats | Mapping) -> str:
    out = []
    for heading, paragraphs in sections(st):
        out += [f"## {heading}", "", *[p + "\n" for p in paragraphs if p]]
    return "\n".join(out)


def latex_text(st: StudyStats | Mapping) -> str:
    """The same paragraphs as LaTeX subsections (the text escaped; χ² and the quotes as LaTeX)."""
    out = []
    for heading, paragraphs in sections(st):
        out += [f"\\subsection*{{{latex.text(heading)}}}", "", *[latex.text(p) + "\n" for p in paragraphs if p]]
    return "\n".join(out)
