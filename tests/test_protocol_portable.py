"""`protocol new` writes a folder that holds wherever it goes (docs/study.md, "A protocol of your
own"): the protocol names its scene beside it, and the scene names the shipped files it uses as
`shipped:PATH`, never an absolute path into one install (which broke when the venv moved or the
folder was shared). Moved elsewhere, the folder validates and its scene runs."""

import os
import shutil
import subprocess
import sys
import tomllib
from pathlib import Path

import pytest

from brainsim_assets import path as asset
from sim.scene import load_scene
from tests.conftest import ROOT
from tests.helpers import studyctl

KINDS = ["yes_no", "rating", "discrimination", "validity"]


def _strings(obj):
    if isinstance(obj, str):
        yield obj
    elif isinstance(obj, dict):
        for v in obj.values():
            yield from _strings(v)
    elif isinstance(obj, list):
        for v in obj:
            yield from _strings(v)


@pytest.mark.parametrize("kind", KINDS)
def test_the_scene_names_no_absolute_path(tmp_path, kind):
    assert studyctl("protocol", "new", "--kind", kind, "--out", tmp_path / "lab").exit_code == 0
    scene = tomllib.loads((tmp_path / "lab" / "scene.toml").read_text())
    absolute = [s for s in _strings(scene) if Path(s).is_absolute()]
    assert absolute == []


@pytest.mark.parametrize("kind", KINDS)
def test_the_scene_names_the_shipped_files_as_shipped(tmp_path, kind):
    assert studyctl("protocol", "new", "--kind", kind, "--out", tmp_path / "lab").exit_code == 0
    scene = tomllib.loads((tmp_path / "lab" / "scene.toml").read_text())
    assert scene["mesh"]["path"] == "shipped:data/brain_fsaverage5.npz"


@pytest.mark.parametrize("kind", KINDS)
def test_a_moved_folder_validates(tmp_path, kind):
    assert studyctl("protocol", "new", "--kind", kind, "--out", tmp_path / "lab").exit_code == 0
    moved = tmp_path / "shared" / "elsewhere"
    shutil.move(tmp_path / "lab", moved)
    res = studyctl("protocol", "validate", moved / "protocol.toml")
    assert res.exit_code == 0, res.output


def test_a_copied_folder_runs_its_scene(tmp_path):
    assert studyctl("protocol", "new", "--kind", "yes_no", "--out", tmp_path / "lab").exit_code == 0
    copy = tmp_path / "colleague" / "study"
    shutil.copytree(tmp_path / "lab", copy)
    shutil.rmtree(tmp_path / "lab")
    res = studyctl("sim", "run", "--scene", copy / "scene.toml", "--view", "none", "--time-scale", "0", "--duration", "0.2")
    assert res.exit_code == 0, res.output


def test_a_shipped_path_reads_the_shipped_file(tmp_path):
    assert studyctl("protocol", "new", "--kind", "yes_no", "--out", tmp_path / "lab").exit_code == 0
    spec = load_scene(tmp_path / "lab" / "scene.toml")
    assert spec.mesh_path == asset("data/brain_fsaverage5.npz")


def test_a_shipped_path_that_is_not_shipped_is_named(tmp_path):
    assert studyctl("protocol", "new", "--kind", "yes_no", "--out", tmp_path / "lab").exit_code == 0
    scene = tmp_path / "lab" / "scene.toml"
    scene.write_text(scene.read_text().replace("shipped:data/brain_fsaverage5.npz", "shipped:data/nowhere.npz"))
    res = studyctl("protocol", "validate", tmp_path / "lab" / "protocol.toml")
    assert res.exit_code == 1
    assert f"mesh.path: {asset('data/nowhere.npz')} does not exist" in res.output, res.output


def _install(where: Path) -> Path:
    """An installed layout of the assets (the package with copies of protocols/ and data/ as its
    package data, 6 MB), first on the path of the processes given it."""
    package = where / "brainsim_assets"
    package.mkdir(parents=True)
    shutil.copy(ROOT / "brainsim_assets" / "__init__.py", package)
    for folder in ("protocols", "data"):
        shutil.copytree(ROOT / folder, package / folder)
    return where


def _studyctl_in(install: Path, *args):
    env = os.environ | {"PYTHONPATH": os.pathsep.join([str(install), str(ROOT)])}
    return subprocess.run([sys.executable, "-m", "studyctl", *map(str, args)], capture_output=True, text=True, env=env, timeout=300,
                          cwd=install)  # -m puts the working folder first on the path: not the checkout


def test_a_folder_written_by_one_install_validates_after_the_install_moved(tmp_path):
    """The venv moved (or the folder went to a colleague's): its first install is gone."""
    first = _install(tmp_path / "venv-a" / "site-packages")
    res = _studyctl_in(first, "protocol", "new", "--kind", "yes_no", "--out", tmp_path / "lab")
    assert res.returncode == 0, res.stderr
    shutil.rmtree(tmp_path / "venv-a")
    second = _install(tmp_path / "venv-b" / "site-packages")
    res = _studyctl_in(second, "protocol", "validate", tmp_path / "lab" / "protocol.toml")
    assert res.returncode == 0, res.stdout + res.stderr
