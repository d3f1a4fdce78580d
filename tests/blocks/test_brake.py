"""The Brake alone on a spinning inertia against closed forms (issue #13 item 3): engaged
exactly t_detect + t_engage after the fault, then a constant deceleration T_hold / J until
the shaft stops, and held."""
import pytest

import spidersim

DIAGRAM = """\
blocks:
  fault: {{type: Step, t_step: {t_f}, before: 0, after: 1}}
  brake: {{type: Brake, T_hold: {T}, t_detect: 0.01, t_engage: 0.02, w_eps: 1.0e-4}}
  shaft: {{type: Inertia, J: {J}, w0: {w0}}}
connections:
  - fault.y -> brake.fault
  - shaft.w -> brake.w
  - brake.tau -> shaft.tau
simulation: {{t_end: 1.0, rtol: 1e-9, atol: 1e-12, max_step: 1.0e-3}}
"""


@pytest.mark.parametrize("T,J,w0", [(5.0, 0.02, 100.0), (20.0, 0.1, -50.0)])
def test_engagement_delay_and_deceleration(T, J, w0):
    t_f = 0.2
    d = spidersim.loads(DIAGRAM.format(t_f=t_f, T=T, J=J, w0=w0))
    r = d.simulate(jit=False)
    t_on = t_f + 0.01 + 0.02
    before = r.t < t_on - 1e-9
    assert abs(r["shaft.w"][before] - w0).max() < 1e-9          # free spinning until then
    assert r["brake.engaged"][before].max() == 0.0
    assert any(abs(t - t_on) < 1e-9 and b == "brake" for t, b, _ in r.events) or \
        abs(r.t[before][-1] - t_on) < 1e-9
    # constant deceleration T/J while |w| >> w_eps: stop time t_on + J |w0| / T
    t_stop = t_on + J * abs(w0) / T
    mid = (r.t > t_on + 1e-3) & (r.t < t_stop - 0.01)
    w_ref = w0 - (1 if w0 > 0 else -1) * T / J * (r.t[mid] - t_on)
    assert abs(r["shaft.w"][mid] - w_ref).max() < 1e-4 * abs(w0)
    after = r.t > t_stop + 0.02
    assert abs(r["shaft.w"][after]).max() < 1e-3                 # held at rest
    # the angle travelled while braking: w0^2 J / (2 T)
    phi = r["shaft.phi"]
    travel = phi[after][0] - phi[r.t <= t_on][-1]
    assert travel == pytest.approx(w0 * abs(w0) * J / (2 * T), rel=1e-3)


def test_no_fault_no_brake():
    d = spidersim.loads(DIAGRAM.format(t_f=5.0, T=5.0, J=0.02, w0=10.0))
    r = d.simulate(jit=False)
    assert r["brake.engaged"].max() == 0.0 and abs(r["shaft.w"] - 10.0).max() < 1e-12
