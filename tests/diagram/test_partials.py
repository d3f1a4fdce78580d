"""The analytic Jacobian assembled from the blocks' declared partials (issue 14 item 3).

Guards: each block's ``partials`` kernel against finite differences of its own ``output``
and ``derivative`` (through a diagram whose every input and output is a state, so that all
four matrices show in ``df/dx``); the chain rule of the generator against closed forms
(a StateSpace alone: ``J = A``; a loop through Sum and Gain derived by hand); the
fallbacks (a block without partials on a path, an algebraic loop) and the runs of the
stiff methods with the analytic Jacobian against those with finite differences.
"""
import os

import numpy as np
import pytest
import yaml

import spidersim
from spidersim.diagram.jacobian import plan
from spidersim.errors import SpidersimError

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))


def _yaml(name, type_name, params):
    entry = {"type": type_name, **params}
    return f"  {name}: " + yaml.safe_dump(entry, default_flow_style=True,
                                          width=10**6).strip()


def _wrapped(type_name, params, sizes):
    """Diagram text: block ``blk`` with each input ``n`` fed by an Integrator ``in_n``
    (itself fed by a zero Constant) and each output that is not a state integrated by
    ``out_o``: every partial of ``blk`` is then an entry of the diagram's ``df/dx``."""
    d0 = spidersim.loads("name: probe\nblocks:\n" + _yaml("blk", type_name, params) + "\n"
                         + "".join(_yaml(f"c_{n}", "Constant", {"value": [0.0] * s}) + "\n"
                                   for n, s in sizes.items())
                         + "connections:\n" + "".join(f"  - c_{n}.y -> blk.{n}\n"
                                                      for n in sizes))
    bl = d0.layout.blocks["blk"]
    outs = [o for o in bl.outputs if o not in bl.state_outputs]
    rng = np.random.default_rng(3)
    lines = ["name: probe", "blocks:", _yaml("blk", type_name, params)]
    conns = []
    for n in bl.inputs:
        s = sizes.get(n, 1)
        lines.append(_yaml(f"in_{n}", "Integrator",
                           {"x0": rng.uniform(0.2, 1.0, s).round(3).tolist()}))
        lines.append(_yaml(f"c_{n}", "Constant", {"value": [0.0] * s}))
        conns += [f"c_{n}.y -> in_{n}.u", f"in_{n}.y -> blk.{n}"]
    for o in outs:
        lines.append(_yaml(f"out_{o}", "Integrator", {}))
        conns.append(f"blk.{o} -> out_{o}.u")
    lines += ["connections:"] + [f"  - {c}" for c in conns]
    return "\n".join(lines) + "\n"


def _fd_jacobian(system, t, x):
    """Central differences of ``system.rhs`` (step 1e-6 (1 + |x_j|))."""
    n = x.size
    J = np.zeros((n, n))
    for j in range(n):
        h = 1e-6 * (1.0 + abs(x[j]))
        xp, xm = x.copy(), x.copy()
        xp[j] += h
        xm[j] -= h
        J[:, j] = (system.rhs(t, xp) - system.rhs(t, xm)) / (2 * h)
    return J


BLOCK_CASES = [
    ("Gain", {"k": 2.5}, {"u": 3}),
    ("Gain", {"k": [1.0, -2.0, 3.0]}, {"u": 3}),
    ("Sum", {"signs": "+-+"}, {"u1": 2, "u2": 2, "u3": 2}),
    ("Sum", {"signs": "-"}, {"u1": 1}),
    ("Integrator", {"x0": [1.0, 2.0]}, {"u": 2}),
    ("LimitedIntegrator", {"x0": 0.2, "lower": -1.0, "upper": 1.5}, {"u": 1}),
    ("StateSpace", {"A": [[0.0, 1.0], [-4.0, -0.4]], "B": [[0.0], [1.0]],
                    "C": [[1.0, 0.0]]}, {"u": 1}),
    ("StateSpace", {"A": [[-1.0, 0.5], [0.0, -2.0]], "B": [[1.0, 0.0], [0.0, 1.0]],
                    "C": [[1.0, 1.0], [0.0, 1.0]], "D": [[0.5, 0.0], [0.0, 2.0]]},
     {"u": 2}),
    ("TransferFunction", {"num": [3.0, 1.0], "den": [2.0, 0.4, 4.0]}, {"u": 1}),
    ("TransferFunction", {"num": [1.0, 2.0], "den": [1.0, 1.0]}, {"u": 1}),
    ("Mux", {"n": 3}, {"u1": 2, "u2": 1, "u3": 2}),
    ("Demux", {"sizes": [2, 1]}, {"u": 3}),
    ("Selector", {"index": [2, 0, 2]}, {"u": 3}),
    ("UnitCast", {"unit": "A"}, {"u": 2}),
    ("DCMotor", {"R": 1.3, "L": 2e-3, "K_t": 0.07, "J": 2e-4, "b": 3e-4},
     {"v": 1, "tau_load": 1}),
    ("DCMotor", {"R": 1.3, "L": 0.0, "K_t": 0.07, "J": 2e-4, "b": 3e-4},
     {"v": 1, "tau_load": 1}),
    ("BrushlessMotor", {"p": 3, "R": 1.5, "L": 0.05, "K_t": 0.15, "J": 0.02, "b": 0.01,
                        "h3": 0.05, "unbalance": 0.1, "tau_cog": 0.02},
     {"v_a": 1, "v_b": 1, "tau_load": 1}),
    ("NRPIDriver", {"kp": 2.0, "ki": 300.0, "kb": 50.0, "V_supply": 100.0, "I_max": 4.0,
                    "gain_a": 0.02, "gain_b": -0.01, "offset_a": 0.03, "offset_b": 0.0},
     {"i_cmd": 1, "theta_e": 1, "i_a": 1, "i_b": 1}),
    ("NRPIDriver", {"kp": 20.0, "ki": 300.0, "kb": 50.0, "V_supply": 0.5, "I_max": 0.3,
                    "gain_a": 0.02}, {"i_cmd": 1, "theta_e": 1, "i_a": 1, "i_b": 1}),
    ("HarmonicDrive", {"ratio": 5.0, "K1": 40.0, "d": 0.5}, {"phi_m": 1, "w_m": 1,
                                                              "phi_l": 1, "w_l": 1}),
    # three-slope law: deflections of the random states (|delta| < 1.5) on the first
    # segment (T1 / K1 = 2.5), the second (0.01 .. 3.3) and the third (beyond 0.009)
    ("HarmonicDrive", {"ratio": 5.0, "stiffness": "three_slope", "K1": 40.0, "K2": 60.0,
                       "K3": 90.0, "T1": 100.0, "T2": 300.0, "d": 0.5,
                       "friction_side": "load", "efficiency": 0.8, "T_c": 0.3, "T_s": 0.5,
                       "v_s": 0.7}, {"phi_m": 1, "w_m": 1, "phi_l": 1, "w_l": 1}),
    ("HarmonicDrive", {"ratio": 5.0, "stiffness": "three_slope", "K1": 40.0, "K2": 60.0,
                       "K3": 90.0, "T1": 0.4, "T2": 200.0, "d": 0.5},
     {"phi_m": 1, "w_m": 1, "phi_l": 1, "w_l": 1}),
    ("HarmonicDrive", {"ratio": 5.0, "stiffness": "three_slope", "K1": 40.0, "K2": 60.0,
                       "K3": 90.0, "T1": 0.1, "T2": 0.5, "d": 0.5, "friction": False},
     {"phi_m": 1, "w_m": 1, "phi_l": 1, "w_l": 1}),
    ("HarmonicDrive", {"ratio": 5.0, "K1": 40.0, "d": 0.5, "backlash": 0.02},  # in the gap
     {"phi_m": 1, "w_m": 1, "phi_l": 1, "w_l": 1}),
    ("Resolver", {"bits": 0}, {"theta": 1, "w": 1}),
    ("Resolver", {"bits": 12}, {"theta": 1, "w": 1}),
    ("RDC", {"f_n": 3.0, "zeta": 0.6}, {"theta": 1}),
    ("RDC", {"f_n": 3.0, "zeta": 0.6, "bits": 12, "w_bits": 12, "w_max": 100.0},
     {"theta": 1}),
    ("JointCascade", {"ratio": 10.0, "kp_q": 2.0, "kp_w": 0.3, "ki_w": 1.5, "ff": 0.7,
                      "I_max": 50.0, "kb": 4.0}, {"q_ref": 1, "qd_ref": 1, "q": 1, "w_m": 1}),
    ("JointCascade", {"ratio": 10.0, "kp_q": 2.0, "kp_w": 0.3, "ki_w": 1.5, "ff": 0.7,
                      "I_max": 0.5, "kb": 4.0}, {"q_ref": 1, "qd_ref": 1, "q": 1, "w_m": 1}),
    *[("Function", {"fn": f}, {"u": 2}) for f in ("sin", "cos", "tan", "tanh", "atan",
                                                   "exp", "log", "sqrt", "abs", "square")],
    ("DeadZone", {"start": -0.1, "end": 0.2, "zero_crossing": False}, {"u": 3}),
    ("Inertia", {"J": 0.3}, {"tau": 1}),
    ("LuGre", {}, {"v": 1}),
    ("LuGre", {"delta": 1.5, "T_c": 0.02, "T_s": 0.09, "v_s": 0.4}, {"v": 1}),
    ("Saturation", {"lower": -0.4, "upper": 0.9}, {"u": 3}),
    ("Saturation", {"lower": -0.4, "upper": 0.9, "zero_crossing": False}, {"u": 3}),
    ("PI", {"kp": 2.0, "ki": 5.0, "y_min": -50.0, "y_max": 50.0}, {"e": 1}),
    ("PI", {"kp": 2.0, "ki": 5.0, "y_min": -0.5, "y_max": 0.5, "antiwindup": "backcalc",
            "kb": 3.0}, {"e": 1}),
    ("PI", {"kp": 2.0, "ki": 5.0, "antiwindup": "none"}, {"e": 1}),
    ("PID", {"kp": 2.0, "ki": 5.0, "kd": 0.3, "N": 20.0, "y_min": -50.0, "y_max": 50.0},
     {"e": 1}),
    ("PID", {"kp": 2.0, "ki": 5.0, "kd": 0.3, "N": 20.0, "y_min": -0.5, "y_max": 0.5,
             "antiwindup": "backcalc", "kb": 3.0}, {"e": 1}),
    ("PID", {"kp": 2.0, "ki": 5.0, "kd": 0.3, "N": 20.0, "antiwindup": "none"}, {"e": 1}),
    ("Product", {"ops": "**"}, {"u1": 2, "u2": 2}),
    ("Product", {"ops": "*/*"}, {"u1": 2, "u2": 2, "u3": 2}),
    ("Product", {"ops": "/**/"}, {"u1": 1, "u2": 1, "u3": 1, "u4": 1}),
    ("Product", {"ops": "/"}, {"u1": 3}),
    ("Switch", {"threshold": 0.5}, {"u1": 2, "u2": 1, "u3": 2}),      # mode 0: u3 passed
]


def test_every_block_with_partials_has_a_case():
    """A block type that declares ``partials`` is checked above: a new one without a case
    fails here."""
    from spidersim.blocks import REGISTRY
    declared = {n for n, c in REGISTRY.items() if c.has_kernel("partials")
                and not n.startswith("_")}
    assert declared == {c[0] for c in BLOCK_CASES}


@pytest.mark.parametrize("type_name,params,sizes", BLOCK_CASES,
                         ids=[f"{c[0]}-{k}" for k, c in enumerate(BLOCK_CASES)])
def test_block_partials_match_finite_differences(type_name, params, sizes):
    """Each block's declared partials (all four matrices, through a diagram that makes
    every input and output a state) equal central differences of its own equations at a
    random state, to 1e-7 of the largest entry: a wrong sign, a missing entry or an entry
    in the wrong row/column fails."""
    d = spidersim.loads(_wrapped(type_name, params, sizes))
    assert plan(d.layout).reason == ""
    s = d.compile(jit=False, jacobian=True)
    assert s.analytic_jacobian
    rng = np.random.default_rng(7)
    x = s.x0 + rng.uniform(-0.5, 0.5, s.n_x)
    J = s.jacobian(0.3, x)
    J_fd = _fd_jacobian(s, 0.3, x)
    scale = max(1.0, np.abs(J_fd).max())
    np.testing.assert_allclose(J, J_fd, rtol=0, atol=1e-7 * scale)
    assert np.abs(J_fd).max() > 0       # the case exercises something


GEAR_GAP = ({"ratio": 5.0, "K1": 40.0, "d": 0.5, "backlash": 0.02},
            {"phi_m": 1, "w_m": 1, "phi_l": 1, "w_l": 1})
MODE_CASES = [
    ("HarmonicDrive", *GEAR_GAP, "contact", [1.0]),
    ("HarmonicDrive", *GEAR_GAP, "contact", [-1.0]),
    ("LimitedIntegrator", {"x0": 0.2, "lower": -1.0, "upper": 1.5}, {"u": 1}, "m", [-1.0]),
    ("LimitedIntegrator", {"x0": 0.2, "lower": -1.0, "upper": 1.5}, {"u": 1}, "m", [1.0]),
    ("DeadZone", {"start": -0.1, "end": 0.2}, {"u": 3}, "m", [-1.0, 0.0, 1.0]),
    ("Saturation", {"lower": -0.4, "upper": 0.9}, {"u": 3}, "m", [-1.0, 0.0, 1.0]),
    ("Saturation", {"lower": -0.4, "upper": 0.9}, {"u": 3}, "m", [1.0, 1.0, -1.0]),
    ("PID", {"kp": 2.0, "ki": 5.0, "kd": 0.3, "N": 20.0, "y_min": -0.5, "y_max": 0.5},
     {"e": 1}, "clamp", [1.0]),
    ("PID", {"kp": 2.0, "ki": 5.0, "kd": 0.3, "N": 20.0, "y_min": -0.5, "y_max": 0.5},
     {"e": 1}, "clamp", [-2.0]),
    ("PI", {"kp": 2.0, "ki": 5.0, "y_min": -0.5, "y_max": 0.5}, {"e": 1}, "clamp", [1.0]),
    ("PI", {"kp": 2.0, "ki": 5.0, "y_min": -0.5, "y_max": 0.5}, {"e": 1}, "clamp", [-1.0]),
    ("PI", {"kp": 2.0, "ki": 5.0, "y_min": -0.5, "y_max": 0.5}, {"e": 1}, "clamp", [2.0]),
    ("PI", {"kp": 2.0, "ki": 5.0, "y_min": -0.5, "y_max": 0.5}, {"e": 1}, "clamp", [-2.0]),
    ("Switch", {"threshold": 0.5}, {"u1": 2, "u2": 1, "u3": 2}, "first", [1.0]),
]


@pytest.mark.parametrize("type_name,params,sizes,mode,values", MODE_CASES,
                         ids=[f"{c[0]}-{c[3]}={c[4]}" for c in MODE_CASES])
def test_block_partials_follow_the_modes(type_name, params, sizes, mode, values):
    """The partials of blocks whose equations change with their event modes (held at a
    limit, saturated, clamped or sliding), with the mode set to each non-default value:
    equal to central differences of the equations in that mode (the modes stay fixed while
    differencing, as between events). A kernel that ignores the mode fails (the free
    branch's derivatives differ from the held/saturated/clamped ones here)."""
    d = spidersim.loads(_wrapped(type_name, params, sizes))
    s = d.compile(jit=False, jacobian=True)
    a, b = d.layout.blocks["blk"].modes[mode]
    s.modes[a:b] = values
    rng = np.random.default_rng(11)
    x = s.x0 + rng.uniform(-0.5, 0.5, s.n_x)
    J = s.jacobian(0.3, x)
    J_fd = _fd_jacobian(s, 0.3, x)
    scale = max(1.0, np.abs(J_fd).max())
    np.testing.assert_allclose(J, J_fd, rtol=0, atol=1e-7 * scale)
    s.modes[a:b] = 0.0                   # the free branch differs: the mode matters here
    assert np.abs(_fd_jacobian(s, 0.3, x) - J_fd).max() > 1e-3 * scale


TWICE = """
name: twice
blocks:
  m: {type: BrushlessMotor, p: 3, R: 1.5, L: 0.05, K_t: 0.15, J: 0.02, b: 0.01}
  g: {type: Gain, k: -2.0}
  va: {type: Constant, value: 1.0}
  vb: {type: Constant, value: 0.5}
  acc: {type: Integrator}
connections:
  - va.y -> m.v_a
  - vb.y -> m.v_b
  - m.tau -> g.u
  - g.y -> m.tau_load
  - m.dw -> acc.u
"""


@pytest.mark.parametrize("jit", [False, True])
def test_block_called_twice(jit):
    """A BrushlessMotor whose torque returns as its load through a Gain is evaluated in two
    calls (``tau`` without feedthrough first, ``dw`` after the Gain). Its outputs'
    sensitivities are chained where each is made (dependency order), not at its last call:
    in call order the Gain read the torque's rows before they were written (found in review:
    the first Jacobian off by a factor 3, later ones left from the previous state). Equal to
    central differences at a state and then at another one."""
    d = spidersim.loads(TWICE)
    assert [w for k, w in d.layout.calls if k == "call"].count("m") == 2
    assert plan(d.layout).reason == ""
    s = d.compile(jit=jit, jacobian=True)
    x1 = s.x0 + np.array([0.3, -0.2, 1.0, 0.4, 0.1])
    x2 = x1 + np.array([0.5, -0.7, 3.0, 1.1, 0.0])
    for x in (x1, x2):
        J, J_fd = s.jacobian(0.0, x), _fd_jacobian(s, 0.0, x)
        np.testing.assert_allclose(J, J_fd, rtol=0, atol=1e-7 * np.abs(J_fd).max())
        assert abs(J[2, 0]) > 1.0              # the torque path through the Gain is there


STATE_SPACE = """
name: ss
blocks:
  ss: {type: StateSpace, A: [[-1000.0, 1.0, 0.0], [0.0, -20.0, 5.0], [2.0, 0.0, -0.5]],
       B: [[1.0], [0.0], [0.0]], C: [[1.0, 0.0, 0.0]], x0: [1.0, -1.0, 2.0]}
  u: {type: Sine, f: 1.0}
connections:
  - u.y -> ss.u
simulation: {t_end: 2.0, method: ROS34PW2, rtol: 1e-7, atol: 1e-10}
"""


def test_state_space_jacobian_is_A_exactly():
    """A StateSpace fed by a source: the compiled analytic Jacobian is ``A`` bit for bit
    (the source depends on no state and needs no partials)."""
    d = spidersim.loads(STATE_SPACE)
    s = d.compile(jit=True, jacobian=True)
    A = np.array([[-1000.0, 1.0, 0.0], [0.0, -20.0, 5.0], [2.0, 0.0, -0.5]])
    J = s.jacobian(0.7, np.array([0.3, 0.1, -2.0]))
    assert np.array_equal(J, A)


LOOP = """
name: chain
blocks:
  x1: {type: Integrator, x0: 1.0}
  x2: {type: Integrator, x0: 0.0}
  e: {type: Sum, signs: "+-"}
  k: {type: Gain, k: 4.0}
  c: {type: Gain, k: 0.5}
  r: {type: Step, t_step: 0.1}
connections:
  - r.y -> e.u1
  - x1.y -> e.u2
  - e.y -> k.u
  - k.y -> x2.u
  - x2.y -> c.u
  - c.y -> x1.u
"""


@pytest.mark.parametrize("jit", [False, True])
def test_chain_through_sum_and_gain_by_hand(jit):
    """``x1' = 0.5 x2``, ``x2' = 4 (r - x1)``: by hand ``J = [[0, 0.5], [-4, 0]]``; the chain
    Sum -> Gain and Gain -> Integrator assembles exactly that (interpreted and compiled)."""
    d = spidersim.loads(LOOP)
    s = d.compile(jit=jit, jacobian=True)
    J = s.jacobian(0.0, np.array([0.3, -0.2]))
    assert np.array_equal(J, np.array([[0.0, 0.5], [-4.0, 0.0]]))


def test_fallback_when_a_block_on_a_path_has_no_partials():
    """A block without partials (a Brake, its torque a function of the speed input)
    between a state and a derivative: no analytic Jacobian, the reason names the block,
    ``jacobian='analytic'`` is refused with it, and the run uses finite differences
    (stats) and still works."""
    text = LOOP.replace("  k: {type: Gain, k: 4.0}", "  k: {type: Brake}").replace(
        "e.y -> k.u", "e.y -> k.w").replace("k.y -> x2.u", "k.tau -> x2.u")
    d = spidersim.loads(text)
    assert "block 'k' (Brake)" in plan(d.layout).reason
    s = d.compile(jit=False, jacobian=True)
    assert not s.analytic_jacobian and s.jacobian(0.0, s.x0) is None
    r = d.simulate(t_end=0.5, method="ROS34PW2", jit=True)
    assert r.stats["jacobian"] == "finite differences"
    with pytest.raises(SpidersimError, match=r"no analytic Jacobian .*block 'k'"):
        d.simulate(t_end=0.5, method="ROS34PW2", jacobian="analytic")


def test_blocks_off_the_state_paths_need_no_partials():
    """A block without partials (a Relay) between a source and the loop: its output
    depends on no state, so the Jacobian is still analytic (and zero there)."""
    text = LOOP.replace("  r: {type: Step, t_step: 0.1}",
                        "  r: {type: Step, t_step: 0.1}\n  f: {type: Relay}")
    text = text.replace("  - r.y -> e.u1", "  - r.y -> f.u\n  - f.y -> e.u1")
    d = spidersim.loads(text)
    assert plan(d.layout).reason == ""
    s = d.compile(jit=False, jacobian=True)
    assert np.array_equal(s.jacobian(0.0, s.x0), np.array([[0.0, 0.5], [-4.0, 0.0]]))


def test_fallback_through_an_algebraic_loop():
    """``y = x1 - 0.5 y`` (a Sum and a Gain in an algebraic loop) on the path into a
    derivative: no analytic Jacobian (the loop is not linearised), finite differences."""
    text = """
name: aloop
blocks:
  x1: {type: Integrator, x0: 1.0}
  s: {type: Sum, signs: "+-"}
  g: {type: Gain, k: 0.5}
  m: {type: Gain, k: -1.0}
connections:
  - x1.y -> s.u1
  - s.y -> g.u
  - g.y -> s.u2
  - s.y -> m.u
  - m.y -> x1.u
"""
    d = spidersim.loads(text)
    assert "algebraic loop" in plan(d.layout).reason
    assert not d.compile(jit=False, jacobian=True).analytic_jacobian


@pytest.mark.parametrize("method", ["ROS34PW2", "NDF"])
def test_stiff_runs_same_with_fewer_evaluations(method):
    """A stiff linear StateSpace (eigenvalues about -1000, -20 and -0.5) from a given
    state, unforced: with the analytic Jacobian the run takes the same steps and reaches
    the same state as with finite differences (1e-6 relative: the Jacobians differ by the
    differences' error only), both match the closed form ``expm(2 A) x0`` (1e-4), and the
    analytic run makes exactly ``groups - 1`` fewer right-hand-side evaluations per
    Jacobian (one evaluation instead of one per column group)."""
    d = spidersim.loads(STATE_SPACE.replace("u: {type: Sine, f: 1.0}",
                                            "u: {type: Constant, value: 0.0}"))
    ra = d.simulate(method=method, jacobian="analytic")
    rf = d.simulate(method=method, jacobian="fd")
    assert ra.stats["jacobian"] == "analytic"
    assert rf.stats["jacobian"] == "finite differences"
    xa, xf = ra.final[1], rf.final[1]
    np.testing.assert_allclose(xa, xf, rtol=1e-6, atol=1e-9)
    from scipy.linalg import expm
    A = np.array([[-1000.0, 1.0, 0.0], [0.0, -20.0, 5.0], [2.0, 0.0, -0.5]])
    exact = expm(A * 2.0) @ np.array([1.0, -1.0, 2.0])
    np.testing.assert_allclose(xa, exact, rtol=1e-4, atol=1e-6)
    ng = rf.stats["jacobian_groups"]
    assert ng >= 2
    assert ra.stats["steps"] == rf.stats["steps"]
    assert ra.stats["jacobian_calls"] == rf.stats["jacobian_calls"] >= 1
    assert rf.stats["rhs_calls"] - ra.stats["rhs_calls"] == \
        (ng - 1) * ra.stats["jacobian_calls"]


def test_jacobian_option_is_checked():
    """``jacobian`` other than auto, fd or analytic is refused by name; DP54 ignores it
    (no Jacobian)."""
    d = spidersim.loads(LOOP)
    with pytest.raises(SpidersimError, match="jacobian must be 'auto', 'fd' or 'analytic'"):
        d.simulate(t_end=0.1, method="ROS34PW2", jacobian="exact")
    r = d.simulate(t_end=0.1, method="DP54", jacobian="analytic")
    assert r.stats["jacobian"] == "none"


def test_compiled_jacobian_allocates_nothing():
    """The system function with its ``JACOBIAN`` branch (and everything numba links into
    it: the kernels, the chain helpers, ``outputs``) calls no NRT allocation: the
    workspace lives in ``sig``, the matrices are borrowed views."""
    import re
    import numba
    from spidersim.solver.sysfn import SYSTEM_SIG
    text = LOOP.replace("x1: {type: Integrator, x0: 1.0}",
                        "x1: {type: StateSpace, A: [[-1.0]], B: [[1.0]], C: [[1.0]]}")
    s = spidersim.loads(text).compile(jit=True, jacobian=True)
    assert np.array_equal(s.jacobian(0.0, s.x0), np.array([[-1.0, 0.5], [-4.0, 0.0]]))
    # compiled afresh here (the module's own was loaded from numba's cache, without IR);
    # the IR holds the callees numba links in
    fresh = numba.cfunc(SYSTEM_SIG)(s.module._system._pyfunc)
    ir = fresh.inspect_llvm()
    assert "Gain6output" in ir and "partials" in ir and "chain" in ir
    calls = set(re.findall(r"@(NRT_\w+)", ir))
    assert not {c for c in calls if "alloc" in c.lower() or "Allocate" in c}, calls


def test_jacobian_generated_only_when_asked():
    """The analytic Jacobian costs compile time, so a module has it only when asked
    (``compile(jacobian=True)``, or a run with ROS34PW2 or NDF): DP54 and LSODA runs
    compile the module without it; a stiff run then makes it again with it."""
    d = spidersim.loads(LOOP)
    s = d.compile(jit=False)
    assert not s.analytic_jacobian and s.jacobian(0.0, s.x0) is None
    assert "task == 8:\n        return 0.0" in d.source(jit=False)
    d.simulate(t_end=0.1, method="DP54", jit=False)
    assert not d.compile(jit=False).analytic_jacobian
    r = d.simulate(t_end=0.1, method="NDF")
    assert r.stats["jacobian"] == "analytic"
    assert d.compile(jit=True).analytic_jacobian      # the superset is kept


@pytest.mark.parametrize("name", ["joint_ripple.yaml", "joint_step.yaml"])
def test_joint_diagrams_have_an_exact_jacobian(name):
    """diagrams/joint_ripple.yaml (NRPI driver, brushless motor called twice, ripple
    sources on) and joint_step.yaml (the whole SPIDER joint subsystem: driver, motor,
    Harmonic Drive with LuGre, resolvers, RDC, sampled cascade, a load inertia): the
    analytic Jacobian equals central differences at the initial state and at a state with
    currents, speeds, angles, bristles and integrals off their start."""
    d = spidersim.load(os.path.join(ROOT, "diagrams", name))
    assert plan(d.layout).reason == ""
    s = d.compile(jit=False, jacobian=True)
    rng = np.random.default_rng(5)
    for x in (s.x0.copy(), s.x0 + rng.uniform(-0.5, 0.5, s.n_x)):
        J, J_fd = s.jacobian(0.01, x), _fd_jacobian(s, 0.01, x)
        np.testing.assert_allclose(J, J_fd, rtol=0, atol=1e-6 * np.abs(J_fd).max())
