"""Contract tests run on every registered block type (see spidersim/blocks/base.py).

Every type in ``REGISTRY`` needs at least one entry in ``EXAMPLES`` below (parameters, input
sizes, and the range of the random inputs); a new block type without one fails
``test_every_type_has_an_example``.
"""
import re

import numpy as np
import pytest

from spidersim.blocks import REGISTRY

from .harness import Probe

#: type -> list of cases: params, input sizes, random-input range [lo, hi]; "moves": every
#: declared feedthrough must visibly move its output for inputs in that range (checked for the
#: blocks whose output is a plain function of the input; over-declaring is allowed
#: elsewhere, e.g. Switch.y declares u2, which acts through the mode only). Harness options
#: "extra", "feed", "wires" for blocks that cannot stand alone.
EXAMPLES = {
    "Constant": [dict(params={"value": [1.0, -2.0]})],
    "Step": [dict(params={"t_step": 0.5})],
    "Ramp": [dict(params={"t_start": 0.2, "slope": 2.0})],
    "Sine": [dict(params={"f": 3.0, "phase": 0.3})],
    "Pulse": [dict(params={"period": 0.4, "delay": 0.1})],
    "TimeTable": [dict(params={"time": [0.0, 1.0, 2.0], "value": [0.0, 1.0, -1.0]})],
    "Gain": [dict(params={"k": 2.5}, sizes={"u": 3}, moves=True),
             dict(params={"k": [1.0, -2.0, 3.0]}, sizes={"u": 3}, moves=True)],
    "Sum": [dict(params={"signs": "+-+"}, sizes={"u1": 2, "u2": 2, "u3": 2}, moves=True),
            dict(params={"signs": "-"}, sizes={"u1": 1}, moves=True)],
    "Product": [dict(params={"ops": "*/"}, sizes={"u1": 2, "u2": 2}, lo=0.5, hi=2.0,
                     moves=True),
                dict(params={"ops": "**/"}, sizes={"u1": 1, "u2": 1, "u3": 1}, lo=0.5,
                     hi=2.0, moves=True)],
    "Function": [dict(params={"fn": fn}, sizes={"u": 2}, moves=True,
                      lo=0.1 if fn in ("log", "sqrt") else -1.0,
                      hi=1.2 if fn == "tan" else 1.0)
                 for fn in ("sin", "cos", "tan", "tanh", "atan", "exp", "log", "sqrt", "abs",
                            "square")],
    "AlgebraicConstraint": [  # f = z - c, solved for z in a loop
        dict(params={"z0": [0.5, 1.0]}, extra={"res": ("Sum", {"signs": "+-"}),
                                              "c": ("Constant", {"value": [2.0, -3.0]})},
             feed={"f": "res.y"}, wires=["blk.z -> res.u1", "c.y -> res.u2"])],
    "Integrator": [dict(params={"x0": [1.0, 2.0, 3.0]}, sizes={"u": 3})],
    "LimitedIntegrator": [dict(params={"x0": 0.2, "lower": -1.0, "upper": 1.5})],
    "StateSpace": [
        dict(params={"A": [[0.0, 1.0], [-4.0, -0.4]], "B": [[0.0], [1.0]],
                     "C": [[1.0, 0.0]]}),
        dict(params={"A": [[-1.0, 0.5], [0.0, -2.0]], "B": [[1.0, 0.0], [0.0, 1.0]],
                     "C": [[1.0, 1.0], [0.0, 1.0]], "D": [[0.5, 0.0], [0.0, 2.0]]},
             sizes={"u": 2}, moves=True),
    ],
    "TransferFunction": [dict(params={"num": [1.0], "den": [1.0, 1.0]}),
                         dict(params={"num": [1.0, 2.0], "den": [1.0, 1.0]}, moves=True),
                         dict(params={"num": [3.0, 1.0], "den": [2.0, 0.4, 4.0]})],
    "Saturation": [dict(params={"lower": -1.0, "upper": 1.0}, sizes={"u": 3}, lo=-0.9,
                        hi=0.9, moves=True),
                   dict(params={"lower": -1.0, "upper": 1.0, "zero_crossing": False},
                        sizes={"u": 3}, lo=-0.9, hi=0.9, moves=True),
                   dict(params={"lower": -1.0, "upper": 1.0}, sizes={"u": 3}, lo=-5.0,
                        hi=5.0)],
    "DeadZone": [dict(params={"start": -0.5, "end": 0.5}, sizes={"u": 2}, lo=0.6, hi=3.0,
                      moves=True),
                 dict(params={"start": -0.5, "end": 0.5}, sizes={"u": 2}, lo=-3.0, hi=-0.6,
                      moves=True),
                 dict(params={"start": -0.5, "end": 0.5, "zero_crossing": False},
                      sizes={"u": 2}, lo=-3.0, hi=3.0)],
    "Relay": [dict(params={"on_point": 0.2, "off_point": -0.2, "on_value": 3.0}),
              dict(params={"initially_on": True})],
    "Switch": [dict(params={"threshold": 0.1}, sizes={"u1": 2, "u2": 1, "u3": 2})],
    "PI": [dict(params={"kp": 2.0, "ki": 5.0, "y_min": -50.0, "y_max": 50.0}, moves=True),
           dict(params={"kp": 2.0, "ki": 5.0, "y_min": -50.0, "y_max": 50.0,
                        "antiwindup": "backcalc", "kb": 3.0}, moves=True),
           dict(params={"kp": 2.0, "ki": 5.0, "antiwindup": "none"}, moves=True)],
    "PID": [dict(params={"kp": 2.0, "ki": 5.0, "kd": 0.1, "N": 50.0, "y_min": -50.0,
                         "y_max": 50.0}, moves=True),
            dict(params={"kp": 2.0, "ki": 5.0, "kd": 0.1, "antiwindup": "backcalc",
                         "kb": 1.0}, moves=True)],
    "ZeroOrderHold": [dict(params={"Ts": 0.1}, sizes={"u": 2})],
    "UnitDelay": [dict(params={"Ts": 0.1, "x0": [1.0, 2.0]}, sizes={"u": 2})],
    "DiscreteTransferFunction": [dict(params={"num": [1.0, 0.5], "den": [1.0, -0.5],
                                              "Ts": 0.1})],
    "DiscretePI": [dict(params={"kp": 1.0, "ki": 2.0, "Ts": 0.1, "y_max": 5.0})],
    "DiscretePID": [dict(params={"kp": 1.0, "ki": 2.0, "kd": 0.1, "Ts": 0.1})],
    "Mux": [dict(params={"n": 3}, sizes={"u1": 2, "u2": 1, "u3": 3}, moves=True),
            dict(params={}, sizes={"u1": 1, "u2": 2}, moves=True)],
    "Demux": [dict(params={"sizes": [2, 1, 3]}, sizes={"u": 6}, moves=True)],
    "Selector": [dict(params={"index": [2, 0, 2]}, sizes={"u": 3}, moves=True)],
    "UnitCast": [dict(params={"unit": "N.m"}, sizes={"u": 2}, moves=True)],
    "DCMotor": [dict(params={"R": 1.5, "L": 2e-3, "K_t": 0.05, "J": 1e-4, "b": 1e-5},
                     lo=-24.0, hi=24.0),
                dict(params={"R": 1.5, "L": 0.0, "K_t": 0.05, "J": 1e-4, "b": 1e-5},
                     lo=-24.0, hi=24.0, moves=True)],
    "Inertia": [dict(params={"J": 0.5, "w0": 1.0}, moves=True)],
    "MassOnStop": [dict(params={"m": 2.0, "x0": 0.5}, lo=-5.0, hi=5.0)],
    "PointMass": [dict(params={"m": 2.0, "g": [0.0, 0.0, -9.81]}, sizes={"constraint": 4,
                                                                              "f": 3},
                       moves=True)],
    "ElasticContact": [dict(params={"K": 1e4, "D": 20.0, "mu": 0.3}, lo=-0.1, hi=0.1,
                            sizes={"pos": 3, "vel": 3}),
                       dict(params={"K": 1e4, "surface": True, "m_s": 5.0, "K_s": 2e4},
                            lo=-0.1, hi=0.1, sizes={"pos": 3, "vel": 3})],
    "RigidContact": [  # lam solved so that the point mass fed back stays on the plane
        dict(params={"engaged": True, "omega": 50.0},
             extra={"body": ("PointMass", {"m": 2.0, "g": [0.0, 0.0, -9.81]})},
             feed={"acc": "body.acc"}, wires=["blk.force -> body.f"], lo=-0.1, hi=0.1,
             sizes={"pos": 3, "vel": 3}),
        dict(params={}, extra={"body": ("PointMass", {"m": 2.0})},
             feed={"acc": "body.acc"}, wires=["blk.force -> body.f"], lo=-0.1, hi=0.1,
             sizes={"pos": 3, "vel": 3})],
    "RigidContact6": [  # lam solved so that the arm fed back holds the selected directions
        dict(params={"engaged": True, "omega": 50.0, "select": [1, 0, 1, 0, 1, 1],
                     "unilateral": [0, 0, 1, 0, 0, 0]},
             extra={"arm": ("Arm", {"q0": [0.1, 0.5, 0.0, -1.0, 0.2, 0.6, 0.0]}),
                    "tq": ("Constant", {"value": [0.0] * 7})},
             feed={"acc": "arm.flange_acc", "alpha": "arm.flange_alpha"},
             wires=["blk.wrench -> arm.f_ext", "tq.y -> arm.tau"], lo=-0.1, hi=0.1,
             sizes={"pos": 3, "rot": 9, "twist": 6}),
        dict(params={}, extra={"arm": ("Arm", {"q0": [0.1, 0.5, 0.0, -1.0, 0.2, 0.6, 0.0]}),
                    "tq": ("Constant", {"value": [0.0] * 7})},
             feed={"acc": "arm.flange_acc", "alpha": "arm.flange_alpha"},
             wires=["blk.wrench -> arm.f_ext", "tq.y -> arm.tau"], lo=-0.1, hi=0.1,
             sizes={"pos": 3, "rot": 9, "twist": 6})],
    "BrushlessMotor": [dict(params={"h3": 0.01, "unbalance": 0.02, "tau_cog": 0.01},
                            lo=-20.0, hi=20.0)],
    "NRPIDriver": [dict(params={"offset_a": 0.03, "gain_b": 0.01, "V_supply": 1e4},
                        lo=-2.0, hi=2.0, moves=True)],
    "LuGre": [dict(params={}, lo=-2.0, hi=2.0, moves=True)],
    "HarmonicDrive": [dict(params={"backlash": 2.9e-4}, lo=-1.0, hi=1.0),
                      dict(params={"stiffness": "three_slope"}, lo=-1.0, hi=1.0, moves=True),
                      dict(params={"friction": False}, lo=-1.0, hi=1.0),
                      dict(params={"friction_side": "load", "efficiency": 0.8}, lo=-1.0,
                           hi=1.0)],
    "Brake": [dict(params={"T_hold": 3.0, "t_detect": 0.1, "t_engage": 0.1})],
    "RDC": [dict(params={"f_n": 300.0, "zeta": 0.6}), dict(params={"bits": 10})],
    "Resolver": [dict(params={"bits": 12}, lo=-3.0, hi=3.0),
                 dict(params={"bits": 10, "Ts": 1e-3, "noise": 1e-3}, lo=-3.0, hi=3.0)],
    "TrapezoidalProfile": [dict(params={"q0": 0.1, "q1": 1.0, "v_max": 0.5, "a_max": 2.0})],
    "QuinticProfile": [dict(params={"q0": 0.1, "q1": 1.0, "T": 2.0})],
    "ViaPointProfile": [dict(params={"points": [0.1, 1.0, 0.5, 0.8],
                                     "times": [0.2, 1.0, 1.8, 2.5]})],
    "ConstantSpeed": [dict(params={"q0": 0.1, "speed": 0.3, "t_start": 0.2})],
    "Arm": [dict(params={"q0": [0.1, 0.5, 0.0, -1.0, 0.2, 0.6, 0.0]},
                 sizes={"tau": 7, "f_ext": 6, "constraint": 4, "constraint6": 15,
                        "tau_r": 7},
                 lo=-5.0, hi=5.0, moves=True)],
    "CartesianLineIK": [dict(params={"q0": [0.0, 0.6, 0.0, -1.3, 0.0, 0.8, 0.0]},
                             lo=-0.05, hi=0.05, moves=True)],
    "ForwardKinematics": [dict(params={}, sizes={"q": 7}, lo=-2.0, hi=2.0, moves=True)],
    "HybridForceController": [
        dict(params={"q0": [0.0, 0.6, 0.0, -1.3, 0.0, 0.8, 0.0], "kp_f": 0.5},
             sizes={"q": 7, "qd": 7, "p_ref": 3, "F_ref": 3, "F_meas": 6}, lo=-1.0,
             hi=1.0, moves=True),
        dict(params={"q0": [0.0, 0.6, 0.0, -1.3, 0.0, 0.8, 0.0],
                     "gravity": [0.0, 0.0, -9.81], "selection": [1, 1, 1, 1, 1, 1]},
             sizes={"q": 7, "qd": 7, "p_ref": 3, "F_ref": 3, "F_meas": 6})],
    "WrenchSensor": [dict(params={"f_c": 50.0}, sizes={"wrench": 6, "rot": 9}),
                     dict(params={"frame": "flange", "bias": [1, 2, 3, 0, 0, 0]},
                          sizes={"wrench": 6, "rot": 9})],
    "Jacobian": [dict(params={}, sizes={"q": 7}, lo=-2.0, hi=2.0)],
    "JointCascade": [dict(params={"ratio": 100.0, "kp_q": 5.0, "kp_w": 0.1, "ki_w": 0.5,
                                  "I_max": 1e4}, lo=-0.1, hi=0.1, moves=True),
                     dict(params={"ratio": 100.0, "Ts": 1e-3})],
}

CASES = [pytest.param(t, k, c, id=f"{t}-{k}") for t, cases in sorted(EXAMPLES.items())
         for k, c in enumerate(cases) if t in REGISTRY]
N_DRAWS = 4


def _probe(case, t):
    return Probe(t, case.get("params"), case.get("sizes"), case.get("extra"),
                 case.get("feed"), case.get("wires", ()))


def _draw(rng, probe, case):
    """Random inputs (set on the probe), random state vector and random time; the modes
    are then initialised from those inputs (as after an event)."""
    lo, hi = case.get("lo", -1.0), case.get("hi", 1.0)
    for n in probe.inputs:
        probe.set_input(n, rng.uniform(lo, hi, probe.sizes[n]))
    x = probe.x0() + rng.normal(0.0, 1.0, probe.x0().shape)
    t = rng.uniform(0.0, 3.0)
    probe.initialize(t, x)
    return t, x


@pytest.mark.parametrize("type_name", sorted(REGISTRY))
def test_every_type_has_an_example(type_name):
    if not EXAMPLES.get(type_name):
        pytest.fail(f"block type {type_name!r} ({REGISTRY[type_name].__module__}) has no "
                    f"example in EXAMPLES in tests/blocks/test_contract.py: add its "
                    f"parameters and input sizes so the contract tests cover it")


@pytest.mark.parametrize("type_name,k,case", CASES)
def test_feedthrough_honesty(type_name, k, case):
    """Moving an input an output does not declare leaves it bit-for-bit unchanged; moving a
    declared one changes it (in the ``moves`` cases)."""
    cls = REGISTRY[type_name]
    rng = np.random.default_rng(1234 + k)
    p = _probe(case, type_name)
    ft = {o: p.layout.feedthrough[o] for o in p.outputs_names}
    for o in p.outputs_names:
        if o not in p.layout.state_outputs:
            assert ft[o] == cls.feedthrough_of(o, p.layout.params), o
    for u in getattr(cls, "implicit", {}):     # through a solved unknown of the block
        for o in ft:
            if u in ft[o]:
                ft[o] = tuple(ft[o]) + tuple(ft[u])
    lo, hi = case.get("lo", -1.0), case.get("hi", 1.0)
    checked_moves = 0
    for _ in range(N_DRAWS):
        t, x = _draw(rng, p, case)
        for name in p.inputs:
            before = p.outputs(t, x)
            p.set_input(name, rng.uniform(lo, hi, p.sizes[name]))
            after = p.outputs(t, x)
            for o in p.outputs_names:
                if name not in ft[o]:
                    assert np.array_equal(before[o], after[o]), (
                        f"{type_name}.{o} moved when input '{name}' changed, but it declares "
                        f"feedthrough only from {ft[o]}: {before[o]} -> {after[o]}")
                elif case.get("moves", False):
                    assert not np.array_equal(before[o], after[o]), (
                        f"{type_name}.{o} declares feedthrough from '{name}' but did not "
                        f"move when it changed ({before[o]})")
                    checked_moves += 1
    if case.get("moves", False):
        assert checked_moves > 0, "moves=True but no declared feedthrough was probed"


def test_simple_blocks_declare_feedthrough():
    """The declared-moves check above is not vacuous for the simplest blocks."""
    assert REGISTRY["Gain"].feedthrough_of("y", {"k": np.ones(1)}) == ("u",)
    assert REGISTRY["Sum"].feedthrough_of("y", {"signs": "+-+"}) == ("u1", "u2", "u3")
    assert REGISTRY["Saturation"].feedthrough_of("y", {}) == ("u",)
    for t in ("Gain", "Sum", "Saturation"):
        assert any(c.get("moves", False) for c in EXAMPLES[t])


@pytest.mark.parametrize("type_name,k,case", CASES)
def test_outputs_and_derivatives_finite(type_name, k, case):
    rng = np.random.default_rng(99 + k)
    p = _probe(case, type_name)
    for _ in range(N_DRAWS):
        t, x = _draw(rng, p, case)
        out = p.outputs(t, x)
        for o, v in out.items():
            assert v.size == p.layout.ports[("out", o)].size
            assert np.all(np.isfinite(v)), f"{type_name}.{o} = {v} at t = {t}"
        for s, v in p.derivatives(t, x).items():
            assert np.all(np.isfinite(v)), f"d/dt {type_name}.{s} = {v} at t = {t}"
        g = p.system.guards(t, x)
        assert np.all(np.isfinite(g)), f"guards of {type_name}: {g} at t = {t}"


@pytest.mark.parametrize("type_name", sorted(REGISTRY))
def test_describe_mentions_every_parameter(type_name):
    cls = REGISTRY[type_name]
    text = cls.describe()
    assert text.startswith(type_name)
    for n, decl in cls.parameters.items():
        assert re.search(rf"^\s+{re.escape(n)} \[{re.escape(decl.unit)}\]", text, re.M), (
            f"describe() of {type_name} has no line for parameter '{n}':\n{text}")
    for n in list(cls.inputs) + list(cls.outputs):
        assert re.search(rf"^\s+{re.escape(n)} \[", text, re.M), (type_name, n)


@pytest.mark.parametrize("type_name", sorted(REGISTRY))
def test_describe_feedthrough_names_inputs(type_name):
    """The feedthrough text of describe() lists input names (``feedthrough="all"`` must not
    be spelled out letter by letter as ``a, l, l``)."""
    cls = REGISTRY[type_name]
    text = cls.describe()
    names = set(cls.inputs) | set(getattr(cls, "implicit", {}))  # a solved unknown
    for case in EXAMPLES.get(type_name, []):
        names |= set(cls.input_names(cls.validate_params(dict(case.get("params", {})))))
    for m in re.finditer(r"direct feedthrough from ([^)]*)\)", text):
        listed = [s.strip() for s in m.group(1).split(",")]
        bad = [s for s in listed if s not in names and s != "all inputs"]
        assert not bad, (f"describe() of {type_name} lists feedthrough from {listed}, "
                         f"which are not inputs of the block:\n{text}")


@pytest.mark.parametrize("type_name", sorted(REGISTRY))
def test_parameters_have_doc_and_unit(type_name):
    cls = REGISTRY[type_name]
    for n, decl in cls.parameters.items():
        assert isinstance(decl.doc, str) and decl.doc.strip(), f"{type_name}.{n}: no doc"
        assert isinstance(decl.unit, str) and decl.unit.strip(), f"{type_name}.{n}: no unit"
        assert " " not in decl.unit, f"{type_name}.{n}: unit {decl.unit!r} has a space"
