"""A second model package written from docs/models.md's text alone (its code blocks, not the
shipped example), installed into a venv of its own with the page's commands, checked, run in a
study beside two built-in models, and named with its version in the study's report."""

from __future__ import annotations

import json
import os
import re
import shutil
import subprocess
import sys
import sysconfig
from pathlib import Path

from tests.conftest import ROOT
from tests.helpers import build_wheel, fast_protocol

DOCS = ROOT / "docs" / "models.md"
FENCE = re.compile(r"^```(\w*)\n(.*?)^```", re.S | re.M)


def _blocks() -> list[tuple[str, str]]:
    """The page's fenced code blocks: (language, text)."""
    return [(m.group(1), m.group(2)) for m in FENCE.finditer(DOCS.read_text())]


def _write_package(folder: Path) -> list[Path]:
    """Every block whose first line is `# stiffening/...`, written to that path under `folder`."""
    written = []
    for _, text in _blocks():
        first, _, body = text.partition("\n")
        if first.startswith("# stiffening/"):
            path = folder / first[2:].strip()
            path.parent.mkdir(parents=True, exist_ok=True)
            path.write_text(body)
            written.append(path)
    return written


def _commands(containing: str) -> list[str]:
    """The command lines of the page's plain block that holds `containing`."""
    (block,) = [text for lang, text in _blocks() if lang == "" and containing in text]
    return [line for line in block.splitlines() if line.strip()]


def test_a_model_written_from_the_docs_installs_into_its_own_venv_and_reports_its_version(tmp_path):
    work = tmp_path / "lab"
    work.mkdir()
    files = _write_package(work)
    assert sorted(p.relative_to(work).as_posix() for p in files) == ["stiffening/pyproject.toml",
                                                                     "stiffening/src/brainsim_stiffening/__init__.py"]
    wheel = build_wheel(tmp_path / "platform")  # docs/install.md's wheel, put where the page says it is
    (work / "dist").mkdir()
    shutil.copy(wheel, work / "dist" / wheel.name)
    venv = tmp_path / "venv"
    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "STUDYCTL_DB")}

    def run(line: str) -> str:
        args = line.replace("~/lab", str(venv)).split()
        if args[:3] == ["python3", "-m", "venv"]:
            args[0] = sys.executable
        res = subprocess.run(args, cwd=work, env=env, capture_output=True, text=True, timeout=600)
        assert res.returncode == 0, f"{line}: {res.stdout[-3000:]}{res.stderr[-3000:]}"
        return res.stdout

    install = _commands("python3 -m venv ~/lab")
    assert install[0] == "python3 -m venv ~/lab", install
    run(install[0])
    # the platform's dependencies: this venv's, through a path file (tests/test_wheel.py), not the index
    site = subprocess.run([str(venv / "bin/python"), "-c", "import sysconfig; print(sysconfig.get_paths()['purelib'])"],
                          check=True, capture_output=True, text=True).stdout.strip()
    Path(site, "deps.pth").write_text(sysconfig.get_paths()["purelib"] + "\n")
    assert install[1] == f"~/lab/bin/pip install dist/{wheel.name}", install
    run(install[1] + " --no-deps")
    for line in install[2:]:  # the model's wheel and its install: offline, as the page writes them
        run(line)

    models = json.loads(run("~/lab/bin/studyctl model list --json"))
    own = next(m for m in models["models"] if m["name"] == "stiffening")
    assert own["source"] == "brainsim-stiffening 0.1.0"
    assert not own["builtin"]
    assert models["problems"] == []
    check = _commands("~/lab/bin/studyctl model list")
    assert "~/lab/bin/studyctl model check stiffening --contract" in check
    card = json.loads(run("~/lab/bin/studyctl model check stiffening --contract --json"))
    assert card["violations"] == [], card["violations"]
    assert all(r["ok"] for r in card["contract"]), card["contract"]
    assert "radius" in run("~/lab/bin/studyctl model describe stiffening")

    # the page's protocol edit on a fast protocol (coarse mesh, one short trial)
    (toml,) = [text for lang, text in _blocks() if lang == "toml" and "[conditions.stiff]" in text]
    design, _, table = toml.partition("[conditions.stiff]")
    assert design.strip() == '[design]\nconditions = ["plate_spring", "fem", "stiff"]'
    study = work / "mystudy"
    study.mkdir()
    protocol = fast_protocol(study, conditions=("plate_spring", "fem", "stiff"), trials=1)
    protocol.write_text(protocol.read_text().replace("[inclusion]", "[conditions.stiff]" + table + "\n[inclusion]", 1))
    run("~/lab/bin/studyctl protocol validate mystudy/protocol.toml")
    run("~/lab/bin/studyctl synth --db mystudy/study.db --protocol mystudy/protocol.toml --participants 1")
    text = run("~/lab/bin/studyctl report text --db mystudy/study.db")
    assert "Condition stiff ran the stiffening model of the package brainsim-stiffening 0.1.0" in text, text
    assert "Condition fem ran the fem model built into brainsim-study" in text, text
    table1 = run("~/lab/bin/studyctl report table1 --db mystudy/study.db")
    assert "stiff: stiffening (" in table1, table1
    assert "from brainsim-stiffening 0.1.0 (source SHA-256 " in table1, table1
    latex = run("~/lab/bin/studyctl report table1 --db mystudy/study.db --format latex")
    assert "Models from outside brainsim-study: stiff ran stiffening from brainsim-stiffening 0.1.0" in latex, latex
    facts = json.loads(run("~/lab/bin/studyctl report table1 --db mystudy/study.db --format json"))["facts"]
    source = next(c["source"] for c in facts["conditions"] if c["condition"] == "stiff")
    assert (source["package"], source["version"], source["builtin"]) == ("brainsim-stiffening", "0.1.0", False)
