import shutil
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
SCENE = ROOT / "protocols" / "scenes" / "brain_pull.toml"
BRAIN_PARAMS = ROOT / "protocols" / "models" / "plate_spring_handset.toml"  # hand-set values the tests rely on


@pytest.fixture
def root() -> Path:
    return ROOT


@pytest.fixture(scope="session")
def small_study(tmp_path_factory):
    """A small SYNTHETIC study database, shared by the report tests."""
    from studyctl.synthetic.synth_run import run_synthetic_study
    from tests.helpers import fast_protocol

    tmp = tmp_path_factory.mktemp("study")
    db = tmp / "s.db"
    run_synthetic_study(db, 6, seed=5, protocol_path=fast_protocol(tmp, trials=1))
    return db


@pytest.fixture(scope="session")
def variants_study(tmp_path_factory):
    """A small SYNTHETIC study of the shipped ratings example (Likert items, the SUS after each
    condition, a choice at the end), shared by the report tests."""
    from studyctl.synthetic.synth_run import run_synthetic_study
    from tests.helpers import variants_protocol

    tmp = tmp_path_factory.mktemp("variants")
    db = tmp / "v.db"
    run_synthetic_study(db, 6, seed=7, protocol_path=variants_protocol(tmp))
    return db


def write_params(path: Path, **overrides) -> Path:
    """A plate-spring parameter file: the brain defaults with `overrides` (None drops a key)."""
    import tomllib

    data = tomllib.loads(BRAIN_PARAMS.read_text())
    data.update(overrides)
    lines = []
    for k, v in data.items():
        if v is None:
            continue
        lines.append(f"{k} = {v!r}" if not isinstance(v, str) else f'{k} = "{v}"')
    path.write_text("\n".join(lines) + "\n")
    return path


@pytest.fixture(scope="session")
def display():
    """A real X display for the participant view: Xvfb (installed by `make test`), started
    once for the session; DISPLAY is set for this process and its children."""
    import os

    from bench.common import start_xvfb

    try:
        proc, display = start_xvfb()
    except FileNotFoundError:
        pytest.fail("Xvfb is not installed: run `make test`, which installs the xvfb package")
    old = os.environ.get("DISPLAY")
    os.environ["DISPLAY"] = display
    yield os.environ["DISPLAY"]
    proc.terminate()
    proc.wait(timeout=10)
    if old is None:
        os.environ.pop("DISPLAY", None)
    else:
        os.environ["DISPLAY"] = old


@pytest.fixture
def xdotool(display):
    """A display where xdotool can type and click (the window tests)."""
    if shutil.which("xdotool") is None:
        pytest.fail("xdotool is not installed: run `make test`, which installs it")
    return display
