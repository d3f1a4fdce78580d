"""ROS34PW2 in the compiled loop on shipped diagrams: the LuGre stick-slip case against
LSODA, the bouncing ball's impacts against DP54 and the closed form, the statistics."""
import os

import numpy as np
import pytest

import spidersim

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
LUGRE = os.path.join(ROOT, "diagrams", "lugre_stick_slip.yaml")
BALL = os.path.join(ROOT, "diagrams", "bouncing_ball.yaml")


@pytest.fixture(scope="module")
def lugre():
    return spidersim.load(LUGRE)


def test_lugre_stick_slip_agrees_with_lsoda(lugre):
    """LuGre stick-slip (sigma0 = 1e5 N/m: stiff bristles), 25 s at the file's 1e-7/1e-10,
    on a 1 ms grid: ROS34PW2 and LSODA agree on the position to 1e-5 m (of 1.9 m travelled;
    2.4e-6 measured), on the velocity to 1e-4 of its range (1.2e-5 measured) and on the
    friction force to 0.01 N (2e-3 N measured, at the break-away jumps); and ROS34PW2 needs far fewer steps than DP54's 59,000
    (the explicit method's stability limit)."""
    kw = dict(output_interval=1e-3)
    ref = lugre.simulate(method="LSODA", **kw)
    r = lugre.simulate(method="ROS34PW2", **kw)
    assert r.stats["method"] == "ROS34PW2" and len(r.t) == len(ref.t)
    assert np.max(np.abs(r["mass.phi"] - ref["mass.phi"])) < 1e-5
    assert np.max(np.abs(r["mass.w"] - ref["mass.w"])) < 1e-4 * np.ptp(ref["mass.w"])
    assert np.max(np.abs(r["fric.tau"] - ref["fric.tau"])) < 0.01
    assert r.stats["steps"] < 20000 and r.stats["jacobian_calls"] > 0
    assert r.stats["lu_decompositions"] <= r.stats["steps"] + r.stats["rejected_steps"]


def test_bouncing_ball_impacts_as_with_dp54():
    """e = 0.95, 30 impacts at 1e-10/1e-12: ROS34PW2 locates every impact where DP54 does,
    within 1e-9 s, and both within 1e-9 s of the closed form t_k (the fall is a quadratic,
    which the Hermite dense output represents exactly)."""
    d = spidersim.load(BALL, set={"ball.e": 0.95, "ball.v_rest": 0})
    e, g, h0 = 0.95, 9.81, 10.0
    t1 = np.sqrt(2 * h0 / g)
    tk = [t1]
    for k in range(1, 30):
        tk.append(tk[-1] + 2 * e ** k * g * t1 / g)
    kw = dict(t_end=tk[-1] + 0.1, rtol=1e-10, atol=1e-12)
    imp = {}
    for m in ("DP54", "ROS34PW2"):
        r = d.simulate(method=m, **kw)
        imp[m] = np.array([t for t, _b, ev in r.events if ev == "impact"])
    assert len(imp["ROS34PW2"]) == len(imp["DP54"]) == 30
    assert np.max(np.abs(imp["ROS34PW2"] - imp["DP54"])) < 1e-9
    assert np.max(np.abs(imp["ROS34PW2"] - np.array(tk))) < 1e-9


def test_interpreted_ros34pw2_runs_radau_and_agrees(lugre):
    """Without numba the method name runs SciPy's Radau in the Python loop (as DP54 runs
    RK45): 10 s of stick-slip (the first break-away, when the spring reaches F_s = 1.5 N
    near 7.5 s, and the first slip of 0.6 m included) agree with the compiled ROS34PW2 to
    1e-5 m in position on a 1 ms grid (1.3e-6 m measured)."""
    kw = dict(t_end=10.0, output_interval=1e-3, method="ROS34PW2")
    r = lugre.simulate(jit=False, **kw)
    c = lugre.simulate(**kw)
    assert r.stats["jacobian_calls"] > 0 and c.stats["lu_decompositions"] > 0
    assert np.max(np.abs(r["mass.phi"] - c["mass.phi"])) < 1e-5
