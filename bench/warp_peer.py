"""The peer: NVIDIA Warp on its CPU device, a kernel of the same local step as
`sim/models/spring_kernels.spring_rhs` (every moving spring projected to its rest length, k d scattered to
its two free nodes with atomic adds), on the same springs and state. `warp.sim` is gone from
Warp 1.x (its solvers moved to the `newton` package); the local/global step has no newton
counterpart, so the comparison is kernel to kernel, and the global solve (CHOLMOD) is shared."""

from __future__ import annotations

import time

import numpy as np


def local_step_ms(x, ei, ej, k, rest, free_pos, n_free, calls: int = 200) -> dict | None:
    """ms per call of the Warp kernel on the CPU, its first compile in s, and its largest
    difference from `sim.models.spring_kernels.spring_rhs`; None where warp-lang is not installed."""
    import contextlib
    import sys

    try:
        import warp as wp
    except ImportError:
        return None
    with contextlib.redirect_stdout(sys.stderr):  # Warp's banner and compile notices: not in --json output
        return _run(wp, x, ei, ej, k, rest, free_pos, n_free, calls)


def _run(wp, x, ei, ej, k, rest, free_pos, n_free, calls):
    wp.config.quiet = True
    wp.init()

    @wp.kernel
    def spring_rhs(x: wp.array(dtype=wp.vec3d), ei: wp.array(dtype=wp.int64), ej: wp.array(dtype=wp.int64),
                   k: wp.array(dtype=wp.float64), rest: wp.array(dtype=wp.float64), free_pos: wp.array(dtype=wp.int64),
                   out: wp.array(dtype=wp.vec3d)):
        s = wp.tid()
        i = ei[s]
        j = ej[s]
        d = x[i] - x[j]
        length = wp.length(d)
        c = k[s]
        if length > wp.float64(0.0):
            c = c * rest[s] / length
        fi = free_pos[i]
        fj = free_pos[j]
        if fi >= wp.int64(0):
            wp.atomic_add(out, int(fi), c * d)
        if fj >= wp.int64(0):
            wp.atomic_sub(out, int(fj), c * d)

    dev = "cpu"
    arrays = [wp.array(np.ascontiguousarray(x), dtype=wp.vec3d, device=dev), wp.array(ei, dtype=wp.int64, device=dev),
              wp.array(ej, dtype=wp.int64, device=dev), wp.array(k, dtype=wp.float64, device=dev),
              wp.array(rest, dtype=wp.float64, device=dev), wp.array(free_pos, dtype=wp.int64, device=dev)]
    out = wp.zeros(n_free, dtype=wp.vec3d, device=dev)
    start = time.perf_counter()
    wp.launch(spring_rhs, dim=len(ei), inputs=[*arrays, out], device=dev)
    wp.synchronize()
    compile_s = time.perf_counter() - start
    start = time.perf_counter()
    for _ in range(calls):
        out.zero_()
        wp.launch(spring_rhs, dim=len(ei), inputs=[*arrays, out], device=dev)
    wp.synchronize()
    ms = (time.perf_counter() - start) / calls * 1e3
    from sim.models.spring_kernels import spring_rhs as ours

    diff = float(np.abs(out.numpy() - ours(x, ei, ej, k, rest, free_pos, n_free)).max())
    return {"ms": ms, "compile_s": compile_s, "max_difference": diff, "version": wp.__version__}
