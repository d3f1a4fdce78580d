"""trim's points carry the modes their blocks take there; trim with fewer residuals than
unknowns; linearize's note at a kink.

References are by hand: a Saturation passes ``u`` inside its limits and holds the limit
outside; a DeadZone gives ``u - end`` above its zone; a clamping PI holds its integral while
``kp e + I > y_max`` and ``e > 0``; the DC motor's steady state is ``V = (R b / K_t + K_t) w``.
"""
import os
import warnings

import numpy as np
import pytest

import spidersim
from spidersim.diagram.analysis import AnalysisError
from spidersim.errors import LinearizationWarning

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
SERVO = os.path.join(ROOT, "diagrams", "servo.yaml")

SAT_GAIN = """
name: s
blocks:
  c: {type: Constant, value: 0.5}
  sat: {type: Saturation, lower: -1, upper: 1}
  g: {type: Gain, k: 2}
connections: [c.y -> sat.u, sat.y -> g.u]
"""


def test_trim_past_a_saturation_limit_is_refused():
    # c.y += 0.7 gave sat.y = 1.2 in the linear mode, residual 0 (a simulation gives 1)
    d = spidersim.loads(SAT_GAIN)
    with pytest.raises(AnalysisError) as ei:
        d.trim(targets={"sat.y": 1.2}, free_inputs=["c.y"], jit=False)
    msg = str(ei.value)
    assert "'sat' (Saturation) mode m 0 -> 1 (-1 at lower, 0 linear, +1 at upper)" in msg
    assert "largest residuals: sat.y = -0.2" in msg


def test_trim_inside_the_limits_keeps_the_linear_mode():
    d = spidersim.loads(SAT_GAIN)
    op = d.trim(targets={"sat.y": 0.9}, free_inputs=["c.y"], jit=False)
    assert op.inputs["c.y"] == pytest.approx(0.4, abs=1e-12)
    assert list(op.modes) == [0.0]
    sys = d.linearize(["c.y"], ["g.y"], at=op, jit=False)
    assert float(sys.D[0, 0]) == pytest.approx(2.0, rel=1e-9)


def test_servo_trim_beyond_the_voltage_limit_is_refused():
    # steady w needs V = (R b / K_t + K_t) w = 0.0502 w: at most 24 V / 0.0502 = 478 rad/s;
    # 600 rad/s "converged" at 30.1 V past the +-24 V saturation
    d = spidersim.load(SERVO, set={"sat.zero_crossing": True})
    kw = dict(free_inputs=["cur_ctrl.y"], derivatives=["motor.w", "motor.i"], jit=False)
    with pytest.raises(AnalysisError, match=r"'sat' \(Saturation\) mode m 0 -> 1.*"
                                            r"largest residuals: motor.w = -122"):
        d.trim(targets={"motor.w": 600.0}, **kw)
    op = d.trim(targets={"motor.w": 470.0}, **kw)
    sat = d.layout.blocks["sat"].modes["m"][0]
    assert op.modes[sat] == 0.0
    states = d.layout.blocks["motor"].states
    i, w = op.x[states["i"][0]], op.x[states["w"][0]]
    assert w == pytest.approx(470.0, rel=1e-9)
    assert 1.0 * i + 0.05 * w == pytest.approx((1e-5 / 0.05 + 0.05) * 470.0, rel=1e-6)


DEAD_ZONE = """
name: dz
blocks:
  c: {type: Constant, value: 2.0}
  dz: {type: DeadZone, start: -1, end: 1}
connections: [c.y -> dz.u]
"""


def test_dead_zone_trim_above_the_zone_and_into_it():
    d = spidersim.loads(DEAD_ZONE)
    op = d.trim(targets={"dz.y": 0.5}, free_inputs=["c.y"], jit=False)
    assert op.inputs["c.y"] == pytest.approx(-0.5, abs=1e-12)   # u = 1.5: y = u - 1
    assert list(op.modes) == [1.0]
    # the mode above the zone puts u = 0.5 for y = -0.5: inside the zone, where y = 0
    with pytest.raises(AnalysisError) as ei:
        d.trim(targets={"dz.y": -0.5}, free_inputs=["c.y"], jit=False)
    msg = str(ei.value)
    assert "'dz' (DeadZone) mode m 1 -> 0" in msg and "dz.y = 0.5" in msg


CLAMPED_PI = """
name: pi
blocks:
  c: {type: Constant, value: 0.5}
  g: {type: Gain, k: 1}
  pi: {type: PI, kp: 1, ki: 10, y_max: 1, I0: 1.5}
connections: [c.y -> g.u, g.y -> pi.e]
"""


def test_clamped_pi_trim_holds_only_while_the_error_pushes_on_the_limit():
    d = spidersim.loads(CLAMPED_PI)
    # e = 0.2 > 0 and v = 1.7 > y_max: clamped, the integral held: a steady state
    op = d.trim(targets={"g.y": 0.2}, free_inputs=["c.y"], jit=False)
    assert op.x[0] == pytest.approx(1.5) and op.modes[0] == 1.0
    # e = -0.2 < 0 releases the clamp: I' = ki e = -2, no steady state (it was returned
    # in the clamped mode of the start, residual 0); free, the solver trades g.y against
    # I' = 10 g.y (g.y = -0.2 + 0.198, I' = -0.0198)
    with pytest.raises(AnalysisError) as ei:
        d.trim(targets={"g.y": -0.2}, free_inputs=["c.y"], jit=False)
    msg = str(ei.value)
    assert "'pi' (PI) mode clamp 1 -> 0 (clamping mode: 0 free" in msg
    assert "largest residuals: g.y = 0.198, d/dt pi.I = -0.0198" in msg


def test_clamped_start_modes_are_not_kept_inside_the_limits():
    # the start's modes (I0 = 1.5: clamped) from x0 = [0.3]: e = 0.2, v = 0.5 inside the
    # limit, where the integral runs (I' = 2); the blocks' modes are chosen afresh from
    # their declared initial ones, as at a simulation's start (a PI's initialize never
    # leaves a clamp while e > 0: its guard does, in a run)
    d = spidersim.loads(CLAMPED_PI)
    with pytest.raises(AnalysisError, match=r"'pi' \(PI\) mode clamp 1 -> 0"):
        d.trim(targets={"g.y": 0.2}, free_inputs=["c.y"], x0=[0.3], jit=False)


def test_trim_with_fewer_residuals_than_unknowns():
    # one residual (g.y - 1), two unknowns (the integrator's state, the input): 'trf' with
    # its exact solver stopped at the start ("did not converge", g.y = -0.5)
    d = spidersim.loads("""
name: s
blocks:
  c: {type: Constant, value: 0.5}
  g: {type: Gain, k: 1}
  i: {type: Integrator}
connections: [c.y -> g.u, g.y -> i.u]
""")
    op = d.trim(targets={"g.y": 1.0}, free_inputs=["c.y"], derivatives=[], jit=False)
    assert op.inputs["c.y"] == pytest.approx(0.5, abs=1e-12)
    assert op.x[0] == 0.0                   # the state no residual needs is not moved


CORNERS = """
name: corner
blocks:
  c: {type: Constant, value: 1.0}
  sat: {type: Saturation, lower: -1, upper: 1, zero_crossing: false}
  dz: {type: DeadZone, start: -1, end: 1, zero_crossing: false}
  a: {type: Function, fn: abs}
connections: [c.y -> sat.u, c.y -> dz.u, c.y -> a.u]
"""


def test_linearize_on_a_corner_notes_both_slopes():
    d = spidersim.loads(CORNERS)
    with pytest.warns(LinearizationWarning) as rec:
        sys = d.linearize(["c.y"], ["sat.y", "dz.y"], jit=False)
    msg = str(rec[0].message)
    assert "sits on a kink" in msg
    assert "sat.y by c.y: 0 above, 1 below" in msg and "dz.y by c.y: 1 above, 0 below" in msg
    assert np.allclose(np.ravel(sys.D), [0.5, 0.5])      # the mean, as before
    at0 = spidersim.loads(CORNERS.replace("value: 1.0", "value: 0.0"))
    with pytest.warns(LinearizationWarning, match=r"a.y by c.y: 1 above, -1 below"):
        at0.linearize(["c.y"], ["a.y"], jit=False)


@pytest.mark.parametrize("fn,u", [("sat", 0.5), ("exp", 10.0), ("square", 1.0)])
def test_linearize_off_corners_and_on_smooth_curves_adds_no_note(fn, u):
    # exp at 10: the one-sided slopes differ by h f'' = 1.3 of 22026 (round-off floor 0.4)
    text = CORNERS.replace("value: 1.0", f"value: {u}")
    if fn != "sat":
        text = text.replace("fn: abs", f"fn: {fn}")
    d = spidersim.loads(text)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        d.linearize(["c.y"], ["sat.y" if fn == "sat" else "a.y"], jit=False)


def test_modes_that_keep_changing_are_refused(monkeypatch):
    # no block of the library is known to cycle; a stand-in that flips the Saturation's
    # mode at every point found: the second flip returns to modes already solved in
    from spidersim.diagram import analysis

    monkeypatch.setattr(analysis, "_settled_modes",
                        lambda d, lin, t, x, u, modes: 1.0 - modes)
    with pytest.raises(AnalysisError) as ei:
        spidersim.loads(SAT_GAIN).trim(targets={"sat.y": 0.9}, free_inputs=["c.y"],
                                       jit=False)
    msg = str(ei.value)
    assert "trim found no point consistent with its blocks' modes" in msg
    assert msg.count("'sat' (Saturation) mode m") == 2          # 0 -> 1; then 1 -> 0
    assert "mode m 0 -> 1" in msg and "then 'sat' (Saturation) mode m 1 -> 0" in msg


def test_cli_prints_the_kink_note(tmp_path, capsys):
    from spidersim.cli import main
    path = tmp_path / "corner.yaml"
    path.write_text(CORNERS)
    rc = main(["linearize", str(path), "--input", "c.y", "--output", "sat.y", "--no-jit",
               "--out", str(tmp_path / "out")])
    out, err = capsys.readouterr()
    assert rc == 0, err
    assert "spidersim: note: the operating point sits on a kink" in err
    assert "sat.y by c.y: 0 above, 1 below" in err
    assert "DC gain:               0.5" in out
