"""Algebraic loops solved by Newton inside the compiled RHS (issue: loops, events)."""
import math
import os

import numpy as np
import pytest
from scipy.optimize import brentq

import spidersim
from spidersim.errors import AlgebraicLoopError

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))


def _err(y, exact, rtol, atol):
    return np.max(np.abs(y - exact)) / (atol + rtol * np.max(np.abs(exact)))


def test_linear_loop_feeding_integrator_matches_closed_form():
    d = spidersim.load(os.path.join(ROOT, "diagrams", "algebraic_loop.yaml"))
    r = d.simulate(jit=False)
    K, t = 3.0, r.t
    assert _err(r["sum.y"], np.sin(2 * np.pi * t) / (1 + K), 1e-9, 1e-12) < 5
    x_exact = (1 - np.cos(2 * np.pi * t)) / (2 * np.pi) / (1 + K)
    assert _err(r["x.y"], x_exact, 1e-9, 1e-12) < 5
    assert r.stats["newton_iterations"] > 0
    # the loop is reported by `check` with its tear variable
    text = d.summary()
    assert "algebraic loop 1" in text and "tear variables: sum.y" in text


TANH_LOOP = """
blocks:
  u:   {type: Constant, value: %(u)s}
  sum: {type: Sum, signs: "+-"}
  fn:  {type: Function, fn: tanh}
  g:   {type: Gain, k: 2}
connections:
  - u.y -> sum.u1
  - g.y -> sum.u2
  - sum.y -> fn.u
  - fn.y -> g.u
"""


@pytest.mark.parametrize("u", [0.3, 1.0, -2.5])
def test_three_block_nonlinear_loop_against_scalar_root(u):
    d = spidersim.loads(TANH_LOOP % {"u": u})
    r = d.simulate(t_end=0.1, rtol=1e-12, atol=1e-14, jit=False)
    y_ref = brentq(lambda y: y - math.tanh(u - 2 * y), -1, 1, xtol=1e-15)
    assert np.max(np.abs(r["fn.y"] - y_ref)) < 1e-12
    assert len(d.layout.loops) == 1 and len(d.layout.loops[0].tears) == 1


def test_two_independent_loops():
    text = """
blocks:
  u:    {type: Sine, f: 2}
  s1:   {type: Sum, signs: "+-"}
  k1:   {type: Gain, k: 1.0}
  s2:   {type: Sum, signs: "+-"}
  k2:   {type: Gain, k: 4.0}
connections:
  - u.y -> s1.u1, s2.u1
  - s1.y -> k1.u
  - k1.y -> s1.u2
  - s2.y -> k2.u
  - k2.y -> s2.u2
"""
    d = spidersim.loads(text)
    assert len(d.layout.loops) == 2
    r = d.simulate(t_end=1.0, rtol=1e-9, atol=1e-12, jit=False)
    s = np.sin(4 * np.pi * r.t)
    assert np.max(np.abs(r["s1.y"] - s / 2)) < 1e-11
    assert np.max(np.abs(r["s2.y"] - s / 5)) < 1e-11


def test_loop_inside_subsystem_used_twice(tmp_path):
    (tmp_path / "fb.yaml").write_text("""
parameters: {K: 1.0}
blocks:
  sum: {type: Sum, signs: "+-"}
  g:   {type: Gain, k: K}
connections:
  - sum.y -> g.u
  - g.y -> sum.u2
inputs: {u: sum.u1}
outputs: {y: sum.y}
""")
    (tmp_path / "top.yaml").write_text("""
subsystems: {fb: fb.yaml}
blocks:
  u: {type: Ramp, slope: 2}
  a: {type: fb, K: 1}
  b: {type: fb, K: 9}
  xa: {type: Integrator}
connections:
  - u.y -> a.u, b.u
  - a.y -> xa.u
simulation: {t_end: 1.0, rtol: 1e-9, atol: 1e-12}
""")
    d = spidersim.load(str(tmp_path / "top.yaml"))
    assert len(d.layout.loops) == 2
    r = d.simulate(jit=False)
    assert np.max(np.abs(r["a.y"] - 2 * r.t / 2)) < 1e-11
    assert np.max(np.abs(r["b.y"] - 2 * r.t / 10)) < 1e-11
    assert _err(r["xa.y"], r.t ** 2 / 2, 1e-9, 1e-12) < 5


def test_rigid_coupling_equals_summed_inertia():
    """Two inertias held together by a coupling torque z with a1(z) - a2(z) = 0 move as
    one inertia J1 + J2 driven by the same torque."""
    text = """
blocks:
  drive: {type: Sine, amplitude: 3, f: 0.5}
  lam:   {type: AlgebraicConstraint, z0: 0}
  net1:  {type: Sum, signs: "+-"}
  j1:    {type: Inertia, J: 0.2}
  j2:    {type: Inertia, J: 0.7}
  diff:  {type: Sum, signs: "+-"}
  one:   {type: Inertia, J: 0.9}
connections:
  - drive.y -> net1.u1, one.tau
  - lam.z -> net1.u2, j2.tau
  - net1.y -> j1.tau
  - j1.a -> diff.u1
  - j2.a -> diff.u2
  - diff.y -> lam.f
simulation: {t_end: 4, rtol: 1e-10, atol: 1e-12}
"""
    d = spidersim.loads(text)
    r = d.simulate(jit=False)
    for a, b in (("j1.phi", "one.phi"), ("j2.phi", "one.phi"), ("j2.w", "one.w")):
        assert _err(r[a], r[b], 1e-10, 1e-12) < 10, a
    # coupling torque: J2 * a = J2 / (J1 + J2) * drive
    assert np.max(np.abs(r["lam.z"] - 0.7 / 0.9 * r["drive.y"])) < 1e-9


def _current_loop(L):
    return spidersim.loads(f"""
blocks:
  ref: {{type: Step, t_step: 0.001, after: 2}}
  err: {{type: Sum, signs: "+-"}}
  pi: {{type: PI, kp: 20, ki: 20000}}
  motor: {{type: DCMotor, R: 1, L: {L}, K_t: 0.05, J: 1e-4, b: 1e-5}}
connections:
  - ref.y -> err.u1
  - motor.i -> err.u2
  - err.y -> pi.e
  - pi.y -> motor.v
simulation: {{t_end: 0.05, rtol: 1e-9, atol: 1e-11, output_interval: 1e-4}}
""")


def test_motor_without_inductance_in_current_loop_is_the_limit_of_small_L():
    d0 = _current_loop(0)
    assert len(d0.layout.loops) == 1          # v -> i -> err -> pi -> v
    r0 = d0.simulate(jit=False)
    errs = []
    for L in (1e-4, 1e-5, 1e-6):
        r = _current_loop(L).simulate(jit=False)
        errs.append(np.max(np.abs(r["motor.w"] - r0["motor.w"])))
    # first-order convergence in L: each decade of L takes a decade off the difference
    assert errs[0] / errs[1] > 8 and errs[1] / errs[2] > 8, errs
    assert errs[2] < 1e-4 * np.max(np.abs(r0["motor.w"]))


def test_compiled_loop_matches_interpreted():
    d = spidersim.load(os.path.join(ROOT, "diagrams", "algebraic_loop.yaml"))
    a, b = d.simulate(jit=True), d.simulate(jit=False)
    assert np.array_equal(a.t, b.t)
    assert np.max(np.abs(a["x.y"] - b["x.y"])) <= 1e-12


UNSOLVABLE = """
blocks:
  one: {type: Constant, value: 1}
  z:   {type: AlgebraicConstraint, z0: 0.5}
  sq:  {type: Product, ops: "**"}
  f:   {type: Sum, signs: "++"}
  x:   {type: Integrator}
connections:
  - z.z -> sq.u1, sq.u2, x.u
  - sq.y -> f.u1
  - one.y -> f.u2
  - f.y -> z.f
"""


def test_unsolvable_loop_walks_the_loop_and_keeps_data(tmp_path):
    d = spidersim.loads(UNSOLVABLE)        # z^2 + 1 = 0 has no real root
    with pytest.raises(AlgebraicLoopError) as ei:
        d.simulate(t_end=1.0, jit=False)
    msg = str(ei.value)
    assert "did not converge" in msg or "singular" in msg
    assert "z.z -> sq.u" in msg and "f.y -> z.f" in msg      # the walk, port by port
    assert "residuals: z.f = " in msg and "advice:" in msg
    assert ei.value.partial is not None


def test_non_finite_residual_is_reported():
    text = """
blocks:
  u:   {type: Constant, value: -1}
  sum: {type: Sum, signs: "+-"}
  fn:  {type: Function, fn: sqrt}
  g:   {type: Gain, k: 1}
connections:
  - u.y -> sum.u1
  - g.y -> sum.u2
  - sum.y -> fn.u
  - fn.y -> g.u
"""
    with pytest.raises(AlgebraicLoopError) as ei:
        spidersim.loads(text).simulate(t_end=0.1, jit=False)
    assert "non-finite residual" in str(ei.value)
    assert "divides by zero or overflows" in str(ei.value)


def test_constraint_that_does_not_depend_on_its_unknown():
    text = """
blocks:
  u: {type: Constant, value: 1}
  z: {type: AlgebraicConstraint}
  x: {type: Integrator}
connections:
  - u.y -> z.f
  - z.z -> x.u
"""
    with pytest.raises(AlgebraicLoopError) as ei:
        spidersim.loads(text)
    assert ei.value.block == "z" and "does not depend on output 'z'" in str(ei.value)


def test_rigid_contact_whose_force_is_not_wired_back_is_refused():
    """RigidContact's residual is its own output and equals lam while inactive: that
    internal lam -> residual path must not count as closing the constraint. Without the
    force wired back into the body nothing outside depends on lam: refused at load, with
    the wiring to add, instead of a singular Jacobian at the first onset."""
    text = """
blocks:
  body: {type: PointMass, m: 1, g: [0, 0, -9.81], p0: [0, 0, 0.1]}
  wall: {type: RigidContact, point: [0, 0, 0], normal: [0, 0, 1]}
connections:
  - body.pos -> wall.pos
  - body.vel -> wall.vel
  - body.acc -> wall.acc
  - wall.constraint -> body.constraint
"""
    with pytest.raises(AlgebraicLoopError) as ei:
        spidersim.loads(text)
    msg = str(ei.value)
    assert ei.value.block == "wall"
    assert "residual 'residual' does not depend on output 'lam' through the diagram" in msg
    assert "(force, wrench)" in msg and "pos, vel, acc" in msg
    # wired back, the same diagram loads and the constraint holds the mass
    d = spidersim.loads(text + "  - wall.force -> body.f\n")
    r = d.simulate(t_end=0.3, jit=False)
    assert [e[1:] for e in r.events] == [("wall", "onset"), ("body", "impact")]
    assert r["wall.lam"][-1] == pytest.approx(9.81, rel=1e-6)
