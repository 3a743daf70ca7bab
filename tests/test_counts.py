"""Counts that add up: one definition of a complete participant (analysis.study.completeness) behind
`status`, Table 1's N, the banners and the lists of the incomplete, kinds of participants
counted apart; `synth --complete` brings an interrupted run to its N and says what it ran."""

import hashlib
import shutil
import sqlite3

import pytest

from tests.helpers import fast_protocol, studyctl

ITEMS = ["natural", "behaviour", "texture", "comfortable", "guidance", "realtime", "feedback", "deformation", "stable"]
CONDITIONS = ("plate_spring", "fem")
END_TEXT = '\n[[questions]]\nid = "comments"\ntext = "Any comments?"\nkind = "text"\nwhen = "end"\n'


def _sha(path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


@pytest.fixture(scope="module")
def mixed_study(tmp_path_factory):
    """One synthetic participant, three people who answered everything (the end-of-study text
    question included), one person with one yes/no answer and one with only the text answer."""
    tmp = tmp_path_factory.mktemp("mixed")
    proto = fast_protocol(tmp, conditions=CONDITIONS, trials=1)
    proto.write_text(proto.read_text() + END_TEXT)
    db = tmp / "s.db"
    assert studyctl("synth", "--protocol", proto, "--db", db, "--participants", 1, "--seed", 3).exit_code == 0
    rows = ["participant,model,item,answer"]
    for code in ("P01", "P02", "P03", "P04", "P05"):
        assert studyctl("participants", "add", code, "--age", 24, "--db", db).exit_code == 0
        assert studyctl("participants", "consent", code, "--db", db).exit_code == 0
    for code in ("P01", "P02", "P03"):
        rows += [f"{code},{m},{i},{'yes' if (k + len(m)) % 3 else 'no'}" for m in CONDITIONS for k, i in enumerate(ITEMS)]
        rows.append(f"{code},,comments,fine")
    rows += ["P04,fem,natural,no", "P05,,comments,none"]
    (tmp / "a.csv").write_text("\n".join(rows) + "\n")
    res = studyctl("answers", "import", tmp / "a.csv", "--db", db)
    assert res.exit_code == 0, res.output
    return db


def test_status_counts_people_complete_with_an_end_of_study_text_question(mixed_study):
    first = studyctl("status", "--db", mixed_study).output.splitlines()[0]
    assert first.startswith("brain_pull_2015: 3 of "), first


def test_status_counts_the_synthetic_participant_apart(mixed_study):
    first = studyctl("status", "--db", mixed_study).output.splitlines()[0]
    assert first.endswith("people complete (and 1 SYNTHETIC)"), first


def test_status_lists_a_person_with_one_answer_and_one_with_only_text_as_incomplete(mixed_study):
    lines = studyctl("status", "--db", mixed_study).output.splitlines()
    assert "incomplete: P04 (1/18), P05 (0/18)" in lines, lines


def test_table1_n_is_the_complete_people_and_synthetic_participants(mixed_study):
    out = studyctl("report", "table1", "--db", mixed_study).output
    assert "N = 4 participants with every answer" in out, out[:600]


def test_table1_banner_counts_the_complete_people(mixed_study):
    out = studyctl("report", "table1", "--db", mixed_study).output
    assert "MIXED DATA: 3 people and 1 SYNTHETIC (simulated) participant pooled" in out, out[:600]


def test_table1_lists_both_incomplete_people(mixed_study):
    out = studyctl("report", "table1", "--db", mixed_study).output
    assert "Left out (incomplete): P04 (1/18), P05 (0/18)." in out, out[:600]


def test_status_json_counts_match_table1(mixed_study):
    import json

    out = json.loads(studyctl("status", "--db", mixed_study, "--json").output)
    assert out["complete"] == {"persons": 3, "synthetic": 1, "mixed": 0}


@pytest.fixture(scope="module")
def withdrawn_study(tmp_path_factory):
    """Two people who answered everything on paper; P01 then withdrew (`withdrawal = "keep"`,
    the default: their answers stay, and the reports count them)."""
    tmp = tmp_path_factory.mktemp("withdrawn")
    db = tmp / "s.db"
    assert studyctl("study", "init", "--protocol", fast_protocol(tmp, conditions=CONDITIONS, trials=1), "--db", db).exit_code == 0
    rows = ["participant,model,item,answer"]
    for code in ("P01", "P02"):
        assert studyctl("participants", "add", code, "--age", 24, "--db", db).exit_code == 0
        assert studyctl("participants", "consent", code, "--db", db).exit_code == 0
        rows += [f"{code},{m},{i},{'yes' if (k + len(m)) % 3 else 'no'}" for m in CONDITIONS for k, i in enumerate(ITEMS)]
    (tmp / "a.csv").write_text("\n".join(rows) + "\n")
    assert studyctl("answers", "import", tmp / "a.csv", "--db", db).exit_code == 0
    assert studyctl("participants", "withdraw", "P01", "--db", db).exit_code == 0
    return db


def test_status_counts_a_withdrawn_person_whose_data_the_reports_keep(withdrawn_study):
    first = studyctl("status", "--db", withdrawn_study).output.splitlines()[0]
    assert first.startswith("brain_pull_2015: 2 of "), first


def test_status_says_a_complete_person_withdrew_with_data_kept(withdrawn_study):
    first = studyctl("status", "--db", withdrawn_study).output.splitlines()[0]
    assert first.endswith("people complete (1 of these withdrew, data kept: counted, as in the reports)"), first


def test_table1_n_counts_the_withdrawn_person_as_status_does(withdrawn_study):
    out = studyctl("report", "table1", "--db", withdrawn_study).output
    assert "N = 2 participants with every answer" in out, out[:600]


def test_status_json_counts_the_complete_who_withdrew(withdrawn_study):
    import json

    out = json.loads(studyctl("status", "--db", withdrawn_study, "--json").output)
    assert out["complete_withdrawn"] == 1, out


@pytest.fixture(scope="module")
def mixed_source_study(mixed_study, tmp_path_factory):
    """The mixed study with one synthetic answer among P01's (a database from before the checks
    that keep sources apart): P01's answers mix sources."""
    db = tmp_path_factory.mktemp("mixed_source") / "s.db"
    shutil.copy(mixed_study, db)
    con = sqlite3.connect(db)
    with con:
        con.execute("update answers set source = 'synthetic' where code = 'P01' and model = 'fem' and item = 'natural'")
    con.close()
    return db


def test_status_counts_a_mixed_source_participant_as_synthetic(mixed_source_study):
    first = studyctl("status", "--db", mixed_source_study).output.splitlines()[0]
    assert first == "brain_pull_2015: 2 of 35 people complete (and 2 SYNTHETIC, 1 of them with a person's answers too)", first


def test_table1_banner_counts_a_mixed_source_participant_as_status_does(mixed_source_study):
    out = studyctl("report", "table1", "--db", mixed_source_study).output
    assert "MIXED DATA: 2 people and 2 SYNTHETIC (simulated) participants pooled" in out, out[:600]


def test_plots_of_a_mixed_study_are_titled_mixed(mixed_study, tmp_path, monkeypatch):
    import analysis.reports.plots as plots
    import studyctl.synthetic.force_traces as force_traces

    titles = []
    real = plots._suptitle
    monkeypatch.setattr(plots, "_suptitle", lambda fig, text, size: (titles.append(text), real(fig, text, size)))
    monkeypatch.setattr(force_traces, "force_traces", lambda protocol: None)  # the traces' figure has no kind of data in its title
    assert studyctl("report", "plots", "--db", mixed_study, "--out", tmp_path / "plots").exit_code == 0
    assert titles, titles
    assert all(t.startswith("MIXED DATA: ") for t in titles), titles


def _interrupt_after(monkeypatch, k: int):
    import studyctl.synthetic.synth_run as runner

    real = runner.completed

    def k_then_ctrl_c(fn, tasks, jobs, scheduler):
        for i, item in enumerate(real(fn, tasks, jobs, scheduler)):
            if i == k:
                raise KeyboardInterrupt
            yield item

    monkeypatch.setattr(runner, "completed", k_then_ctrl_c)
    return lambda: monkeypatch.setattr(runner, "completed", real)


@pytest.fixture
def interrupted(tmp_path, monkeypatch):
    """A `synth --participants 4` interrupted after 1 session stored."""
    db = tmp_path / "s.db"
    proto = fast_protocol(tmp_path, conditions=("plate_spring",), trials=1)
    restore = _interrupt_after(monkeypatch, 1)
    res = studyctl("synth", "--db", db, "--participants", "4", "--protocol", proto, "--seed", "4")
    restore()
    return db, res


def test_an_interrupted_synth_suggests_complete(interrupted):
    db, res = interrupted
    assert f"`studyctl synth --db {db} --complete` runs the 3 registered participants left without one, completing this run's 4" in res.output, res.output


@pytest.fixture
def interrupted_in_a_session(tmp_path, monkeypatch):
    """A `synth --participants 3` (one job) whose Ctrl-C lands inside S002's session, as it
    nearly always does: the session raises its own Interrupted, naming its scratch study."""
    import studyctl.session.run as session

    real = session._run_condition

    def ctrl_c_in_s002(run, *args):
        if run.code == "S002":
            raise KeyboardInterrupt
        return real(run, *args)

    monkeypatch.setattr(session, "_run_condition", ctrl_c_in_s002)
    db = tmp_path / "s.db"
    res = studyctl("synth", "--db", db, "--participants", "3", "--seed", "4",
                   "--protocol", fast_protocol(tmp_path, conditions=("plate_spring",), trials=1))
    monkeypatch.setattr(session, "_run_condition", real)
    return db, res


def test_ctrl_c_inside_a_synthetic_session_exits_130(interrupted_in_a_session):
    _, res = interrupted_in_a_session
    assert res.exit_code == 130, res.output


def test_ctrl_c_inside_a_synthetic_session_suggests_complete(interrupted_in_a_session):
    db, res = interrupted_in_a_session
    assert res.output.strip() == (f"synthetic sessions: 1 of 3\nError: synth: interrupted after 1 of 3 sessions (each stored whole); `studyctl synth --db {db} "
                                  "--complete` runs the 2 registered participants left without one, completing this run's 3"), res.output


def test_ctrl_c_inside_a_synthetic_session_names_no_scratch_study(interrupted_in_a_session):
    _, res = interrupted_in_a_session
    assert "studyctl-synth-" not in res.output, res.output


def test_synth_complete_after_ctrl_c_inside_a_session_brings_the_run_to_its_n(interrupted_in_a_session):
    db, _ = interrupted_in_a_session
    assert studyctl("synth", "--db", db, "--complete").exit_code == 0
    assert sqlite3.connect(db).execute("select count(*) from sessions where status = 'done'").fetchone()[0] == 3


def test_synth_complete_brings_an_interrupted_run_to_its_n(interrupted):
    db, _ = interrupted
    assert studyctl("synth", "--db", db, "--complete").exit_code == 0
    assert sqlite3.connect(db).execute("select count(*) from sessions where status = 'done'").fetchone()[0] == 4


def test_synth_complete_says_what_it_ran_in_one_line(interrupted):
    db, _ = interrupted
    out = studyctl("synth", "--db", db, "--complete").output
    assert "ran 3 SYNTHETIC sessions of 'brain_pull_2015': 0 new, 3 left by an interrupted run, run from the start " \
           "(S002, S003, S004; seed 4); 4 synthetic participants with a session in total" in out, out


def test_synth_complete_never_calls_a_session_run_from_the_start_resumed(interrupted):
    db, _ = interrupted
    out = studyctl("synth", "--db", db, "--complete").output
    assert "resumed" not in out, out


def test_a_synth_with_nothing_left_over_names_no_interrupted_run(one, tmp_path):
    db = tmp_path / "s.db"
    shutil.copy(one, db)
    out = studyctl("synth", "--db", db, "--participants", 1, "--seed", 5).output
    assert "ran 1 SYNTHETIC session of 'brain_pull_2015': 1 new (seed 5); 2 synthetic participants" in out, out


def test_synth_complete_leaves_four_participants(interrupted):
    db, _ = interrupted
    studyctl("synth", "--db", db, "--complete")
    assert sqlite3.connect(db).execute("select count(*) from participants").fetchone()[0] == 4


def test_new_participants_while_an_interrupted_run_waits_are_refused(interrupted):
    db, _ = interrupted
    before = _sha(db)
    res = studyctl("synth", "--db", db, "--participants", "3")
    assert res.exit_code == 1
    assert res.output.strip() == (f"Error: --db: {db} holds 3 synthetic participants an interrupted synth registered without a "
                                  "session; give --complete to run them (with --participants N to add N more after)")
    assert _sha(db) == before


def test_complete_with_nothing_to_complete_is_refused(small_study):
    before = _sha(small_study)
    res = studyctl("synth", "--db", small_study, "--complete")
    assert res.exit_code == 1
    assert res.output.strip() == (f"Error: --complete: {small_study} holds no synthetic participant an interrupted synth "
                                  "left without a session; nothing to complete")
    assert _sha(small_study) == before


def test_synth_without_participants_or_complete_is_refused(small_study):
    res = studyctl("synth", "--db", small_study)
    assert res.exit_code == 1
    assert res.output.strip() == ("Error: --participants: missing; give how many new synthetic participants (1..1000), "
                                  "or --complete to finish an interrupted run")


@pytest.fixture(scope="module")
def unset_study(tmp_path_factory):
    """A study of one condition of a lab's model whose option `k0` is unset (None)."""
    from tests.helpers import BAD

    tmp = tmp_path_factory.mktemp("unset")
    proto = fast_protocol(tmp, conditions=("plate_spring", "own"), trials=1)
    proto.write_text(proto.read_text().replace("[inclusion]", f'[conditions.own]\nmodel = "{BAD}:Unset"\n\n[inclusion]', 1))
    db = tmp / "s.db"
    res = studyctl("synth", "--protocol", proto, "--db", db, "--participants", 2, "--seed", 1)
    assert res.exit_code == 0, res.output
    return db


def test_report_text_never_prints_an_unset_option_as_none(unset_study):
    text = studyctl("report", "text", "--db", unset_study).output
    assert "None" not in text, text


def test_table1_conditions_never_print_an_unset_option_as_none(unset_study):
    text = studyctl("report", "table1", "--db", unset_study).output
    assert "None" not in text, text


def test_report_text_still_names_the_set_option(unset_study):
    text = studyctl("report", "text", "--db", unset_study).output
    assert "stiffness 200" in text, text


def _synth(tmp_path_factory, name: str, n: int, seed: int, protocol) -> object:
    tmp = tmp_path_factory.mktemp(name)
    db = tmp / "s.db"
    res = studyctl("synth", "--protocol", protocol(tmp), "--db", db, "--participants", n, "--seed", seed)
    assert res.exit_code == 0, res.output
    return db


@pytest.fixture(scope="module")
def one(tmp_path_factory):
    return _synth(tmp_path_factory, "one", 1, 3, lambda tmp: fast_protocol(tmp, trials=1))


@pytest.fixture(scope="module")
def two(tmp_path_factory):
    return _synth(tmp_path_factory, "two", 2, 3, lambda tmp: fast_protocol(tmp, trials=1))


@pytest.fixture(scope="module")
def two_variants(tmp_path_factory):
    from tests.helpers import variants_protocol

    return _synth(tmp_path_factory, "two_variants", 2, 3, variants_protocol)


def _holm_counts(db) -> dict:
    import json
    import re

    table = studyctl("report", "table1", "--db", db).output
    text = studyctl("report", "text", "--db", db).output
    js = json.loads(studyctl("report", "stats", "--json", "--db", db).output)
    return {"table1": sorted(set(re.findall(r"Holm over all (\d+) pairs tested", table))),
            "text": sorted(set(re.findall(r"family of all (\d+) pairwise tests", text))),
            "json": [str(js["methods"]["analysis"]["holm_family"])]}


@pytest.mark.parametrize("study", ["two", "small_study", "variants_study"])
def test_the_holm_family_is_one_number_in_table1_text_and_json(study, request):
    counts = _holm_counts(request.getfixturevalue(study))
    assert counts["table1"] == counts["text"] == counts["json"], counts


def test_at_n_2_the_holm_family_counts_only_the_tests_run(two):
    counts = _holm_counts(two)
    assert counts["json"] != ["27"], counts  # 27 pairs exist; at N = 2 some are not testable


def test_at_n_1_no_mcnemar_pair_is_tested(one):
    out = studyctl("report", "table1", "--db", one).output
    rows = [line for line in out.splitlines() if "not testable at N = 1" in line]
    assert rows, rows
    assert all("not tested: not testable at N = 1" in r for r in rows), rows


def test_at_n_1_no_row_prints_a_mcnemar_p_value(one):
    import re

    out = studyctl("report", "table1", "--db", one).output
    assert not re.search(r"(plate_spring|fem|mass_spring)-(plate_spring|fem|mass_spring) [0-9]", out), out


@pytest.mark.parametrize("command", [("table1",), ("text",), ("stats",), ("table1", "--format", "latex"), ("table1", "--format", "html")])
def test_no_nan_in_a_report_at_n_2(two, command):
    import re

    out = studyctl("report", *command, "--db", two).output
    assert not re.search(r"\bnan\b", out, re.I), re.findall(r".{60}\bnan\b.{20}", out, re.I)


def test_the_gee_working_correlation_at_n_2_says_why_it_is_missing(two):
    out = studyctl("report", "table1", "--db", two).output
    assert "exchangeable working correlation (not estimated: fewer than 5 participants)" in out, out


@pytest.fixture(scope="module")
def two_rho(tmp_path_factory):
    """Two participants whose GEE fit returns a finite working correlation (seed 2), though the
    fit is flagged not estimable (fewer than 5 participants)."""
    return _synth(tmp_path_factory, "two_rho", 2, 2, lambda tmp: fast_protocol(tmp, trials=1))


def test_a_gee_flagged_not_estimable_prints_no_working_correlation_in_table1(two_rho):
    out = studyctl("report", "table1", "--db", two_rho).output
    assert "exchangeable working correlation (not estimated: fewer than 5 participants)" in out, out


def test_a_gee_flagged_not_estimable_prints_no_working_correlation_in_report_stats(two_rho):
    out = studyctl("report", "stats", "--db", two_rho).output
    assert "exchangeable working correlation (not estimated: fewer than 5 participants)" in out, out


@pytest.mark.parametrize("command", [("table1",), ("text",), ("stats",)])
def test_no_nan_in_a_ratings_report(variants_study, command):
    import re

    out = studyctl("report", *command, "--db", variants_study).output
    assert not re.search(r"\bnan\b", out, re.I), re.findall(r".{60}\bnan\b.{20}", out, re.I)


def _intervals(node, path=""):
    """(path, low, high) of every interval in a report's JSON."""
    if isinstance(node, dict):
        if "ci_low" in node and "ci_high" in node:
            yield path, node["ci_low"], node["ci_high"]
        for k, v in node.items():
            yield from _intervals(v, f"{path}/{k}")
    elif isinstance(node, list):
        for i, v in enumerate(node):
            yield from _intervals(v, f"{path}/{i}")


def test_sus_mixed_model_means_stay_inside_0_100_in_the_json(two_variants):
    import json

    js = json.loads(studyctl("report", "stats", "--json", "--db", two_variants).output)
    means = js["kinds"]["scores"]["sus"]["mixed_model"]["means"]
    out = [(m, c["ci_low"], c["ci_high"]) for m, c in means.items()
           if c["ci_low"] is not None and not 0 <= c["ci_low"] <= c["ci_high"] <= 100]
    assert out == []


def test_a_clipped_sus_interval_says_so_in_a_note(two_variants):
    import json

    js = json.loads(studyctl("report", "stats", "--json", "--db", two_variants).output)
    assert any("clipped to it" in n for n in js["kinds"]["scores"]["sus"]["mixed_model"]["notes"]), js["kinds"]["scores"]["sus"]["mixed_model"]


def test_every_sus_interval_in_the_json_stays_inside_0_100(two_variants):
    import json

    js = json.loads(studyctl("report", "stats", "--json", "--db", two_variants).output)
    found = [(p, lo, hi) for p, lo, hi in _intervals(js["kinds"]["scores"]["sus"]["conditions"])
             if lo is not None and not 0 <= lo <= hi <= 100]
    assert found == []


def test_table1_says_what_the_deformation_time_measured(small_study):
    out = studyctl("report", "table1", "--db", small_study).output
    assert "per visual frame, the model's deformation with the surface a participant's view draws" in out, out[-1500:]


@pytest.fixture(scope="module")
def small_jnd(tmp_path_factory):
    from tests.helpers import jnd_protocol

    return _synth(tmp_path_factory, "jnd", 2, 3, lambda tmp: jnd_protocol(tmp, conditions=("plate_spring", "fem"), trials=12))


def test_report_jnd_says_why_a_pair_is_not_tested(small_jnd):
    out = studyctl("report", "jnd", "--db", small_jnd).output
    assert "plate_spring vs fem: not tested (fewer than 3 participants with a Weber fraction in every condition)" in out, out


def test_report_jnd_prints_no_bare_dash_interval(small_jnd):
    out = studyctl("report", "jnd", "--db", small_jnd).output
    assert "[-, -]" not in out, out


def test_report_jnd_explains_a_dash_in_its_notes(small_jnd):
    out = studyctl("report", "jnd", "--db", small_jnd).output
    assert "A - marks a value there is none of" in out, out


def _stored_version(db) -> str:
    (version,), = sqlite3.connect(db).execute("select distinct software_version from sessions").fetchall()
    return version.removeprefix("brainsim-study ")


def test_report_stats_json_gives_a_built_in_model_the_sessions_version(one):
    import json

    js = json.loads(studyctl("report", "stats", "--json", "--db", one).output)
    versions = {m["source"]["version"] for m in js["methods"]["apparatus"]["models"]}
    assert versions == {_stored_version(one)}, js["methods"]["apparatus"]["models"]


def test_table1_json_gives_a_built_in_model_the_sessions_version(one):
    import json

    js = json.loads(studyctl("report", "table1", "--format", "json", "--db", one).output)
    versions = {c["source"]["version"] for c in js["facts"]["conditions"]}
    assert versions == {_stored_version(one)}, js["facts"]["conditions"]
