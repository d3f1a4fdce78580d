"""ViaPointProfile against closed forms: through every via point at its time, C2 at the via
times, the velocity rule at interior points, QuinticProfile for two points, end holds."""
import numpy as np
import pytest

import spidersim
from spidersim import ParameterError

from .harness import Probe, simulate

# slopes 1, 2, -0.5, -0.5: point 1 keeps the sign (mean 1.5), point 2 turns (0), point 3
# keeps it (mean -0.5)
POINTS = [0.0, 1.0, 3.0, 2.0, 1.0]
TIMES = [0.5, 1.5, 2.5, 4.5, 6.5]


def rule_velocities(q, t):
    """Velocities at the via points by the rule: 0 at the ends, the mean of the adjacent
    slopes at an interior point when they have the same sign, else 0."""
    v = [0.0]
    for k in range(1, len(q) - 1):
        a = (q[k] - q[k - 1]) / (t[k] - t[k - 1])
        b = (q[k + 1] - q[k]) / (t[k + 1] - t[k])
        v.append((a + b) / 2 if a * b > 0 else 0.0)
    return v + [0.0]


def segment_poly(q0, q1, v0, v1, t0, t1):
    """Coefficients (ascending powers of tau = t - t0) of the quintic with position,
    velocity and zero acceleration given at both ends, solved as a 6x6 linear system."""
    h = t1 - t0
    A = np.array([[1, 0, 0, 0, 0, 0],
                  [0, 1, 0, 0, 0, 0],
                  [0, 0, 2, 0, 0, 0],
                  [1, h, h**2, h**3, h**4, h**5],
                  [0, 1, 2 * h, 3 * h**2, 4 * h**3, 5 * h**4],
                  [0, 0, 2, 6 * h, 12 * h**2, 20 * h**3]], dtype=float)
    return np.linalg.solve(A, [q0, v0, 0.0, q1, v1, 0.0])


def reference(q, tv, t):
    """(q, qd, qdd) of the via-point path at time ``t`` (closed form)."""
    if t < tv[0]:
        return q[0], 0.0, 0.0
    if t > tv[-1]:
        return q[-1], 0.0, 0.0
    v = rule_velocities(q, tv)
    j = min(int(np.searchsorted(tv, t, side="right")), len(tv) - 1)
    c = np.polynomial.Polynomial(segment_poly(q[j - 1], q[j], v[j - 1], v[j], tv[j - 1], tv[j]))
    tau = t - tv[j - 1]
    return c(tau), c.deriv(1)(tau), c.deriv(2)(tau)


def probe(points=POINTS, times=TIMES):
    return Probe("ViaPointProfile", {"points": list(points), "times": list(times)})


def at(p, t, k):
    """Outputs (q, qd, qdd) of the probe at time ``t`` with ``k`` via times passed."""
    p.set_mode("k", float(k))
    o = p.outputs(t)
    return np.array([o["q"][0], o["qd"][0], o["qdd"][0]])


def mode_at(times, t):
    """The mode the events give at ``t``: number of via times <= t."""
    return int(np.searchsorted(times, t, side="right"))


def test_passes_through_every_via_point_at_its_time():
    p = probe()
    for k, (qk, tk) in enumerate(zip(POINTS, TIMES)):
        # after the event at t_k: start of segment k (or the end hold)
        assert at(p, tk, k + 1)[0] == pytest.approx(qk, abs=1e-12)
        # before the event at t_k: end of segment k - 1 (or the start hold)
        assert at(p, tk, k)[0] == pytest.approx(qk, abs=1e-12)


def test_matches_the_closed_form_between_via_points():
    p = probe()
    for t in np.linspace(0.0, 7.0, 141):
        np.testing.assert_allclose(at(p, t, mode_at(TIMES, t)), reference(POINTS, TIMES, t),
                                   rtol=0, atol=1e-12)


def test_position_velocity_acceleration_continuous_at_via_times():
    p = probe()
    v = rule_velocities(POINTS, TIMES)
    for k, tk in enumerate(TIMES):
        before, after = at(p, tk, k), at(p, tk, k + 1)
        np.testing.assert_allclose(before, after, rtol=0, atol=1e-12)
        np.testing.assert_allclose(after, [POINTS[k], v[k], 0.0], rtol=0, atol=1e-12)
        # and just around the event, on the pieces the integrator uses there
        eps = 1e-7
        np.testing.assert_allclose(at(p, tk - eps, k), at(p, tk + eps, k + 1), rtol=0,
                                   atol=1e-5)


def test_velocity_rule_at_interior_points():
    p = probe()
    qd = [at(p, TIMES[k], k + 1)[1] for k in range(len(TIMES))]
    assert qd[0] == 0.0 and qd[-1] == 0.0
    assert qd[1] == pytest.approx(1.5, abs=1e-14)      # slopes 1 and 2: the mean
    assert qd[2] == 0.0                                 # slopes 2 and -0.5: a turn
    assert qd[3] == pytest.approx(-0.5, abs=1e-14)     # slopes -0.5 and -0.5


def test_velocity_zero_where_a_slope_is_zero():
    p = probe([0.0, 1.0, 1.0, 2.0], [0.0, 1.0, 2.0, 3.0])
    assert at(p, 1.0, 2)[1] == 0.0 and at(p, 2.0, 3)[1] == 0.0
    # no overshoot on the flat piece
    for t in np.linspace(1.0, 2.0, 21):
        assert at(p, t, 2)[0] == pytest.approx(1.0, abs=1e-12)


@pytest.mark.parametrize("q0,q1,t0,t1", [(0.1, 1.0, 0.0, 2.0), (2.0, -0.5, 0.3, 1.1),
                                         (-1.0, -1.0, 1.0, 4.0)])
def test_two_points_equal_quintic_profile(q0, q1, t0, t1):
    via = probe([q0, q1], [t0, t1])
    qp = Probe("QuinticProfile", {"q0": q0, "q1": q1, "T": t1 - t0, "t_start": t0})
    for t in np.linspace(0.0, t1 + 1.0, 97):
        k = mode_at([t0, t1], t)
        qp.set_mode("phase", float(k))
        o = qp.outputs(t)
        np.testing.assert_allclose(at(via, t, k), [o["q"][0], o["qd"][0], o["qdd"][0]],
                                   rtol=0, atol=1e-12)


def test_holds_before_first_and_after_last_via_time():
    p = probe()
    for t in (0.0, 0.2, 0.5 - 1e-9):
        assert list(at(p, t, 0)) == [POINTS[0], 0.0, 0.0]
    for t in (6.5 + 1e-9, 7.0, 100.0):
        assert list(at(p, t, len(POINTS))) == [POINTS[-1], 0.0, 0.0]


def test_next_time_is_each_via_time_in_turn():
    cls = spidersim.blocks.REGISTRY["ViaPointProfile"]
    times = np.array(TIMES)
    k = np.zeros(1)
    seen = []
    while True:
        nxt = cls.next_time(0.0, times, k)
        if nxt == np.inf:
            break
        seen.append(nxt)
        cls.time_event(nxt, k)
    assert seen == TIMES and k[0] == len(TIMES)


@pytest.mark.parametrize("times", ["[0, 1, 1, 2]", "[0, 2, 1, 3]", "[3, 2, 1, 0]"])
def test_check_refuses_non_increasing_times(times):
    with pytest.raises(ParameterError, match="'times' must be strictly increasing"):
        spidersim.loads("blocks:\n  r: {type: ViaPointProfile, points: [0, 1, 2, 3], "
                        f"times: {times}}}\n")


def test_check_refuses_a_segment_shorter_than_the_time_resolution():
    """1e-13 s between two via points (a typing slip) gave a reference velocity of 1e13
    without a word; segments shorter than 1e-7 s (the shortest run) are refused, naming
    the segment. 1e-7 s itself is accepted."""
    text = "blocks:\n  r: {type: ViaPointProfile, points: [0, 1, 2], times: [0, 1, %s]}\n"
    with pytest.raises(ParameterError, match=r"from times\[1\] = 1 s to times\[2\] = "
                                             r"1.0000000000001 s lasts 9.99e-14 s"):
        spidersim.loads(text % "1.0000000000001")
    with pytest.raises(ParameterError, match="'times' must be finite"):
        spidersim.loads(text % ".inf")
    spidersim.loads(text % "1.0000001")
    spidersim.loads(text.replace("[0, 1, %s]", "[0, 10, %s]") % "10.0000001")  # 9.99999994e-8


def test_check_refuses_fewer_than_two_points():
    with pytest.raises(ParameterError, match="'points' needs at least 2 via points, got 1"):
        spidersim.loads("blocks:\n  r: {type: ViaPointProfile, points: [1], times: [0]}\n")


def test_check_refuses_negative_times_and_length_mismatch():
    with pytest.raises(ParameterError, match="'times' must be >= 0"):
        spidersim.loads("blocks:\n  r: {type: ViaPointProfile, points: [0, 1], "
                        "times: [-1, 1]}\n")
    with pytest.raises(ParameterError, match="'times' must have 3 elements"):
        spidersim.loads("blocks:\n  r: {type: ViaPointProfile, points: [0, 1, 2], "
                        "times: [0, 1]}\n")


def test_simulated_diagram_passes_through_the_via_points():
    """In a simulation the via times are events and samples; the recorded q is the closed
    form, and integrating qdd twice (Integrators) gives back a path through the points."""
    text = (f"name: via\nblocks:\n  r: {{type: ViaPointProfile, points: {POINTS}, "
            f"times: {TIMES}}}\n  iv: {{type: Integrator}}\n"
            f"  ip: {{type: Integrator, x0: {POINTS[0]}}}\n"
            "connections:\n  - r.qdd -> iv.u\n  - iv.y -> ip.u\n")
    r = simulate(text, t_end=7.0, rtol=1e-10, atol=1e-12)
    assert [e[0] for e in r.events] == TIMES
    t, q, qd = r.t, r["r.q"], r["r.qd"]
    for qk, tk in zip(POINTS, TIMES):
        k = np.flatnonzero(t == tk)
        assert k.size >= 1, f"via time {tk} is not a sample"
        assert q[k] == pytest.approx(qk, abs=1e-12)
        assert r["ip.y"][k] == pytest.approx(qk, abs=1e-7)        # integrated twice
    ref = np.array([reference(POINTS, TIMES, s) for s in t])
    np.testing.assert_allclose(q, ref[:, 0], rtol=0, atol=1e-12)
    np.testing.assert_allclose(qd, ref[:, 1], rtol=0, atol=1e-12)
    np.testing.assert_allclose(r["iv.y"], qd, rtol=0, atol=1e-7)
    assert np.all(q[t < TIMES[0]] == POINTS[0]) and np.all(q[t > TIMES[-1]] == POINTS[-1])


def test_compiled_kernel_agrees_with_interpreted():
    d = spidersim.loads(f"name: via\nblocks:\n  r: {{type: ViaPointProfile, points: {POINTS}, "
                        f"times: {TIMES}}}\n")
    a = d.simulate(t_end=7.0, jit=False, output_interval=0.01)
    b = d.simulate(t_end=7.0, jit=True, output_interval=0.01)
    assert b.stats["jit"] is True
    np.testing.assert_array_equal(a.t, b.t)
    for s in ("r.q", "r.qd", "r.qdd"):
        np.testing.assert_allclose(b[s], a[s], rtol=0, atol=1e-12)
