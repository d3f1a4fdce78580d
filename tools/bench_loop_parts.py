"""Where the compiled loop's time per step goes (issue 14): measured, not guessed.

    python tools/bench_loop_parts.py [servo|ball|loop ...]

For each problem (the runs of ``tools/bench_loop.py``: DP54, the same tolerances):

1. **Python around the loop**: ``Diagram.simulate`` against the compiled ``run_loop`` calls
   alone (best of 30): what ``simulate`` spends outside machine code (compile-cache look-up,
   arrays, the Result).
2. **System-function calls per step, by task**: the run again with a counting system
   function (a C function of the same signature that counts its task and calls the diagram's
   own through its address; the loop is not changed, so the counts are those of the real
   run; the counting costs time, so this run is not timed).
3. **Cost of one call, by task**: each task called 20,000 times in a compiled loop through
   the pointer, as ``run_loop`` calls it (ns per call, best of 7); ``DERIVATIVES`` also
   with a loop that alternates two states, so the branch predictor and caches see what the
   DP54 stages give them.
4. **The split**: calls x cost per task against the ``run_loop`` time: what the system
   function costs per step and what is left for the loop's own work (stages, error norm,
   bookkeeping, events, recording).
"""
from __future__ import annotations

import math
import os
import sys
import time

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from check_loop_identical import CASES  # noqa: E402

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


def _counting_system(address, counts):
    """A system function that adds 1 to ``counts[task]`` and calls the one at ``address``."""
    from llvmlite import ir
    from numba import cfunc, types
    from numba.extending import intrinsic
    from spidersim.solver.sysfn import SYSTEM_SIG

    @intrinsic
    def _forward(typingctx, task, t, x, sig, p, modes, out, k, f):
        def codegen(context, builder, signature, args):
            dbl, i64 = ir.DoubleType(), ir.IntType(64)
            ptr = ir.PointerType(dbl)
            fnty = ir.FunctionType(dbl, [i64, dbl, ptr, ptr, ptr, ptr, ptr, i64, dbl])
            target = builder.inttoptr(ir.Constant(i64, address), fnty.as_pointer())
            cnt = builder.inttoptr(ir.Constant(i64, counts.ctypes.data),
                                   ir.PointerType(i64))
            slot = builder.gep(cnt, [args[0]])
            builder.store(builder.add(builder.load(slot), ir.Constant(i64, 1)), slot)
            return builder.call(target, list(args))
        return signature_of(task, t, x, sig, p, modes, out, k, f), codegen

    def signature_of(*a):
        return types.float64(*a)

    @cfunc(SYSTEM_SIG, nogil=True)
    def counting(task, t, x, sig, p, modes, out, k, f):
        return _forward(task, t, x, sig, p, modes, out, k, f)

    return counting


def _run_loop_only(d, kw, entry=None):
    """The compiled loop's calls alone (no ``simulate`` around them); returns the run."""
    from spidersim.solver import loop as L
    system = d.compile(True, loop=True)
    run = L.CompiledLoop(entry or system.compiled_entry, system, 0.0, kw["t_end"], kw["rtol"],
                         kw["atol"], kw["max_step"], None, None, method=kw["method"])
    while True:
        c = run.call()
        if c == L.ROWS_FULL:
            run.grow_rows()
        elif c == L.EVENTS_FULL:
            run.grow_events()
        elif c != L.PAUSE:
            return run


def _best(fn, repeat):
    best = math.inf
    for _ in range(repeat):
        t0 = time.perf_counter()
        fn()
        best = min(best, time.perf_counter() - t0)
    return best


def _task_costs(system, n=20000, repeat=7):
    """ns per call of each task through the pointer (in a compiled loop)."""
    from spidersim.solver import sysfn
    from spidersim.solver._jit import njit

    @njit
    def many(fn, task, n, t, x, sig, p, modes, out, x2):
        acc = 0.0
        for i in range(n):
            xx = x if (i & 1) == 0 else x2
            acc += sysfn.call(fn, task, t + 1e-9 * i, xx, sig, p, modes, out, 0, 0.0)
        return acc

    fn = system.compiled_entry
    x = system.x0.copy() + 0.1
    x2 = x * 1.0001
    sig, p = system.sig, system.p
    modes = system.modes.copy()
    saved = system.modes.copy()
    out = np.zeros(max(system.n_x, system.n_g, len(system.timed), 1))
    costs = {}
    for task in (sysfn.OUTPUTS, sysfn.DERIVATIVES, sysfn.GUARDS, sysfn.GUARDS_AT_SIG,
                 sysfn.NEXT_TIME):
        many(fn, task, 10, 0.5, x, sig, p, modes, out, x2)
        base = _best(lambda: many(fn, task, 1, 0.5, x, sig, p, modes, out, x2), repeat)
        tt = _best(lambda: many(fn, task, n, 0.5, x, sig, p, modes, out, x2), repeat)
        costs[sysfn.TASKS[task]] = 1e9 * (tt - base) / n
    system.modes[:] = saved
    return costs


def part(name):
    import spidersim
    from spidersim.solver import sysfn
    from spidersim.solver.loop import I_STEPS, I_REJECTED
    path, sets, kw = CASES[name]
    d = spidersim.load(os.path.join(ROOT, path), set=sets)
    r = d.simulate(**kw)
    steps = r.stats["steps"]
    t_sim = _best(lambda: d.simulate(**kw), 30)
    t_loop = _best(lambda: _run_loop_only(d, kw), 30)
    print(f"== {name}: {steps} steps, {r.stats['rejected_steps']} rejected, "
          f"{len(r.events)} events, {len(r.t)} rows ==")
    print(f"simulate {1e3 * t_sim:.3f} ms = run_loop {1e3 * t_loop:.3f} ms "
          f"({1e6 * t_loop / steps:.3f} us/step) + Python around it "
          f"{1e3 * (t_sim - t_loop):.3f} ms")
    system = d.compile(True, loop=True)
    counts = np.zeros(16, dtype=np.int64)
    counting = _counting_system(system.compiled_entry, counts)
    run = _run_loop_only(d, kw, entry=counting.address)
    assert run.ist[I_STEPS] == steps, "the counting run took other steps"
    costs = _task_costs(d.compile(True, loop=True))
    total = 0.0
    print(f"{'task':14s} {'calls':>7s} {'per step':>9s} {'ns/call':>8s} {'us/step':>8s}")
    for task, nm in enumerate(sysfn.TASKS):
        c = int(counts[task])
        if not c:
            continue
        ns = costs.get(nm, math.nan)
        share = c * ns / steps / 1e3
        if not math.isnan(share):
            total += share
        print(f"{nm:14s} {c:7d} {c / steps:9.2f} {ns:8.1f} {share:8.3f}")
    per = 1e6 * t_loop / steps
    print(f"system function {total:.3f} us/step of {per:.3f}: the loop's own work "
          f"{per - total:.3f} us/step ({100 * (per - total) / per:.0f} %)")
    print(f"(rejected trial steps: {run.ist[I_REJECTED]})")
    print()


def main(argv):
    for n in argv or ["servo", "ball", "loop"]:
        part(n)


if __name__ == "__main__":
    main(sys.argv[1:])
