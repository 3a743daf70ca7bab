"""Timing helpers: percentiles of per-call times, printed with ratios to targets."""

from __future__ import annotations

import time

import numpy as np


def per_call(fn, calls: int, batch: int = 100) -> np.ndarray:
    """Seconds per call, measured over batches of `batch` calls (amortises the clock's cost)."""
    out = np.empty(calls // batch)
    clock = time.perf_counter
    for b in range(len(out)):
        start = clock()
        for _ in range(batch):
            fn()
        out[b] = (clock() - start) / batch
    return out


def each_call(fn, calls: int) -> np.ndarray:
    out = np.empty(calls)
    clock = time.perf_counter
    for k in range(calls):
        start = clock()
        fn()
        out[k] = clock() - start
    return out


def report(name: str, seconds: np.ndarray, unit: str, target: float | None = None, reference: tuple[str, float] | None = None) -> dict:
    scale = {"us": 1e6, "ms": 1e3}[unit]
    v = seconds * scale
    p50, p95, p99 = np.percentile(v, [50, 95, 99])
    line = f"{name:<44} p50 {p50:9.3f} {unit}  p95 {p95:9.3f}  p99 {p99:9.3f}  max {v.max():9.3f}"
    if target is not None:
        line += f"  | target {target:g} {unit}: p99 is {target / p99:6.1f}x under" if p99 < target else f"  | target {target:g} {unit}: MISSED ({p99 / target:.1f}x over)"
    if reference is not None:
        line += f"  | {reference[0]} {reference[1]:g} {unit} = {reference[1] / p50:.0f}x p50"
    print(line)
    return {"name": name, "unit": unit, "p50": p50, "p95": p95, "p99": p99, "max": float(v.max())}
