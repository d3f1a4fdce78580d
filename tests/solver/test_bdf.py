"""The compiled variable-order BDF/NDF (spidersim.solver.bdf) on hand-written system
functions (numba cfuncs of sysfn.SYSTEM_SIG, no diagram): observed order with the order
forced, the error constants and the error estimate against a hand derivation, stiff problems
against expm and tight SciPy Radau references, dense output, Jacobian reuse, restarts
across jumps, and the failure return."""
import math

import numba
import numpy as np
import pytest
from scipy.integrate import solve_ivp
from scipy.linalg import expm

from spidersim.solver import bdf
from spidersim.solver import rosenbrock as R
from spidersim.solver import sysfn

NONE = np.zeros(1)                       # sig / modes: unused by these systems

# --- the systems -------------------------------------------------------------------------------

A_SMOOTH = np.array([[-0.5, 2.0], [-2.0, -0.5]])


@numba.cfunc(sysfn.SYSTEM_SIG)
def smooth(task, t, xp, sigp, pp, mp, outp, k, f):
    """x' = A_SMOOTH x (a damped rotation, eigenvalues -0.5 +- 2i)."""
    if task == sysfn.DERIVATIVES:
        x = numba.carray(xp, 2)
        out = numba.carray(outp, 2)
        out[0] = -0.5 * x[0] + 2.0 * x[1]
        out[1] = -2.0 * x[0] - 0.5 * x[1]
    return 0.0


A_STIFF = np.array([[-1.0, 50.0, 0.0], [0.0, -1e4, 1.0], [0.0, 0.0, -1e2]])


@numba.cfunc(sysfn.SYSTEM_SIG)
def stiff(task, t, xp, sigp, pp, mp, outp, k, f):
    """x' = A_STIFF x: eigenvalues -1, -1e2, -1e4, non-normal."""
    if task == sysfn.DERIVATIVES:
        x = numba.carray(xp, 3)
        out = numba.carray(outp, 3)
        out[0] = -x[0] + 50.0 * x[1]
        out[1] = -1e4 * x[1] + x[2]
        out[2] = -1e2 * x[2]
    return 0.0


@numba.cfunc(sysfn.SYSTEM_SIG)
def robertson(task, t, xp, sigp, pp, mp, outp, k, f):
    """Robertson's chemical kinetics (stiffness ~1e9 at late times)."""
    if task == sysfn.DERIVATIVES:
        x = numba.carray(xp, 3)
        out = numba.carray(outp, 3)
        out[0] = -0.04 * x[0] + 1e4 * x[1] * x[2]
        out[1] = 0.04 * x[0] - 1e4 * x[1] * x[2] - 3e7 * x[1] ** 2
        out[2] = 3e7 * x[1] ** 2
    return 0.0


@numba.cfunc(sysfn.SYSTEM_SIG)
def vdp(task, t, xp, sigp, pp, mp, outp, k, f):
    """Van der Pol x'' - mu (1 - x^2) x' + x = 0 with mu = p[0]."""
    if task == sysfn.DERIVATIVES:
        x = numba.carray(xp, 2)
        p = numba.carray(pp, 1)
        out = numba.carray(outp, 2)
        out[0] = x[1]
        out[1] = p[0] * (1.0 - x[0] ** 2) * x[1] - x[0]
    return 0.0


@numba.cfunc(sysfn.SYSTEM_SIG)
def relax(task, t, xp, sigp, pp, mp, outp, k, f):
    """x' = -lam (x - u), lam = p[0], u = p[1] (an input the caller switches)."""
    if task == sysfn.DERIVATIVES:
        x = numba.carray(xp, 1)
        p = numba.carray(pp, 2)
        out = numba.carray(outp, 1)
        out[0] = -p[0] * (x[0] - p[1])
    return 0.0


@numba.cfunc(sysfn.SYSTEM_SIG)
def blows_up(task, t, xp, sigp, pp, mp, outp, k, f):
    """x' = -x, but NaN from t = 0.5 on (no step can pass it)."""
    if task == sysfn.DERIVATIVES:
        x = numba.carray(xp, 1)
        out = numba.carray(outp, 1)
        out[0] = -x[0] if t < 0.5 else math.nan
    return 0.0


def f_py(cf, n, p=NONE):
    """The cfunc as a Python f(t, x) for SciPy."""
    def f(t, x):
        out = np.zeros(n)
        sysfn.derivatives(cf.address, t, np.ascontiguousarray(x, float), NONE, p, NONE, out)
        return out
    return f


def solve(cf, x0, t_end, rtol, atol, t_out, p=NONE, pattern=None, max_order=5):
    """bdf.solve on a cfunc (at most 50,000 steps); returns (out rows at t_out, iw
    counters)."""
    n = len(x0)
    V, JW, iw, fw = bdf.work(n, max_order)
    out = np.zeros((len(t_out), n))
    t = bdf.solve(cf.address, 0.0, t_end, np.array(x0, float), rtol, atol,
                  R.pattern_array(pattern, n), np.array(t_out, float), out, NONE, p, NONE,
                  V, JW, iw, fw, 50000)
    assert t == t_end
    return out, iw


# --- order and error constants -----------------------------------------------------------------

def exact_smooth(t, y0=np.array([1.0, 0.5])):
    return expm(A_SMOOTH * t) @ y0


def seeded(k, h):
    """Work arrays at t = 0 with the exact history of the smooth problem at order k, step h
    (D[j] = nabla^j y(0) from y(0), y(-h), ..., y(-k h)), order and step held fixed."""
    V, JW, iw, fw = bdf.work(2)
    Y = [exact_smooth(-m * h) for m in range(k + 1)]
    for j in range(k + 1):
        V[j] = sum((-1) ** m * math.comb(j, m) * Y[m] for m in range(j + 1))
    iw[bdf.I_ORDER] = k
    iw[bdf.I_FIXED] = 1
    iw[bdf.I_FCUR_VALID] = 0
    fw[bdf.F_H] = h
    return V, JW, iw, fw


def fixed_run(k, n_steps, t_end=1.0, rtol=1e-13, atol=1e-13):
    h = t_end / n_steps
    V, JW, iw, fw = seeded(k, h)
    x1, f1 = np.zeros(2), np.zeros(2)
    jpat = R.pattern_array(None, 2)
    t = 0.0
    for s in range(n_steps):
        hh = bdf.advance(smooth.address, t, 10.0, x1, f1, rtol, atol, math.inf, V, JW, iw, fw,
                         jpat, NONE, NONE, NONE)
        assert abs(hh - h) < 1e-14
        t = (s + 1) * h
    assert iw[bdf.I_NNEWTON] == 0 and iw[bdf.I_ORDER] == k
    return np.linalg.norm(x1 - exact_smooth(t_end))


@pytest.mark.parametrize("k", [1, 2, 3, 4, 5])
def test_observed_order_with_the_order_forced(k):
    """Fixed order k and fixed step from an exact history (no start-up error) on a smooth
    linear problem: the global error at t = 1 falls by 2^k per halving of h (h = 1/20, 1/40,
    1/80), measured within 0.1. Guards the history update, the predictor and the gamma/alpha
    coefficients of the corrector (a wrong one drops the order to 1)."""
    e = [fixed_run(k, n) for n in (20, 40, 80)]
    for a, b in zip(e, e[1:]):
        assert abs(math.log2(a / b) - k) < 0.1


# Shampine & Reichelt 1997, Table 1: the NDF's kappa (orders 1..5)
PAPER_KAPPA = [-0.1850, -1 / 9, -0.0823, -0.0415, 0.0]


@pytest.mark.parametrize("k", [1, 2, 3, 4, 5])
def test_local_error_constant_and_its_estimate(k):
    """One step of order k from the exact history (h = 0.01): the local error must be
    C h^(k+1) y^(k+1) with C = (kappa_k gamma_k + 1/(k+1)) / alpha_k, alpha_k = (1 - kappa_k)
    gamma_k, from the paper's kappa (hand derivation: the formula's truncation error
    kappa gamma_k nabla^(k+1) y + h^(k+1) y^(k+1)/(k+1), divided by the coefficient alpha_k of
    y_(n+1)), to 5 % (the next term is O(h)). And the method's estimate (uniform scale atol,
    so err * atol is the rms of the estimated error vector) must be (alpha_k + C_k) times
    that local error, C_k = kappa_k gamma_k + 1/(k+1), to 5 %: the estimate C_k d is the
    formula's truncation error (ode15s's and SciPy's convention, alpha_k times the local
    error) and d = y_(n+1) - y0 = nabla^(k+1) y + e itself contains the local error e.
    Guards KAPPA, ALPHA and ERROR_CONST."""
    h = 0.01
    V, JW, iw, fw = seeded(k, h)
    x1, f1 = np.zeros(2), np.zeros(2)
    atol = 1e-9
    bdf.advance(smooth.address, 0.0, 10.0, x1, f1, 1e-14, atol, math.inf, V, JW, iw, fw,
                R.pattern_array(None, 2), NONE, NONE, NONE)
    err = x1 - exact_smooth(h)
    kappa = PAPER_KAPPA[k - 1]
    gamma = sum(1.0 / j for j in range(1, k + 1))
    alpha = (1 - kappa) * gamma
    C = kappa * gamma + 1.0 / (k + 1)
    c = C / alpha
    lead = c * h ** (k + 1) * (np.linalg.matrix_power(A_SMOOTH, k + 1) @ exact_smooth(0.0))
    assert np.linalg.norm(err - lead) < 0.05 * np.linalg.norm(lead)
    rms_true = math.sqrt(np.mean(err ** 2))
    assert fw[bdf.F_ERR] * atol == pytest.approx((alpha + C) * rms_true, rel=0.05)


# --- stiff problems ------------------------------------------------------------------------------

def test_stiff_linear_system_against_expm():
    """x' = A x with eigenvalues -1, -1e2, -1e4 (non-normal) to t = 2 at rtol 1e-8, atol
    1e-12: every output (t = 0.001 .. 2, dense output included) within 1e-6 relative (+1e-11)
    of expm(A t) x0 (3.4e-7 measured), in far fewer steps than an explicit method's
    stability limit allows (h < 2.8e-4: > 7000 steps; 628 measured)."""
    x0 = np.array([1.0, 1.0, 1.0])
    t_out = np.array([0.001, 0.01, 0.1, 0.5, 1.0, 2.0])
    out, iw = solve(stiff, x0, 2.0, 1e-8, 1e-12, t_out)
    for t, row in zip(t_out, out):
        ex = expm(A_STIFF * t) @ x0
        assert np.all(np.abs(row - ex) <= 1e-6 * np.abs(ex) + 1e-11), (t, row, ex)
    assert iw[bdf.I_NSTEPS] < 1500


def robertson_reference(t_out):
    return solve_ivp(f_py(robertson, 3), (0, t_out[-1]), [1.0, 0, 0], method="Radau",
                     rtol=1e-12, atol=1e-16, t_eval=t_out).y.T


def test_robertson_against_a_tight_radau_reference():
    """Robertson to t = 4e4 at rtol 1e-8, atol 1e-14: every component (the tiny x1 ~1e-6 ..
    1e-8 too) within 1e-6 relative of SciPy's Radau at rtol 1e-12 (1e-7 measured); mass x0 + x1 + x2
    = 1 conserved to 1e-12 (the Newton steps keep linear invariants when the Jacobian's
    columns sum to zero); a few hundred steps where an explicit method needs millions."""
    t_out = np.array([0.4, 4.0, 40.0, 400.0, 4e3, 4e4])
    out, iw = solve(robertson, [1.0, 0, 0], 4e4, 1e-8, 1e-14, t_out)
    ref = robertson_reference(t_out)
    assert np.all(np.abs(out - ref) < 1e-6 * ref)
    assert np.all(np.abs(out.sum(axis=1) - 1.0) < 1e-12)
    assert iw[bdf.I_NSTEPS] < 2000


def test_van_der_pol_mu_1000():
    """Van der Pol, mu = 1000, x0 = (2, 0), to t = 3000 (almost two relaxation periods of
    ~1614) at rtol 1e-7, atol 1e-9: x at t = 500, 1500, 2500, 3000 (on the slow branches)
    within 1e-4 absolute of SciPy's Radau at 1e-10 with the exact Jacobian (8e-6 measured);
    under 3000 steps (2445 measured; an explicit method needs ~1e6) with under one Jacobian
    per 10 steps (126 measured)."""
    p = np.array([1000.0])
    t_out = np.array([500.0, 1500.0, 2500.0, 3000.0])
    out, iw = solve(vdp, [2.0, 0.0], 3000.0, 1e-7, 1e-9, t_out, p=p)
    jac = lambda t, x: np.array([[0.0, 1.0], [-2e3 * x[0] * x[1] - 1.0,   # noqa: E731
                                              1e3 * (1.0 - x[0] ** 2)]])
    ref = solve_ivp(f_py(vdp, 2, p), (0, 3000), [2.0, 0.0], method="Radau", rtol=1e-10,
                    atol=1e-12, t_eval=t_out, jac=jac).y.T
    assert np.all(np.abs(out[:, 0] - ref[:, 0]) < 1e-4)
    assert iw[bdf.I_NSTEPS] < 3000
    assert iw[bdf.I_NJAC] * 10 < iw[bdf.I_NSTEPS]


def test_jacobian_reuse():
    """The reuse policy actually holds J: on Robertson (rtol 1e-6) fewer than one Jacobian
    per 20 accepted steps and fewer LU factorisations than steps; every Jacobian follows a
    Newton failure with a stale J (or is the first one), and the counted RHS calls add up:
    steps (f1) + Newton iterations + one per Jacobian group + start."""
    out, iw = solve(robertson, [1.0, 0, 0], 4e4, 1e-6, 1e-10, np.array([4e4]))
    steps, njac, nlu = iw[bdf.I_NSTEPS], iw[bdf.I_NJAC], iw[bdf.I_NLU]
    assert njac * 20 < steps
    assert nlu < steps
    assert njac <= iw[bdf.I_NNEWTON] + 1


# --- dense output, restarts, failures -------------------------------------------------------------

def test_dense_output_between_steps():
    """Between the accepted steps of the smooth problem (rtol 1e-9): the interpolant at each
    step's end is x1 and at its start the previous state (to 1e-13: the polynomial
    interpolates the history, also after a rescaling), and at 1/3 and 2/3 of each step its
    error against the exact solution is no larger than twice the worst global error at the
    step ends (the interpolant is as accurate as the steps)."""
    V, JW, iw, fw = bdf.work(2)
    x = exact_smooth(0.0)
    f0 = A_SMOOTH @ x
    bdf.restart(0.0, x, f0, 1e-4, V, JW, iw, fw)
    jpat = R.pattern_array(None, 2)
    x1, f1, out = np.zeros(2), np.zeros(2), np.zeros(2)
    t = 0.0
    worst = worst_end = 0.0
    while t < 3.0:
        h = bdf.advance(smooth.address, t, 3.0, x1, f1, 1e-9, 1e-12, math.inf, V, JW, iw, fw,
                        jpat, NONE, NONE, NONE)
        assert h > 0.0
        t_new = t + h
        bdf.dense(t_new, V, iw, fw, t_new, out)
        assert np.allclose(out, x1, rtol=1e-13, atol=1e-15)
        bdf.dense(t_new, V, iw, fw, t, out)
        assert np.allclose(out, x, rtol=1e-12, atol=1e-14)
        for th in (1 / 3, 2 / 3):
            bdf.dense(t_new, V, iw, fw, t + th * h, out)
            ex = exact_smooth(t + th * h)
            worst = max(worst, np.max(np.abs(out - ex)))
        worst_end = max(worst_end, np.max(np.abs(x1 - exact_smooth(t_new))))
        x = x1.copy()
        t = t_new
    assert iw[bdf.I_ORDER] >= 3                    # the polynomial is of high order here
    assert worst_end < 1e-7
    assert worst < 2.0 * worst_end


def test_restart_after_jumps():
    """x' = -lam (x - u), lam = 1e3 (stiff), u switched 0 -> 1 at t = 1 and x set to -2 at
    t = 2 (segment ends via t_seg, restart at each): steps end exactly at the segment ends,
    and x(3) = 1 - 3 exp(-lam) ~ 1, x(2.001) = 1 - 3 exp(-1) agree with the closed form to
    1e-6 (the history is not carried across the jumps)."""
    lam = 1e3
    p = np.array([lam, 0.0])
    V, JW, iw, fw = bdf.work(1)
    jpat = R.pattern_array(None, 1)
    x = np.array([1.0])
    x1, f1 = np.zeros(1), np.zeros(1)
    seen = {}
    t = 0.0
    for t_seg, jump in ((1.0, None), (2.0, "u"), (3.0, "x")):
        if jump == "u":
            p[1] = 1.0
        elif jump == "x":
            x[0] = -2.0
        f0 = np.array([-lam * (x[0] - p[1])])
        bdf.restart(t, x, f0, 1e-5, V, JW, iw, fw)
        while t < t_seg:
            h = bdf.advance(relax.address, t, t_seg, x1, f1, 1e-9, 1e-12, math.inf, V, JW, iw,
                            fw, jpat, NONE, p, NONE)
            assert h > 0.0 and t + h <= t_seg * (1 + 1e-15)
            if t < 2.001 <= t + h:
                out = np.zeros(1)
                bdf.dense(t + h, V, iw, fw, 2.001, out)
                seen[2.001] = out[0]
            t = t_seg if abs(t + h - t_seg) < 1e-12 else t + h
            x[:] = x1
        if t_seg == 1.0:
            assert abs(x[0] - math.exp(-lam)) < 1e-12
    assert abs(seen[2.001] - (1 - 3 * math.exp(-1.0))) < 1e-6
    assert abs(x[0] - (1 - 3 * math.exp(-lam))) < 1e-6


def test_step_size_underflow_returns_zero():
    """A right-hand side that is NaN from t = 0.5: advance returns 0.0 (step size below ten
    spacings of floating-point numbers at t) instead of looping, short of t = 0.5."""
    V, JW, iw, fw = bdf.work(1)
    jpat = R.pattern_array(None, 1)
    x = np.array([1.0])
    bdf.restart(0.0, x, -x, 1e-3, V, JW, iw, fw)
    x1, f1 = np.zeros(1), np.zeros(1)
    t = 0.0
    for _ in range(10000):
        h = bdf.advance(blows_up.address, t, 1.0, x1, f1, 1e-6, 1e-9, math.inf, V, JW, iw, fw,
                        jpat, NONE, NONE, NONE)
        if h == 0.0:
            break
        t += h
    assert h == 0.0 and t < 0.5
    assert abs(t - 0.5) < 1e-6


def test_max_order_knob_and_its_check():
    """max_order caps the order (Robertson at max_order 2 never goes above 2 and needs more
    steps than at 5); a max_order outside 1..5 is a ValueError naming it."""
    _, iw2 = solve(robertson, [1.0, 0, 0], 40.0, 1e-8, 1e-14, np.array([40.0]), max_order=2)
    _, iw5 = solve(robertson, [1.0, 0, 0], 40.0, 1e-8, 1e-14, np.array([40.0]))
    assert iw2[bdf.I_ORDER] <= 2
    assert iw2[bdf.I_NSTEPS] > iw5[bdf.I_NSTEPS]
    with pytest.raises(ValueError, match="max_order"):
        bdf.work(3, max_order=6)


def test_sparse_pattern_gives_the_same_jacobian_in_fewer_evaluations():
    """The Jacobian over the coloured column groups of the structural pattern of A_STIFF
    (upper bidiagonal: 2 groups instead of 3) gives the same run as the dense pattern (same
    steps, outputs to 1e-12 relative) with one evaluation less per Jacobian."""
    x0 = [1.0, 1.0, 1.0]
    t_out = np.array([0.01, 1.0, 2.0])
    pattern = A_STIFF != 0.0
    assert R.n_groups(R.pattern_array(pattern, 3)) == 2
    dense_out, iw_d = solve(stiff, x0, 2.0, 1e-8, 1e-12, t_out)
    sparse_out, iw_s = solve(stiff, x0, 2.0, 1e-8, 1e-12, t_out, pattern=pattern)
    assert iw_s[bdf.I_NSTEPS] == iw_d[bdf.I_NSTEPS]
    assert iw_s[bdf.I_NJAC] == iw_d[bdf.I_NJAC]
    assert iw_d[bdf.I_NFEV] - iw_s[bdf.I_NFEV] == iw_d[bdf.I_NJAC]
    assert np.allclose(sparse_out, dense_out, rtol=1e-12, atol=1e-20)
