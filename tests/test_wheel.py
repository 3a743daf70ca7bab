"""The wheel as a user installs it: built from the repository, installed into a new venv, run
from a folder outside the checkout. It must carry the brain, the scene, the protocol, the model
files, the field and the observer's truth (brainsim_assets)."""

import json
import os
import shutil
import subprocess
import sys
import sysconfig
from pathlib import Path

import pytest

from tests.conftest import ROOT
from tests.helpers import build_wheel


def run_as_a_user(venv: Path, cwd: Path) -> dict:
    """The issue's commands, from `cwd`, with the venv's own `studyctl` and Python."""
    bin_ = venv / "bin"
    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "STUDYCTL_DB")}

    def run(*args):
        res = subprocess.run([str(a) for a in args], cwd=cwd, env=env, capture_output=True, text=True, timeout=600)
        assert res.returncode == 0, f"{args}: {res.stdout[-2000:]}{res.stderr[-2000:]}"
        return res.stdout

    out = {"help": run(bin_ / "studyctl", "-h"), "version": run(bin_ / "python", "-m", "studyctl", "--version")}
    out["sim"] = json.loads(run(bin_ / "studyctl", "sim", "run", "--time-scale", "0", "--duration", "0.5", "--json"))
    out["init"] = run(bin_ / "studyctl", "study", "init", "--db", cwd / "study.db")  # the shipped protocol, installed
    out["synth"] = json.loads(run(bin_ / "studyctl", "synth", "--db", cwd / "study.db", "--participants", "2", "--json"))
    out["published"] = json.loads(run(bin_ / "studyctl", "report", "published", "--json"))
    out["where"] = run(bin_ / "python", "-c", "import brainsim_assets, studyctl; print(brainsim_assets.root()); print(studyctl.__file__)")
    return out


def _check(out: dict, venv: Path) -> None:
    assert "Usage: studyctl" in out["help"]
    assert "--help" in out["help"]
    assert out["version"].strip().startswith("studyctl, version ")
    assert out["sim"]["ticks"] == 500
    assert out["sim"]["scene"] == "brain_pull"
    assert out["synth"]["participants"] == 2
    assert out["synth"]["synthetic"] is True
    assert len(out["published"]["flags"]) == 1
    assert "bounds" in out["published"]
    # everything came from the venv, nothing from the checkout
    assert str(ROOT) not in out["where"]
    assert all(str(venv) in line for line in out["where"].split())


def test_the_wheel_carries_its_data_and_runs_from_outside_the_repository(tmp_path):
    """Installed (no dependencies) into a new venv that sees this venv's dependencies through a
    path file, but not the checkout: fast enough for every run."""
    wheel = build_wheel(tmp_path)
    venv = tmp_path / "venv"
    subprocess.run([sys.executable, "-m", "venv", str(venv)], check=True)
    py = venv / "bin" / "python"
    site = subprocess.run([str(py), "-c", "import sysconfig; print(sysconfig.get_paths()['purelib'])"], check=True,
                          capture_output=True, text=True).stdout.strip()
    # this venv's third-party packages as a plain path entry: its .pth files (the editable
    # install of the checkout) are not processed from there
    Path(site, "deps.pth").write_text(sysconfig.get_paths()["purelib"] + "\n")
    subprocess.run([str(py), "-m", "pip", "install", "-q", "--no-deps", str(wheel)], check=True, capture_output=True)
    outside = tmp_path / "elsewhere"
    outside.mkdir()
    _check(run_as_a_user(venv, outside), venv)


def _python312():
    for cand in (shutil.which("python3.12"), str(Path.home() / ".pyenv/versions/3.12.1/bin/python3.12")):
        if cand and Path(cand).exists() and subprocess.run([cand, "-c", "pass"], capture_output=True).returncode == 0:
            return cand
    return None


@pytest.mark.slow
def test_the_wheel_installs_with_its_dependencies_on_python_3_12_and_runs_outside(tmp_path):
    """The whole install a user does, on Python 3.12, dependencies from the package index
    (about 2 minutes; scikit-sparse builds against the system's SuiteSparse)."""
    py312 = _python312()
    if py312 is None:
        pytest.fail("Python 3.12 is not installed (pyenv install 3.12, or the distribution's python3.12)")
    wheel = build_wheel(tmp_path)
    venv = tmp_path / "venv312"
    subprocess.run([py312, "-m", "venv", str(venv)], check=True)
    subprocess.run([str(venv / "bin/python"), "-m", "pip", "install", "-q", "--upgrade", "pip>=25.1"], check=True, capture_output=True)
    res = subprocess.run([str(venv / "bin/python"), "-m", "pip", "install", "-q", str(wheel)], capture_output=True, text=True)
    assert res.returncode == 0, res.stderr[-3000:]
    outside = tmp_path / "elsewhere"
    outside.mkdir()
    out = run_as_a_user(venv, outside)
    _check(out, venv)
    assert "python3.12" in out["where"]
