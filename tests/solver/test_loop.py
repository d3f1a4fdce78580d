"""The compiled integration loop on hand-written systems (no YAML, no code generator).

Each system is a dozen lines implementing the contract of :mod:`spidersim.solver.system`,
turned into a system function (:mod:`spidersim.solver.sysfn`) by a fixed dispatcher and
compiled by numba; the loop is spidersim's, compiled once for every system.
"""
import importlib.util
import math
import sys

import numpy as np
import pytest

from spidersim.errors import IntegrationError
from spidersim.solver import loop as L
from spidersim.solver import sysfn

HEADER = '''
import math
import numpy as np
from numba import carray, cfunc, njit

from spidersim.solver.sysfn import SYSTEM_SIG


def _jit(f):
    return njit(cache=False, error_model="numpy")(f)
'''

# the system function (spidersim.solver.sysfn) over the hand-written functions
DISPATCH = '''
@_jit
def _evaluate(task, t, x, sig, p, modes, out, k, f):
    if task == 3:
        return next_time(t, p, modes)
    if task == 4:
        time_events(t, x, sig, p, modes, f, out)
    elif task == 5:                        # INITIALIZE, then the outputs (the contract)
        initialize(t, x, sig, p, modes)
        outputs(t, x, sig, p, modes)
    elif task == 7:                        # GUARDS_AT_SIG: sig holds the outputs of (t, x)
        guards(t, x, sig, p, modes, out)
    else:
        outputs(t, x, sig, p, modes)
        if task == 1:
            derivatives(t, x, sig, p, modes, out)
        elif task == 2:
            guards(t, x, sig, p, modes, out)
        elif task == 6:
            apply_event(t, x, sig, p, modes, k, f)
    return 0.0


@cfunc(SYSTEM_SIG)
def _system(task, t, x, sig, p, modes, out, k, f):
    return _evaluate(task, t, carray(x, N_X), carray(sig, 2), carray(p, N_P),
                     carray(modes, N_MODES), carray(out, max(N_X, N_G, 1)), k, f)


SYSTEM = _system.address
'''

BALL = '''
# ball: x'' = -g; impact at x = 0 falling: v -> -e v; at rest below v_rest. p = [g, e, v_rest]
@_jit
def outputs(t, x, sig, p, modes):
    pass

@_jit
def derivatives(t, x, sig, p, modes, xdot):
    if modes[0] == 1.0:
        xdot[0] = 0.0
        xdot[1] = 0.0
    else:
        xdot[0] = x[1]
        xdot[1] = -p[0]

@_jit
def guards(t, x, sig, p, modes, g):
    g[0] = x[0] if modes[0] == 0.0 else 1.0

@_jit
def apply_event(t, x, sig, p, modes, k, direction):
    x[0] = 0.0
    x[1] = p[1] * abs(x[1])
    if abs(x[1]) < p[2]:
        x[1] = 0.0
        modes[0] = 1.0

@_jit
def next_time(t, p, modes):
    return math.inf

@_jit
def time_events(t, x, sig, p, modes, tol, fired):
    return 0

@_jit
def initialize(t, x, sig, p, modes):
    pass
'''

SAMPLED = '''
# a sampled integrator: y[k+1] = y[k] + Ts * u at t = k Ts (u = 1), beside x' = 1
@_jit
def outputs(t, x, sig, p, modes):
    sig[0] = modes[0]

@_jit
def derivatives(t, x, sig, p, modes, xdot):
    xdot[0] = 1.0

@_jit
def guards(t, x, sig, p, modes, g):
    pass

@_jit
def apply_event(t, x, sig, p, modes, k, direction):
    pass

@_jit
def next_time(t, p, modes):
    return modes[1]

@_jit
def time_events(t, x, sig, p, modes, tol, fired):
    if modes[1] <= t + tol:
        modes[0] += p[0]
        modes[1] += p[0]
        fired[0] = 1
    return 0

@_jit
def initialize(t, x, sig, p, modes):
    pass
'''


class HandSystem:
    """The attributes the compiled loop reads, for a hand-written module."""

    def __init__(self, module, x0, p, modes, events=(), timed=()):
        self.module = module
        assert (module.N_X, module.N_P, module.N_MODES, module.N_G) == (
            len(x0), len(p), len(modes), len(events))
        self.x0 = np.array(x0, float)
        self.n_x = len(x0)
        self.p = np.array(p, float)
        self.modes = np.array(modes, float)
        self.sig = np.zeros(2)
        self.event_table = list(events)
        self.timed = list(timed)
        self.n_g = len(self.event_table)
        self.record_size = self.n_x
        self.record_slices = {f"x{i}": (i, i + 1) for i in range(self.n_x)}
        self.units = {k: "1" for k in self.record_slices}
        self._s_idx = np.zeros(0, np.int64)
        self._x_idx = np.arange(self.n_x)
        self.compiled_entry = module.SYSTEM

    def record_row(self, t, x, buf, row):
        return sysfn.record(self.compiled_entry, t, x, self.sig, self.p, self.modes,
                            self._s_idx, self._x_idx, buf, row)

    def newton_iterations(self):
        return 0

    def loop_failure(self):
        return "", None

    def diagnose(self, t, x):
        return ""


def build(name, text, tmp_path, n_x, n_p, n_modes, n_g):
    path = tmp_path / f"{name}.py"
    sizes = f"N_X, N_P, N_MODES, N_G = {n_x}, {n_p}, {n_modes}, {n_g}\n"
    path.write_text(HEADER + sizes + text + "\n\n" + DISPATCH)
    spec = importlib.util.spec_from_file_location(name, path)
    mod = importlib.util.module_from_spec(spec)
    sys.modules[name] = mod
    spec.loader.exec_module(mod)
    return mod


def run(system, t_end, **kw):
    return L.integrate_dp54(system, system.compiled_entry, t_end, **kw)


def impact_times(h0, e, g, n):
    t1 = math.sqrt(2 * h0 / g)
    out = [t1]
    for k in range(1, n):
        out.append(out[-1] + 2 * e ** k * g * t1 / g)
    return np.array(out)


@pytest.fixture(scope="module")
def ball(tmp_path_factory):
    return build("hand_ball", BALL, tmp_path_factory.mktemp("ball"), 2, 3, 1, 1)


@pytest.fixture(params=["DP54", "ROS34PW2", "NDF"])
def method(request):
    """The closed-form tests run with both methods of the compiled loop."""
    return request.param


def test_bouncing_ball_impacts_at_the_closed_form_times(ball, method):
    s = HandSystem(ball, [10.0, 0.0], [9.81, 0.8, 0.05], [0.0],
                   events=[("ball", "impact", -1.0)])
    r = run(s, 15.0, rtol=1e-10, atol=1e-12, method=method)
    t_imp = np.array([t for t, _b, _e in r.events])
    assert np.max(np.abs(t_imp[:10] - impact_times(10.0, 0.8, 9.81, 10))) < 1e-9
    assert r["x0"][-1] == 0.0 and r["x1"][-1] == 0.0 and np.min(r["x0"]) > -1e-9
    # the energy between impacts is constant (no event lost or applied twice)
    # rows at an event: before, then after it (the last row at that time)
    v_after = [r["x1"][np.searchsorted(r.t, t, side="right") - 1] for t in t_imp[:5]]
    assert np.allclose(np.diff(np.log(v_after)), math.log(0.8), atol=1e-7)


def test_bouncing_ball_zeno_is_chattering_at_the_accumulation_time(ball, method):
    s = HandSystem(ball, [10.0, 0.0], [9.81, 0.8, 0.0], [0.0],
                   events=[("ball", "impact", -1.0)])
    with pytest.raises(IntegrationError) as ei:
        run(s, 30.0, rtol=1e-10, atol=1e-12, method=method)
    t_zeno = math.sqrt(2 * 10 / 9.81) * (1 + 2 * 0.8 / 0.2)
    assert "chattering" in str(ei.value) and abs(ei.value.partial.t[-1] - t_zeno) < 1e-3


def test_grid_output_resumes_across_full_buffers(ball, method):
    s = HandSystem(ball, [10.0, 0.0], [9.81, 0.8, 0.05], [0.0],
                   events=[("ball", "impact", -1.0)])
    r = run(s, 15.0, rtol=1e-10, atol=1e-12, output_interval=1e-3,   # 15001 rows > 1024
            method=method)
    assert len(r.t) == 15001 and np.allclose(np.diff(r.t), 1e-3)
    t1 = math.sqrt(2 * 10 / 9.81)
    pre = r.t < t1
    assert np.allclose(r["x0"][pre], 10 - 0.5 * 9.81 * r.t[pre] ** 2, atol=1e-9)


def test_pause_and_resume_give_the_same_result(ball, method):
    """Returning to Python every 3 steps changes nothing: the whole state of the run (the
    Jacobian, its age and the LU factors of ROS34PW2 too) lives in the arrays."""
    def go(pause):
        s = HandSystem(ball, [10.0, 0.0], [9.81, 0.8, 0.05], [0.0],
                       events=[("ball", "impact", -1.0)])
        run_ = L.CompiledLoop(s.compiled_entry, s, 0.0, 15.0, 1e-8, 1e-10, math.inf, None,
                              None, method=method)
        while True:
            code = run_.call(pause)
            if code == L.ROWS_FULL:
                run_.grow_rows()
            elif code != L.PAUSE:
                assert code == L.DONE
                return run_.tbuf[:run_.ist[L.I_ROWS]].copy(), run_.buf[:run_.ist[L.I_ROWS]]
    ta, xa = go(3)
    tb, xb = go(100000)
    assert np.array_equal(ta, tb) and np.array_equal(xa, xb)


def test_sampled_integrator_fires_at_every_sample(tmp_path, method):
    mod = build("hand_sampled", SAMPLED, tmp_path, 1, 1, 2, 0)
    Ts = 0.1
    s = HandSystem(mod, [0.0], [Ts], [0.0, 0.0], timed=["zoh"])
    r = run(s, 1.0, rtol=1e-8, atol=1e-10, method=method)
    times = [t for t, b, e in r.events]
    assert [b for _t, b, _e in r.events] == ["zoh"] * 11
    assert np.allclose(times, np.arange(11) * Ts, atol=1e-12)
    assert s.modes[0] == pytest.approx(11 * Ts)
    assert r["x0"][-1] == pytest.approx(1.0, abs=1e-12)
    # no step straddles a sample: every sample time is a row
    for t in times:
        assert np.min(np.abs(r.t - t)) < 1e-12


def test_stop_request_ends_the_run_with_what_was_computed(tmp_path):
    mod = build("hand_sampled_stop", SAMPLED, tmp_path, 1, 1, 2, 0)
    s = HandSystem(mod, [0.0], [1e-3], [0.0, 0.0], timed=["zoh"])
    seen = []
    r = run(s, 1000.0, rtol=1e-8, atol=1e-10, progress=seen.append,
            should_stop=lambda: len(seen) >= 2)
    assert r.status == "interrupted" and 0 < r.t[-1] < 1000.0
    assert r.t[-1] == pytest.approx(seen[-1])
    # what was recorded is consistent: x = t and one sample per millisecond so far
    assert np.allclose(r["x0"], r.t, atol=1e-9)
    assert len(r.events) == pytest.approx(r.t[-1] / 1e-3 + 1, abs=1.5)
