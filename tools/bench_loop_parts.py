"""Where the compiled loop's time per step goes (issue 14): measured, not guessed.

    python tools/bench_loop_parts.py [servo|ball|loop ...]
    python tools/bench_loop_parts.py --ablate [servo|ball ...]
    python tools/bench_loop_parts.py --impacts

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

``--ablate``: ``run_loop`` again in scratch copies of :mod:`spidersim.solver.loop_body`,
each with one feature removed (recording, the unseen-return probe, ``next_time`` per step,
the pause/row-cap/stall bookkeeping; ``ABLATIONS``), timed interleaved with the copy as is.
Removing a feature can change the steps (printed): the copies are for timing only.

``--impacts``: the ball at 25, 50, 100 impacts and three tolerances, ``run_loop`` and the
hand-written DP54 of ``tools/bench_loop.py`` interleaved; a least-squares fit of time
against steps and impacts gives each one's cost per step and per impact (:func:`impacts`).
"""
from __future__ import annotations

import math
import os
import sys
import time

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from bench_common import best_time as _best  # noqa: E402
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




def _task_costs(system, n=20000, repeat=7):
    """ns per call of each task through the pointer (in a compiled loop)."""
    from bench_common import pointer_loop
    from spidersim.solver import sysfn
    many = pointer_loop()

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
    if argv and argv[0] == "--ablate":
        ablation(argv[1:] or ["servo", "ball"])
        return
    if argv and argv[0] == "--impacts":
        impacts()
        return
    unknown = [n for n in argv if n not in CASES]
    if unknown:
        print(__doc__)
        print(f"problems: {', '.join(CASES)}; not known: {', '.join(unknown)}")
        sys.exit(0 if unknown in (["--help"], ["-h"]) else 2)
    for n in argv or ["servo", "ball", "loop"]:
        part(n)



# --- ablation: run_loop with single features removed, in scratch copies ----------------------

ABLATIONS = {
    "as is": [],
    "no recording": [
        ("ok = _sf.record_guards(fn, t_new, x1, sig, p, modes, s_idx, x_idx, buf, row0,\n"
         "                                   G[G_NEW])",
         "_sf.guards(fn, t_new, x1, sig, p, modes, G[G_NEW])"),
        ("ok = _row(fn, t_new, x1, tbuf, buf, ist, s_idx, x_idx, sig, p, modes)",
         "_sf.outputs(fn, t_new, x1, sig, p, modes)")],
    "no unseen probe": [
        ("    interpolant) into ``G[G_TMP]``; ``sig`` is left at the step end.\"\"\"\n",
         "    interpolant) into ``G[G_TMP]``; ``sig`` is left at the step end.\"\"\"\n"
         "    return -1\n")],
    "no next_time": [("t_next = _sf.next_time(fn, t, p, modes)", "t_next = math.inf")],
    "no pause/cap/stall": [
        ("code = _pause_code(t, ev_reserve, pause_steps, tbuf, ev_t, ist, fst)", "code = 0"),
        ("_cap_for_rows(grid, tbuf, ist, fst)\n", "fst[F_HCAP] = fst[F_MAXSTEP]\n"),
        ("if _stalled(h, t_new, ist):", "if False:")],
    "_dense inlined": [
        ("@njit_borrowed\ndef _dense(", "@njit_borrowed(inline=\"always\")\ndef _dense(")],
    "_dense + dp54.dense inlined": [
        ("@njit_borrowed\ndef _dense(", "_dp54_dense = njit_borrowed(inline=\"always\")("
         "_dp54.dense.py_func)\n\n\n@njit_borrowed(inline=\"always\")\ndef _dense("),
        ("        _dp54.dense(t, h, x, x1, K, s, out)", "        _dp54_dense(t, h, x, x1, K, s, out)")],
    "DP54 advance direct": [
        ("h, fac = _advance(fn, t, t_seg, x, K, x1, JW, jpat, B, ist, fst, sig, p, modes)",
         "h, fac = _advance_dp54(fn, t, t_seg, x, K, x1, ist, fst, sig, p, modes)")],
    "helpers inlined": [
        ("@njit_borrowed\ndef _tol(", "@njit_borrowed(inline=\"always\")\ndef _tol("),
        ("@njit_borrowed\ndef _pause_code(", "@njit_borrowed(inline=\"always\")\ndef _pause_code("),
        ("@njit_borrowed\ndef _cap_for_rows(",
         "@njit_borrowed(inline=\"always\")\ndef _cap_for_rows("),
        ("@njit_borrowed\ndef _stalled(", "@njit_borrowed(inline=\"always\")\ndef _stalled("),
        ("@njit_borrowed\ndef _advance_dp54(",
         "@njit_borrowed(inline=\"always\")\ndef _advance_dp54(")],
    "row from last stage": [
        ("            ok = _row(fn, t_new, x1, tbuf, buf, ist, s_idx, x_idx, sig, p, modes)",
         "            if ist[I_METHOD] == METHOD_DP54 and t + h == t_new:\n"
         "                r = ist[I_ROWS]\n"
         "                ok = _sf.copy_row(x1, sig, s_idx, x_idx, buf, r)\n"
         "                tbuf[r] = t_new\n"
         "                ist[I_ROWS] = r + 1\n"
         "            else:\n"
         "                ok = _row(fn, t_new, x1, tbuf, buf, ist, s_idx, x_idx, sig, p, modes)")],
    "DP54 branch": [
        ("        h, fac = _advance(fn, t, t_seg, x, K, x1, JW, jpat, B, ist, fst, sig, p, modes)\n",
         "        if ist[I_METHOD] == 0:\n"
         "            h, fac = _advance_dp54(fn, t, t_seg, x, K, x1, ist, fst, sig, p, modes)\n"
         "        else:\n"
         "            h, fac = _advance(fn, t, t_seg, x, K, x1, JW, jpat, B, ist, fst, sig, p,\n"
         "                              modes)\n")],
}


#: rows and events of the ablation runs: never full (without ``_pause_code`` a full buffer
#: would be written past its end)
CAPACITY = 1 << 16


def _scratch_loops(names):
    """Scratch copies of :mod:`spidersim.solver.loop_body` with the substitutions of
    ``ABLATIONS`` (imported from a temporary directory, compiled there)."""
    import importlib
    import tempfile
    src_path = os.path.join(ROOT, "spidersim", "solver", "loop_body.py")
    src = open(src_path).read().replace("from ._jit", "from spidersim.solver._jit")
    src = src.replace("from . import", "from spidersim.solver import")
    src = src.replace("from .", "from spidersim.solver.")
    tmp = tempfile.mkdtemp(prefix="loop_ablation_")
    sys.path.insert(0, tmp)
    loops = {}
    for k, name in enumerate(names):
        text = src
        missing = [old for old, _new in ABLATIONS[name] if old not in text]
        if missing:     # e.g. a change measured here and since made in loop_body
            print(f"(ablation '{name}' does not apply to loop_body as it is: text not found: "
                  f"{missing[0][:60]!r}; skipped)")
            continue
        for old, new in ABLATIONS[name]:
            text = text.replace(old, new)
        with open(os.path.join(tmp, f"lb_ablation_{k}.py"), "w") as fh:
            fh.write(text)
        loops[name] = importlib.import_module(f"lb_ablation_{k}").run_loop_dp54   # DP54 cases
    return loops


def ablation(problems, repeat=31):
    """run_loop time of each problem with each ablation, interleaved (best of ``repeat``;
    the environment variable ``ABLATIONS``, comma-separated, picks some)."""
    import spidersim
    from spidersim.solver import loop as L
    from spidersim.solver.sysfn import entry_point
    pick = os.environ.get("ABLATIONS")
    loops = _scratch_loops(["as is"] + [a for a in ABLATIONS if a != "as is" and (
        not pick or a in pick.split(","))])
    for name in problems:
        path, sets, kw = CASES[name]
        d = spidersim.load(os.path.join(ROOT, path), set=sets)
        d.simulate(**kw)

        def runner(rl):
            def run():
                system = d.compile(True, loop=True)
                r = L.CompiledLoop(system.compiled_entry, system, 0.0, kw["t_end"],
                                   kw["rtol"], kw["atol"], kw["max_step"], None, None,
                                   method=kw["method"], capacity=CAPACITY)
                while True:
                    args = (r.entry,) + r.arguments()
                    c = int((entry_point(rl, args) or rl)(*args))
                    if c == L.ROWS_FULL:
                        r.grow_rows()
                    elif c == L.EVENTS_FULL:
                        r.grow_events()
                    elif c != L.PAUSE:
                        return r
            return run
        runs = {ab: runner(rl) for ab, rl in loops.items()}
        steps = {ab: int(fn().ist[L.I_STEPS]) for ab, fn in runs.items()}
        best = {ab: math.inf for ab in runs}
        for _ in range(repeat):
            for ab, fn in runs.items():
                t0 = time.perf_counter()
                fn()
                best[ab] = min(best[ab], time.perf_counter() - t0)
        print(f"== {name}: run_loop with one feature removed (best of {repeat}, "
              f"interleaved) ==")
        base = best["as is"]
        for ab in runs:
            print(f"{ab:22s} {1e3 * best[ab]:8.3f} ms  {steps[ab]:6d} steps  "
                  f"saves {1e6 * (base - best[ab]) / steps['as is']:6.3f} us/step")
        print()



# --- the ball: cost per step and per impact, by regression ------------------------------------

def _ball_t_end_n(n, e_=0.95, g=9.81, h0=10.0):
    """The time half-way between impacts ``n`` and ``n + 1`` of the ball of
    ``tools/check_loop_identical.py``."""
    t1 = math.sqrt(2 * h0 / g)
    tn = t1 + sum(2 * e_ ** k * g * t1 / g for k in range(1, n))
    return tn + 0.5 * 2 * e_ ** n * t1


def impacts(repeat=15, rounds=3):
    """The ball (DP54) with 25, 50 and 100 impacts at rtol 1e-8, 1e-10 and 1e-12 (atol
    1e-2 rtol), spidersim's ``run_loop`` (no Python around it) and the hand-written DP54 of
    ``tools/bench_loop.py``, interleaved; least squares ``time = a steps + b impacts + c``
    for each: what one step and one impact (location, event, restart) cost."""
    import spidersim
    from bench_loop import ball_f, ball_guard, ball_jump, make_dp54
    from spidersim.solver import loop as L
    d = spidersim.load(os.path.join(ROOT, "diagrams", "bouncing_ball.yaml"),
                       set={"ball.e": 0.95, "ball.v_rest": 0})
    solve = make_dp54(ball_f, ball_guard, ball_jump)
    tout, yout = np.empty(200000), np.empty((200000, 2))
    y0, tev = np.array([10.0, 0.0]), np.zeros(0)
    cases = [(n, rt) for n in (25, 50, 100) for rt in (1e-8, 1e-10, 1e-12)]
    runs = {}
    for n, rt in cases:
        kw = dict(t_end=_ball_t_end_n(n), rtol=rt, atol=1e-2 * rt, max_step=math.inf,
                  method="DP54")
        d.simulate(**kw)
        run = _run_loop_only(d, kw)
        h = solve(y0, tev, kw["t_end"], rt, kw["atol"], tout, yout)
        runs[(n, rt)] = (kw, run.ist[L.I_STEPS], h[1], h[3])
    best = {k: [math.inf, math.inf] for k in runs}
    for _ in range(rounds):
        for k, (kw, _s, _hs, _he) in runs.items():
            best[k][0] = min(best[k][0], _best(lambda: _run_loop_only(d, kw), repeat))
            best[k][1] = min(best[k][1], _best(
                lambda: solve(y0, tev, kw["t_end"], kw["rtol"], kw["atol"], tout, yout),
                repeat))
    print("== ball: run_loop and hand DP54 by impacts and tolerance (best of "
          f"{rounds} x {repeat}) ==")
    print(f"{'impacts':>7s} {'rtol':>7s} {'steps':>6s} {'run_loop [ms]':>14s} "
          f"{'hand steps':>10s} {'hand [ms]':>10s}")
    for k, (kw, s, hs, he) in runs.items():
        print(f"{k[0]:7d} {k[1]:7.0e} {s:6d} {1e3 * best[k][0]:14.3f} {hs:10d} "
              f"{1e3 * best[k][1]:10.3f}")
    for col, label, si in ((0, "spidersim run_loop", 1), (1, "hand DP54", 2)):
        A = np.array([[runs[k][si], k[0], 1.0] for k in runs], dtype=float)
        y = np.array([best[k][col] for k in runs])
        coef, *_ = np.linalg.lstsq(A, y, rcond=None)
        resid = y - A @ coef
        print(f"{label:20s} {1e6 * coef[0]:6.3f} us/step, {1e6 * coef[1]:6.3f} us/impact, "
              f"{1e6 * coef[2]:7.2f} us fixed (residual rms {1e6 * resid.std():.2f} us)")
    print()


if __name__ == "__main__":
    main(sys.argv[1:])
