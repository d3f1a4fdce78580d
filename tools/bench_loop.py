"""The compiled integration loop (method DP54) against hand-written baselines, one run.

    python tools/bench_loop.py [servo|ball|loop|lugre|servo_stiff|spider]

For each problem, interleaved in one process (best of 7 rounds of the mean time of a call,
each round as many calls as fill 20 ms):

* **spidersim DP54**: the diagram run with ``method: DP54`` (compiled loop, events inside);
* **hand DP54**: a fully compiled Dormand-Prince 5(4) integrator written by hand in this file
  for exactly these equations (its own tableau, the same step-size controller, initial step
  rule and tolerances; events located by bisection on the dense output to 1e-13 s);
* **numba RHS + LSODA**: the same equations as one numba function driven by SciPy's LSODA
  step by step (events located with brentq on its dense output), the usual Python way;
* **spidersim LSODA**: the diagram with SciPy's LSODA in spidersim's Python loop.

``lugre``, ``servo_stiff`` and ``spider`` time the stiff methods instead: spidersim
``NDF`` and ``ROS34PW2`` against the same equations as one hand-written numba function driven by SciPy's
LSODA (LuGre, servo; none for spider.yaml), a hand-written fully compiled ROS34PW2 of the
same tableau, Jacobian reuse and step-size rules (LuGre, which has no time event), and
spidersim LSODA, interleaved, with steps, RHS calls, Jacobians and LU
factorisations (``spider`` is not in the default set: it takes minutes).

The ratio printed is spidersim DP54 / hand DP54 (target <= 1.3) and LSODA / spidersim DP54.
Steps and RHS calls are printed: the hand-written servo clips its voltage with min/max, while
spidersim locates the saturation corners as events, so their step counts differ.
"""
from __future__ import annotations

import math
import os
import statistics
import sys
import time

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from bench_common import interleaved  # noqa: E402
from numba import njit

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))

# Dormand-Prince 5(4), written out again for the baseline
c = np.array([0, 1 / 5, 3 / 10, 4 / 5, 8 / 9, 1, 1])
a = np.zeros((7, 7))
a[1, 0] = 1 / 5
a[2, :2] = [3 / 40, 9 / 40]
a[3, :3] = [44 / 45, -56 / 15, 32 / 9]
a[4, :4] = [19372 / 6561, -25360 / 2187, 64448 / 6561, -212 / 729]
a[5, :5] = [9017 / 3168, -355 / 33, 46732 / 5247, 49 / 176, -5103 / 18656]
a[6, :6] = [35 / 384, 0, 500 / 1113, 125 / 192, -2187 / 6784, 11 / 84]
e = np.array([71 / 57600, 0, -71 / 16695, 71 / 1920, -17253 / 339200, 22 / 525, -1 / 40])
dd = np.array([-12715105075 / 11282082432, 0, 87487479700 / 32700410799,
               -10690763975 / 1880347072, 701980252875 / 199316789632,
               -1453857185 / 822651844, 69997945 / 29380423])


def make_dp54(f, guard, jump):
    """A fully compiled DP54 for ``f(t, y, out)`` with one state event ``guard(t, y)``
    (falling through zero; ``jump(y)`` applies it) and time events at ``tev``."""

    @njit
    def norm_err(y, y1, K, h, rtol, atol):
        s = 0.0
        for i in range(y.size):
            er = 0.0
            for j in range(7):
                er += e[j] * K[j, i]
            sc = atol + rtol * max(abs(y[i]), abs(y1[i]))
            s += (h * er / sc) ** 2
        return math.sqrt(s / y.size)

    @njit
    def dense(t, h, y, y1, K, s, out):
        th = (s - t) / h
        for i in range(y.size):
            r2 = y1[i] - y[i]
            r3 = h * K[0, i] - r2
            r4 = r2 - h * K[6, i] - r3
            r5 = 0.0
            for j in range(7):
                r5 += dd[j] * K[j, i]
            out[i] = y[i] + th * (r2 + (1 - th) * (r3 + th * (r4 + (1 - th) * h * r5)))

    @njit
    def solve(y0, tev, t_end, rtol, atol, tout, yout):
        n = y0.size
        y = y0.copy()
        y1 = np.empty(n)
        yt = np.empty(n)
        K = np.empty((7, n))
        t = 0.0
        rows = 0
        steps = 0
        nfev = 0
        nev = 0
        k_ev = 0
        tout[rows] = t
        yout[rows] = y
        rows += 1
        h = 0.0
        while t < t_end:
            t_seg = t_end
            if k_ev < tev.size:
                t_seg = min(tev[k_ev], t_end)
            f(t, y, K[0])
            nfev += 1
            # initial step (Hairer)
            d0 = 0.0
            d1 = 0.0
            for i in range(n):
                sc = atol + abs(y[i]) * rtol
                d0 += (y[i] / sc) ** 2
                d1 += (K[0, i] / sc) ** 2
            d0 = math.sqrt(d0 / n)
            d1 = math.sqrt(d1 / n)
            h0 = 1e-6 if d0 < 1e-5 or d1 < 1e-5 else 0.01 * d0 / d1
            h0 = min(h0, t_seg - t)
            for i in range(n):
                yt[i] = y[i] + h0 * K[0, i]
            f(t + h0, yt, K[1])
            nfev += 1
            d2 = 0.0
            for i in range(n):
                sc = atol + abs(y[i]) * rtol
                d2 += ((K[1, i] - K[0, i]) / sc) ** 2
            d2 = math.sqrt(d2 / n) / h0
            h1 = max(1e-6, h0 * 1e-3) if max(d1, d2) <= 1e-15 else \
                (0.01 / max(d1, d2)) ** 0.2
            h = min(100 * h0, h1, t_seg - t)
            g_old = guard(t, y)
            while t < t_seg:
                rejected = False
                while True:
                    if t + h > t_seg:
                        h = t_seg - t
                    for s in range(1, 7):
                        for i in range(n):
                            acc = 0.0
                            for j in range(s):
                                acc += a[s, j] * K[j, i]
                            yt[i] = y[i] + h * acc
                        f(t + c[s] * h, yt, K[s])
                    for i in range(n):
                        y1[i] = yt[i]
                    f(t + h, y1, K[6])
                    nfev += 6
                    err = norm_err(y, y1, K, h, rtol, atol)
                    if err <= 1.0:
                        fac = 10.0 if err == 0 else min(10.0, 0.9 * err ** -0.2)
                        if rejected:
                            fac = min(1.0, fac)
                        break
                    h *= max(0.2, 0.9 * err ** -0.2)
                    rejected = True
                steps += 1
                t_new = t_seg if t + h >= t_seg else t + h
                g_new = guard(t_new, y1)
                if g_old > 0.0 and g_new <= 0.0:          # locate by bisection
                    lo, hi = t, t_new
                    while hi - lo > 1e-13 * max(1.0, abs(hi)):
                        mid = 0.5 * (lo + hi)
                        dense(t, h, y, y1, K, mid, yt)
                        if guard(mid, yt) > 0.0:
                            lo = mid
                        else:
                            hi = mid
                    dense(t, h, y, y1, K, hi, yt)
                    jump(yt)
                    nev += 1
                    t = hi
                    y[:] = yt
                    tout[rows] = t
                    yout[rows] = y
                    rows += 1
                    if rows >= tout.size:
                        return rows, steps, nfev, nev
                    break                     # restart: new initial step after the event
                g_old = g_new
                t = t_new
                y[:] = y1
                K[0] = K[6]
                tout[rows] = t
                yout[rows] = y
                rows += 1
                if rows >= tout.size:
                    return rows, steps, nfev, nev
                h = h * fac
            if k_ev < tev.size and t >= tev[k_ev] and t >= t_seg:
                k_ev += 1
                nev += 1
        return rows, steps, nfev, nev

    return solve


def _best(fn, repeat=7, round_time=0.02):
    """Best and median over ``repeat`` rounds of the mean time of one call; a round is as
    many calls as fill about ``round_time`` seconds (at least one), the same rule for every
    variant: single calls of a fraction of a millisecond vary by 10-20 % from one to the
    next (the garbage collector, the caches after the previous variant)."""
    t0 = time.perf_counter()
    out = fn()
    number = max(1, int(round_time / max(time.perf_counter() - t0, 1e-7)))
    times = []
    for _ in range(repeat):
        t0 = time.perf_counter()
        for _ in range(number):
            out = fn()
        times.append((time.perf_counter() - t0) / number)
    return min(times), statistics.median(times), out


def _lsoda_hand(f, guard, jump, y0, tev, t_end, rtol, atol):
    """numba RHS + SciPy LSODA stepped from Python, events by brentq on dense output."""
    from scipy.integrate import LSODA
    from scipy.optimize import brentq

    def rhs(t, y):
        out = np.empty(y.size)
        f(t, y, out)
        return out

    def run():
        y, t, steps, rows = np.array(y0, float), 0.0, 0, [0.0]
        bounds = [x for x in tev if x < t_end] + [t_end]
        for t_seg in bounds:
            while t < t_seg:
                s = LSODA(rhs, t, y, t_seg, rtol=rtol, atol=atol)
                g_old = guard(t, y)
                hit = False
                while s.status == "running":
                    t_prev = s.t
                    s.step()
                    steps += 1
                    g_new = guard(s.t, s.y)
                    if g_old > 0.0 and g_new <= 0.0:
                        dn = s.dense_output()
                        tc = brentq(lambda q: guard(q, dn(q)), t_prev, s.t, xtol=1e-13)
                        y = dn(tc)
                        jump(y)
                        t = tc
                        hit = True
                        break
                    g_old = g_new
                    rows.append(s.t)
                if not hit:
                    t, y = s.t, s.y.copy()
        return len(rows), steps
    return run


# --- the problems -----------------------------------------------------------------------

@njit
def servo_f(t, y, out):
    i, w, th, I_s, I_c = y[0], y[1], y[2], y[3], y[4]
    ref = 1.0 if t >= 0.01 else 0.0
    w_ref = 20.0 * (ref - th)
    e_w = w_ref - w
    i_ref = 0.05 * e_w + I_s
    e_i = i_ref - i
    v = min(max(5.0 * e_i + I_c, -24.0), 24.0)
    out[0] = (v - 1.0 * i - 0.05 * w) / 1e-3
    out[1] = (0.05 * i - 1e-5 * w) / 1e-4
    out[2] = w
    out[3] = 1.0 * e_w
    out[4] = 5000.0 * e_i


@njit
def no_guard(t, y):
    return 1.0


@njit
def no_jump(y):
    pass


@njit
def ball_f(t, y, out):
    out[0] = y[1]
    out[1] = -9.81


@njit
def ball_guard(t, y):
    return y[0]


@njit
def ball_jump(y):
    y[0] = 0.0
    y[1] = -0.95 * y[1]


@njit
def loop_f(t, y, out):
    out[0] = math.sin(2 * math.pi * t) / 4.0     # y = u - 3 y solved by hand: y = u / 4


def _report(title, rows):
    print(f"== {title} ==")
    print(f"{'variant':28s} {'best [ms]':>10s} {'median [ms]':>12s} {'steps':>7s} "
          f"{'events':>7s}")
    for name, b, m, steps, nev in rows:
        print(f"{name:28s} {1e3 * b:10.3f} {1e3 * m:12.3f} {steps:7d} {nev:7d}")
    sp, hand, lsoda = rows[0][1], rows[1][1], rows[2][1]
    print(f"spidersim DP54 / hand DP54: {sp / hand:.2f}x (target <= 1.3); numba RHS + LSODA / "
          f"spidersim DP54: {lsoda / sp:.1f}x")
    print()


def _problem(title, path, sets, f, guard, jump, y0, tev, t_end, rtol, atol, n_out):
    import spidersim
    d = spidersim.load(os.path.join(ROOT, path), set=sets)
    kw = dict(t_end=t_end, rtol=rtol, atol=atol, max_step=math.inf)
    d.simulate(method="DP54", **kw)
    solve = make_dp54(f, guard, jump)
    tout, yout = np.empty(n_out), np.empty((n_out, len(y0)))
    y0 = np.array(y0, float)
    tev = np.array(tev, float)
    solve(y0, tev, t_end, rtol, atol, tout, yout)
    lsoda = _lsoda_hand(f, guard, jump, y0, tev, t_end, rtol, atol)
    res = {}
    for _ in range(1):
        res["sp"] = _best(lambda: d.simulate(method="DP54", **kw))
        res["hand"] = _best(lambda: solve(y0, tev, t_end, rtol, atol, tout, yout))
        res["lsoda"] = _best(lsoda, repeat=5)
        res["sp_lsoda"] = _best(lambda: d.simulate(method="LSODA", **kw), repeat=5)
    r = res["sp"][2]
    h = res["hand"][2]
    rows = [("spidersim DP54 (compiled)", res["sp"][0], res["sp"][1], r.stats["steps"],
             len(r.events)),
            ("hand DP54 (fully compiled)", res["hand"][0], res["hand"][1], h[1], h[3]),
            ("numba RHS + SciPy LSODA", res["lsoda"][0], res["lsoda"][1], res["lsoda"][2][1],
             0),
            ("spidersim LSODA", res["sp_lsoda"][0], res["sp_lsoda"][1],
             res["sp_lsoda"][2].stats["steps"], len(res["sp_lsoda"][2].events))]
    _report(title, rows)


def bench_servo():
    _problem("servo: diagrams/servo.yaml, 1 s, 1e-6/1e-8", "diagrams/servo.yaml", {},
             servo_f, no_guard, no_jump, [0, 0, 0, 0, 0], [0.01], 1.0, 1e-6, 1e-8, 100000)


def bench_ball():
    e_, g, h0 = 0.95, 9.81, 10.0
    t1 = math.sqrt(2 * h0 / g)
    t100 = t1 + sum(2 * e_ ** k * g * t1 / g for k in range(1, 100))
    t_end = t100 + 0.5 * 2 * e_ ** 100 * t1
    _problem("ball: bouncing_ball.yaml, e = 0.95, 100 impacts, 1e-10/1e-12",
             "diagrams/bouncing_ball.yaml", {"ball.e": e_, "ball.v_rest": 0}, ball_f,
             ball_guard, ball_jump, [h0, 0.0], [], t_end, 1e-10, 1e-12, 200000)


def bench_loop():
    _problem("loop: algebraic_loop.yaml (y = u - 3y by Newton) vs y = u/4 by hand, "
             "1e-9/1e-12", "diagrams/algebraic_loop.yaml", {}, loop_f, no_guard, no_jump,
             [0.0], [], 2.0, 1e-9, 1e-12, 100000)


# --- the stiff method ------------------------------------------------------------------------

@njit
def lugre_f(t, y, out):
    """lugre_stick_slip.yaml by hand: y = (position, velocity, bristle deflection)."""
    phi, w, z = y[0], y[1], y[2]
    g = 1.0 + 0.5 * math.exp(-(w / 1e-3) ** 2)
    dz = w - 1e5 * abs(w) * z / g
    fric = 1e5 * z + math.sqrt(1e5) * dz + 0.4 * w
    out[0] = w
    out[1] = 2.0 * (0.1 * t - phi) - fric
    out[2] = dz


# ROS34PW2 (Rang & Angermann 2005), written out again for the baseline: the published
# A, Gamma, b, b_hat, transformed to the form without matrix-vector products
_RG = 0.43586652150845900
_RA = np.zeros((4, 4))
_RA[1, 0] = 0.87173304301691801
_RA[2, :2] = [0.84457060015369423, -0.11299064236484185]
_RA[3, 2] = 1.0
_RGam = np.diag([_RG] * 4)
_RGam[1, 0] = -0.87173304301691801
_RGam[2, :2] = [-0.90338057013044082, 0.054180672388095326]
_RGam[3, :3] = [0.24212380706095346, -1.2232505839045147, 0.54526025533510214]
_Rb = np.array([0.24212380706095346, -1.2232505839045147, 1.5452602553351020, _RG])
_Rbh = np.array([0.37810903145819369, -0.096042292212423178, 0.5, 0.21793326075422950])
_RGi = np.linalg.inv(_RGam)
r_a = _RA @ _RGi                      # stage states  x + sum_j a_ij u_j
r_c = -np.tril(_RGi, -1)              # stage right-hand sides  + sum_j (c_ij / h) u_j
r_m = _Rb @ _RGi                      # solution
r_e = (_Rb - _Rbh) @ _RGi             # error estimate
r_alpha = _RA.sum(axis=1)


def make_ros34pw2(f):
    """A fully compiled ROS34PW2 for ``f(t, y, out)`` without events: the Jacobian by forward
    differences on every column (Hairer's increment), kept 20 accepted steps (W-method) and
    refreshed after a rejection; LU factors of ``I / (h gamma) - J`` by Gaussian elimination
    with partial pivoting, kept while ``h`` is unchanged (a step-size factor in [1, 1.2] is
    taken as 1); step-size factor ``clip(0.9 err^(-1/3), 0.2, 5)``, no growth right after a
    rejection; DP54's initial step rule; every accepted step recorded."""

    @njit
    def lu(M, piv):
        n = M.shape[0]
        for k in range(n):
            p = k
            for i in range(k + 1, n):
                if abs(M[i, k]) > abs(M[p, k]):
                    p = i
            piv[k] = p
            if M[p, k] == 0.0:
                return False
            if p != k:
                for j in range(n):
                    M[k, j], M[p, j] = M[p, j], M[k, j]
            for i in range(k + 1, n):
                M[i, k] /= M[k, k]
                for j in range(k + 1, n):
                    M[i, j] -= M[i, k] * M[k, j]
        return True

    @njit
    def lu_solve(M, piv, b):
        n = M.shape[0]
        for k in range(n):
            p = piv[k]
            if p != k:
                b[k], b[p] = b[p], b[k]
        for i in range(n):
            for j in range(i):
                b[i] -= M[i, j] * b[j]
        for i in range(n - 1, -1, -1):
            for j in range(i + 1, n):
                b[i] -= M[i, j] * b[j]
            b[i] /= M[i, i]

    @njit
    def jacobian(t, y, f0, ys, fp, J):
        """``J = df/dy`` by forward differences, column by column (Hairer's increment)."""
        n = y.size
        for j in range(n):
            for i in range(n):
                ys[i] = y[i]
            dj = math.sqrt(2.220446049250313e-16 * max(1e-5, abs(y[j])))
            ys[j] = y[j] + dj
            dj = ys[j] - y[j]
            f(t, ys, fp)
            for i in range(n):
                J[i, j] = (fp[i] - f0[i]) / dj

    @njit
    def rms(v, y, rtol, atol):
        s = 0.0
        for i in range(v.size):
            s += (v[i] / (atol + rtol * abs(y[i]))) ** 2
        return math.sqrt(s / v.size)

    @njit
    def solve(y0, t_end, rtol, atol, max_step, tout, yout):
        n = y0.size
        y = y0.copy()
        y1 = np.empty(n)
        ys = np.empty(n)
        f0 = np.empty(n)
        fp = np.empty(n)
        U = np.empty((4, n))
        J = np.empty((n, n))
        M = np.empty((n, n))
        piv = np.empty(n, np.int64)
        t = 0.0
        rows, steps, nfev, njev, nlu = 1, 0, 0, 0, 0
        tout[0] = t
        yout[0] = y
        f(t, y, f0)
        nfev += 1
        h0 = 1e-6                                   # initial step (Hairer)
        d0, d1 = rms(y, y, rtol, atol), rms(f0, y, rtol, atol)
        if d0 >= 1e-5 and d1 >= 1e-5:
            h0 = 0.01 * d0 / d1
        h0 = min(h0, t_end)
        for i in range(n):
            ys[i] = y[i] + h0 * f0[i]
        f(t + h0, ys, fp)
        nfev += 1
        for i in range(n):
            fp[i] -= f0[i]
        d2 = rms(fp, y, rtol, atol) / h0
        h1 = max(1e-6, h0 * 1e-3) if max(d1, d2) <= 1e-15 else (0.01 / max(d1, d2)) ** (1 / 3)
        h = min(100 * h0, h1, t_end)
        age = -1
        h_lu = 0.0
        while t < t_end:
            h = min(h, max_step)
            if age < 0 or age >= 20:
                jacobian(t, y, f0, ys, fp, J)
                nfev += n
                njev += 1
                age = 0
                h_lu = 0.0
            rejected = False
            while True:
                if t + h > t_end:
                    h = t_end - t
                if h != h_lu:
                    d = 1.0 / (h * _RG)
                    for i in range(n):
                        for j in range(n):
                            M[i, j] = -J[i, j]
                        M[i, i] += d
                    lu(M, piv)
                    nlu += 1
                    h_lu = h
                for s in range(4):
                    if s == 0:
                        for i in range(n):
                            U[0, i] = f0[i]
                    else:
                        for i in range(n):
                            acc = y[i]
                            for j in range(s):
                                acc += r_a[s, j] * U[j, i]
                            ys[i] = acc
                        f(t + r_alpha[s] * h, ys, fp)
                        for i in range(n):
                            acc = fp[i]
                            for j in range(s):
                                acc += r_c[s, j] / h * U[j, i]
                            U[s, i] = acc
                    lu_solve(M, piv, U[s])
                nfev += 3
                err = 0.0
                for i in range(n):
                    x1 = y[i]
                    e = 0.0
                    for j in range(4):
                        x1 += r_m[j] * U[j, i]
                        e += r_e[j] * U[j, i]
                    y1[i] = x1
                    err += (e / (atol + rtol * max(abs(y[i]), abs(x1)))) ** 2
                err = math.sqrt(err / n)
                if err <= 1.0:
                    fac = 5.0 if err == 0.0 else min(5.0, 0.9 * err ** (-1 / 3))
                    if rejected:
                        fac = min(1.0, fac)
                    if 1.0 <= fac <= 1.2:
                        fac = 1.0
                    break
                if age > 0:                         # an older Jacobian: refresh it here
                    jacobian(t, y, f0, ys, fp, J)
                    nfev += n
                    njev += 1
                    age = 0
                    h_lu = 0.0
                h *= max(0.2, 0.9 * err ** (-1 / 3))
                rejected = True
            t = t_end if t + h >= t_end else t + h
            y[:] = y1
            f(t, y, f0)
            nfev += 1
            age += 1
            steps += 1
            tout[rows] = t
            yout[rows] = y
            rows += 1
            if rows >= tout.size:
                break
            h *= fac
        return rows, steps, nfev, njev, nlu

    return solve


def _ros_hand(f, y0, t_end, rtol, atol, max_step, rows=400_000):
    """The hand-written ROS34PW2 for ``f`` as a call of no arguments (buffers allocated
    once, outside the timing, as spidersim keeps its own between runs)."""
    solve = make_ros34pw2(f)
    y0 = np.array(y0, float)
    tout, yout = np.empty(rows), np.empty((rows, y0.size))

    def run():
        return solve(y0, t_end, rtol, atol, max_step, tout, yout), yout
    return run


def _stiff(title, path, t_end, rtol, atol, repeat=5, dp54=True, hand=None):
    """spidersim ROS34PW2 vs numba RHS + SciPy LSODA (``hand = (f, y0, tev)``: the same
    equations written by hand, time events at ``tev``) vs spidersim LSODA (and spidersim
    DP54), interleaved in one process: best and median wall times, steps, RHS calls,
    Jacobians, LU factorisations."""
    import spidersim
    d = spidersim.load(os.path.join(ROOT, path))
    kw = dict(t_end=t_end, rtol=rtol, atol=atol)
    variants = [("spidersim NDF", lambda: d.simulate(method="NDF", **kw)),
                ("spidersim ROS34PW2", lambda: d.simulate(method="ROS34PW2", **kw))]
    if dp54:
        variants.append(("spidersim DP54", lambda: d.simulate(method="DP54", **kw)))
    if hand is not None and not hand[2]:         # no time events: the hand ROS34PW2 has none
        variants.append(("hand ROS34PW2", _ros_hand(hand[0], hand[1], t_end, rtol, atol,
                                                     t_end / 50)))   # spidersim's max_step
    if hand is not None:
        f, y0, tev = hand
        variants.append(("numba RHS + SciPy LSODA",
                         _lsoda_hand(f, no_guard, no_jump, np.array(y0, float),
                                     np.array(tev, float), t_end, rtol, atol)))
    variants.append(("spidersim LSODA", lambda: d.simulate(method="LSODA", **kw)))
    res, outs = interleaved(variants, repeat)
    print(f"== {title} ==")
    print(f"{'variant':26s} {'best [ms]':>10s} {'median [ms]':>12s} {'steps':>7s} "
          f"{'RHS':>8s} {'Jac':>6s} {'LU':>6s} {'x real time':>12s}")
    for name, _fn in variants:
        o = outs[name]
        if isinstance(o, tuple) and isinstance(o[0], tuple):     # _ros_hand
            steps, nfev, njev, nlu = o[0][1:]
        elif isinstance(o, tuple):                   # (rows, steps) of _lsoda_hand
            steps, nfev, njev, nlu = o[1], -1, -1, -1
        else:
            st = o.stats
            steps, nfev = st["steps"], st["rhs_calls"]
            njev, nlu = st["jacobian_calls"], st["lu_decompositions"]
        b, m = min(res[name]), statistics.median(res[name])
        print(f"{name:26s} {1e3 * b:10.2f} {1e3 * m:12.2f} {steps:7d} {nfev:8d} {njev:6d} "
              f"{nlu:6d} {t_end / b:12.1f}")
    sp = min(res["spidersim ROS34PW2"])
    if "hand ROS34PW2" in res:
        print(f"spidersim ROS34PW2 / hand ROS34PW2: {sp / min(res['hand ROS34PW2']):.2f}x "
              "(target <= 1.3)")
    print(f"spidersim LSODA / ROS34PW2: {min(res['spidersim LSODA']) / sp:.2f}x"
          + (f"; numba RHS + LSODA / spidersim ROS34PW2: "
             f"{min(res['numba RHS + SciPy LSODA']) / sp:.2f}x" if hand else "")
          + (f"; DP54 / ROS34PW2: {min(res['spidersim DP54']) / sp:.2f}x" if dp54 else ""))
    print()


def bench_lugre():
    _stiff("LuGre stick-slip: diagrams/lugre_stick_slip.yaml, 20 s, 1e-7/1e-10",
           "diagrams/lugre_stick_slip.yaml", 20.0, 1e-7, 1e-10, hand=(lugre_f, [0, 0, 0], []))


def bench_servo_stiff():
    _stiff("servo (stiff method): diagrams/servo.yaml, 1 s, 1e-6/1e-8", "diagrams/servo.yaml",
           1.0, 1e-6, 1e-8, hand=(servo_f, [0, 0, 0, 0, 0], [0.01]))


def bench_spider():
    _stiff("spider.yaml, 10 s, 1e-6/1e-8", "spider.yaml", 10.0, 1e-6, 1e-8, repeat=2,
           dp54=False)


BENCHES = {"servo": bench_servo, "ball": bench_ball, "loop": bench_loop, "lugre": bench_lugre,
           "servo_stiff": bench_servo_stiff, "spider": bench_spider}


def main(argv):
    for n in argv or [b for b in BENCHES if b != "spider"]:
        if n not in BENCHES:
            sys.exit(f"unknown benchmark '{n}'; choose from {', '.join(BENCHES)}")
        BENCHES[n]()


if __name__ == "__main__":
    main(sys.argv[1:])
