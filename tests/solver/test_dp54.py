"""Dormand-Prince 5(4) helpers tested on plain functions (no diagram, no generated code).

Each check fails when a coefficient is wrong: the convergence orders below are those of the
fifth-order solution, the fourth-order error estimate and the fourth-order dense output.
"""
import math

import numpy as np
import pytest

from spidersim.solver import dp54
from spidersim.solver.events import crossed, locate_on


def decay(t, x, sig, p, modes, xdot):
    """x' = -x + sin(t): x(t) = (sin t - cos t)/2 + (x0 + 1/2) e^-t."""
    xdot[0] = -x[0] + math.sin(t)


def exact(t, x0=1.0):
    return 0.5 * (math.sin(t) - math.cos(t)) + (x0 + 0.5) * math.exp(-t)


def one_step(h, t=0.3):
    x = np.array([exact(t)])
    K = dp54.work_array(1)
    decay(t, x, None, None, None, K[0])
    x1 = np.zeros(1)
    err = dp54.step(decay, t, x, h, K, x1, 1e-6, 1e-8)
    return x, x1, K, err, t


def test_step_is_fifth_order():
    # local error of a fifth-order method is O(h^6): halving h divides it by 64
    e = [abs(one_step(h)[1][0] - exact(0.3 + h)) for h in (0.2, 0.1)]
    assert 40 < e[0] / e[1] < 90


def test_error_estimate_is_fourth_order_and_honest():
    # the estimate is of the embedded fourth-order solution: O(h^5), halving h -> /32
    est = [one_step(h)[3] for h in (0.2, 0.1)]
    assert 20 < est[0] / est[1] < 45
    # it is larger than the actual error of the propagated fifth-order solution
    x, x1, K, err, t = one_step(0.2)
    actual = abs(x1[0] - exact(t + 0.2)) / (1e-8 + 1e-6 * max(abs(x[0]), abs(x1[0])))
    assert err > actual


def test_dense_output_interpolates_and_is_fourth_order():
    for h in (0.2,):
        x, x1, K, err, t = one_step(h)
        out = np.zeros(1)
        dp54.dense(t, h, x, x1, K, t, out)
        assert out[0] == pytest.approx(x[0], abs=1e-15)
        dp54.dense(t, h, x, x1, K, t + h, out)
        assert out[0] == pytest.approx(x1[0], abs=1e-15)
    errs = []
    for h in (0.4, 0.2):
        x, x1, K, err, t = one_step(h)
        out = np.zeros(1)
        dp54.dense(t, h, x, x1, K, t + 0.37 * h, out)
        errs.append(abs(out[0] - exact(t + 0.37 * h)))
    assert 16 < errs[0] / errs[1] < 80          # O(h^5) locally: /32 per halving


def test_factor_follows_the_error_norm():
    assert dp54.factor(0.0, False) == dp54.MAX_FACTOR
    assert dp54.factor(1e-12, True) == 1.0          # no growth right after a rejection
    assert dp54.factor(1.0, False) == pytest.approx(0.9)
    assert dp54.factor(1e9, False) == dp54.MIN_FACTOR
    assert dp54.factor(32.0, False) == pytest.approx(0.9 / 2)


def test_first_step_is_positive_and_bounded():
    K = dp54.work_array(1)
    x = np.array([1.0])
    decay(0.0, x, None, None, None, K[0])
    h = dp54.first_step(decay, 0.0, x, K[0], 0.5, 1e-6, 1e-8, K)
    assert 0 < h <= 0.5
    # the step it proposes meets the tolerance or nearly (the usual choice)
    x1 = np.zeros(1)
    assert dp54.step(decay, 0.0, x, h, K, x1, 1e-6, 1e-8) < 10
    assert dp54.first_step(decay, 0.0, x, K[0], 1e-9, 1e-6, 1e-8, K) <= 1e-9


def test_crossings_respect_direction_and_arming():
    g0, g1 = np.array([-1.0, 1.0, 0.0, -1.0]), np.array([1.0, -1.0, 1.0, 1.0])
    assert list(crossed(g0, g1, [1, 1, 1, -1])) == [0]
    assert list(crossed(g0, g1, [0, 0, 0, 0])) == [0, 1, 3]
    assert list(crossed(g0, g1, [0, 0, 0, 0], np.ones(4, bool))) == [0, 1, 2, 3]


@pytest.mark.parametrize("root", [0.1, 0.5, 0.999999])
def test_bracketing_finds_the_far_side_within_xtol(root):
    g = lambda s: math.tanh(50 * (s - root)) + 1e-3 * (s - root) ** 3   # noqa: E731
    r = locate_on(g, 0.0, 1.0, g(0.0), g(1.0), 1e-13)
    assert g(r) >= 0.0 and 0.0 <= r - root <= 2e-13
