"""Contact against closed forms: elastic and perfectly rigid surfaces, point mass and arm.

Elastic (ElasticContact, a point mass hitting the plane z = 0 with speed v0):

* undamped, no gravity: the contact is a half period of ``m delta'' = -K delta``, duration
  ``pi / sqrt(K / m)``, exit speed ``v0`` (claimed within 1e-6 relative, measured ~1e-10);
* damped: ``delta = v0 / w_d exp(-zeta w_n t) sin(w_d t)`` until the normal force
  ``K delta + D delta'`` would pull (release), the instant and the exit speed from it;
* with gravity: ``delta'' = g - w_n^2 delta``, contact ends when delta returns to 0;
* second-order surface: total energy (body, surface mass, both springs) conserved;
* Coulomb friction: once settled under gravity the body decelerates at ``mu g``.

Rigid (RigidContact, the loop on the constraint force solved by Newton):

* point mass: onset at the free-fall instant, plastic impact, penetration < 1e-6 m,
  lam = m g at rest, release at the instant a pull exceeds the weight, free motion after;
* arm: in static equilibrium ``lam`` is the force of ``tau = g(q) - J_v^T n lam``; an
  approach at speed gives the plastic-impact jump of PHYSICS.md
  ``qd+ = qd- - M^-1 J_n^T (J_n M^-1 J_n^T)^-1 J_n qd-``; a pull releases it.
"""
from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.optimize import brentq

import spidersim
from spidersim.multibody import Chain

N = 7
Q0 = np.array([0.0, 0.6, 0.0, -1.3, 0.0, 0.8, 0.0])
G = 9.81


def _yl(v):
    return "[" + ", ".join(repr(float(x)) for x in np.atleast_1d(v)) + "]"


def _events(r, block, name):
    return [e[0] for e in r.events if e[1] == block and e[2] == name]


# =========================================================================== elastic
def drop(K, m, v0, D=0.0, g=0.0, h=0.0, extra="", vx=0.0, t_end=0.2, **sim):
    """Point mass at height h moving down at v0 onto the plane z = 0 (normal +z)."""
    text = f"""
name: drop
blocks:
  body: {{type: PointMass, m: {m}, g: [0, 0, {-g}], p0: [0, 0, {h}], v0: [{vx}, 0, {-v0}]}}
  wall: {{type: ElasticContact, point: [0, 0, 0], normal: [0, 0, 1], K: {K}, D: {D}{extra}}}
connections:
  - body.pos -> wall.pos
  - body.vel -> wall.vel
  - wall.force -> body.f
log: [body.pos, body.vel, body.acc, wall.fn, wall.delta, wall.energy, wall.w, wall.wd]
"""
    cfg = dict(t_end=t_end, rtol=1e-11, atol=1e-13)
    cfg.update(sim)
    return spidersim.loads(text).simulate(**cfg)


def _contact(r):
    on, off = _events(r, "wall", "onset"), _events(r, "wall", "release")
    assert len(on) >= 1 and len(off) >= 1, r.events
    return on[0], off[0]


@pytest.mark.parametrize("K, m", [(1e4, 2.0), (1e6, 30.0)])
def test_elastic_undamped_contact_lasts_half_a_period(K, m):
    v0 = 1.0
    r = drop(K, m, v0, t_end=math.pi / math.sqrt(K / m) + 0.01)
    t_on, t_off = _contact(r)
    assert t_on == pytest.approx(0.0, abs=1e-12)
    exact = math.pi / math.sqrt(K / m)
    assert abs((t_off - t_on) / exact - 1) < 1e-6, (t_off - t_on, exact)
    # energy: elastic and kinetic exchange without loss, exit speed = entry speed
    assert r["body.vel"][-1, 2] == pytest.approx(v0, rel=1e-6)
    E = 0.5 * m * r["body.vel"][:, 2] ** 2 + r["wall.energy"]
    assert np.abs(E / (0.5 * m * v0 ** 2) - 1).max() < 1e-6
    assert r["wall.fn"].min() >= 0.0                       # never pulls


def test_elastic_damped_release_when_the_force_would_pull():
    K, m, D, v0 = 1e5, 5.0, 200.0, 0.5
    wn = math.sqrt(K / m)
    zeta = D / (2 * math.sqrt(K * m))
    wd = wn * math.sqrt(1 - zeta ** 2)

    def delta(t):
        return v0 / wd * math.exp(-zeta * wn * t) * math.sin(wd * t)

    def deltad(t):
        return v0 * math.exp(-zeta * wn * t) * (math.cos(wd * t)
                                                - zeta * wn / wd * math.sin(wd * t))

    # the force K delta + D delta' turns negative before delta returns to zero
    t_rel = brentq(lambda t: K * delta(t) + D * deltad(t), 0.5 * math.pi / wd, math.pi / wd,
                   xtol=1e-15)
    r = drop(K, m, v0, D=D, t_end=t_rel + 0.01)
    t_on, t_off = _contact(r)
    assert 0.1 < zeta < 0.3
    assert abs((t_off - t_on) / t_rel - 1) < 1e-6, (t_off - t_on, t_rel)
    assert t_off - t_on < math.pi / wd * (1 - 1e-3)        # really before delta = 0
    # after release the body flies at the speed it had then (no force in flight)
    assert r["body.vel"][-1, 2] == pytest.approx(-deltad(t_rel), rel=1e-6)
    assert r["wall.fn"].min() >= 0.0


def test_elastic_drop_under_gravity():
    K, m, h = 2e4, 3.0, 0.05
    wn = math.sqrt(K / m)
    v = math.sqrt(2 * G * h)
    t_land = v / G
    # in contact: delta'' = g - wn^2 delta, delta(0) = 0, delta'(0) = v
    def delta(t):
        return G / wn ** 2 * (1 - math.cos(wn * t)) + v / wn * math.sin(wn * t)

    t_c = brentq(delta, 0.6 * math.pi / wn, 2 * math.pi / wn - 1e-9, xtol=1e-15)
    r = drop(K, m, 0.0, g=G, h=h, t_end=t_land + t_c + 0.01)
    t_on, t_off = _contact(r)
    assert t_on == pytest.approx(t_land, rel=1e-9)
    assert abs((t_off - t_on) / t_c - 1) < 1e-6
    # rebound speed = impact speed (no damping)
    k = np.searchsorted(r.t, t_off, side="right")
    assert r["body.vel"][k, 2] == pytest.approx(v, rel=1e-6)


def test_second_order_surface_conserves_energy():
    K, m, v0 = 1e5, 2.0, 1.0
    ms, Ks = 5.0, 4e4
    r = drop(K, m, v0, extra=f", surface: true, m_s: {ms}, K_s: {Ks}, D_s: 0", t_end=0.08)
    vb, wd = r["body.vel"], r["wall.wd"]
    E = 0.5 * m * np.sum(vb ** 2, axis=1) + 0.5 * ms * wd ** 2 + r["wall.energy"]
    E0 = 0.5 * m * v0 ** 2
    assert np.abs(E / E0 - 1).max() < 1e-6, np.abs(E / E0 - 1).max()
    # the surface really moved and kept part of the energy after the body left
    assert r["wall.w"].min() < -1e-3
    t_on, t_off = _contact(r)
    after = r.t > t_off
    assert after.any()
    assert 0.5 * m * vb[after][-1, 2] ** 2 < 0.99 * E0


def test_coulomb_friction_decelerates_at_mu_g():
    K, m, mu, vx = 1e5, 4.0, 0.3, 2.0
    D = 2.0 * math.sqrt(K * m)                            # critically damped: no bounce
    r = drop(K, m, 0.0, D=D, g=G, h=1e-4, vx=vx, t_end=0.6,
             extra=f", mu: {mu}, v_eps: 1e-4", output_interval=1e-3)
    assert not _events(r, "wall", "release")
    t_on = _events(r, "wall", "onset")[0]
    settled = (r.t > t_on + 0.2) & (r["body.vel"][:, 0] > 0.05)
    assert settled.sum() > 50
    np.testing.assert_allclose(r["wall.fn"][settled], m * G, rtol=1e-6)
    np.testing.assert_allclose(r["body.acc"][settled, 0], -mu * G, rtol=1e-6)
    # and the speed falls linearly at that rate
    t, v = r.t[settled], r["body.vel"][settled, 0]
    slope = np.polyfit(t, v, 1)[0]
    assert slope == pytest.approx(-mu * G, rel=1e-6)


def test_elastic_contact_starting_inside_the_surface():
    """At rest 1 mm inside (no gravity): pushed out in a quarter period, at speed
    delta0 sqrt(K/m); the contact is engaged from the start, not missed."""
    K, m, d0 = 1e4, 2.0, 1e-3
    wn = math.sqrt(K / m)
    r = drop(K, m, 0.0, h=-d0, t_end=math.pi / wn)
    assert _events(r, "wall", "onset") == []
    off = _events(r, "wall", "release")
    assert len(off) == 1 and off[0] == pytest.approx(0.5 * math.pi / wn, rel=1e-6)
    assert r["wall.fn"][0] == pytest.approx(K * d0, rel=1e-12)
    assert r["body.vel"][-1, 2] == pytest.approx(d0 * wn, rel=1e-6)


# =========================================================================== rigid: point mass
# a PointMass 'body' on a RigidContact 'wall' (the force goes back through a Sum 'sum')
MASS_ON_WALL = """  - body.pos -> wall.pos
  - body.vel -> wall.vel
  - body.acc -> wall.acc
  - wall.constraint -> body.constraint
"""


def rigid_mass(m=2.0, h=0.1, t_pull=0.5, pull=2.0, t_end=0.8):
    """Point mass falls from h onto a rigid plane z = 0; from t_pull a force pull * m g up."""
    text = f"""
name: rigid_mass
blocks:
  body: {{type: PointMass, m: {m}, g: [0, 0, {-G}], p0: [0.2, -0.1, {h}]}}
  wall: {{type: RigidContact, point: [0, 0, 0], normal: [0, 0, 1]}}
  lift: {{type: Step, t_step: {t_pull}, before: 0, after: {pull * m * G}}}
  zero: {{type: Constant, value: 0}}
  f:    {{type: Mux, n: 3}}
  sum:  {{type: Sum, signs: "++"}}
connections:
{MASS_ON_WALL}  - zero.y -> f.u1
  - zero.y -> f.u2
  - lift.y -> f.u3
  - wall.force -> sum.u1
  - f.y -> sum.u2
  - sum.y -> body.f
log: [body.pos, body.vel, wall.lam, wall.gap]
"""
    return spidersim.loads(text).simulate(t_end=t_end, rtol=1e-10, atol=1e-12,
                                          output_interval=1e-3)


@pytest.fixture(scope="module")
def mass_run():
    return rigid_mass()


def test_rigid_point_mass_lands_sticks_and_holds_its_weight(mass_run):
    r, m, h = mass_run, 2.0, 0.1
    on = _events(r, "wall", "onset")
    assert len(on) == 1
    assert on[0] == pytest.approx(math.sqrt(2 * h / G), rel=1e-9)
    assert _events(r, "body", "impact") == on              # the plastic impact, same instant
    contact = (r.t > on[0]) & (r.t < 0.5)
    assert contact.sum() > 100
    assert np.abs(r["wall.gap"][contact]).max() < 1e-6
    assert np.abs(r["body.vel"][contact, 2]).max() < 1e-6
    np.testing.assert_allclose(r["wall.lam"][contact], m * G, rtol=1e-6)
    # tangential position untouched by the normal constraint
    np.testing.assert_allclose(r["body.pos"][:, :2], [[0.2, -0.1]] * len(r.t), atol=1e-12)


def test_rigid_point_mass_released_when_pulled(mass_run):
    r = mass_run
    off = _events(r, "wall", "release")
    assert off == [pytest.approx(0.5, abs=1e-9)]
    after = r.t > 0.5
    assert np.abs(r["wall.lam"][after]).max() < 1e-9
    # net force up = m g: z = g/2 (t - 0.5)^2 from the plane (up to the hold's 1e-6 m)
    z_exact = 0.5 * G * (r.t[after] - 0.5) ** 2
    assert np.abs(r["body.pos"][after, 2] - z_exact).max() < 2e-6


def test_rigid_contact_engaged_at_the_start_never_pulls():
    """``engaged: true`` with the applied force already pulling: let go at t = 0."""
    text = f"""
name: start_pulling
blocks:
  body: {{type: PointMass, m: 2, g: [0, 0, {-G}]}}
  wall: {{type: RigidContact, point: [0, 0, 0], normal: [0, 0, 1], engaged: true}}
  up:   {{type: Constant, value: [0, 0, {4 * G}]}}
  sum:  {{type: Sum, signs: "++"}}
connections:
{MASS_ON_WALL}  - wall.force -> sum.u1
  - up.y -> sum.u2
  - sum.y -> body.f
"""
    r = spidersim.loads(text).simulate(t_end=0.2, rtol=1e-10, atol=1e-12)
    assert np.abs(r["wall.lam"]).max() < 1e-9
    np.testing.assert_allclose(r["body.pos"][:, 2], 0.5 * G * r.t ** 2, rtol=1e-8,
                               atol=1e-12)


# =========================================================================== rigid: the arm
def _chain(gravity):
    ch = Chain.from_yaml()
    ch.gravity = np.asarray(gravity, float)
    return ch


# the flange on a RigidContact 'wall' (velocity, acceleration in; wrench, impact back)
ARM_ON_WALL = """  - arm.flange_pos -> wall.pos
  - arm.flange_twist[0:3] -> wall.vel
  - arm.flange_acc -> wall.acc
  - wall.wrench -> arm.f_ext
  - wall.constraint -> arm.constraint
"""


def arm_on_plane(lam0, t_pull=None, t_end=0.3):
    """The arm under gravity, flange resting on the plane z = z(q0) (normal +z), torques
    tau = g(q0) - J_v^T n lam0 (pushing with lam0); from t_pull the push becomes a pull."""
    ch = _chain([0, 0, -G])
    n = np.array([0.0, 0.0, 1.0])
    p0 = ch.fk(Q0)[:3, 3]
    Jn = n @ ch.jacobian(Q0)[:3]
    tau = ch.rnea(Q0, np.zeros(N), np.zeros(N)) - Jn * lam0
    t_pull = t_end + 1.0 if t_pull is None else t_pull       # never, in this run
    pull = "".join(f"  - pull.y -> pullv.u{i + 1}\n" for i in range(N))
    text = f"""
name: arm_on_plane
blocks:
  tau:   {{type: Constant, value: {_yl(tau)}}}
  pull:  {{type: Step, t_step: {t_pull}, before: 0, after: 1}}
  pullv: {{type: Mux, n: {N}}}
  k:     {{type: Gain, k: {_yl(2 * Jn * lam0)}}}
  sum:   {{type: Sum, signs: "++"}}
  arm:   {{type: Arm, q0: {_yl(Q0)}, gravity: [0, 0, {-G}]}}
  wall:  {{type: RigidContact, point: {_yl(p0)}, normal: [0, 0, 1], engaged: true}}
connections:
  - tau.y -> sum.u1
{pull}  - pullv.y -> k.u
  - k.y -> sum.u2
  - sum.y -> arm.tau
{ARM_ON_WALL}log: [arm.q, arm.qd, wall.lam, wall.gap]
"""
    return spidersim.loads(text).simulate(t_end=t_end, rtol=1e-10, atol=1e-12,
                                          output_interval=1e-3, jit=False)


def test_arm_static_constraint_force_from_joint_torques():
    lam0 = 40.0
    r = arm_on_plane(lam0)
    assert not r.events
    np.testing.assert_allclose(r["wall.lam"], lam0, rtol=1e-6)
    assert np.abs(r["wall.gap"]).max() < 1e-9
    assert np.abs(r["arm.qd"]).max() < 1e-8
    assert np.abs(r["arm.q"] - Q0).max() < 1e-9


def test_arm_released_when_pulled_away():
    lam0 = 40.0
    r = arm_on_plane(lam0, t_pull=0.1, t_end=0.3)
    assert _events(r, "wall", "release") == [pytest.approx(0.1, abs=1e-9)]
    before, after = r.t < 0.1, r.t > 0.1
    np.testing.assert_allclose(r["wall.lam"][before], lam0, rtol=1e-6)
    assert np.abs(r["wall.lam"][after]).max() < 1e-9
    gap = r["wall.gap"][after]
    assert gap[-1] > 1e-4 and np.all(np.diff(gap) > 0)      # moving away from the plane


def test_arm_impact_is_the_plastic_jump():
    """g = 0, tau = 0: the arm coasts with qd0 until the flange hits a plane 1 cm below."""
    ch = _chain([0, 0, 0])
    qd0 = np.array([0.1, 0.3, -0.2, -0.4, 0.2, 0.1, 0.3])
    n = np.array([0.0, 0.0, 1.0])
    v0 = (ch.jacobian(Q0) @ qd0)[:3]
    assert n @ v0 < -0.1                                    # approaching
    point = ch.fk(Q0)[:3, 3] - 0.01 * n
    text = f"""
name: arm_impact
blocks:
  tau:  {{type: Constant, value: {_yl(np.zeros(N))}}}
  arm:  {{type: Arm, q0: {_yl(Q0)}, qd0: {_yl(qd0)}}}
  wall: {{type: RigidContact, point: {_yl(point)}, normal: [0, 0, 1]}}
connections:
  - tau.y -> arm.tau
{ARM_ON_WALL}log: [arm.q, arm.qd, arm.flange_twist, wall.lam, wall.gap]
"""
    r = spidersim.loads(text).simulate(t_end=0.15, rtol=1e-10, atol=1e-12, jit=False)
    on = _events(r, "wall", "onset")
    assert len(on) == 1 and 0.0 < on[0] < 0.1
    assert _events(r, "arm", "impact") == on
    rows = np.flatnonzero(r.t == on[0])
    assert len(rows) >= 2, "pre- and post-event samples at the onset"
    i0, i1 = rows[0], rows[-1]
    q = r["arm.q"][i0]
    np.testing.assert_array_equal(r["arm.q"][i1], q)
    assert abs(r["wall.gap"][i0]) < 1e-9
    qd_m, qd_p = r["arm.qd"][i0], r["arm.qd"][i1]
    M = ch.mass_matrix(q)
    Jn = (n @ ch.jacobian(q)[:3])[None, :]
    Minv_Jt = np.linalg.solve(M, Jn.T)
    exact = qd_m - (Minv_Jt @ np.linalg.solve(Jn @ Minv_Jt, Jn @ qd_m)).ravel()
    np.testing.assert_allclose(qd_p, exact, rtol=1e-9, atol=1e-12)
    assert np.linalg.norm(qd_p - qd_m) > 0.05 * np.linalg.norm(qd_m)   # a real jump
    assert abs(r["arm.flange_twist"][i1, 2]) < 1e-10                   # normal speed gone
    # plastic: kinetic energy lost, never gained
    assert qd_p @ M @ qd_p < qd_m @ M @ qd_m
    # afterwards the flange never goes through the plane
    after = r.t > on[0]
    assert r["wall.gap"][after].min() > -1e-6
