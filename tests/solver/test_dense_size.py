"""Methods with n_x x n_x matrices refuse more states than they can hold, before allocating.

A 1 MB diagram (a Constant of 99,000 values into an Integrator) needed about 10 GB on every
run: the structural Jacobian pattern was built as a dense n_x x n_x boolean matrix even for
DP54, which never reads it, and LSODA, BDF, Radau, ROS34PW2 and NDF would then allocate their
n_x x n_x float matrices. Guarded here: the pattern is made only when an implicit method asks;
the dense methods refuse above ``MAX_DENSE_STATES`` with what it would take and what to use,
on the SciPy path, in the compiled loop (before its work arrays) and in linearization.
"""
from __future__ import annotations

import math

import numpy as np
import pytest

import spidersim
import spidersim.diagram.model as model
from spidersim.errors import SpidersimError
from spidersim.solver import dense_size as I
from spidersim.solver.linearize import jacobians
from spidersim.solver.loop import CompiledLoop



def _wide(n):
    return spidersim.loads(f"""
blocks:
  c: {{type: Constant, value: {[1.0] * n}}}
  i: {{type: Integrator}}
connections:
  - c.y -> i.u
simulation: {{t_end: 0.01}}
log: [i.y]
""")


@pytest.mark.parametrize("method", I.DENSE)
def test_dense_methods_refuse_more_states_than_the_limit(method):
    d = _wide(I.MAX_DENSE_STATES + 1)
    with pytest.raises(SpidersimError, match=rf"method {method} keeps 4001 x 4001 matrices "
                                             r".*at most 4000 states .*use an explicit method"):
        d.simulate(method=method, jit=False)


def test_the_limit_itself_runs_and_explicit_methods_take_more(monkeypatch):
    """At the limit a dense method runs; above it an explicit one does, without ever
    making the n_x x n_x pattern (the pattern function is made to fail)."""
    monkeypatch.setattr(I, "MAX_DENSE_STATES", 30)
    r = _wide(30).simulate(method="BDF", jit=False)
    assert r["i.y"][-1] == pytest.approx(np.full(30, 0.01), rel=1e-9)

    def no_pattern(layout):
        raise AssertionError("the Jacobian pattern was built for an explicit method")
    monkeypatch.setattr(model, "jacobian_sparsity", no_pattern)
    r = _wide(5000).simulate(method="RK45", jit=False)
    assert r["i.y"][-1] == pytest.approx(np.full(5000, 0.01), rel=1e-9)


def test_the_pattern_is_made_once_when_an_implicit_method_asks(monkeypatch):
    calls = []
    real = model.jacobian_sparsity

    def counted(layout):
        calls.append(layout)
        return real(layout)
    monkeypatch.setattr(model, "jacobian_sparsity", counted)
    d = _wide(3)
    d.simulate(method="RK45", jit=False)
    assert calls == []
    d.simulate(method="BDF", jit=False)
    d.simulate(method="Radau", jit=False)
    assert len(calls) == 1


class _Wide:
    n_x = I.MAX_DENSE_STATES + 1


@pytest.mark.parametrize("method", ["NDF", "ROS34PW2"])
def test_compiled_loop_refuses_before_its_work_arrays(method):
    with pytest.raises(SpidersimError, match="at most 4000 states"):
        CompiledLoop(None, _Wide(), 0.0, 1.0, 1e-6, 1e-8, math.inf, None, None,
                     method=method)


def test_linearization_refuses_before_its_matrix():
    calls = []

    def evaluate(x, u):
        calls.append(1)
        return x, x[:1]
    with pytest.raises(SpidersimError, match=r"4001 x 4001 matrix A .* at most 4000 states"):
        jacobians(evaluate, np.zeros(I.MAX_DENSE_STATES + 1), np.zeros(1))
    assert calls == []


def test_trim_refuses_before_its_dense_jacobian():
    d = _wide(I.MAX_DENSE_STATES + 1)
    with pytest.raises(spidersim.AnalysisError, match=r"4001-column Jacobian: at most 4000"):
        spidersim.trim(d, jit=False)
