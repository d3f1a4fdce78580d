"""spidersim benchmarks: print tables of figures (not tests; the machines are shared and noisy,
so compare ratios measured in one run).

    python tools/bench.py            # all benchmarks
    python tools/bench.py servo      # one of them

servo
    ``diagrams/servo.yaml`` (DC motor, position P -> speed PI -> current PI -> +-24 V) for 1 s:
    spidersim compiled, spidersim interpreted, and a hand-written numba right-hand side of the
    same equations under the same SciPy solver and tolerances, integrated through the same two
    segments (the reference step at t = 0.01 s is a time event in spidersim). Target: compiled
    <= 1.5x hand-written (integration time, compile excluded). Compile time cold (empty numba
    and spidersim caches, in a fresh process) and from cache (second fresh process).
loop
    ``diagrams/algebraic_loop.yaml`` (``y = u - K y`` solved by Newton at every evaluation)
    against the same equations solved by hand (a gain ``1/(1+K)``), both compiled, same
    solver and tolerances. Target: overhead ratio <= 2.
ball
    ``diagrams/bouncing_ball.yaml`` with e = 0.95 through its first 100 impacts: wall time.
ripple
    1 s of ``diagrams/joint_ripple.yaml`` (NRPI driver + two-phase brushless motor at
    955 rpm with the three imperfections) against a hand-written numba right-hand side of
    the same equations under the same solver and tolerances. Target <= 1.5x.
spider
    10 s of ``spider.yaml``: wall time, steps, RHS calls, compile time, real-time factor
    (target >= 1.0 on one core), and the arm's forward dynamics per call (target <= 30 us).
spider16
    10 s of ``spider.yaml`` in its two sensing variants, one after the other in one
    process: as shipped (16-bit converters, joint controllers sampled at 1 kHz, DP54) and
    idealized (``res_bits 0``, ``Ts_ctrl 0``: exact angles, continuous cascade, NDF); wall
    time, real-time factor (issue 14 targets: >= 2 with 16 bits, >= 10 ideal) and the
    solver counters (steps, RHS calls, Jacobians, LU, time events, segments).
contact
    ``diagrams/force_control_rigid_ideal.yaml`` (arm pressed on a rigid plane by the hybrid
    controller): wall time, Newton iterations per RHS evaluation, largest penetration.
memory
    Memory against run length: ``diagrams/servo.yaml`` for 1, 10 and 100 s with the compiled
    loop (output grid 1 ms) and with LSODA: the peak of the memory Python allocates during
    ``simulate`` (tracemalloc), the bytes of the logged result, and their difference, which
    must stay flat (everything but the logged signals is allocated once).
compile
    ``spider.yaml`` compiled with its integration loop in fresh processes: a new diagram
    (spidersim's kernels and loop in numba's cache), all cold (empty numba cache too) and
    from the cache (see ``tools/bench_codegen.py compile``). Targets: cold <= 10 s, cached
    <= 1 s.
sweep
    A 3 x 2 grid of ``diagrams/impact_fault_joint1.yaml`` serial in one process and on a local Dask
    cluster of 2 workers: runs per minute each, the speed-up (cluster start-up and each
    worker's first import of the cached compiled module included), and whether both gave
    the same numbers.
"""
from __future__ import annotations

import os
import statistics
import subprocess
import sys
import tempfile
import time

import numpy as np

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
SERVO = os.path.join(ROOT, "diagrams", "servo.yaml")


def _best(fn, repeat=7):
    times = []
    out = None
    for _ in range(repeat):
        t0 = time.perf_counter()
        out = fn()
        times.append(time.perf_counter() - t0)
    return min(times), statistics.median(times), out


def _hand_written():
    """The servo equations written by hand as one numba function (the reference)."""
    from numba import njit
    from scipy.integrate import LSODA

    @njit(cache=True)
    def f(t, y, ref):
        i, w, th, I_s, I_c = y
        R, L, K, J, b = 1.0, 1e-3, 0.05, 1e-4, 1e-5
        w_ref = 20.0 * (ref - th)
        e_w = w_ref - w
        i_ref = 0.05 * e_w + I_s
        e_i = i_ref - i
        v = 5.0 * e_i + I_c
        v = min(max(v, -24.0), 24.0)
        out = np.empty(5)
        out[0] = (v - R * i - K * w) / L
        out[1] = (K * i - b * w) / J
        out[2] = w
        out[3] = 1.0 * e_w
        out[4] = 5000.0 * e_i
        return out

    def run():
        y = np.zeros(5)
        ts, ys = [0.0], [y.copy()]
        steps = nfev = 0
        for t0, t1, ref in ((0.0, 0.01, 0.0), (0.01, 1.0, 1.0)):
            s = LSODA(lambda t, y, r=ref: f(t, y, r), t0, y, t1, rtol=1e-6, atol=1e-8)
            while s.status == "running":
                s.step()
                ts.append(s.t)
                ys.append(s.y.copy())
                steps += 1
            nfev += s.nfev
            y = s.y.copy()
        return np.array(ts), np.array(ys), steps, nfev

    f(0.0, np.zeros(5), 0.0)
    return run


_COMPILE_SNIPPET = r"""
import time, sys
t0 = time.perf_counter()
import spidersim
t1 = time.perf_counter()
d = spidersim.load(sys.argv[1])
d.compile(jit=True)
t2 = time.perf_counter()
print(f"{t1 - t0:.4f} {d._compile_time:.4f} {t2 - t0:.4f}")
"""


def _compile_times(path):
    """(import, compile, total) seconds: cold in an empty cache, then from that cache."""
    with tempfile.TemporaryDirectory() as tmp:
        env = dict(os.environ, SPIDERSIM_CACHE=os.path.join(tmp, "spidersim"),
                   NUMBA_CACHE_DIR=os.path.join(tmp, "numba"))
        out = []
        for _ in range(2):
            res = subprocess.run([sys.executable, "-c", _COMPILE_SNIPPET, path], env=env,
                                 capture_output=True, text=True, check=True)
            out.append(tuple(float(v) for v in res.stdout.split()))
        return out


def bench_servo():
    import spidersim

    print("== servo: diagrams/servo.yaml, 1 s, LSODA rtol 1e-6 atol 1e-8 ==")
    (cold, cached) = _compile_times(SERVO)
    d = spidersim.load(SERVO)
    d.compile(jit=True)
    best_c, med_c, r_c = _best(lambda: d.simulate(jit=True))
    d.compile(jit=False)
    best_i, med_i, r_i = _best(lambda: d.simulate(jit=False), repeat=3)
    run = _hand_written()
    best_h, med_h, (t_h, y_h, steps_h, nfev_h) = _best(run)
    err = abs(r_c["motor.phi"][-1] - y_h[-1, 2])
    rows = [("spidersim compiled", best_c, med_c, r_c.stats["steps"], r_c.stats["rhs_calls"]),
            ("spidersim interpreted", best_i, med_i, r_i.stats["steps"],
             r_i.stats["rhs_calls"]),
            ("hand-written numba", best_h, med_h, steps_h, nfev_h)]
    print(f"{'variant':24s} {'best [ms]':>10s} {'median [ms]':>12s} {'steps':>7s} "
          f"{'RHS calls':>10s} {'/hand (best)':>13s}")
    for name, b, m, s, n in rows:
        print(f"{name:24s} {1e3 * b:10.2f} {1e3 * m:12.2f} {s:7d} {n:10d} {b / best_h:13.2f}")
    print(f"final angle: spidersim {r_c['motor.phi'][-1]:.9f}, hand-written {y_h[-1, 2]:.9f} "
          f"(|diff| {err:.2e})")
    print(f"compile cold: {cold[1]:.2f} s (process total {cold[2]:.2f} s, import "
          f"{cold[0]:.2f} s); from cache: {cached[1]:.2f} s (process total {cached[2]:.2f} s)")
    print(f"ratio compiled / hand-written (target <= 1.5): {best_c / best_h:.2f}")
    print(f"ratio interpreted / compiled: {best_i / best_c:.1f}")
    print()


LOOP_HAND = """
name: loop_by_hand
parameters: {K: 3.0}
blocks:
  u:   {type: Sine, amplitude: 1, f: 1}
  sol: {type: Gain, k: 1/(1+K)}          # y = u - K y solved by hand: y = u / (1 + K)
  x:   {type: Integrator}
connections:
  - u.y -> sol.u
  - sol.y -> x.u
simulation: {t_end: 2.0, rtol: 1e-9, atol: 1e-12}
"""


def bench_loop():
    """Newton-solved loop versus the same equations solved by hand, both compiled."""
    import spidersim

    print("== loop: diagrams/algebraic_loop.yaml (y = u - K y by Newton) vs y = u/(1+K) ==")
    d_loop = spidersim.load(os.path.join(ROOT, "diagrams", "algebraic_loop.yaml"))
    d_hand = spidersim.loads(LOOP_HAND)
    for d in (d_loop, d_hand):
        d.compile(jit=True)
    b_loop, m_loop, r_loop = _best(lambda: d_loop.simulate(jit=True))
    b_hand, m_hand, r_hand = _best(lambda: d_hand.simulate(jit=True))
    err = np.max(np.abs(r_loop["x.y"][-1] - r_hand["x.y"][-1]))
    print(f"{'variant':24s} {'best [ms]':>10s} {'median [ms]':>12s} {'steps':>7s} "
          f"{'RHS calls':>10s} {'Newton it.':>11s}")
    for name, b, m, r in (("Newton loop", b_loop, m_loop, r_loop),
                          ("solved by hand", b_hand, m_hand, r_hand)):
        print(f"{name:24s} {1e3 * b:10.2f} {1e3 * m:12.2f} {r.stats['steps']:7d} "
              f"{r.stats['rhs_calls']:10d} {r.stats['newton_iterations']:11d}")
    print(f"final x: |difference| {err:.2e}")
    print(f"overhead ratio loop / by hand (target <= 2): {b_loop / b_hand:.2f}")
    print()


def bench_ball():
    """Bouncing ball through its first 100 impacts (e = 0.95)."""
    import spidersim

    e, g, h0 = 0.95, 9.81, 10.0
    t1 = np.sqrt(2 * h0 / g)
    t100 = t1 + sum(2 * e ** k * g * t1 / g for k in range(1, 100))
    d = spidersim.load(os.path.join(ROOT, "diagrams", "bouncing_ball.yaml"),
                       set={"ball.e": e, "ball.v_rest": 0})
    d.compile(jit=True)
    t_end = t100 + 0.5 * 2 * e ** 100 * t1
    best, med, r = _best(lambda: d.simulate(t_end=t_end, jit=True), repeat=5)
    impacts = [t for t, b, ev in r.events if ev == "impact"]
    print("== ball: diagrams/bouncing_ball.yaml with e = 0.95, first 100 impacts, DOP853 "
          "1e-10/1e-12 ==")
    print(f"impacts: {len(impacts)}; last at {impacts[-1]:.9f} s (closed form "
          f"{t100:.9f} s, |diff| {abs(impacts[-1] - t100):.1e}); steps {r.stats['steps']}, "
          f"RHS calls {r.stats['rhs_calls']}")
    print(f"wall time: best {1e3 * best:.1f} ms, median {1e3 * med:.1f} ms "
          f"({1e3 * best / len(impacts):.2f} ms per impact)")
    print()


def _ripple_hand_written():
    """diagrams/joint_ripple.yaml's equations (NRPI driver + two-phase motor) by hand."""
    from numba import njit
    from scipy.integrate import LSODA

    sys.path.insert(0, os.path.join(ROOT, "tools"))
    from bench_codegen import ripple_f          # the equations, written once

    @njit(cache=True)
    def f(t, y):
        out = np.empty(6)
        ripple_f(t, y, out)
        return out

    def run(t_end=1.0):
        y0 = np.array([0.0, 0.0, 2 * np.pi * 955 / 60, 0.0, 0.0, 0.0])
        s = LSODA(f, 0.0, y0, t_end, rtol=1e-7, atol=1e-9, max_step=t_end / 50)
        ts, ys, steps = [0.0], [y0], 0
        while s.status == "running":
            s.step()
            ts.append(s.t)
            ys.append(s.y.copy())
            steps += 1
        return np.array(ts), np.array(ys), steps, s.nfev

    f(0.0, np.zeros(6))
    return run


def bench_ripple():
    """1 s of diagrams/joint_ripple.yaml against the same equations by hand."""
    import spidersim

    d = spidersim.load(os.path.join(ROOT, "diagrams", "joint_ripple.yaml"))
    d.simulation["output_interval"] = None         # record at the steps, as the hand loop
    d.compile(jit=True)
    best_c, med_c, r = _best(lambda: d.simulate(t_end=1.0, jit=True), repeat=3)
    run = _ripple_hand_written()
    best_h, med_h, (th, yh, steps_h, nfev_h) = _best(run, repeat=3)
    print("== ripple: diagrams/joint_ripple.yaml, 1 s at 955 rpm, LSODA 1e-7/1e-9 ==")
    print(f"{'variant':24s} {'best [ms]':>10s} {'median [ms]':>12s} {'steps':>7s} "
          f"{'RHS calls':>10s}")
    print(f"{'spidersim compiled':24s} {1e3 * best_c:10.1f} {1e3 * med_c:12.1f} "
          f"{r.stats['steps']:7d} {r.stats['rhs_calls']:10d}")
    print(f"{'hand-written numba':24s} {1e3 * best_h:10.1f} {1e3 * med_h:12.1f} "
          f"{steps_h:7d} {nfev_h:10d}")
    print(f"final speed: spidersim {r['motor.w'][-1]:.9f}, hand-written {yh[-1, 2]:.9f} rad/s")
    print(f"ratio compiled / hand-written (target <= 1.5): {best_c / best_h:.2f}")
    print()


def bench_spider():
    """10 s of spider.yaml (the main job) and the cost of one arm forward dynamics."""
    import spidersim
    from spidersim.multibody import Chain
    from spidersim.multibody import kernels as K

    d = spidersim.load(os.path.join(ROOT, "spider.yaml"))
    t0 = time.perf_counter()
    d.compile(jit=True)
    compile_s = time.perf_counter() - t0
    best, med, r = _best(lambda: d.simulate(t_end=10.0, jit=True), repeat=2)
    s = r.stats
    print("== spider: spider.yaml, 10 s simulated (7 joints + arm + 30 kg payload), "
          f"{s['method']} {s['rtol']:g}/{s['atol']:g} ==")
    print(f"wall time {best:.2f} s (median {med:.2f} s); steps {s['steps']}, RHS calls "
          f"{s['rhs_calls']}, Jacobians {s['jacobian_calls']}; compile {compile_s:.1f} s "
          f"(this process: cold or from cache)")
    print(f"real-time factor (simulated / wall, target >= 10 with ideal resolvers): "
          f"{10.0 / best:.2f}")
    arm = Chain.from_yaml()
    rng = np.random.default_rng(0)
    q, qd, tau = rng.normal(size=7), rng.normal(size=7), rng.normal(size=7)
    qdd = np.zeros(7)
    args = (q, qd, tau, arm.gravity, np.zeros(6), np.zeros(7), arm.P, arm._ws, arm._M, arm._tmp,
            arm._base, qdd, np.empty(0))            # no factor reuse: the full computation
    K.forward_dynamics(*args)                       # compile (or load) first
    fd = next(iter(K.forward_dynamics.overloads.values())).entry_point
    n = 20000
    t0 = time.perf_counter()
    for _ in range(n):
        fd(*args)
    per = (time.perf_counter() - t0) / n
    print(f"arm forward dynamics (composite-rigid-body M + Cholesky + two RNEA passes: "
          f"bias and base wrench), "
          f"compiled: {1e6 * per:.1f} us per call from Python (target <= 30 us)")
    print()


def bench_spider16():
    """spider.yaml 10 s with 16-bit resolvers and sampled control, and idealized."""
    import spidersim

    print("== spider16: spider.yaml, 10 s simulated, 1e-6/1e-8, one process ==")
    print(f"{'variant':52s} {'wall s':>7s} {'x real':>7s} {'steps':>7s} {'RHS':>8s} "
          f"{'Jac':>5s} {'LU':>6s} {'t.ev.':>6s} {'segm.':>6s}")
    for label, over, method in (
            ("16 bits, 1 kHz sampled cascade (as shipped)", {}, "DP54"),
            ("ideal angles, continuous cascade", {"res_bits": 0, "Ts_ctrl": 0}, "NDF")):
        d = spidersim.load(os.path.join(ROOT, "spider.yaml"), set=over)
        d.compile(jit=True)
        d.simulate(t_end=0.01, method=method)            # the loop's first call
        best, _, r = _best(lambda: d.simulate(t_end=10.0, method=method), repeat=2)
        s = r.stats
        print(f"{label + ', ' + method:52s} {best:7.2f} {10.0 / best:7.2f} {s['steps']:7d} "
              f"{s['rhs_calls']:8d} {s['jacobian_calls']:5d} {s['lu_decompositions']:6d} "
              f"{s['time_events']:6d} {s['segments']:6d}")
    print()


def bench_contact():
    from spidersim import load
    d = load(os.path.join(ROOT, "diagrams", "force_control_rigid_ideal.yaml"))
    d.compile()
    best, med, r = _best(d.simulate, repeat=3)
    s = r.stats
    print("== contact: diagrams/force_control_rigid_ideal.yaml, 1.6 s, rigid plane closed as an "
          "acceleration-level loop ==")
    print(f"wall time {best:.3f} s (median {med:.3f} s); steps {s['steps']}, RHS calls "
          f"{s['rhs_calls']}, Newton iterations {s['newton_iterations']} "
          f"({s['newton_iterations'] / max(1, s['rhs_calls']):.2f} per output evaluation "
          f"of the RHS)")
    print(f"max |penetration| {np.abs(r['wall.gap']).max():.2e} m (target < 1e-6)")
    print()


def bench_sweep():
    from spidersim.sweep import sweep
    path = os.path.join(ROOT, "diagrams", "impact_fault_joint1.yaml")
    vary = [("V_ci", [20.0, 28.0, 36.0]), ("K", [1e4, 1e6])]
    n = 6
    print("== sweep: diagrams/impact_fault_joint1.yaml, grid V_ci = 20, 28, 36 x K = 1e4, 1e6 "
          "(6 runs of 0.9 s) ==")
    serial = sweep(path, vary, workers=0)
    dask2 = sweep(path, vary, workers=2)
    same = all(a.get("peak_force") == b.get("peak_force")
               for a, b in zip(serial.rows, dask2.rows))
    for name, res in (("serial (this process)", serial),
                      ("Dask, 2 local workers", dask2)):
        per = [r["wall_s"] for r in res.rows]
        print(f"{name:24s} {res.wall_s:6.1f} s  {60 * n / res.wall_s:6.1f} runs/min  "
              f"(per run {min(per):.2f}..{max(per):.2f} s; compiled in a run: "
              f"{sum(bool(r['compiled']) for r in res.rows)})")
    print(f"speed-up 2 workers / serial (cluster start-up included): "
          f"{serial.wall_s / dask2.wall_s:.2f}; same numbers: {same}")
    print()


def bench_memory():
    import tracemalloc

    import spidersim
    d = spidersim.load(SERVO)
    d.compile(jit=True, loop=True)
    print("== memory: diagrams/servo.yaml, output grid 1 ms: peak allocated during simulate "
          "vs the logged result ==")
    print(f"{'method':8s} {'t_end [s]':>9s} {'rows':>8s} {'result [MB]':>12s} "
          f"{'peak [MB]':>10s} {'peak - result [MB]':>19s}")
    for method in ("DP54", "LSODA"):
        d.simulate(t_end=0.1, method=method, output_interval=1e-3)    # warm
        for t_end in (1.0, 10.0, 100.0):
            tracemalloc.start()
            r = d.simulate(t_end=t_end, method=method, output_interval=1e-3)
            _cur, peak = tracemalloc.get_traced_memory()
            tracemalloc.stop()
            res = r.t.nbytes + r._data.nbytes
            print(f"{method:8s} {t_end:9.0f} {len(r.t):8d} {res / 1e6:12.2f} {peak / 1e6:10.2f} "
                  f"{(peak - res) / 1e6:19.2f}")
    print()


def bench_compile():
    sys.path.insert(0, os.path.join(ROOT, "tools"))
    from bench_codegen import bench_compile as run
    run(["spider"])
    print()


BENCHES = {"servo": bench_servo, "loop": bench_loop, "ball": bench_ball,
           "ripple": bench_ripple, "spider": bench_spider, "spider16": bench_spider16,
           "contact": bench_contact,
           "memory": bench_memory, "compile": bench_compile, "sweep": bench_sweep}


def main(argv):
    names = argv or list(BENCHES)
    for n in names:
        if n not in BENCHES:
            sys.exit(f"unknown benchmark '{n}'; choose from {', '.join(BENCHES)}")
        BENCHES[n]()


if __name__ == "__main__":
    main(sys.argv[1:])
