"""Run independent tasks (a bench's cases, synthetic participants, a plan's simulated studies):
in this process, on the local cores, or on a Dask cluster.

Tasks are plain picklable values and `fn` a module-level function, so the same work runs
unchanged in a process pool or on Dask workers (which must have this package installed).
`run_tasks` gives the results in task order; `completed` gives each as it finishes.
"""

from __future__ import annotations

import multiprocessing as mp
import os
import signal
import socket
from collections.abc import Callable, Iterator, Sequence
from concurrent.futures import ProcessPoolExecutor, as_completed

from sim.errors import SimError


class SweepError(SimError):
    """A sweep could not run (e.g. the Dask scheduler is unreachable)."""


def default_jobs() -> int:
    return max(1, len(os.sched_getaffinity(0)))


def run_tasks(fn: Callable, tasks: Sequence, jobs: int | None = None, scheduler: str | None = None,
              progress: Callable[[int, int], None] | None = None) -> list:
    """`[fn(t) for t in tasks]`, in parallel; `progress(done, total)` after each task.

    A task gives the same bits here, in a local pool and on a Dask worker: every process that
    factorises runs its BLAS on one thread (`sim.linalg.one_thread_pools`)."""
    tasks = list(tasks)
    results: list = [None] * len(tasks)
    for done, (i, result) in enumerate(completed(fn, tasks, jobs, scheduler), start=1):
        results[i] = result
        if progress:
            progress(done, len(tasks))
    return results


def completed(fn: Callable, tasks: Sequence, jobs: int | None = None, scheduler: str | None = None) -> Iterator[tuple[int, object]]:
    """`(index, fn(tasks[index]))` as each task finishes: in this process (jobs 1), in a pool of
    `jobs` local processes (default: one per core), or on the Dask cluster at `scheduler`,
    which runs a task again elsewhere when its worker dies (up to `distributed`'s
    allowed-failures, 3 by default; a local process that dies stops the pool instead)."""
    tasks = list(tasks)
    if scheduler:
        yield from _dask(fn, tasks, scheduler)
        return
    jobs = default_jobs() if jobs is None else jobs
    if jobs <= 1 or len(tasks) <= 1:
        for i, t in enumerate(tasks):
            yield i, fn(t)
        return

    # spawn: a fresh interpreter per worker, no forked locks or threads (progress bars, BLAS)
    pool = ProcessPoolExecutor(max_workers=min(jobs, len(tasks)), mp_context=mp.get_context("spawn"), initializer=_quiet_on_ctrl_c)
    wait = True
    try:
        futures = {pool.submit(fn, t): i for i, t in enumerate(tasks)}
        for fut in as_completed(futures):
            yield futures[fut], fut.result()
    except KeyboardInterrupt:  # the workers ignore it (no traceback from them): end them, do not wait
        wait = False
        for proc in list((getattr(pool, "_processes", None) or {}).values()):
            proc.terminate()
        raise
    finally:  # on an error here or in the caller: the tasks not started are dropped, not run first
        pool.shutdown(wait=wait, cancel_futures=True)


def _quiet_on_ctrl_c() -> None:
    """A pool worker ignores Ctrl-C (the terminal sends it to every process of the command): the
    command's own process gets it, ends the workers and says what was kept. (Workers that died of
    it themselves would break the pool first, and the command would report that instead.)"""
    signal.signal(signal.SIGINT, signal.SIG_IGN)


def connect(scheduler: str):
    """A Dask client of the cluster at `scheduler`, or a SweepError saying why not (callers
    that write check it before they write anything)."""
    distributed = _distributed()  # before the address is tried: a missing extra is said as such
    try:
        if scheduler.startswith("tcp://"):  # a refused port is told at once (the client would retry for 10 s)
            host, _, port = scheduler[len("tcp://"):].rpartition(":")
            if not host or not port.isdigit():
                raise ValueError("the address needs a host and a port, e.g. tcp://host:8786")
            socket.create_connection((host.strip("[]"), int(port)), timeout=10).close()
        return distributed.Client(scheduler, timeout="10s")
    except (OSError, TimeoutError, ValueError) as exc:
        raise SweepError(f"scheduler {scheduler}: cannot connect ({exc})") from None


def reachable(scheduler: str | None) -> None:
    """A SweepError now when there is a `scheduler` and it cannot be reached: callers check it
    before they write anything or run work that comes before the cluster's."""
    if scheduler is not None and not scheduler.strip():  # '' is not "here": say so rather than run locally
        raise SweepError("--scheduler: the address is empty; give one (tcp://host:8786), or leave --scheduler out to run here")
    if scheduler:
        connect(scheduler).close()


def _distributed():
    """The `distributed` package (the dask extra), or a SweepError saying how to install it."""
    try:
        import distributed  # optional: the dask extra, only for --scheduler
    except (ImportError, OSError) as exc:  # absent, or installed and broken (a dependency, a shared library)
        if isinstance(exc, ModuleNotFoundError) and exc.name == "distributed":
            raise SweepError("--scheduler needs the dask extra: pip install 'brainsim-study[dask]'") from None
        reason = " ".join(str(exc).split())[:200] or type(exc).__name__
        raise SweepError(f"--scheduler needs distributed, which failed to import: {reason}; "
                         "pip install 'brainsim-study[dask]'") from None
    return distributed


def _dask(fn, tasks, scheduler):
    with connect(scheduler) as client:
        futures = client.map(fn, tasks, pure=False)
        index = {f.key: i for i, f in enumerate(futures)}
        for fut in _distributed().as_completed(futures):
            yield index[fut.key], fut.result()
