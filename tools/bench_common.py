"""Shared by the benchmark scripts: variants timed interleaved in one process."""
from __future__ import annotations

import time


def interleaved(variants, repeat):
    """Call every ``(name, fn)`` once to compile or load it, then ``repeat`` rounds of one
    call each, interleaved (a load change hits every variant alike). Returns ``(times,
    outs)``: wall times per name and each variant's last return value."""
    for _name, fn in variants:
        fn()
    times = {name: [] for name, _ in variants}
    outs = {}
    for _ in range(repeat):
        for name, fn in variants:
            t0 = time.perf_counter()
            outs[name] = fn()
            times[name].append(time.perf_counter() - t0)
    return times, outs


def best_time(fn, repeat):
    """The shortest wall time [s] of ``repeat`` calls of ``fn()``."""
    best = float("inf")
    for _ in range(repeat):
        t0 = time.perf_counter()
        fn()
        best = min(best, time.perf_counter() - t0)
    return best


def pointer_loop():
    """A compiled function ``many(fn, task, n, t, x, sig, p, modes, out, x2)`` calling the
    system function ``fn`` ``n`` times through its pointer (alternating ``x`` and ``x2`` so
    that nothing is hoisted out of the loop); returns the sum of the results."""
    from spidersim.solver import sysfn
    from spidersim.solver._jit import njit

    @njit
    def many(fn, task, n, t, x, sig, p, modes, out, x2):
        acc = 0.0
        for i in range(n):
            xx = x if (i & 1) == 0 else x2
            acc += sysfn.call(fn, task, t + 1e-9 * i, xx, sig, p, modes, out, 0, 0.0)
        return acc
    return many
