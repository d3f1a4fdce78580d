"""Sources against their closed forms; switching sources switch exactly at their time events."""
import math

import numpy as np
import pytest

import spidersim
from spidersim import ParameterError

from .harness import Probe, simulate


def _src(block, t_end=2.0, extra_blocks="", connections="", **kw):
    text = f"name: src\nblocks:\n  s: {block}\n{extra_blocks}"
    if connections:
        text += f"connections:\n{connections}"
    return simulate(text, t_end=t_end, **kw)


def test_constant_vector():
    r = _src("{type: Constant, value: [1.5, -2, 0]}", t_end=1.0)
    assert r["s.y"].shape == (len(r.t), 3)
    np.testing.assert_array_equal(r["s.y"], np.tile([1.5, -2.0, 0.0], (len(r.t), 1)))


@pytest.mark.parametrize("with_state", [False, True])
def test_step_switches_exactly_at_t_step(with_state):
    """The integrator stops at the event: t_step is a sample time, read as ``after`` by the
    last sample there, and no sample between two levels is ever recorded."""
    t_step, before, after = 0.37, -0.5, 2.25
    extra = "  i: {type: Integrator}\n" if with_state else ""
    conn = "  - s.y -> i.u\n" if with_state else ""
    r = _src(f"{{type: Step, t_step: {t_step}, before: {before}, after: {after}}}",
             extra_blocks=extra, connections=conn, rtol=1e-8, atol=1e-10)
    y, t = r["s.y"], r.t
    at = np.flatnonzero(t == t_step)                # exact time, not just close
    assert at.size >= 1
    k = int(at[-1])
    assert y[k] == after and y[k + 1] == after and t[k + 1] > t_step
    assert y[k - 1] == before
    assert np.all(y[t < t_step] == before)
    assert np.all(y[t > t_step] == after)
    assert [(e[0], e[1]) for e in r.events] == [(t_step, "s")]
    if with_state:
        # the segment ends at t_step with the old level, then restarts with the new one
        assert at.size == 2 and y[at[0]] == before
        # and the integral has its corner exactly at t_step
        expect = np.where(t < t_step, before * t, before * t_step + after * (t - t_step))
        np.testing.assert_allclose(r["i.y"], expect, rtol=1e-9, atol=1e-9)


def test_stateless_diagram_records_like_a_stateful_one():
    """A diagram without states must, like one with states, end its record at t_end and
    record both levels at an event time (so that plots show a vertical edge).

    Regression: integrate.py's old ``n_x == 0`` branch recorded only
    ``np.linspace(t, t_seg, 51)[1:-1]``, so neither t_end nor the pre-event sample at a
    segment end was ever recorded.
    """
    r = _src("{type: Step, t_step: 0.37, before: -0.5, after: 2.25}", t_end=2.0)
    assert r.t[-1] == 2.0, f"last sample at t = {r.t[-1]}, t_end = 2.0"
    at = np.flatnonzero(r.t == 0.37)
    assert list(r["s.y"][at]) == [-0.5, 2.25]


def test_step_at_time_zero_is_after_from_the_start():
    r = _src("{type: Step, t_step: 0, before: 3, after: 7}", t_end=1.0)
    assert np.all(r["s.y"] == 7.0)


def test_step_at_infinity_never_steps():
    """``t_step: inf`` is "never" (the default of a subsystem's optional cut, e.g.
    joint_torque.yaml's t_cut): ``before`` throughout, no event; with a state too."""
    r = _src("{type: Step, t_step: inf, before: 3, after: 7}", t_end=1.0,
             extra_blocks="  i: {type: Integrator}\n", connections="  - s.y -> i.u\n")
    assert np.all(r["s.y"] == 3.0) and r.events == []
    np.testing.assert_allclose(r["i.y"][-1], 3.0, rtol=1e-9)


def test_ramp():
    slope, t0, off = -1.5, 0.6, 0.25
    r = _src(f"{{type: Ramp, slope: {slope}, t_start: {t0}, offset: {off}}}")
    t, y = r.t, r["s.y"]
    assert np.any(t == t0)
    expect = off + np.where(t > t0, slope * (t - t0), 0.0)
    np.testing.assert_allclose(y, expect, rtol=0, atol=1e-14)
    assert np.any(y < off + slope * 1.3)            # the record covers the ramp


def test_sine():
    A, f, ph, off = 1.7, 2.5, 0.4, -0.3
    r = _src(f"{{type: Sine, amplitude: {A}, f: {f}, phase: {ph}, offset: {off}}}",
             t_end=1.0, output_interval=0.01)
    assert len(r.t) == 101
    np.testing.assert_allclose(r.t, np.arange(101) * 0.01, atol=1e-14)
    np.testing.assert_allclose(r["s.y"], off + A * np.sin(2 * np.pi * f * r.t + ph),
                               rtol=0, atol=1e-13)


def _pulse_ref(t, amp, period, duty, delay, low):
    phase = np.mod(t - delay, period)
    return np.where((t >= delay) & (phase < duty * period), low + amp, low)


def test_pulse_edges_and_levels():
    amp, period, duty, delay, low = 2.0, 0.3, 0.25, 0.1, -1.0
    t_end = 1.05
    r = _src(f"{{type: Pulse, amplitude: {amp}, period: {period}, duty: {duty}, "
             f"delay: {delay}, low: {low}}}", t_end=t_end)
    rise = [delay + k * period for k in range(4)]
    fall = [delay + (k + duty) * period for k in range(3)]
    edges = sorted(e for e in rise + fall if e < t_end)
    ev = [e[0] for e in r.events]
    assert len(ev) == len(edges)
    np.testing.assert_allclose(ev, edges, rtol=0, atol=1e-14)
    t, y = r.t, r["s.y"]
    for e in edges:  # each edge is a sample time: new level there, old level just before
        k = int(np.flatnonzero(np.abs(t - e) < 1e-14)[-1])
        high_after = any(abs(e - x) < 1e-14 for x in rise)
        assert y[k] == (low + amp if high_after else low)
        assert y[k - 1] == (low if high_after else low + amp)
    away = np.min(np.abs(t[:, None] - np.array(edges)[None, :]), axis=1) > 1e-9
    assert away.sum() >= 10
    np.testing.assert_array_equal(y[away], _pulse_ref(t[away], amp, period, duty, delay, low))


def test_timetable_interpolation_and_end_holds():
    tt, vv = [0.5, 1.0, 2.0, 2.5], [1.0, 3.0, -1.0, 0.5]
    r = _src(f"{{type: TimeTable, time: {tt}, value: {vv}}}", t_end=3.5)
    t, y = r.t, r["s.y"]
    for e in tt:
        assert np.any(t == e)
    assert [e[0] for e in r.events] == tt
    assert np.all(y[t < 0.5] == 1.0)             # holds the first value before the table
    assert np.all(y[t > 2.5] == 0.5)             # and the last one after it
    inside = (t > 0.5) & (t < 2.5)
    assert inside.sum() > 20        # default max_step t_end / 50 = 0.07 s: ~29 samples
    np.testing.assert_allclose(y[inside], np.interp(t[inside], tt, vv), rtol=0, atol=1e-13)


def test_timetable_with_past_times_starts_on_the_right_piece():
    r = _src("{type: TimeTable, time: [-2, -1, 1, 2], value: [5, 0, 2, 4]}", t_end=3.0)
    np.testing.assert_allclose(r["s.y"], np.interp(r.t, [-2, -1, 1, 2], [5, 0, 2, 4]),
                               rtol=0, atol=1e-13)


@pytest.mark.parametrize("times, where", [("[0, 1, 1, 2]", "time[2] = 1 s is not after time[1] = 1 s"),
                                          ("[0, 2, 1]", "time[2] = 1 s is not after time[1] = 2 s"),
                                          ("[1, 0]", "time[1] = 0 s is not after time[0] = 1 s")])
def test_timetable_rejects_non_increasing_time(times, where):
    """The error names the first pair out of order, in plain numbers."""
    n = len(times.strip("[]").split(","))
    text = (f"blocks:\n  s: {{type: TimeTable, time: {times}, "
            f"value: {[0.0] * n}}}\n")
    with pytest.raises(ParameterError, match="strictly increasing") as ei:
        spidersim.loads(text)
    assert where in str(ei.value) and "np.float64" not in str(ei.value)


def test_timetable_rejects_value_length_mismatch():
    with pytest.raises(ParameterError, match="value"):
        spidersim.loads("blocks:\n  s: {type: TimeTable, time: [0, 1, 2], value: [0, 1]}\n")


def test_step_mode_selects_the_value_directly():
    p = Probe("Step", {"t_step": 1.0, "before": 4.0, "after": -4.0})
    assert p.outputs(5.0)["y"][0] == 4.0        # the mode, not t, selects the level
    p.set_mode("on", 1.0)
    assert p.outputs(0.0)["y"][0] == -4.0


def test_sine_probe_matches_formula():
    p = Probe("Sine", {"amplitude": 2.0, "f": 0.5, "phase": -1.0, "offset": 3.0})
    for t in (0.0, 0.3, 1.7, 12.25):
        assert p.outputs(t)["y"][0] == pytest.approx(3.0 + 2.0 * math.sin(math.pi * t - 1.0),
                                                     abs=1e-15)
