"""What the light commands load: `studyctl --help`, a protocol's check and `status` import none of
the heavy libraries (the statistics, the plots, the compiled kernels, OpenGL, QUEST+, SciPy); the
few imports left inside functions outside the CLI are there to keep it so."""

import json
import subprocess
import sys
import textwrap
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
PROTOCOL = ROOT / "protocols" / "brain_pull_2015.toml"
HEAVY = ("matplotlib", "statsmodels", "numba", "moderngl", "glfw", "OpenGL", "sklearn", "questplus", "scipy", "icalendar", "distributed")


def _run(*args: str) -> dict:
    """`studyctl ARGS` run in a fresh interpreter: its exit status and the HEAVY top-level
    modules the interpreter holds after it."""
    code = textwrap.dedent(f"""
        import contextlib, io, json, sys
        from studyctl.cli import cli
        status = 0
        with contextlib.redirect_stdout(io.StringIO()):
            try:
                cli.main(args={list(args)!r}, prog_name="studyctl")
            except SystemExit as exc:
                status = exc.code or 0
        print(json.dumps({{"status": status, "heavy": sorted(m for m in {HEAVY!r} if m in sys.modules)}}))
    """)
    out = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True, check=True)
    return json.loads(out.stdout.strip().splitlines()[-1])


def test_importing_the_cli_loads_no_heavy_library():
    code = f"import json, sys, studyctl.cli; print(json.dumps(sorted(m for m in {HEAVY!r} if m in sys.modules)))"
    out = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True, check=True)
    assert json.loads(out.stdout) == []


def test_help_loads_no_heavy_library():
    got = _run("--help")
    assert got["status"] == 0
    assert got["heavy"] == []


def test_a_protocols_check_loads_no_heavy_library():
    got = _run("protocol", "validate", str(PROTOCOL))
    assert got["status"] == 0
    assert got["heavy"] == []


def test_status_loads_no_heavy_library(tmp_path):
    db = tmp_path / "study.db"
    subprocess.run([sys.executable, "-m", "studyctl", "study", "init", "--db", str(db), "--protocol", str(PROTOCOL)],
                   cwd=ROOT, capture_output=True, check=True)
    got = _run("status", "--db", str(db))
    assert got["status"] == 0
    assert got["heavy"] == []
