"""Failure reports of the compiled loop when the derivatives turn non-finite just beyond
the last step (log or sqrt of a negative): DP54 and NDF reported only "required step size
is less than spacing between numbers"; LSODA said "non-finite value". And the relative
tolerance's valid range, refused by check, run and the API alike."""
import numpy as np
import pytest

import spidersim
from spidersim.cli import main
from spidersim.errors import DiagramError, IntegrationError

FN = """\
blocks:
  s: {{type: Sine, amplitude: 1, f: 1, offset: 0.5}}
  f: {{type: Function, fn: {fn}}}
  i: {{type: Integrator}}
connections: [s.y -> f.u, f.y -> i.u]
simulation: {{t_end: 2, method: {method}}}
"""


@pytest.mark.parametrize("method", ["DP54", "NDF"])
@pytest.mark.parametrize("fn", ["log", "sqrt"])
def test_non_finite_derivative_is_named(method, fn):
    """0.5 + sin(2 pi t) turns negative at t = 7/12 s = 0.58333 s: the failure says
    'non-finite value' and names the signal f.y (the block f) that is NaN there, at that
    time to 1e-6 s. Compiled loop (what the CLI runs); the interpreted DP54 (SciPy loop)
    reports the same."""
    d = spidersim.loads(FN.format(fn=fn, method=method))
    with pytest.raises(IntegrationError) as ei:
        d.simulate()                            # the compiled loop, as the CLI runs it
    msg = str(ei.value)
    assert "non-finite value just after t" in msg and "signal 'f.y' is [nan]" in msg, msg
    assert ei.value.partial.t[-1] == pytest.approx(7 / 12, abs=1e-6)
    if method == "DP54":
        with pytest.raises(IntegrationError, match=r"non-finite value just after t[\s\S]*"
                                                   r"signal 'f.y' is \[nan\]"):
            d.simulate(jit=False)


@pytest.mark.parametrize("method", ["BDF", "Radau", "NDF"])
def test_implicit_scipy_steppers_report_non_finite_derivatives(method):
    """SciPy's BDF and Radau (and NDF interpreted, which runs SciPy's BDF) factor their
    iteration matrix with LAPACK, which raised "array must not contain infs or NaNs" out of
    the stepper: an internal error. Now a failure naming the NaN signal, near 7/12 s."""
    d = spidersim.loads(FN.format(fn="log", method=method))
    with pytest.raises(IntegrationError, match=r"non-finite value[\s\S]*signal 'f.y' is "
                                               r"\[nan\]") as ei:
        d.simulate(jit=False)
    assert ei.value.partial.t[-1] == pytest.approx(7 / 12, abs=1e-3)


SERVO = """\
blocks:
  c: {{type: Constant, value: 1}}
  x: {{type: Integrator}}
connections: [c.y -> x.u]
simulation: {{t_end: 0.1, method: DP54, rtol: {rtol}}}
"""


@pytest.mark.parametrize("rtol", ["1e-20", "1e-15", "2", "1e300"])
def test_rtol_outside_its_range_is_refused(tmp_path, capsys, rtol):
    """rtol below 1e-14 or above 1 is refused at the file's line with the valid range, by
    load (so check, run and the service alike) and by simulate(rtol=...); 1e-14 and 1
    themselves are accepted."""
    with pytest.raises(DiagramError, match=r"simulation.rtol must be in \[1e-14, 1\]"):
        spidersim.loads(SERVO.format(rtol=rtol))
    f = tmp_path / "s.yaml"
    f.write_text(SERVO.format(rtol=rtol))
    assert main(["check", str(f)]) == 2
    assert "s.yaml:5: simulation.rtol must be in [1e-14, 1]" in capsys.readouterr().err
    d = spidersim.loads(SERVO.format(rtol="1e-6"))
    with pytest.raises(DiagramError, match=r"rtol must be in"):
        d.simulate(rtol=float(rtol), jit=False)
    for ok in ("1e-14", "1"):
        spidersim.loads(SERVO.format(rtol=ok))


def test_the_diagnosis_names_the_stiffest_mode_and_its_state():
    """A run that fails on stiffness (a 1e-12 s lag beside a slow integrator): the
    diagnosis names the eigenvalue of largest magnitude of d xdot / d x and the state
    that carries it, not only the state with the largest derivative (which named an
    unrelated current for a gear stiffness of 1e300)."""
    d = spidersim.loads("blocks:\n  u: {type: Constant, value: 1}\n"
                        "  lag: {type: TransferFunction, num: [1], den: [1e-12, 1]}\n"
                        "  slow: {type: Integrator}\n"
                        "connections: [u.y -> lag.u, u.y -> slow.u]\n"
                        "simulation: {t_end: 1}\n")
    s = d.compile()
    x = np.array(s.x0, dtype=float)
    text = s.diagnose(0.0, x)
    assert "stiffest mode 1e+12 rad/s (time constant 1e-12 s)" in text, text
    assert "mostly state 'lag." in text, text
