"""Linearization through sampled blocks and quantizers (contract item 9 of
spidersim.blocks.base) and through singular algebraic loops.

A sampled block on the path is refused (its held output has no derivative between samples:
the shipped joint_step.yaml read "DC gain 0" without a word); a quantizer is linearized as
its unquantized gain, checked against closed forms of the continuous model; a singular
algebraic loop is a clear error (exit status 2), as ``run`` reports it."""
import os
import warnings

import numpy as np
import pytest

import spidersim
from spidersim.cli import main
from spidersim.diagram.analysis import AnalysisError
from spidersim.errors import AlgebraicLoopError, LinearizationWarning

DIAGRAMS = os.path.join(os.path.dirname(__file__), "..", "..", "diagrams")


def _freq(sys, w):
    """G(jw) of a SISO state space, from its matrices."""
    A, B, C, D = (np.asarray(m, dtype=float) for m in (sys.A, sys.B, sys.C, sys.D))
    n = A.shape[0]
    return (C @ np.linalg.solve(1j * w * np.eye(n) - A, B) + D)[0, 0]


QUANTIZED_LOOP = """\
blocks:
  u:   {type: Constant, value: 0.3}
  e:   {type: Sum, signs: "+-"}
  k:   {type: Gain, k: 40}
  x:   {type: Integrator}
  res: {type: Resolver, bits: 8}
connections: [u.y -> e.u1, res.theta_m -> e.u2, e.y -> k.u, k.y -> x.u, x.y -> res.theta]
"""


def test_quantizer_in_a_loop_is_linearized_as_unity_gain():
    """dx/dt = k (u - Q(x)) with an 8-bit resolver Q: linearized as Q(x) = x, the transfer
    u -> x is k / (s + k) (A = -k, B = k, C = 1; DC gain 1). Before, the staircase's zero
    slope gave A = 0: a free integrator k / s. A LinearizationWarning names the resolver."""
    d = spidersim.loads(QUANTIZED_LOOP)
    with pytest.warns(LinearizationWarning, match=r"unquantized gain: res\b"):
        sys = d.linearize(["u.y"], ["x.y"], jit=False)
    k = 40.0
    assert np.asarray(sys.A)[0, 0] == pytest.approx(-k, rel=1e-8)
    assert np.asarray(sys.B)[0, 0] == pytest.approx(k, rel=1e-8)
    for w in (0.0, 4.0, 40.0, 400.0):
        assert _freq(sys, w) == pytest.approx(k / (1j * w + k), rel=1e-8)


RDC_PAIR = """\
blocks:
  th:  {type: Constant, value: 0.0}
  rdc: {type: RDC, f_n: 50, zeta: 0.7, bits: 12, w_bits: 16, w_max: 1000}
connections: [th.y -> rdc.theta]
"""


def test_rdc_digital_outputs_follow_the_tracking_loop_closed_form():
    """RDC with 12-bit angle and 16-bit velocity words, linearized from its input angle at
    theta = theta_r = 0: theta -> theta_d is (2 zeta w_n s + w_n^2) / (s^2 + 2 zeta w_n s +
    w_n^2), theta -> w_d (the loop integrator, dw_r/dt = w_n^2 e) is w_n^2 s / (s^2 +
    2 zeta w_n s + w_n^2) (both words as their unquantized values); a few frequencies to
    1e-7."""
    d = spidersim.loads(RDC_PAIR)
    with pytest.warns(LinearizationWarning, match="rdc"):
        sys = d.linearize(["th.y"], ["rdc.theta_d", "rdc.w_d"], jit=False)
    wn, z = 2 * np.pi * 50, 0.7
    import control
    for w in (1.0, wn / 3, wn, 5 * wn):
        s = 1j * w
        h = (2 * z * wn * s + wn ** 2) / (s ** 2 + 2 * z * wn * s + wn ** 2)
        g = np.asarray(control.evalfr(sys, s))
        assert g[0, 0] == pytest.approx(h, rel=1e-7)
        assert g[1, 0] == pytest.approx(wn ** 2 * s / (s ** 2 + 2 * z * wn * s + wn ** 2),
                                        rel=1e-7)


def test_joint_step_quantizers_alone_give_the_ideal_sensor_model():
    """joint_step.yaml with the cascade continuous (Ts_ctrl = 0) but the 16-bit converters
    as shipped: the model equals that with res_bits = 0 (same A, B, C, D), the position
    loop's DC gain is 1; before, the load resolver's zero slope opened the position loop
    (a spurious free integrator)."""
    path = os.path.join(DIAGRAMS, "joint_step.yaml")
    d16 = spidersim.load(path, set={"joint.Ts_ctrl": 0})
    d0 = spidersim.load(path, set={"joint.Ts_ctrl": 0, "joint.res_bits": 0})
    with pytest.warns(LinearizationWarning, match="joint.rdc_m, joint.res_l"):
        s16 = d16.linearize(["ref.q"], ["link.phi"], jit=False)
    with warnings.catch_warnings():
        warnings.simplefilter("error")           # nothing quantized: no note
        s0 = d0.linearize(["ref.q"], ["link.phi"], jit=False)
    for a, b in zip((s16.A, s16.B, s16.C, s16.D), (s0.A, s0.B, s0.C, s0.D)):
        np.testing.assert_array_equal(np.asarray(a), np.asarray(b))
    assert abs(_freq(s0, 1e-6)) == pytest.approx(1.0, rel=1e-4)


def test_sampled_controller_on_the_path_is_refused_naming_it():
    """joint_step.yaml as shipped (cascade sampled at 1 kHz): ref.q -> link.phi passes
    through joint.ctrl, so linearize refuses, naming the block and Ts = 0 as the way to a
    continuous model (it printed DC gain 0 with exit status 0)."""
    d = spidersim.load(os.path.join(DIAGRAMS, "joint_step.yaml"))
    with pytest.raises(AnalysisError, match=r"'joint\.ctrl' \(JointCascade, Ts = 0\.001 s: "
                                            r"Ts = 0 makes it continuous"):
        d.linearize(["ref.q"], ["link.phi"], jit=False)
    with pytest.raises(AnalysisError, match="joint.ctrl"):
        d.loop_transfer("joint.ctrl.i_cmd", jit=False)


DISCRETE_ONLY = """\
blocks:
  u: {type: Step, t_step: 0.1}
  e: {type: Sum, signs: "+-"}
  c: {type: DiscretePI, kp: 1, ki: 2, Ts: 0.01}
  d: {type: UnitDelay, Ts: 0.01}
  z: {type: ZeroOrderHold, Ts: 0.5}
  g: {type: Gain, k: 2}
connections: [u.y -> e.u1, d.y -> e.u2, e.y -> c.e, c.y -> d.u, u.y -> z.u, u.y -> g.u]
simulation: {t_end: 1}
analysis:
  cl: {inputs: [u.y], outputs: [d.y]}
  beside: {inputs: [u.y], outputs: [g.y]}
"""


def test_discrete_blocks_on_the_path_are_refused_and_off_the_path_ignored():
    """A loop of only discrete blocks (it reported 0 states and gain 0): both blocks named,
    as discrete-time blocks with no continuous form; the ZeroOrderHold z is off the path
    u -> g and does not stop that linearization (gain 2)."""
    d = spidersim.loads(DISCRETE_ONLY)
    with pytest.raises(AnalysisError) as ei:
        d.linearize(["u.y"], ["d.y"], jit=False)
    msg = str(ei.value)
    assert "'c' (DiscretePI, Ts = 0.01 s" in msg and "'d' (UnitDelay" in msg
    assert "'z'" not in msg and "no continuous form" in msg
    sys = d.linearize(["u.y"], ["g.y"], jit=False)
    assert np.asarray(sys.D)[0, 0] == pytest.approx(2.0, rel=1e-9)


def test_check_and_linearize_report_a_sampled_path_with_exit_status_2(tmp_path, capsys):
    """``check`` refuses the analysis entry 'cl' at its line; ``linearize`` refuses it
    before making a folder; both with exit status 2."""
    f = tmp_path / "disc.yaml"
    f.write_text(DISCRETE_ONLY)
    assert main(["check", str(f)]) == 2
    err = capsys.readouterr().err
    assert "disc.yaml:11: analysis 'cl': cannot linearize through sampled block" in err
    out = tmp_path / "o"
    assert main(["linearize", str(f), "cl", "--out", str(out)]) == 2
    assert "'c' (DiscretePI" in capsys.readouterr().err
    assert not out.exists()


SINGULAR = """\
parameters: {K: -1.0}
blocks:
  u:   {type: Sine, amplitude: 1, f: 1}
  sum: {type: Sum, signs: "+-"}
  fb:  {type: Gain, k: K}
  x:   {type: Integrator}
connections: [u.y -> sum.u1, sum.y -> fb.u, fb.y -> sum.u2, sum.y -> x.u]
simulation: {t_end: 1}
analysis:
  a: {inputs: [u.y], outputs: [x.y]}
  lp: {loop: fb.y}
"""


def test_singular_algebraic_loop_is_a_clear_error(tmp_path, capsys):
    """sum.y = u - K sum.y with K = -1 has no unique solution: linearizing through it walks
    the loop as ``run`` does (AlgebraicLoopError; it was an internal error on NaN
    matrices), and the loop transfer at fb.y, L(j inf) = -1, is refused as singular when
    closed (it was python-control's 'I - sign * D2 * D1 is singular'); exit status 2.
    With K = 3 the same pair linearizes: u -> sum.y = 1 / (1 + K) = 0.25."""
    d = spidersim.loads(SINGULAR)
    with pytest.raises(AlgebraicLoopError, match=r"singular Jacobian[\s\S]*fb\.y -> sum\.u2"):
        d.linearize(["u.y"], ["x.y"], jit=False)
    with pytest.raises(AnalysisError, match=r"L\(j inf\) = -1 makes 1 \+ L\(j inf\) = 0"):
        d.loop_transfer("fb.y", jit=False)
    ok = spidersim.loads(SINGULAR, set={"K": 3.0})
    assert np.asarray(ok.linearize(["u.y"], ["sum.y"], jit=False).D)[0, 0] == \
        pytest.approx(0.25, rel=1e-9)
    f = tmp_path / "sing.yaml"
    f.write_text(SINGULAR)
    for name in ("a", "lp"):
        assert main(["linearize", str(f), name, "--no-jit", "--out",
                     str(tmp_path / name)]) == 2
        assert "internal error" not in capsys.readouterr().err
