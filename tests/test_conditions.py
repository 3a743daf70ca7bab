"""Conditions as named model configurations (issue 26, item 1): validated against the scene at
the protocol's own lines, resolved and stored with each session, shown in exports and reports."""

import dataclasses
import json
import re
import sqlite3

import pandas as pd
import pytest

from sim.scene import load_scene
from studyctl.conditions import condition_scene_spec, config_sha256, resolved_config
from studyctl.protocol import check_protocol, load_protocol
from studyctl.synthetic.synth_run import run_synthetic_study
from tests.helpers import fast_protocol, studyctl

VARIANTS = """
[conditions.paper]
model = "plate_spring"
variant = "paper"

[conditions.located]
model = "plate_spring"
variant = "located"

[conditions.stiff_fem]
model = "fem"
young = 6000.0
"""


def _protocol(tmp_path, conditions=("paper", "located", "stiff_fem"), tables=VARIANTS, trials=1):
    path = fast_protocol(tmp_path, conditions=conditions, trials=trials)
    text = path.read_text().replace("[inclusion]", tables + "\n[inclusion]")
    path.write_text(text)
    return path


def test_named_conditions_resolve_over_the_scenes_configuration(tmp_path):
    p = load_protocol(_protocol(tmp_path))
    assert p.conditions == ("paper", "located", "stiff_fem")
    configs = {c: resolved_config(c, condition_scene_spec(p, c)) for c in p.conditions}
    assert configs["paper"]["variant"] == "paper"
    assert configs["located"]["variant"] == "located"
    # what a condition leaves out is the scene's: its plate parameters, the FEM's 8 mm mesh
    assert configs["paper"]["plate_spring"] == configs["located"]["plate_spring"]
    assert configs["stiff_fem"]["options"]["resolution"] == 0.008
    assert configs["stiff_fem"]["options"]["formulation"] == "linear"
    assert configs["stiff_fem"]["material"]["young"] == 6000.0
    # the old form (a model name) is the scene's own configuration
    fem = resolved_config("fem", condition_scene_spec(p, "fem"))
    # the scene gives no young: the law's small-strain limit, 2 mu (1 + 0.45), mu = 1351.45 Pa (human cortex, fitted on every mode)
    assert fem["material"]["young"] == pytest.approx(2 * 1351.453 * 1.45, rel=1e-5)
    assert fem["options"] == configs["stiff_fem"]["options"]
    hashes = {config_sha256(c) for c in configs.values()}
    assert len(hashes) == 3
    assert all(re.fullmatch(r"[0-9a-f]{64}", h) for h in hashes)
    # the same configuration, found again, has the same hash; paths enter as file contents
    assert config_sha256(resolved_config("paper", condition_scene_spec(p, "paper"))) == config_sha256(configs["paper"])


REFUSED = {
    "an option the model does not take": ('variant = "paper"\n', 'variant = "paper"\nformulation = "linear"\n',
                                          r":(\d+): conditions.paper.formulation: unknown key; allowed: model, variant, params, field"),
    "a value out of range": ("young = 6000.0", "young = -1.0", r":(\d+): conditions.stiff_fem.young: -1.0 is out of range; allowed: \[1, 1e\+09\] Pa"),
    "a value not among the allowed": ('variant = "located"', 'variant = "locatd"',
                                      r":(\d+): conditions.located.variant: 'locatd' is not one of paper, continuous, located"),
    "an unknown model": ('model = "fem"', 'model = "sph"', r":(\d+): conditions.stiff_fem.model: 'sph' is not a model; allowed: fem, mass_spring, plate_spring"),
    "a condition listed twice": ('conditions = ["paper", "located", "stiff_fem"]', 'conditions = ["paper", "paper", "stiff_fem", "located"]',
                                 r":(\d+): design.conditions: a condition appears twice"),
    "a table not listed": ('conditions = ["paper", "located", "stiff_fem"]', 'conditions = ["paper", "located"]',
                           r":(\d+): conditions.stiff_fem: not listed in design.conditions"),
    "an undeclared name": ('conditions = ["paper", "located", "stiff_fem"]', 'conditions = ["paper", "located", "stiff_fem", "soft"]',
                           r":(\d+): design.conditions: unknown condition 'soft'; allowed: a \[conditions.NAME\] table \(paper, located, stiff_fem\)"),
    "a model's name as a condition's": ("[conditions.stiff_fem]", "[conditions.fem]",
                                         r":(\d+): conditions.fem: 'fem' is a model's name, which means the scene's own configuration"),
    "a list among the names": ('conditions = ["paper", "located", "stiff_fem"]', 'conditions = ["paper", "located", "stiff_fem", ["fem"]]',
                               r":(\d+): design.conditions: \['fem'\] is not a condition's name"),
    "a material key the model ignores": ('model = "fem"\nyoung = 6000.0', 'model = "mass_spring"\npoisson = 0.3',
                                         r":(\d+): conditions.stiff_fem.poisson: unknown key; allowed: model, resolution, integrator"),
    "nine conditions": ('conditions = ["paper", "located", "stiff_fem"]',
                        'conditions = ["paper", "located", "stiff_fem", "fem", "mass_spring", "plate_spring", "a", "b", "c"]',
                        r":(\d+): design.conditions: 9 conditions; allowed: 1..8"),
}


@pytest.mark.parametrize("case", REFUSED)
def test_bad_conditions_are_refused_at_their_line(tmp_path, case):
    old, new, pattern = REFUSED[case]
    path = _protocol(tmp_path)
    text = path.read_text()
    assert old in text
    path.write_text(text.replace(old, new, 1))
    _, problems = check_protocol(path)
    hit = next((p for p in problems if re.search(pattern, p)), None)
    assert hit, problems
    line, field = int(re.search(pattern, hit).group(1)), re.search(r"\.toml:\d+: ([a-z_.]+):", hit).group(1)
    text = path.read_text().splitlines()[line - 1].strip()
    # the line of the key at fault, or of the table when the table itself is
    assert text == f"[{field}]" if field.count(".") == 1 and field.startswith("conditions.") else text.startswith(field.split(".")[-1] + " ="), (hit, text)
    res = studyctl("protocol", "validate", path)
    assert res.exit_code == 1
    assert "Traceback" not in res.output


def test_a_condition_whose_model_the_scene_lacks_runs_the_models_declared_defaults(tmp_path):
    """No [models.fem] in the scene: the condition's FEM is the model's declared options
    (sim/models/builtin.py) with the condition's keys on top, stored in full."""
    from sim.models.builtin import FemOptions

    path = _protocol(tmp_path)
    scene = tmp_path / "scene.toml"
    text = scene.read_text()
    a = text.index("[models.fem]")
    scene.write_text(text[:a] + text[text.index("\n[", a + 1) + 1:])
    protocol, problems = check_protocol(path)
    assert problems == []
    spec = condition_scene_spec(protocol, "stiff_fem")
    assert "fem" not in load_scene(scene).models
    defaults = {f.name: f.default for f in dataclasses.fields(FemOptions)} | {"order": 2}
    assert spec.model_spec().options == defaults


def test_sessions_store_what_each_condition_ran_and_reports_show_it(tmp_path):
    db = tmp_path / "s.db"
    run_synthetic_study(db, 2, seed=3, jobs=1, protocol_path=_protocol(tmp_path))
    con = sqlite3.connect(db)
    rows = con.execute("select session_id, model, label, config, config_sha256 from conditions order by session_id, position").fetchall()
    forces = dict(con.execute("select model, max(max_force_n) from trials group by model").fetchall())
    con.close()
    assert len(rows) == 6
    assert {r[1] for r in rows} == {"paper", "located", "stiff_fem"}
    for _, name, label, config, sha in rows:
        cfg = json.loads(config)
        assert cfg["condition"] == name
        assert config_sha256(cfg) == sha
        assert label in ("A", "B", "C")
    # two configurations of one model render different forces
    assert forces["paper"] != forces["located"]
    # the export carries the configuration; the reports name it, by condition
    assert studyctl("export", "--db", db, "--out", tmp_path / "ex").exit_code == 0
    cond = pd.read_csv(tmp_path / "ex" / "conditions.csv")
    assert {"config", "config_sha256"} <= set(cond.columns)
    assert cond["config"].map(lambda c: json.loads(c)["model"]).tolist().count("fem") == 2
    md = studyctl("report", "table1", "--db", db).output
    assert "| Question | paper: yes/no" in md
    assert "3 conditions" in md
    assert re.search(r"paper: plate_spring \(variant paper\), built in, configuration [0-9a-f]{12}; located: plate_spring \(variant located\)", md)
    assert "stiff_fem: fem (formulation linear, grasp_radius 0.005, order 1, resolution 0.008; E 6000 Pa, nu 0.45)" in md
    res = studyctl("report", "table1", "--db", db, "--format", "html", "--out", tmp_path / "r.html")
    assert res.exit_code == 0
    assert "<h2>Conditions</h2>" in (tmp_path / "r.html").read_text()
    facts = json.loads(studyctl("report", "table1", "--db", db, "--format", "json").output)["facts"]
    assert [c["condition"] for c in facts["conditions"]] == ["paper", "located", "stiff_fem"]
    assert all(c["sessions"] == 2 and len(c["config_sha256"]) == 64 for c in facts["conditions"])


def test_the_shipped_variants_protocol_validates():
    from tests.conftest import ROOT

    res = studyctl("protocol", "validate", ROOT / "protocols/plate_spring_variants.toml")
    assert res.exit_code == 0, res.output
    assert "3 conditions" in res.output, res.output
    p = load_protocol(ROOT / "protocols/plate_spring_variants.toml")
    variants = [resolved_config(c, condition_scene_spec(p, c)).get("variant") for c in p.conditions]
    assert variants == ["paper", "located", None]


def test_a_replay_runs_what_the_session_ran_or_refuses(tmp_path):
    db = tmp_path / "s.db"
    run_synthetic_study(db, 1, seed=5, jobs=1, protocol_path=_protocol(tmp_path))
    for k in (1, 2, 3):  # one trial per condition: the recorded forces, bit for bit
        out = json.loads(studyctl("replay", "--db", db, "--session", 1, "--trial", k, "--json").output)
        assert out["max_force_difference_n"] == 0.0, out
        assert out["ticks"] == out["recorded_ticks"], out
    # the scene changed since: the FEM condition now resolves to another configuration
    scene = tmp_path / "scene.toml"
    scene.write_text(scene.read_text().replace("resolution = 0.008", "resolution = 0.006", 1))
    con = sqlite3.connect(db)
    k = 1 + [r[0] for r in con.execute("select model from conditions where session_id = 1 order by position")].index("stiff_fem")
    con.close()
    res = studyctl("replay", "--db", db, "--session", 1, "--trial", k)
    assert res.exit_code == 1
    assert "condition 'stiff_fem' of session 1 ran configuration" in res.output
    assert "cannot replay it" in res.output
    assert "Traceback" not in res.output


def test_young_scales_the_linear_fems_grasp_stiffness(tmp_path):
    # linear elasticity: the stiffness is proportional to Young's modulus (6000 Pa against the law's 3919)
    import numpy as np

    from sim.scene import Scene

    p = load_protocol(_protocol(tmp_path))
    K = {}
    for c in ("fem", "stiff_fem"):
        scene = Scene(condition_scene_spec(p, c))
        K[c] = np.asarray(scene.model.grasp(scene.script(0).start, 0).data.K)
    ratio = 6000.0 / (2 * 1351.453 * 1.45)
    assert np.allclose(K["stiff_fem"], ratio * K["fem"], rtol=1e-5, atol=0.0)


def test_a_scene_value_that_clashes_with_a_condition_says_where_it_comes_from(tmp_path):
    tables = '[conditions.paper]\nmodel = "plate_spring"\nvariant = "paper"\n\n[conditions.corot]\nmodel = "fem"\nformulation = "corotational"\n'
    path = _protocol(tmp_path, conditions=("paper", "corot"), tables=tables)
    scene = tmp_path / "scene.toml"
    scene.write_text(scene.read_text().replace("\norder = 1 ", "\norder = 2 ", 1))  # the shipped scene's P2
    _, problems = check_protocol(path)
    assert any("conditions.corot.order: quadratic tetrahedra (order 2) run the linear formulation only (the scene's order = 2, "
               "with this condition's options)" in p for p in problems), problems


def test_the_observers_truth_is_the_scenes_whatever_the_conditions_order(tmp_path):
    # Review finding: the truth came from the first condition's scene (a stiffer FEM listed first
    # made the observer judge every condition against E = 6000 Pa)
    feats = {}
    for order in (("stiff_fem", "paper"), ("paper", "stiff_fem")):
        d = tmp_path / "_".join(order)
        d.mkdir()
        tables = '[conditions.paper]\nmodel = "plate_spring"\nvariant = "paper"\n\n[conditions.stiff_fem]\nmodel = "fem"\nyoung = 6000.0\n'
        run_synthetic_study(d / "s.db", 1, seed=2, jobs=1, protocol_path=_protocol(d, conditions=order, tables=tables))
        con = sqlite3.connect(d / "s.db")
        feats[order] = sorted(con.execute("select model, feature, value from observer_features").fetchall())
        con.close()
    assert feats[("stiff_fem", "paper")] == feats[("paper", "stiff_fem")]


def test_a_changed_configuration_is_not_resumed_and_a_failing_one_writes_nothing(tmp_path):
    db = tmp_path / "s.db"
    protocol = _protocol(tmp_path)
    assert studyctl("study", "init", "--protocol", protocol, "--db", db).exit_code == 0
    assert studyctl("participants", "add", "S01", "--synthetic", "--db", db).exit_code == 0
    scene = tmp_path / "scene.toml"
    original = scene.read_text()
    # the scene changed after the study was made, so that the FEM condition no longer builds
    scene.write_text(original.replace('formulation = "linear"', 'formulation = "corotational"', 1).replace("\norder = 1 ", "\norder = 2 ", 1))
    res = studyctl("session", "run", "--participant", "S01", "--synthetic", "--db", db)
    assert res.exit_code == 1, res.output
    assert "order" in res.output, res.output
    assert "Traceback" not in res.output, res.output
    con = sqlite3.connect(db)
    assert con.execute("select count(*) from sessions").fetchone()[0] == 0  # nothing half-made
    con.close()
    # a session interrupted, then its scene edited: its conditions would mix two configurations
    scene.write_text(original)
    from studyctl.session.run import run_session

    class Stop(Exception):
        pass

    def stop_after_first_trial(msg):
        if "trial 1 of 1" in msg and "(2 of 3)" in msg:
            raise Stop

    with pytest.raises(Stop):
        run_session(db, "S01", synthetic=True, seed=1, time_scale=0.0, progress=stop_after_first_trial)
    scene.write_text(original.replace("rate_hz = 30", "rate_hz = 60", 1))  # the visual rate: a mass-spring's frame step
    res = studyctl("session", "run", "--participant", "S01", "--synthetic", "--resume", "--db", db)
    assert res.exit_code == 1, res.output
    assert "ran configuration" in res.output, res.output
    assert "resuming would mix the two" in res.output, res.output


def test_a_configuration_is_the_same_wherever_the_project_lies(tmp_path):
    """The hash of what a condition runs names files by content, never by where they lie (a study
    moved to another directory resumes, the shipped rig profile matches on a clean clone)."""
    import shutil
    from pathlib import Path

    from studyctl.synthetic.rig import condition_keys

    root = Path(__file__).resolve().parents[1]
    moved = tmp_path / "elsewhere" / "protocols"
    shutil.copytree(root / "protocols", moved)
    (moved.parent / "data").mkdir()
    shutil.copy(root / "data/brain_fsaverage5.npz", moved.parent / "data")  # the scene's surface
    here, there = (load_protocol(d / "brain_pull_2015.toml") for d in (root / "protocols", moved))
    assert condition_keys(here) == condition_keys(there)
    cfg = resolved_config("fem", condition_scene_spec(there, "fem"))
    assert "elsewhere" not in json.dumps(cfg)
    assert cfg["material"]["law_source"]["file"] == "human_cortex.toml"
