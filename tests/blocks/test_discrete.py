"""Sampled blocks against their difference equations.

Samples are time events at t_k = offset + k Ts: the record holds, at each t_k, the value
before and (last) the value after the update; the output is held in between.
"""
import numpy as np
import pytest
from scipy.signal import lfilter

import spidersim
from spidersim import ParameterError

from .harness import Probe, simulate

TS = 0.1
T_END = 1.05                    # samples k = 0 .. 10


def _run(block, src="{type: Ramp, slope: 1}", t_end=T_END):
    port = "e" if "PI" in block else "u"          # DiscretePI/PID read the error e
    return simulate(f"blocks:\n  u: {src}\n  b: {block}\nconnections:\n  - u.y -> b.{port}\n",
                    t_end=t_end, rtol=1e-8, atol=1e-10)


def _held(r, name, ts=TS, offset=0.0):
    """Output just after each sample time, and whether it is held constant in between."""
    t, y = r.t, r[name]
    ks = np.arange(int(np.floor((t[-1] - offset) / ts + 1e-9)) + 1)
    out = []
    for k in ks:
        tk = offset + k * ts
        at = np.flatnonzero(np.abs(t - tk) <= 1e-12)
        assert at.size, f"sample time {tk} is not a record time"
        out.append(y[at[-1]])
        nxt = (t > tk + 1e-12) & (t < tk + ts - 1e-12)
        assert np.all(y[nxt] == y[at[-1]]), f"{name} not held after t = {tk}"
    return np.array(out)


def test_zero_order_hold():
    r = _run("{type: ZeroOrderHold, Ts: 0.1}")
    y = _held(r, "b.y")
    np.testing.assert_allclose(y, TS * np.arange(11), rtol=0, atol=1e-12)
    assert [e[0] for e in r.events if e[1] == "b"] == pytest.approx(TS * np.arange(11),
                                                                    abs=1e-12)


def test_zero_order_hold_offset_and_vector():
    r = simulate("blocks:\n  u: {type: Constant, value: [1, 2]}\n  s: {type: Sine, f: 1}\n"
                 "  m: {type: Mux}\n  b: {type: ZeroOrderHold, Ts: 0.25, offset: 0.1}\n"
                 "connections:\n  - u.y -> m.u1\n  - s.y -> m.u2\n  - m.y -> b.u\n",
                 t_end=1.0, rtol=1e-8, atol=1e-10)
    y = r["b.y"]
    assert np.all(y[r.t < 0.1 - 1e-12] == 0.0)        # nothing sampled yet
    tk = 0.1 + 0.25 * np.arange(4)
    for k, t in enumerate(tk):
        at = np.flatnonzero(np.abs(r.t - t) <= 1e-12)[-1]
        np.testing.assert_allclose(y[at], [1.0, 2.0, np.sin(2 * np.pi * t)], atol=1e-12)


def test_unit_delay():
    """y = x0 on [0, Ts), then y(t_k) = u(t_k-1)."""
    r = _run("{type: UnitDelay, Ts: 0.1, x0: -7}")
    y = _held(r, "b.y")
    assert y[0] == -7.0
    np.testing.assert_allclose(y[1:], TS * np.arange(10), rtol=0, atol=1e-12)


@pytest.mark.parametrize("num,den", [([1.0], [1.0, -0.5]),
                                     ([0.2, 0.1], [1.0, -0.9]),
                                     ([0.5, 0.3, 0.1], [2.0, -1.0, 0.3]),
                                     ([1.0], [1.0, -1.2, 0.5])])
def test_discrete_transfer_function_difference_equation(num, den):
    """Against scipy.signal.lfilter on the input samples (num padded to len(den): powers
    of z, as control.tf(num, den, Ts))."""
    r = _run(f"{{type: DiscreteTransferFunction, num: {num}, den: {den}, Ts: 0.1}}",
             src="{type: Sine, f: 0.7, offset: 0.3}")
    y = _held(r, "b.y")
    uk = 0.3 + np.sin(2 * np.pi * 0.7 * TS * np.arange(len(y)))
    b = np.r_[np.zeros(len(den) - len(num)), num]
    np.testing.assert_allclose(y, lfilter(b, den, uk), rtol=1e-12, atol=1e-12)


def test_discrete_transfer_function_rejects_improper():
    with pytest.raises(ParameterError, match="improper"):
        spidersim.loads("blocks:\n  b: {type: DiscreteTransferFunction, num: [1, 1], "
                        "den: [1], Ts: 0.1}\n  c: {type: Constant}\nconnections:\n"
                        "  - c.y -> b.u\n")


def _pi_reference(ek, kp, ki, kd, y_min, y_max):
    I, e_prev, out = 0.0, None, []
    for k, e in enumerate(ek):
        d = kd * (e - e_prev) / TS if e_prev is not None else 0.0
        v = kp * e + I + d
        out.append(min(max(v, y_min), y_max))
        if not ((v > y_max and e > 0) or (v < y_min and e < 0)):
            I += ki * TS * e
        e_prev = e
    return np.array(out)


@pytest.mark.parametrize("ctrl,kd", [("DiscretePI", 0.0), ("DiscretePID", 0.05)])
@pytest.mark.parametrize("limits", [(-np.inf, np.inf), (-0.4, 0.6)])
def test_discrete_controllers(ctrl, kd, limits):
    """y_k = sat(kp e_k + I_k + kd (e_k - e_k-1)/Ts), I_k+1 = I_k + ki Ts e_k unless the
    output is limited and e_k drives it further (clamping)."""
    lo, hi = limits
    kp, ki = 0.5, 3.0
    lim = "" if np.isinf(hi) else f", y_min: {lo}, y_max: {hi}"
    extra = f", kd: {kd}" if ctrl == "DiscretePID" else ""
    r = _run(f"{{type: {ctrl}, kp: {kp}, ki: {ki}, Ts: 0.1{lim}{extra}}}",
             src="{type: Sine, f: 0.6, amplitude: 0.8}", t_end=2.05)
    y = _held(r, "b.y")
    ek = 0.8 * np.sin(2 * np.pi * 0.6 * TS * np.arange(len(y)))
    np.testing.assert_allclose(y, _pi_reference(ek, kp, ki, kd, lo, hi), rtol=1e-12,
                               atol=1e-12)
    if np.isfinite(hi):
        assert np.any(y == hi) and np.any(y == lo)


def test_discrete_blocks_have_no_feedthrough():
    for t, prm in (("ZeroOrderHold", {"Ts": 0.1}), ("UnitDelay", {"Ts": 0.1}),
                   ("DiscretePI", {"Ts": 0.1}), ("DiscretePID", {"Ts": 0.1}),
                   ("DiscreteTransferFunction", {"num": [1.0, 0.0], "den": [1.0, 0.5],
                                                 "Ts": 0.1})):
        p = Probe(t, prm)
        assert all(v == () for v in p.layout.feedthrough.values()), t


CHAIN = ("blocks:\n  u: {type: Ramp, slope: 1}\n  a: {type: ZeroOrderHold, Ts: 0.1}\n"
         "  b: {type: ZeroOrderHold, Ts: 0.1}\n  c: {type: ZeroOrderHold, Ts: 0.1}\n"
         "connections:\n  - u.y -> a.u\n  - a.y -> b.u\n  - u.y -> c.u\n")


def test_which_time_events_see_each_other():
    """Structure, decided at compile time: of three samplers at the same instants, b (fed
    by a) must see a's event of the same instant and c must not wait for anyone but the
    ramp (whose start is a time event too), so the outputs are evaluated again only
    before those (``codegen.influence``)."""
    from spidersim.diagram.codegen import _timed_blocks, influence
    d = spidersim.loads(CHAIN)
    d.compile(jit=False)
    timed = _timed_blocks(d.layout)
    names = [bl.path for bl in timed]
    reach = influence(d.layout, timed)
    got = {names[k]: sorted(names[j] for j in pre) for k, pre in enumerate(reach)}
    assert got == {"u": [], "a": ["u"], "b": ["a"], "c": ["u"]}


@pytest.mark.parametrize("method", ["DP54", "LSODA"])
def test_chained_samplers_pass_a_sample_on_at_once(method):
    """a samples the ramp and b samples a at the same instants: b holds a's new sample
    (t_k) at once, not the previous one (t_k - Ts), on both loops; c (beside them) holds
    the ramp. A time event that did not see a's event of the same instant would lag b by
    one period."""
    r = spidersim.loads(CHAIN).simulate(t_end=T_END, method=method, rtol=1e-8, atol=1e-10)
    expected = TS * np.arange(11)
    # one round of time events per instant: the ramp's start and three samplers at
    # t_0 = 0, three samplers at t_1..t_10; a row before and after each round except at
    # the start (a loop that asked for the next sample time with stale modes fired
    # "nothing" again and again, adding rows at the same instant)
    assert r.stats["time_events"] == 1 + 3 * 11
    assert [e[0] for e in r.events if e[1] == "a"] == pytest.approx(list(expected), abs=1e-12)
    assert np.count_nonzero(np.diff(r.t) == 0.0) == 10
    for name in ("a", "b", "c"):
        np.testing.assert_allclose(_held(r, f"{name}.y"), expected, rtol=0, atol=1e-12)


FEEDBACK = {
    "counter": ("  one: {type: Constant, value: 1}\n  s: {type: Sum, signs: '++'}\n"
                "  ud: {type: UnitDelay, Ts: 0.1}\n",
                "[one.y -> s.u1, ud.y -> s.u2, s.y -> ud.u]", "ud.y",
                lambda k: k),                                  # y[k+1] = y[k] + 1
    "two_delays": ("  one: {type: Constant, value: 1}\n  s: {type: Sum, signs: '++'}\n"
                   "  a: {type: UnitDelay, Ts: 0.1}\n  b: {type: UnitDelay, Ts: 0.1}\n",
                   "[one.y -> s.u1, b.y -> s.u2, s.y -> a.u, a.y -> b.u]", "a.y",
                   lambda k: (k + 1) // 2),        # a[k+1] = 1 + b[k], b[k+1] = a[k]
    "integrator_dtf": ("  one: {type: Constant, value: 1}\n  s: {type: Sum, signs: '+-'}\n"
                       "  tf: {type: DiscreteTransferFunction, num: [0.1], den: [1, -1],"
                       " Ts: 0.1}\n",
                       "[one.y -> s.u1, tf.y -> s.u2, s.y -> tf.u]", "tf.y",
                       lambda k: 1 - 0.9 ** k),    # y[k+1] = y[k] + 0.1 (1 - y[k])
}


@pytest.mark.parametrize("method", ["DP54", "LSODA", "NDF", "RK45"])
@pytest.mark.parametrize("case", sorted(FEEDBACK))
def test_discrete_feedback_loop_samples_the_new_output(case, method):
    """A sampled block whose output feeds its own input back (through a Sum, in discrete
    time only): at each sample the held output moves first (``time_output``), then the
    input is sampled from it, so the difference equations hold from k = 0 to 10. Before,
    the sample and the output move were one kernel and the input was computed from the
    previous output: the counter read 0, 1, 1, 2, 2, ... (5 at k = 10), the discrete
    integrator 0.6926 instead of 1 - 0.9^10 = 0.6513, on every method."""
    blocks, wires, name, want = FEEDBACK[case]
    r = spidersim.loads(f"blocks:\n{blocks}connections: {wires}\n").simulate(
        t_end=T_END, method=method, rtol=1e-8, atol=1e-10)
    np.testing.assert_allclose(_held(r, name), [want(k) for k in range(11)], rtol=0,
                               atol=1e-12)


@pytest.mark.parametrize("sampled", [
    "{type: ZeroOrderHold, Ts: 0.1}",
    "{type: DiscretePI, kp: 0.5, ki: 1, Ts: 0.1}",
    "{type: DiscreteTransferFunction, num: [1, 0.5], den: [1, -0.5], Ts: 0.1}",
])
def test_discrete_algebraic_loop_is_refused(sampled):
    """A sampled block whose held output depends on the sample it takes (ZOH, DiscretePI,
    a proper DTF) reading its own output back through a Gain and a Sum only: refused when
    the diagram is built, walking the loop, with the advice (before, the sample silently
    read the previous output: a one-period delay the diagram does not show)."""
    text = ("blocks:\n  one: {type: Constant, value: 1}\n  s: {type: Sum, signs: '+-'}\n"
            f"  z: {sampled}\n  g: {{type: Gain, k: 0.5}}\n"
            "connections: [one.y -> s.u1, g.y -> s.u2, s.y -> z.u, z.y -> g.u]\n")
    if "DiscretePI" in sampled:
        text = text.replace("s.y -> z.u", "s.y -> z.e")
    with pytest.raises(spidersim.AlgebraicLoopError) as ei:
        spidersim.loads(text)
    msg = str(ei.value)
    assert "discrete algebraic loop" in msg and "'z'" in msg and "UnitDelay" in msg
    assert "z.y -> g.u -> g.y -> s.u2 -> s.y -> z." in msg


def test_sampled_loop_through_a_state_or_a_delay_is_accepted():
    """The same loops closed through an Integrator (a state) or around a UnitDelay or a
    strictly proper DTF (outputs known before the sample) are not algebraic."""
    for sampled, extra, wires in [
            ("{type: ZeroOrderHold, Ts: 0.1}", "  i: {type: Integrator}\n",
             "z.y -> i.u, i.y -> g.u"),
            ("{type: UnitDelay, Ts: 0.1}", "", "z.y -> g.u"),
            ("{type: DiscreteTransferFunction, num: [0.1], den: [1, -1], Ts: 0.1}", "",
             "z.y -> g.u")]:
        text = ("blocks:\n  one: {type: Constant, value: 1}\n  s: {type: Sum, signs: '+-'}\n"
                f"  z: {sampled}\n  g: {{type: Gain, k: 0.5}}\n{extra}"
                f"connections: [one.y -> s.u1, g.y -> s.u2, s.y -> z.u, {wires}]\n")
        spidersim.loads(text)


@pytest.mark.parametrize("ctrl", ["DiscretePI", "DiscretePID"])
@pytest.mark.parametrize("I0, y0", [(0.4, 0.4), (3.0, 1.0), (-5.0, -2.0)])
def test_controller_output_before_its_first_sample_is_its_initial_command(ctrl, I0, y0):
    """With offset > 0 a discrete controller outputs its initial command I0 (within the
    limits) until its first sample, as a UnitDelay outputs x0 (before, 0 whatever I0)."""
    r = spidersim.loads(
        "blocks:\n  e: {type: Constant, value: 1}\n"
        f"  c: {{type: {ctrl}, kp: 1, ki: 2, Ts: 0.1, offset: 0.05, I0: {I0}, "
        "y_min: -2, y_max: 1}\nconnections: [e.y -> c.e]\n").simulate(t_end=0.3, jit=False)
    before = r.t < 0.05 - 1e-12
    assert np.count_nonzero(before) >= 1
    assert np.all(r["c.y"][before] == y0)
