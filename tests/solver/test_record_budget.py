"""The recording budget (spidersim.solver.record_budget): a run whose recorded rows would
exhaust the memory stops with a clear error and keeps the rows it computed, instead of
growing its buffers until the operating system kills the process (found by a hostile
diagram: ``max_step: 1e-9`` over 1000 s took 23 GB before the kernel killed it)."""
import math

import numpy as np
import pytest

from spidersim.errors import IntegrationError, SpidersimError
from spidersim.solver import record_budget as rb
from spidersim.solver.integrate import integrate
from spidersim.solver.system import PlainSystem


class Oscillator(PlainSystem):
    """x'' = -x from x = 1: the rows kept at a failure can be checked against cos t."""

    def __init__(self):
        super().__init__([1.0, 0.0])

    def rhs(self, t, x):
        return np.array([x[1], -x[0]])


@pytest.fixture
def budget_mb(monkeypatch):
    """A budget of 0.1 MB: 4166 rows of 2 values and their time (24 bytes a row)."""
    monkeypatch.setenv(rb.ENV, "0.1")
    return 0.1


def test_budget_from_the_environment_and_from_the_machine(monkeypatch):
    """The override is in megabytes; without it, 40 % of the physical memory; a bad value
    is an error that names the variable."""
    monkeypatch.setenv(rb.ENV, "2.5")
    assert rb.budget_bytes() == 2.5e6
    assert rb.max_rows(2) == int(2.5e6 // 24)
    monkeypatch.delenv(rb.ENV)
    import os
    phys = os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES")
    assert rb.budget_bytes() == pytest.approx(0.4 * phys)
    for bad in ("-1", "nan", "lots"):
        monkeypatch.setenv(rb.ENV, bad)
        with pytest.raises(SpidersimError, match=rb.ENV):
            rb.budget_bytes()


def test_growth_doubles_up_to_the_budget_then_stops(budget_mb):
    limit = rb.max_rows(2)
    assert limit == 4166
    assert rb.grown_rows(1024, 2) == 2048
    assert rb.grown_rows(4000, 2) == limit          # clipped, not doubled past the budget
    assert rb.grown_rows(limit, 2) is None


@pytest.mark.parametrize("kw, what", [
    (dict(max_step=1e-4), "max_step = 0.0001 s over 1 s, every step recorded"),
    (dict(output_interval=1e-4), "output_interval = 0.0001 s over 1 s"),
])
def test_a_run_certain_to_exceed_the_budget_is_refused_before_it_starts(budget_mb, kw, what):
    """10,000 rows > 4166: refused at once, saying what to change."""
    with pytest.raises(SpidersimError) as ei:
        integrate(Oscillator(), 1.0, method="RK45", **kw)
    msg = str(ei.value)
    assert what in msg and "recording budget of 0.0001 GB (4166 rows)" in msg
    assert "output_interval" in msg and rb.ENV in msg
    assert not isinstance(ei.value, IntegrationError)      # nothing was computed


def test_a_run_within_the_budget_is_not_refused(budget_mb):
    """4,000 grid rows fit 4166: the run completes (the check is not off by a factor)."""
    r = integrate(Oscillator(), 1.0, method="RK45", output_interval=2.5e-4)
    assert len(r.t) == 4001 and r.status == "ok"


@pytest.mark.parametrize("method", ["RK45", "LSODA"])
def test_scipy_loop_stops_at_the_budget_and_keeps_its_rows(budget_mb, method):
    """Every step recorded, the step count not known in advance: the run fails when the
    buffer is full at the budget, with every row it recorded, each still on cos t."""
    with pytest.raises(IntegrationError) as ei:
        integrate(Oscillator(), 1e4, method=method, rtol=1e-8, atol=1e-10)
    r = ei.value.partial
    assert "reached the memory budget" in str(ei.value) and rb.ENV in str(ei.value)
    assert len(r.t) == 4166 and r.status == "failed"
    assert np.all(np.diff(r.t) > 0) and r.t[-1] < 1e4
    assert np.max(np.abs(r["x"][:, 0] - np.cos(r.t))) < 1e-4
    assert r.stats["t_reached"] == r.t[-1]


def test_compiled_loop_stops_at_the_budget_and_keeps_its_rows(budget_mb):
    """The same in the compiled loop (a generated diagram, DP54), which asks for more rows
    while it still has ``ROW_RESERVE`` free (the rows of one step with events)."""
    from spidersim.solver.loop_state import ROW_RESERVE
    import spidersim
    d = spidersim.loads(
        "name: osc\n"
        "blocks:\n"
        "  x: {type: Integrator, x0: 1}\n"
        "  v: {type: Integrator, x0: 0}\n"
        "  k: {type: Gain, k: -1}\n"
        "connections: [x.y -> k.u, k.y -> v.u, v.y -> x.u]\n")
    with pytest.raises(IntegrationError) as ei:
        d.simulate(t_end=1e4, method="DP54", rtol=1e-8, atol=1e-10, max_step=math.inf)
    r = ei.value.partial
    assert "reached the memory budget" in str(ei.value)
    # the event log's first 1024 entries of 32 bytes share the budget with the rows
    rows = int((0.1e6 - 1024 * 32) // rb.row_bytes(d.compile(True, loop=True).record_size))
    assert rows - ROW_RESERVE <= len(r.t) <= rows and r.status == "failed" and np.all(np.diff(r.t) >= 0)
    assert np.max(np.abs(r["x.y"] - np.cos(r.t))) < 1e-4


def _sampled_every_0_1_ms():
    """A zero-order hold sampling a sine every 0.1 ms: one time event per sample."""
    import spidersim
    return spidersim.loads(
        "name: sampled\n"
        "blocks:\n"
        "  u: {type: Sine, amplitude: 1, f: 1}\n"
        "  z: {type: ZeroOrderHold, Ts: 1e-4}\n"
        "connections: [u.y -> z.u]\n")


def test_compiled_loop_event_log_stops_at_the_budget(budget_mb):
    """A sampled block every 0.1 ms for 1000 s logs 10^7 time events: on a grid of 1 s the
    rows fit, the event log does not; the run stops at the budget (0.1 MB shared with the
    rows: about 2350 entries of 32 bytes) with its grid rows and events so far, each sample
    at k * 0.1 ms. The loop
    hands back while it still has room for one step's events (``4 (guards + sampled
    blocks) + 64`` = 68 here)."""
    d = _sampled_every_0_1_ms()
    with pytest.raises(IntegrationError) as ei:
        d.simulate(t_end=1e3, method="DP54", output_interval=1.0)
    r = ei.value.partial
    assert "event log reached the memory budget" in str(ei.value)
    times = np.array([t for t, blk, kind in r.events])
    # the grid's rows (1024 of t, u.y, z.y: 24 bytes) share the budget with the log
    n = int((0.1e6 - 1024 * 24) // 32)
    assert n - 68 <= len(times) <= n
    assert np.allclose(times, 1e-4 * np.arange(len(times)), rtol=0, atol=1e-12)


def test_scipy_loop_event_log_stops_at_the_budget(monkeypatch):
    """The SciPy steppers' event log (a Python list, counted at 800 bytes an event, checked
    every 1024 events, more often near the budget) shares the budget with the rows: at 2 MB
    and 1010 grid rows it holds a little over 2048 events of a sampled block every 0.1 ms,
    then the run stops with them, each at k * 0.1 ms, the message counting them (LSODA:
    about 60 us an event, 10^7 events in 1000 s would take 7 GB). Before, the log stopped at
    the last multiple of 1024 that left room for 1024 more: at a budget below that, "0
    entries" at t = 0."""
    monkeypatch.setenv(rb.ENV, "2")
    d = _sampled_every_0_1_ms()
    with pytest.raises(IntegrationError) as ei:
        d.simulate(t_end=1e3, method="LSODA", output_interval=1.0, jit=False)
    r = ei.value.partial
    assert "event log reached the memory budget" in str(ei.value)
    assert "sample less often" in str(ei.value)
    times = np.array([t for t, blk, kind in r.events])
    assert 2048 < len(times) < 2048 + 1024
    assert f": {len(times)} entries" in str(ei.value)
    assert np.allclose(times, 1e-4 * np.arange(len(times)), rtol=0, atol=1e-12)
    monkeypatch.setenv(rb.ENV, "0.3")      # room for fewer than 1024 events
    with pytest.raises(IntegrationError) as ei:
        d.simulate(t_end=1e3, method="LSODA", output_interval=1.0, jit=False)
    n = len(ei.value.partial.events)
    assert n > 100 and f": {n} entries" in str(ei.value)
