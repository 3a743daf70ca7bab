"""An optional extra that is installed but fails to import (a missing shared library, a build
for another NumPy: ImportError or OSError from inside the package): `export --format parquet`
and `--scheduler` say so in one line with how to install it, exit 1, and write nothing. The
broken package is a fake one put first on the path of a fresh process."""

import os
import subprocess
import sys

import pytest

from tests.conftest import ROOT
from tests.helpers import fast_protocol, studyctl

BROKEN = {
    "ImportError": 'raise ImportError("libarrow.so.1900: cannot open shared object file: No such file or directory")',
    "OSError": 'raise OSError("libarrow.so.1900: wrong ELF class:\\nELFCLASS32")',
}


def _broken(tmp_path, package: str, body: str):
    fake = tmp_path / "fake"
    (fake / package).mkdir(parents=True)
    (fake / package / "__init__.py").write_text(body + "\n")
    return fake


def _studyctl(fake, *args):
    env = os.environ | {"PYTHONPATH": os.pathsep.join([str(fake), str(ROOT)])}
    return subprocess.run([sys.executable, "-m", "studyctl", *map(str, args)], capture_output=True, text=True, env=env,
                          cwd=fake, timeout=300)


@pytest.fixture(scope="module")
def db(tmp_path_factory):
    d = tmp_path_factory.mktemp("extras")
    res = studyctl("study", "init", "--protocol", fast_protocol(d, conditions=("plate_spring",), trials=1), "--db", d / "s.db")
    assert res.exit_code == 0, res.output
    return d / "s.db"


@pytest.mark.parametrize("kind", sorted(BROKEN))
def test_export_parquet_with_a_pyarrow_that_fails_to_import_is_one_line(tmp_path, db, kind):
    fake = _broken(tmp_path, "pyarrow", BROKEN[kind])
    before = db.read_bytes()
    res = _studyctl(fake, "export", "--db", db, "--format", "parquet", "--out", tmp_path / "out")
    assert res.returncode == 1
    reason = "libarrow.so.1900: cannot open shared object file: No such file or directory" if kind == "ImportError" \
        else "libarrow.so.1900: wrong ELF class: ELFCLASS32"
    assert res.stderr == (f"Error: export --format parquet needs pyarrow, which failed to import: {reason}; "
                          "pip install 'brainsim-study[parquet]'\n")
    assert res.stdout == ""
    assert not (tmp_path / "out").exists()
    assert db.read_bytes() == before


def test_export_parquet_without_pyarrow_names_the_extra(tmp_path, db):
    """A package that is absent (a ModuleNotFoundError of pyarrow itself) is not 'failed to import'."""
    fake = _broken(tmp_path, "pyarrow", 'raise ModuleNotFoundError("No module named \'pyarrow\'", name="pyarrow")')
    res = _studyctl(fake, "export", "--db", db, "--format", "parquet", "--out", tmp_path / "out")
    assert res.returncode == 1
    assert res.stderr == "Error: export --format parquet needs the parquet extra: pip install 'brainsim-study[parquet]'\n"
    assert not (tmp_path / "out").exists()


def test_a_scheduler_with_a_distributed_that_fails_to_import_is_one_line(tmp_path):
    fake = _broken(tmp_path, "distributed", 'raise OSError("libzmq.so.5: cannot open shared object file")')
    res = _studyctl(fake, "synth", "--participants", "2", "--db", tmp_path / "s.db", "--scheduler", "tcp://127.0.0.1:1")
    assert res.returncode == 1
    assert res.stderr == ("Error: --scheduler needs distributed, which failed to import: libzmq.so.5: cannot open shared object "
                          "file; pip install 'brainsim-study[dask]'\n")
    assert not (tmp_path / "s.db").exists()
