"""The compiled variable-order BDF (spidersim.solver.bdf) against SciPy and ROS34PW2, one run.

    python tools/bench_bdf.py [robertson|lugre]

For each problem, interleaved in one process (best of 5 wall times):

* **spidersim BDF**: :func:`spidersim.solver.bdf.solve` on a hand-written system function
  (a numba ``cfunc`` of ``sysfn.SYSTEM_SIG``), dense output on the grid; once with
  ``f(t + h, x1)`` evaluated after every step (the loop interface's ``f1``) and once without;
* **numba RHS + SciPy LSODA / BDF**: the same equations as one numba function (the cfunc
  calls it too) driven by SciPy's steppers step by step, dense output on the grid;
* **compiled ROS34PW2**: spidersim's Rosenbrock-W helpers (:mod:`spidersim.solver.rosenbrock`)
  sequenced as in the compiled loop (Jacobian kept 20 steps, refreshed after a rejection,
  h held for factors in [1, 1.2]) by a small compiled driver in this file on the same cfunc.

Printed: wall time, steps, RHS calls (Jacobian columns included), Jacobians, LU
factorisations, and the largest error on the output grid against a tight reference (SciPy
Radau at rtol 1e-12 for Robertson, LSODA at 1e-12 for LuGre), in units of the tolerance
``atol + rtol |x_ref|``.
"""
from __future__ import annotations

import math
import os
import statistics
import sys

import numba
import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from bench_common import interleaved  # noqa: E402
from numba import njit
from scipy.integrate import BDF, LSODA, Radau, solve_ivp

sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))

from spidersim.solver import bdf, dp54, sysfn            # noqa: E402
from spidersim.solver import rosenbrock as R              # noqa: E402
from spidersim.solver.newton import lu_solve              # noqa: E402

NONE = np.zeros(1)


# --- the problems: one numba function each, the cfunc and SciPy's wrapper call it -----------

@njit(cache=True)
def robertson_f(t, y, out):
    out[0] = -0.04 * y[0] + 1e4 * y[1] * y[2]
    out[1] = 0.04 * y[0] - 1e4 * y[1] * y[2] - 3e7 * y[1] ** 2
    out[2] = 3e7 * y[1] ** 2


@njit(cache=True)
def lugre_f(t, y, out):
    """diagrams/lugre_stick_slip.yaml by hand (as tools/bench_loop.py): unit mass pulled
    through a spring k = 2 N/m at 0.1 m/s on LuGre friction (sigma0 = 1e5 N/m, sigma1 =
    sqrt(1e5) N.s/m, D = 0.4 N.s/m, F_c = 1 N, F_s = 1.5 N, v_s = 1e-3 m/s); y = (position,
    velocity, bristle deflection)."""
    phi, w, z = y[0], y[1], y[2]
    g = 1.0 + 0.5 * math.exp(-(w / 1e-3) ** 2)
    dz = w - 1e5 * abs(w) * z / g
    fric = 1e5 * z + math.sqrt(1e5) * dz + 0.4 * w
    out[0] = w
    out[1] = 2.0 * (0.1 * t - phi) - fric
    out[2] = dz


def make_cfunc(f, n):
    @numba.cfunc(sysfn.SYSTEM_SIG)
    def system(task, t, xp, sigp, pp, mp, outp, k, ff):
        if task == sysfn.DERIVATIVES:
            f(t, numba.carray(xp, n), numba.carray(outp, n))
        return 0.0
    return system


def make_py(f, n):
    @njit
    def rhs(t, y):
        out = np.empty(n)
        f(t, y, out)
        return out
    return rhs


# --- ROS34PW2 on a system function, as the compiled loop sequences it --------------------------

@njit(cache=True)
def _ros_jacobian(fn, t, x, K, J, jpat, st, sig, p, modes):
    y, fp, d = K[R.ROW_TRIAL], K[R.ROW_FPERT], K[R.ROW_SCRATCH]
    ng = R.n_groups(jpat)
    for g in range(ng):
        R.perturb_group(g, x, jpat, y, d)
        sysfn.derivatives(fn, t, y, sig, p, modes, fp)
        R.store_group(g, K[0], fp, d, jpat, J)
    st[1] += ng
    st[2] += 1


@njit(cache=True)
def ros_solve(fn, t0, t_end, x0, rtol, atol, jpat, t_out, out, sig, p, modes):
    """ROS34PW2 from (t0, x0) to t_end with dense output at t_out; returns the counters
    (steps, RHS calls, Jacobians, LU)."""
    n = x0.size
    K = np.zeros((R.K_ROWS, n))
    J = np.zeros((n, n))
    LU = np.zeros((n, n))
    x = x0.copy()
    x1 = np.zeros(n)
    st = np.zeros(4, dtype=np.int64)
    sysfn.derivatives(fn, t0, x, sig, p, modes, K[0])
    y, f1 = K[R.ROW_TRIAL], K[R.ROW_SCRATCH]
    h0 = dp54.initial_h0(x, K[0], rtol, atol, t_end - t0, y)
    sysfn.derivatives(fn, t0 + h0, y, sig, p, modes, f1)
    h = dp54.initial_step(x, K[0], f1, h0, rtol, atol, t_end - t0)
    st[1] += 2
    t = t0
    k = 0
    while k < t_out.size and t_out[k] <= t0:
        out[k, :] = x0
        k += 1
    age = -1
    h_lu = 0.0
    while t < t_end:
        if age < 0 or age >= R.JAC_MAX_AGE:
            _ros_jacobian(fn, t, x, K, J, jpat, st, sig, p, modes)
            age = 0
            h_lu = 0.0
        rejected = False
        while True:
            if t + h > t_end:
                h = t_end - t
            ok = True
            if h != h_lu:
                ok = R.factor_matrix(J, LU, K[R.ROW_PIV], h)
                st[3] += 1
                h_lu = h if ok else 0.0
            err = math.inf
            if ok:
                K[1, :] = K[0]
                lu_solve(LU, K[R.ROW_PIV], K[1])
                for s in range(1, 4):
                    R.stage_state(s, x, K, y)
                    sysfn.derivatives(fn, t + R.alpha_of(s) * h, y, sig, p, modes, K[s + 1])
                    R.stage_rhs(s, K, h, K[s + 1])
                    lu_solve(LU, K[R.ROW_PIV], K[s + 1])
                R.solution(x, K, x1)
                err = R.error_norm(x, x1, K, rtol, atol)
                st[1] += 3
            if err <= 1.0:
                break
            if age > 0:
                _ros_jacobian(fn, t, x, K, J, jpat, st, sig, p, modes)
                age = 0
                h_lu = 0.0
            h *= R.factor(err, rejected)
            rejected = True
        sysfn.derivatives(fn, t + h, x1, sig, p, modes, K[R.ROW_END])
        st[1] += 1
        st[0] += 1
        age += 1
        t_new = t_end if t + h >= t_end else t + h
        while k < t_out.size and t_out[k] <= t_new:
            R.dense(t, h, x, x1, K, t_out[k], out[k])
            k += 1
        fac = R.factor(err, rejected)
        if 1.0 <= fac <= R.HOLD_MAX:
            fac = 1.0
        t = t_new
        x[:] = x1
        K[0, :] = K[R.ROW_END]
        h *= fac
    return st


# --- SciPy stepper, step by step ---------------------------------------------------------------

def scipy_run(cls, rhs, y0, t_end, rtol, atol, t_out, **kw):
    s = cls(rhs, 0.0, y0, t_end, rtol=rtol, atol=atol, **kw)
    out = np.zeros((t_out.size, y0.size))
    k, steps = 0, 0
    while k < t_out.size and t_out[k] <= 0.0:
        out[k] = y0
        k += 1
    while s.status == "running":
        s.step()
        steps += 1
        if k < t_out.size and t_out[k] <= s.t:
            d = s.dense_output()
            while k < t_out.size and t_out[k] <= s.t:
                out[k] = d(t_out[k])
                k += 1
    return out, (steps, s.nfev, s.njev, s.nlu)


def bench(title, f, n, y0, t_end, rtol, atol, t_out, reference, repeat=5):
    cf = make_cfunc(f, n)
    rhs = make_py(f, n)
    y0 = np.array(y0, float)
    jpat = R.pattern_array(None, n)
    ref = reference(rhs, y0, t_end, t_out)

    def bdf_run(want_f1):
        def run():
            V, JW, iw, fw = bdf.work(n)
            iw[bdf.I_WANT_F1] = want_f1
            out = np.zeros((t_out.size, n))
            bdf.solve(cf.address, 0.0, t_end, y0, rtol, atol, jpat, t_out, out, NONE, NONE,
                      NONE, V, JW, iw, fw)
            return out, (iw[bdf.I_NSTEPS], iw[bdf.I_NFEV], iw[bdf.I_NJAC], iw[bdf.I_NLU])
        return run

    def ros_run():
        out = np.zeros((t_out.size, n))
        st = ros_solve(cf.address, 0.0, t_end, y0, rtol, atol, jpat, t_out, out, NONE, NONE,
                       NONE)
        return out, tuple(st)

    variants = [
        ("spidersim BDF", bdf_run(0)),
        ("spidersim BDF (f1 each step)", bdf_run(1)),
        ("numba RHS + SciPy LSODA",
         lambda: scipy_run(LSODA, rhs, y0, t_end, rtol, atol, t_out)),
        ("numba RHS + SciPy BDF", lambda: scipy_run(BDF, rhs, y0, t_end, rtol, atol, t_out)),
        ("compiled ROS34PW2", ros_run),
    ]
    times, outs = interleaved(variants, repeat)
    print(f"== {title} ==")
    print(f"{'variant':30s} {'best [ms]':>10s} {'median':>9s} {'steps':>7s} {'RHS':>7s} "
          f"{'Jac':>5s} {'LU':>6s} {'max err/tol':>12s}")
    scale = atol + rtol * np.abs(ref)
    for name, _fn in variants:
        out, (steps, nfev, njac, nlu) = outs[name]
        err = float(np.max(np.abs(out - ref) / scale))
        b, m = min(times[name]), statistics.median(times[name])
        print(f"{name:30s} {1e3 * b:10.3f} {1e3 * m:9.3f} {steps:7d} {nfev:7d} {njac:5d} "
              f"{nlu:6d} {err:12.2f}")
    best = min(times["spidersim BDF"])
    print("speed-up of spidersim BDF: " + ", ".join(
        f"{min(times[name]) / best:.1f}x vs {name}" for name, _ in variants[2:]))
    print()


def radau_reference(rhs, y0, t_end, t_out):
    return solve_ivp(rhs, (0.0, t_end), y0, method=Radau, rtol=1e-12, atol=1e-16,
                     t_eval=t_out).y.T


def lsoda_reference(rhs, y0, t_end, t_out):
    return solve_ivp(rhs, (0.0, t_end), y0, method=LSODA, rtol=1e-12, atol=1e-14,
                     t_eval=t_out).y.T


def bench_robertson():
    t_out = np.concatenate(([0.0], np.logspace(-5, np.log10(4e4), 60)[:-1], [4e4]))
    bench("Robertson, t = 0 .. 4e4, rtol 1e-6, atol 1e-10 (60 log-spaced outputs)",
          robertson_f, 3, [1.0, 0.0, 0.0], 4e4, 1e-6, 1e-10, t_out, radau_reference)


def bench_lugre():
    bench("LuGre stick-slip (lugre_stick_slip.yaml by hand), 20 s, rtol 1e-7, atol 1e-10 "
          "(outputs every 0.1 s)", lugre_f, 3, [0.0, 0.0, 0.0], 20.0, 1e-7, 1e-10,
          np.linspace(0.0, 20.0, 201), lsoda_reference)


BENCHES = {"robertson": bench_robertson, "lugre": bench_lugre}


def main(argv):
    for name in argv or list(BENCHES):
        if name not in BENCHES:
            sys.exit(f"unknown benchmark '{name}'; choose from {', '.join(BENCHES)}")
        BENCHES[name]()


if __name__ == "__main__":
    main(sys.argv[1:])
