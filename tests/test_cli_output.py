"""The whole output of the CLI's main commands, written out here and checked by hand (as
sqlite-utils's tests do): a change to what a user reads shows up as a diff of this file.

The study is a tiny SYNTHETIC one (the shipped protocol on the coarse scene, 2 participants,
seed 1): the observer turns counted work, not wall-clock time, into what it perceives, so the
same seed gives the same answers on any machine. What does depend on the machine is put in by
the test (the temporary folder) or masked, and said where (the deformation times Table 1 and
`synth` measure; the configuration hashes, which cover a scene file that names this checkout's
folder).
"""

import re
import shutil
from importlib import metadata
from types import SimpleNamespace

import click
import pytest

from sim.models import registry
from studyctl.cli import cli
from studyctl.store import SCHEMA_VERSION, Store
from studyctl.store import sessions as session_rows
from tests.conftest import ROOT
from tests.helpers import fast_protocol, studyctl

# rich tables as in a pipe (120 columns, no colour), whatever the terminal the tests run from
ENV = {"FORCE_COLOR": None, "NO_COLOR": None, "TTY_COMPATIBLE": None, "TTY_INTERACTIVE": None, "COLUMNS": None, "STUDYCTL_DB": None}


def run(*args, code=0):
    res = studyctl(*args, env=ENV)
    assert res.exit_code == code, res.output
    return res


def table(text: str) -> str:
    """`text` without the spaces rich pads a table's lines with at their end."""
    return "".join(line.rstrip() + "\n" for line in text.splitlines())


@pytest.fixture(scope="module")
def synth(tmp_path_factory):
    """(the folder, the database, what `synth` printed) of the tiny study."""
    tmp = tmp_path_factory.mktemp("cli")
    db = tmp / "s.db"
    res = run("synth", "--db", db, "--protocol", fast_protocol(tmp, trials=1), "--participants", "2", "--seed", "1")
    return tmp, db, res.stdout, res.stderr


@pytest.fixture
def study(synth, tmp_path):
    """A copy of the tiny study that a test may change."""
    db = tmp_path / "s.db"
    shutil.copy(synth[1], db)
    return db


@pytest.mark.parametrize("name, line", [
    ("brain_pull_2015", "brain_pull_2015: 3 conditions, 9 questions, 3 trials per condition, target 35 participants"),
    ("construct_validity", "construct_validity: 1 condition, 13 questions, 10 trials per condition, target 30 participants"),
    ("plate_spring_variants", "plate_spring_variants: 3 conditions, 20 questions, 3 trials per condition, target 24 participants"),
    ("stiffness_jnd", "stiffness_jnd: 3 conditions, 0 questions, discrimination of stiffness in 40 trials per condition, target 12 participants"),
])
def test_protocol_validate_a_shipped_protocol(name, line):
    path = ROOT / "protocols" / f"{name}.toml"
    assert run("protocol", "validate", path).output == f"{path}: ok ({line})\n"


@pytest.mark.parametrize("old, new, error", [
    ("trials_per_condition = 1 ", "trials_per_condition = 101 ", "15: design.trials_per_condition: 101 is out of range; allowed: 0..100"),
    ("target_participants = 35", "target_participants = 0", "8: study.target_participants: 0 is out of range; allowed: 1..10000"),
    ('conditions = ["plate_spring", "fem", "mass_spring"]', 'conditions = ["plate_spring", "fem", "mass_sprung"]',
     "12: design.conditions: unknown condition 'mass_sprung'; allowed: a [conditions.NAME] table or a model name "
     "(fem, mass_spring, plate_spring)"),
])
def test_protocol_validate_a_bad_protocol_is_one_line_on_stderr(tmp_path, old, new, error):
    path = fast_protocol(tmp_path, trials=1)
    text = path.read_text()
    assert text.count(old) == 1
    path.write_text(text.replace(old, new))
    res = run("protocol", "validate", path, code=1)
    assert res.stderr == f"{path}:{error}\n"
    assert res.stdout == ""


def test_protocol_validate_a_missing_file(tmp_path):
    path = tmp_path / "nowhere.toml"
    res = run("protocol", "validate", path, code=1)
    assert res.stderr == f"{path}: not found\n"
    assert res.stdout == ""


@pytest.fixture
def builtin_models_only(monkeypatch):
    """The registry sees the built-in models alone, at version 0.1.0: the table is the same
    whatever plugins this machine has installed, and the width of its columns the same whatever
    the release."""
    found = metadata.entry_points

    def entry_points(**kw):
        return [SimpleNamespace(name=ep.name, value=ep.value, dist=SimpleNamespace(name=registry.HOME, version="0.1.0"))
                for ep in found(**kw) if ep.dist is not None and ep.dist.name == registry.HOME]

    monkeypatch.setattr(metadata, "entry_points", entry_points)
    registry._registered.cache_clear()
    yield
    registry._registered.cache_clear()  # the next reader scans the real entry points again


def test_model_list(builtin_models_only):
    assert table(run("model", "list").output) == """\
                                                    3 tissue models
┏━━━━━━━━━━━━━━┳━━━━━━━━━━━━━━━━━━━━━━┳━━━━━━━━━━━━━━━━━━━━━━━━━━━━━━━━━━━━━━━━━━━━━━━━━━━━━━━━━━━━┳━━━━━━━━━━━━━━━━━━━┓
┃ name         ┃ from                 ┃ description                                                ┃ stiffness scaling ┃
┡━━━━━━━━━━━━━━╇━━━━━━━━━━━━━━━━━━━━━━╇━━━━━━━━━━━━━━━━━━━━━━━━━━━━━━━━━━━━━━━━━━━━━━━━━━━━━━━━━━━━╇━━━━━━━━━━━━━━━━━━━┩
│ fem          │ brainsim-study 0.1.0 │ finite elements on the body-fitted tetrahedra, linear or   │ yes               │
│              │                      │ corotational, P1 or P2                                     │                   │
│ mass_spring  │ brainsim-study 0.1.0 │ springs along the tetrahedra's edges; explicit, implicit   │ yes               │
│              │                      │ or local/global integration                                │                   │
│ plate_spring │ brainsim-study 0.1.0 │ the paper's plate-spring stack over a geodesic disc (Eqs.  │ yes               │
│              │                      │ 1-18)                                                      │                   │
└──────────────┴──────────────────────┴────────────────────────────────────────────────────────────┴───────────────────┘
"""


def test_study_init(tmp_path):
    db = tmp_path / "s.db"
    out = run("study", "init", "--protocol", fast_protocol(tmp_path, trials=1), "--db", db).output
    assert out == f"created {db}: study brain_pull_2015 (schema {SCHEMA_VERSION})\n"


def test_synth(synth):
    tmp, db, out, _ = synth
    out, timed = re.subn(r", \d+\.\d s\)$", ", T s)", out, flags=re.M)  # the run's wall-clock seconds
    assert timed == 1
    assert out == (f"created {db} for the protocol {tmp / 'protocol.toml'}\n"
                   "ran 2 SYNTHETIC sessions of 'brain_pull_2015': 2 new (seed 1); "
                   "2 synthetic participants with a session in total (1 job, T s)\n")


def test_synth_on_a_pipe_says_where_it_is_on_stderr(synth):
    """The demo's 35 sessions were silent in a log: a line per tenth of the sessions (each here)."""
    assert synth[3] == "synthetic sessions: 1 of 2\nsynthetic sessions: 2 of 2\n"


def test_one_participant_one_session(tmp_path):
    out = run("synth", "--db", tmp_path / "one.db", "--protocol", fast_protocol(tmp_path, trials=1), "--participants", "1", "--seed", "1").stdout
    out = re.sub(r", \d+\.\d s\)$", ", T s)", out, flags=re.M)
    assert out.endswith("ran 1 SYNTHETIC session of 'brain_pull_2015': 1 new (seed 1); 1 synthetic participant with a session in total (1 job, T s)\n")
    assert run("participants", "add", "P01", "--db", tmp_path / "one.db").output == "added P01\n"
    assert run("status", "--db", tmp_path / "one.db").output == """\
brain_pull_2015: 0 of 35 people complete (and 1 SYNTHETIC)
participants: 1 person (0 consented, 0 withdrawn), 1 synthetic
sessions: 1 done
answers: 27
next: nobody scheduled
"""


def test_a_participant_whose_session_is_done_is_not_next(study):
    run("participants", "add", "P01", "--db", study)
    run("participants", "consent", "P01", "--date", "2026-01-15", "--db", study)
    run("schedule", "--start", "2037-12-01", "--end", "2037-12-02", "--db", study)
    assert run("status", "--db", study).output.endswith("\nnext: P01 2037-12-01 09:00:00\n")
    with Store(study) as store:  # P01's session, done (a person's session needs a person at the terminal)
        session_rows.session_done(store, session_rows.open_session(store, "P01", False, "simulated", "", "", "", "", None))
    assert run("status", "--db", study).output.endswith("\nnext: nobody scheduled\n")


def test_a_finished_session_names_its_participant_and_its_number_in_the_study(study):
    """"session 3 of S003 complete" read as S003's third session: each participant has one."""
    run("participants", "add", "S003", "--synthetic", "--db", study)
    done = run("session", "run", "--participant", "S003", "--synthetic", "--db", study).stdout
    assert done.startswith("S003's session complete (session 3 of the study): conditions ")


def test_status(synth):
    assert run("status", "--db", synth[1]).output == """\
brain_pull_2015: 0 of 35 people complete (and 2 SYNTHETIC)
participants: 0 people (0 consented, 0 withdrawn), 2 synthetic
sessions: 2 done
answers: 54
next: nobody scheduled
"""


def test_status_counts_a_withdrawn_synthetic_participant_in_both_counts(study):
    run("participants", "withdraw", "S001", "--db", study)
    assert run("status", "--db", study).output == """\
brain_pull_2015: 0 of 35 people complete (and 2 SYNTHETIC) (1 of these withdrew, data kept: counted, as in the reports)
participants: 0 people (0 consented, 0 withdrawn), 2 synthetic (1 withdrawn)
sessions: 2 done
answers: 54
next: nobody scheduled
"""


def test_participants_list(synth):
    assert table(run("participants", "list", "--db", synth[1]).output) == """\
                              2 participants
┏━━━━━━┳━━━━━━━━━━━┳━━━━━┳━━━━━━━━━┳━━━━━━┳━━━━━━━━━┳━━━━━━━━━┳━━━━━━━━━━━┓
┃ code ┃ kind      ┃ age ┃ consent ┃ slot ┃ session ┃ answers ┃ withdrawn ┃
┡━━━━━━╇━━━━━━━━━━━╇━━━━━╇━━━━━━━━━╇━━━━━━╇━━━━━━━━━╇━━━━━━━━━╇━━━━━━━━━━━┩
│ S001 │ synthetic │ 28  │ -       │ -    │ done    │ 27      │ -         │
│ S002 │ synthetic │ 26  │ -       │ -    │ done    │ 27      │ -         │
└──────┴───────────┴─────┴─────────┴──────┴─────────┴─────────┴───────────┘
"""


# P01 and P02 in the first two 45-minute slots; each participant the next of the 6 Williams orders
# of (plate_spring, fem, mass_spring), in the order they were registered
SCHEDULE = """\
┏━━━━━━━━━━━━━┳━━━━━━━━━━━━━━━━━━━━━┳━━━━━━━┳━━━━━━━━━━━━━━━━━━━━━━━━━━━━━━━━━━┓
┃ participant ┃ start               ┃ end   ┃ order                            ┃
┡━━━━━━━━━━━━━╇━━━━━━━━━━━━━━━━━━━━━╇━━━━━━━╇━━━━━━━━━━━━━━━━━━━━━━━━━━━━━━━━━━┩
│ P01         │ 2037-12-01T09:00:00 │ 09:45 │ mass_spring > plate_spring > fem │
│ P02         │ 2037-12-01T09:45:00 │ 10:30 │ mass_spring > fem > plate_spring │
│ S001        │ -                   │       │ plate_spring > fem > mass_spring │
│ S002        │ -                   │       │ fem > mass_spring > plate_spring │
└─────────────┴─────────────────────┴───────┴──────────────────────────────────┘
"""


def test_people_added_consented_and_scheduled(study):
    assert run("participants", "add", "P01", "--age", "25", "--db", study).output == "added P01\n"
    assert run("participants", "add", "P02", "--db", study).output == "added P02\n"
    assert run("participants", "consent", "P01", "--date", "2026-01-15", "--db", study).output == "recorded consent of P01: form 1, signed 2026-01-15\n"
    # a dry run shows the schedule and stores nothing
    dry = run("schedule", "--start", "2037-12-01", "--end", "2037-12-02", "--dry-run", "--db", study).output
    assert table(dry) == "      DRY RUN, nothing stored: Schedule (2 of 4 participants have a slot)\n" + SCHEDULE
    assert run("status", "--db", study).output.endswith("\nnext: nobody scheduled\n")
    # the same schedule, stored
    stored = run("schedule", "--start", "2037-12-01", "--end", "2037-12-02", "--db", study).output
    assert table(stored) == "                   Schedule (2 of 4 participants have a slot)\n" + SCHEDULE
    assert run("status", "--db", study).output == """\
brain_pull_2015: 0 of 35 people complete (and 2 SYNTHETIC)
participants: 2 people (1 consented, 0 withdrawn), 2 synthetic
sessions: 2 done
answers: 54
next: P01 2037-12-01 09:00:00; P02 2037-12-01 09:45:00
"""
    assert table(run("participants", "list", "--db", study).output) == """\
                                      4 participants
┏━━━━━━┳━━━━━━━━━━━┳━━━━━┳━━━━━━━━━┳━━━━━━━━━━━━━━━━━━━━━┳━━━━━━━━━┳━━━━━━━━━┳━━━━━━━━━━━┓
┃ code ┃ kind      ┃ age ┃ consent ┃ slot                ┃ session ┃ answers ┃ withdrawn ┃
┡━━━━━━╇━━━━━━━━━━━╇━━━━━╇━━━━━━━━━╇━━━━━━━━━━━━━━━━━━━━━╇━━━━━━━━━╇━━━━━━━━━╇━━━━━━━━━━━┩
│ P01  │ person    │ 25  │ 1       │ 2037-12-01T09:00:00 │ -       │ 0       │ -         │
│ P02  │ person    │ -   │ -       │ 2037-12-01T09:45:00 │ -       │ 0       │ -         │
│ S001 │ synthetic │ 28  │ -       │ -                   │ done    │ 27      │ -         │
│ S002 │ synthetic │ 26  │ -       │ -                   │ done    │ 27      │ -         │
└──────┴───────────┴─────┴─────────┴─────────────────────┴─────────┴─────────┴───────────┘
"""
    assert run("schedule", "cancel", "P02", "--db", study).output == (
        "cancelled P02's slot at 2037-12-01T09:45:00; `studyctl schedule` gives a new one\n")
    assert run("status", "--db", study).output.endswith("\nnext: P01 2037-12-01 09:00:00\n")


NOT_TESTED = "not tested: no participant answered the two differently: nothing to test"
ALIKE = "n/a (every participant answered alike in every condition: nothing to test)"
NONE_DIFFER = f"plate_spring-fem {NOT_TESTED}; plate_spring-mass_spring {NOT_TESTED}; fem-mass_spring {NOT_TESTED}"
ALL = "2/0, 100.0% [34.2%, 100.0%]"  # Wilson 95%: 2 of 2 said yes
HALF = "1/1, 50.0% [9.5%, 90.5%]"  # 1 of 2


def test_report_table1(synth):
    out = run("report", "table1", "--db", synth[1]).output
    # each condition's mean +- sd (median, p95) of the deformation time: this machine's wall clock
    out, timed = re.subn(r"\| \d+\.\d\d \+- \d+\.\d\d \(median \d+\.\d\d, p95 \d+\.\d\d\) ", "| T ", out)
    assert timed == 3
    out, hashed = re.subn(r"configuration [0-9a-f]{12}", "configuration H", out)  # the scene file names this checkout
    assert hashed == 3
    assert out == f"""\
**Table 1: brain_pull_2015.** SYNTHETIC DATA (simulated participants): not evidence about people. N = 2 participants with every answer; within-subject, 3 conditions, williams counterbalancing.

| Question | plate_spring: yes/no, rate [95% CI] | fem: yes/no, rate [95% CI] | mass_spring: yes/no, rate [95% CI] | Cochran's Q (p) | McNemar p, Holm over all 12 pairs tested |
|---|---|---|---|---|---|
| Is interaction real and natural? | {ALL} | {ALL} | {HALF} | 2.00 (0.368) | plate_spring-fem {NOT_TESTED}; plate_spring-mass_spring 1; fem-mass_spring 1 |
| Does interactive process meet people's behavior? | {HALF} | {ALL} | {HALF} | 2.00 (0.368) | plate_spring-fem 1; plate_spring-mass_spring {NOT_TESTED}; fem-mass_spring 1 |
| Does the interaction reflect the texture feature of organs? | {ALL} | {ALL} | {ALL} | {ALIKE} | {NONE_DIFFER} |
| Is the interaction comfortable? | {ALL} | {HALF} | {HALF} | 2.00 (0.368) | plate_spring-fem 1; plate_spring-mass_spring 1; fem-mass_spring {NOT_TESTED} |
| Can it guide interoperate? | {ALL} | {ALL} | {ALL} | {ALIKE} | {NONE_DIFFER} |
| Is the interaction real-time? | {ALL} | {ALL} | {HALF} | 2.00 (0.368) | plate_spring-fem {NOT_TESTED}; plate_spring-mass_spring 1; fem-mass_spring 1 |
| Is feedback information true? | {ALL} | {ALL} | {HALF} | 2.00 (0.368) | plate_spring-fem {NOT_TESTED}; plate_spring-mass_spring 1; fem-mass_spring 1 |
| Are deformation effects realistic? | {ALL} | {HALF} | {HALF} | 2.00 (0.368) | plate_spring-fem 1; plate_spring-mass_spring 1; fem-mass_spring {NOT_TESTED} |
| Is the system stable? | {ALL} | {ALL} | {ALL} | {ALIKE} | {NONE_DIFFER} |
| Time for real-time deformation of the model, ms: benchmark of this machine | T | T | T | | |

Rates with Wilson 95% intervals; Cochran's Q across the models; pairwise exact McNemar tests, Holm over all 12 pairs tested. \
Deformation time: each participant's mean over their trials, mean +- sd over participants: wall-clock time of this machine per visual frame, \
the model's deformation with the surface a participant's view draws, not a measure of the participants (no test).

Primary analysis, all questions: logistic GEE `answer ~ C(model) + C(period) + C(item)`, participants as clusters, \
exchangeable working correlation (not estimated: fewer than 5 participants), robust standard errors \
(NOT ESTIMABLE OR NOT CONVERGED: fewer than 5 participants): fem vs plate_spring not estimable; mass_spring vs plate_spring not estimable; \
mass_spring vs fem not estimable.

Conditions (what each ran; participants saw only their labels): \
plate_spring: plate_spring (variant continuous), built in, configuration H; \
fem: fem (formulation linear, grasp_radius 0.005, order 1, resolution 0.008; E 3919.21 Pa, nu 0.45), built in, configuration H; \
mass_spring: mass_spring (acceleration none, coupling 300.0, damping 5.0, dt 0.033333, grasp_radius 0.005, integrator local-global, \
iterations 10, resolution 0.008; E 3919.21 Pa), built in, configuration H.
"""


def test_export(synth, tmp_path):
    out = tmp_path / "export"
    assert run("export", "--db", synth[1], "--out", out).output == f"wrote 16 files to {out}\n"
    # every pseudonymous table and the traces' list; never the identifying one
    assert sorted(f.name for f in out.iterdir()) == [
        "answers.csv", "conditions.csv", "consent.csv", "corrections.csv", "discrimination.csv", "events.csv", "latency.csv",
        "observer_features.csv", "participant_fields.csv", "participants.csv", "rig_profile.csv", "schedule.csv", "sessions.csv",
        "synthetic_traits.csv", "traces.csv", "trials.csv"]


def _options(command, path=()):
    for param in command.params:
        if isinstance(param, click.Option) and not param.hidden:
            yield " ".join(path), param
    for name, sub in getattr(command, "commands", {}).items():
        yield from _options(sub, (*path, name))


def test_every_option_of_every_command_has_help():
    """`synth --seed`, `report table1 --out` and `--format`, `schedule --json` had none."""
    assert [f"{path} {param.opts[-1]}" for path, param in _options(cli) if not (param.help or "").strip()] == []
