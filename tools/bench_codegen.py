"""Cost of the generated right-hand side and of compiling it (issue 14, items 2 and 5).

    python tools/bench_codegen.py [rhs|compile|size] [servo|ripple|spider ...]

* **rhs**: nanoseconds per evaluation of the state derivative of servo.yaml,
  joint_ripple.yaml and spider.yaml through the system function, as the compiled loop calls
  it (``sysfn.derivatives(fn, t, x, sig, p, modes, xdot)``), timed inside a compiled loop of 2e5
  calls (no Python per call; best of 5, in CPU time of the process), against the same equations written by hand as one
  numba function (servo: ``tools/bench_loop.servo_f``; ripple: the equations of
  ``tools/bench._ripple_hand_written`` writing into ``out``; spider has no hand-written
  counterpart);
* **compile**: seconds to ``load`` + ``compile`` (with the integration loop) in a fresh
  process: *new diagram* (an empty ``SPIDERSIM_CACHE``, spidersim's own kernels and loop
  already in numba's cache: what a user pays for a new structure), *all cold* (an empty
  ``NUMBA_CACHE_DIR`` too: the first run after installing), then *cached* (again, from both
  caches); the compile's CPU time too (on a shared machine the wall time is inflated by
  other load);
* **size**: lines of the generated module.
"""
from __future__ import annotations

import math
import os
import subprocess
import sys
import tempfile
import time

import numpy as np
from numba import njit

from spidersim.solver import sysfn

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, os.path.join(ROOT, "tools"))
PATHS = {"servo": os.path.join(ROOT, "diagrams", "servo.yaml"),
         "ripple": os.path.join(ROOT, "diagrams", "joint_ripple.yaml"),
         "spider": os.path.join(ROOT, "spider.yaml")}
N_CALLS = 200_000


@njit
def ripple_f(t, y, out):
    """diagrams/joint_ripple.yaml's equations by hand (as tools/bench.py), into ``out``."""
    p, R, L, Kt, J = 7, 1.5, 1.5e-3, 0.15, 10.0
    h3, unb, off_a = 0.008, 0.015, 0.015 * 2.0
    kp, ki, kb, V, Imax = 1.5e-3 * 2 * np.pi * 2000, 1.5 * 2 * np.pi * 2000, 1000.0, 28.0, 4.0
    I_cmd, tau_load = 2.0, 0.15 * 2.0
    ia, ib, w, th, Ia, Ib = y[0], y[1], y[2], y[3], y[4], y[5]
    te = p * th
    fa = -math.sin(te) - h3 * math.sin(3 * te)
    fb = math.cos(te) - h3 * math.cos(3 * te)
    ka, kb_ = Kt * (1 + 0.5 * unb), Kt * (1 - 0.5 * unb)
    amp = min(max(I_cmd, -Imax), Imax)
    ea = -amp * math.sin(te) - (ia + off_a)
    eb = amp * math.cos(te) - ib
    va_u, vb_u = kp * ea + Ia, kp * eb + Ib
    va, vb = min(max(va_u, -V), V), min(max(vb_u, -V), V)
    out[0] = (va - R * ia - ka * w * fa) / L
    out[1] = (vb - R * ib - kb_ * w * fb) / L
    out[2] = (ka * fa * ia + kb_ * fb * ib - tau_load) / J
    out[3] = w
    out[4] = ki * ea + kb * (va - va_u)
    out[5] = ki * eb + kb * (vb - vb_u)


@njit
def _generated_loop(n, fn, x, sig, p, modes, xdot):
    """``n`` evaluations of a system function's derivatives, as the compiled loop does."""
    for k in range(n):
        sysfn.derivatives(fn, 1e-9 * k, x, sig, p, modes, xdot)
    return xdot[0]


def _timer(f, generated):
    """A compiled loop of ``n`` calls of ``f`` (time moving by 1 ns per call)."""
    if generated:
        return _generated_loop
    else:
        @njit
        def loop(n, x, out):
            for k in range(n):
                f(1e-9 * k, x, out)
            return out[0]
    return loop


def _per_call(loop, args, repeat=5):
    loop(10, *args)
    best = math.inf
    for _ in range(repeat):
        t0 = time.process_time()       # CPU time: the machine may be shared
        loop(N_CALLS, *args)
        best = min(best, time.process_time() - t0)
    return best / N_CALLS


def bench_rhs(names):
    import spidersim
    from bench_loop import servo_f
    hand = {"servo": servo_f, "ripple": ripple_f}
    print(f"== generated derivatives() per call (loop of {N_CALLS} compiled calls, best of 5)")
    print(f"{'diagram':8s} {'generated [ns]':>15s} {'hand [ns]':>10s} {'ratio':>7s}")
    for name in names:
        d = spidersim.load(PATHS[name])
        s = d.compile(jit=True)
        x = s.x0.copy()
        xdot = np.zeros_like(x)
        gen = _per_call(_timer(None, True), (s.fn, x, s.sig, s.p, s.modes.copy(), xdot))
        if name in hand:
            y = x if name != "servo" else np.zeros(5)
            h = _per_call(_timer(hand[name], False), (y.copy(), np.zeros(y.size)))
            print(f"{name:8s} {1e9 * gen:15.1f} {1e9 * h:10.1f} {gen / h:7.1f}")
        else:
            print(f"{name:8s} {1e9 * gen:15.1f} {'-':>10s} {'-':>7s}")


_COMPILE = r"""
import time, sys
t0, c0 = time.perf_counter(), time.process_time()
import spidersim
d = spidersim.load(sys.argv[1])
t1, c1 = time.perf_counter(), time.process_time()
d.compile(jit=True, loop=True)
t2, c2 = time.perf_counter(), time.process_time()
print(f"{t1 - t0:.3f} {t2 - t1:.3f} {c2 - c1:.3f}")
"""


def bench_compile(names):
    print("== compile with the integration loop, in a fresh process: import + load [s], "
          "compile [s]")
    for name in names:
        with tempfile.TemporaryDirectory() as tmp:
            base = dict(os.environ, SPIDERSIM_CACHE=os.path.join(tmp, "spidersim"),
                        PYTHONPATH=ROOT + os.pathsep + os.environ.get("PYTHONPATH", ""))
            cold = dict(base, NUMBA_CACHE_DIR=os.path.join(tmp, "numba"))
            cold["SPIDERSIM_CACHE"] = os.path.join(tmp, "spidersim-cold")
            row = []
            for env in (base, cold, cold):
                res = subprocess.run([sys.executable, "-c", _COMPILE, PATHS[name]], env=env,
                                     capture_output=True, text=True, check=True)
                row.append([float(v) for v in res.stdout.split()])
        for label, (lo, co, pu) in zip(("new diagram", "all cold", "cached"), row):
            print(f"{name:8s} {label:12s} load {lo:5.2f} + compile {co:6.2f} s "
                  f"(CPU {pu:6.2f} s)")


def bench_size(names):
    import spidersim
    print("== generated module size in lines")
    for name in names:
        src = spidersim.load(PATHS[name]).source()
        n = src.count("\n")
        print(f"{name:8s} {n:6d} lines, {len(src) // 1024:5d} kB in all")


def main(argv):
    what = argv[0] if argv and argv[0] in ("rhs", "compile", "size") else None
    names = [a for a in argv if a in PATHS] or list(PATHS)
    for w, fn in (("size", bench_size), ("rhs", bench_rhs), ("compile", bench_compile)):
        if what in (None, w):
            fn(names)
            print()


if __name__ == "__main__":
    main(sys.argv[1:])
