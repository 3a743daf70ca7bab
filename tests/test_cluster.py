"""`synth` and `plan` on a Dask cluster (a LocalCluster of worker processes): the same answers as
local jobs for the same seed, every participant stored exactly once when a worker is killed
mid-run, and an unreachable cluster refused before anything is written."""

import os
import signal
import sqlite3

import numpy as np
import pandas as pd
import pytest
from click.testing import CliRunner

from studyctl.cli import cli
from studyctl.synthetic.synth_run import run_synthetic_study
from tests.helpers import fast_protocol, synthetic_content, synthetic_summary

distributed = pytest.importorskip("distributed")


@pytest.fixture(scope="module")
def cluster():
    with distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=True, dashboard_address=None) as c:
        yield c


def test_synth_on_a_cluster_equals_local_jobs_and_a_killed_worker_loses_no_participant(tmp_path, cluster):
    protocol = fast_protocol(tmp_path, trials=1)
    run_synthetic_study(tmp_path / "local.db", 3, seed=5, jobs=2, protocol_path=protocol)
    killed = []
    with distributed.Client(cluster) as watcher:
        def kill_a_busy_worker(done, total):
            if done == 1:  # two participants left, each worker running one
                busy = [w for w, keys in watcher.processing().items() if keys]
                pid = watcher.run(os.getpid, workers=busy[:1])[busy[0]]
                os.kill(pid, signal.SIGKILL)  # its nanny starts a new one; the scheduler reruns its task
                killed.append(busy[0])

        out = run_synthetic_study(tmp_path / "dask.db", 3, seed=5, protocol_path=protocol, scheduler=cluster.scheduler_address,
                                  progress=kill_a_busy_worker)
    assert killed
    assert out["participants"] == 3
    con = sqlite3.connect(tmp_path / "dask.db")
    sessions = con.execute("select code, status, synthetic from sessions order by code").fetchall()
    trials = con.execute("select count(*), count(distinct session_id || model || trial) from trials").fetchone()
    con.close()
    assert sessions == [(f"S{k:03d}", "done", 1) for k in range(1, 4)]  # each participant once, finished
    assert trials == (3 * 3, 3 * 3)
    # the same answers, orders, trials' forces and perceived features as the local processes
    assert synthetic_content(tmp_path / "dask.db") == synthetic_content(tmp_path / "local.db")
    for (path,) in sqlite3.connect(tmp_path / "dask.db").execute("select trace_path from trials"):
        a, b = np.load(tmp_path / path), np.load(tmp_path / path.replace("dask.db", "local.db"))
        assert all(np.array_equal(a[k], b[k]) for k in a.files if k != "deformation_s")  # deformation times are measured


def _summaries():
    from studyctl.synthetic.observer import ObserverParams

    slow = synthetic_summary(1.0, flops=ObserverParams().flops_per_ms * 80)
    return {"plate_spring": [synthetic_summary(1.0), synthetic_summary(1.2)], "fem": [synthetic_summary(1.0)], "mass_spring": [slow]}


def test_plan_tables_are_the_same_here_in_local_processes_and_on_a_cluster(tmp_path, cluster):
    from studyctl.protocol import load_protocol
    from studyctl.synthetic.plan import BATCH, null_table, power_table

    protocol = load_protocol(fast_protocol(tmp_path, trials=1))
    kw = {"simulations": BATCH + 5, "seed": 3, "summaries": _summaries(), "primary": False}  # two batches per N, one short
    seen = []
    here = power_table(protocol, [6, 12], **kw, progress=lambda done, total: seen.append((done, total)))
    assert seen[-1] == (2 * (BATCH + 5), 2 * (BATCH + 5))
    assert len(seen) == 4
    pd.testing.assert_frame_equal(here, power_table(protocol, [6, 12], **kw, jobs=2))
    pd.testing.assert_frame_equal(here, power_table(protocol, [6, 12], **kw, scheduler=cluster.scheduler_address))
    assert here["power"].between(0, 1).all()
    assert (here["simulations"] == BATCH + 5).all()
    null = null_table(protocol, participants=12, **kw)
    pd.testing.assert_frame_equal(null, null_table(protocol, participants=12, **kw, scheduler=cluster.scheduler_address))


@pytest.mark.parametrize("command", [["synth", "--participants", "2"], ["plan", "--participants", "6", "--simulations", "10"]])
def test_an_unreachable_scheduler_is_a_one_line_error_and_nothing_is_written(tmp_path, command):
    db = tmp_path / "s.db"
    args = command + (["--db", str(db)] if command[0] == "synth" else []) + ["--scheduler", "tcp://127.0.0.1:1"]
    res = CliRunner().invoke(cli, args)
    assert res.exit_code == 1, res.output
    assert "scheduler tcp://127.0.0.1:1: cannot connect" in res.output, res.output
    assert len(res.output.strip().splitlines()) == 1
    assert "Traceback" not in res.output
    assert not db.exists()


def test_a_lab_model_runs_on_the_cluster_as_in_local_jobs(tmp_path, cluster):
    """A condition of a lab's own model (tests/plugins, by "package.module:Class"): the workers
    load it like the built-in ones, and the answers are the local jobs'."""
    from tests.helpers import BAD

    protocol = fast_protocol(tmp_path, conditions=("plate_spring", "own"), trials=1)
    protocol.write_text(protocol.read_text().replace("[inclusion]", f'[conditions.own]\nmodel = "{BAD}:Spring"\n\n[inclusion]', 1))
    run_synthetic_study(tmp_path / "local.db", 2, seed=7, jobs=1, protocol_path=protocol)
    out = run_synthetic_study(tmp_path / "dask.db", 2, seed=7, protocol_path=protocol, scheduler=cluster.scheduler_address)
    assert out["participants"] == 2
    assert synthetic_content(tmp_path / "dask.db") == synthetic_content(tmp_path / "local.db")
    models = {m for (m,) in sqlite3.connect(tmp_path / "dask.db").execute("select distinct model from trials")}
    assert models == {"plate_spring", "own"}
