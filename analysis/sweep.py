"""Run a sweep's independent tasks: in this process, on the local cores, or on a Dask cluster.

Tasks are plain picklable values and `fn` a module-level function, so the same sweep runs
unchanged in a process pool or on Dask workers (which must have this package installed).
Results come back in task order whatever order they finish in.
"""

from __future__ import annotations

import os
from collections.abc import Callable, Sequence


class SweepError(Exception):
    """A sweep could not run (e.g. the Dask scheduler is unreachable)."""


def default_jobs() -> int:
    return max(1, len(os.sched_getaffinity(0)))


def run_tasks(fn: Callable, tasks: Sequence, jobs: int | None = None, scheduler: str | None = None,
              progress: Callable[[int, int], None] | None = None) -> list:
    """`[fn(t) for t in tasks]`, in parallel; `progress(done, total)` after each task.

    A task gives the same bits here, in a local pool and on a Dask worker: every process that
    factorises runs its BLAS on one thread (`sim.linalg._one_thread_pools`)."""
    tasks = list(tasks)
    total = len(tasks)
    report = progress or (lambda done, total: None)
    if scheduler:
        return _run_dask(fn, tasks, scheduler, report)
    jobs = default_jobs() if jobs is None else jobs
    if jobs <= 1 or total <= 1:
        out = []
        for i, t in enumerate(tasks, start=1):
            out.append(fn(t))
            report(i, total)
        return out
    import multiprocessing as mp
    from concurrent.futures import ProcessPoolExecutor, as_completed

    results: list = [None] * total
    # spawn: a fresh interpreter per worker, no forked locks or threads (progress bars, BLAS)
    with ProcessPoolExecutor(max_workers=min(jobs, total), mp_context=mp.get_context("spawn")) as pool:
        futures = {pool.submit(fn, t): i for i, t in enumerate(tasks)}
        for done, fut in enumerate(as_completed(futures), start=1):
            results[futures[fut]] = fut.result()
            report(done, total)
    return results


def _run_dask(fn, tasks, scheduler, report):
    try:
        from distributed import Client, as_completed
    except ImportError:
        raise SweepError("--scheduler needs the dask extra: pip install 'brainsim-study[dask]'") from None
    try:
        client = Client(scheduler, timeout="10s")
    except (OSError, TimeoutError) as exc:
        raise SweepError(f"scheduler {scheduler}: cannot connect ({exc})") from None
    with client:
        futures = client.map(fn, tasks, pure=False)
        index = {f.key: i for i, f in enumerate(futures)}
        results: list = [None] * len(tasks)
        for done, fut in enumerate(as_completed(futures), start=1):
            results[index[fut.key]] = fut.result()
            report(done, len(tasks))
    return results
