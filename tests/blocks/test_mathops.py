"""Gain, Sum and Product against their formulas, through the compiled (interpreted) system."""
import numpy as np
import pytest

import spidersim
from spidersim import ParameterError

from .harness import Probe, simulate

RNG = np.random.default_rng(7)


def test_gain_scalar_on_a_vector():
    p = Probe("Gain", {"k": -2.5}, sizes={"u": 4})
    u = RNG.normal(size=4)
    p.set_input("u", u)
    np.testing.assert_array_equal(p.outputs()["y"], -2.5 * u)


def test_gain_per_element():
    k = np.array([1.0, -3.0, 0.5])
    p = Probe("Gain", {"k": k}, sizes={"u": 3})
    u = RNG.normal(size=3)
    p.set_input("u", u)
    np.testing.assert_array_equal(p.outputs()["y"], k * u)
    p.set_param("k", [2.0, 2.0, -1.0])            # numeric parameter, no recompilation
    np.testing.assert_array_equal(p.outputs()["y"], np.array([2.0, 2.0, -1.0]) * u)


def test_gain_size_mismatch_is_rejected():
    text = ("blocks:\n  c: {type: Constant, value: [1, 2, 3]}\n  g: {type: Gain, k: [1, 2]}\n"
            "connections:\n  - c.y -> g.u\n")
    with pytest.raises(ParameterError, match="'k' has 2 elements"):
        spidersim.loads(text)


def test_gain_in_a_simulation():
    r = simulate("blocks:\n  s: {type: Sine, amplitude: 2, f: 1.5}\n  g: {type: Gain, k: -4}\n"
                 "connections:\n  - s.y -> g.u\n", t_end=1.0, output_interval=0.05)
    np.testing.assert_allclose(r["g.y"], -8.0 * np.sin(3.0 * np.pi * r.t), rtol=0, atol=1e-13)


def test_sum_three_inputs_with_signs():
    p = Probe("Sum", {"signs": "+-+"}, sizes={"u1": 3, "u2": 3, "u3": 3})
    assert p.inputs == ["u1", "u2", "u3"]
    u = RNG.normal(size=(3, 3))
    for n, v in zip(p.inputs, u):
        p.set_input(n, v)
    np.testing.assert_allclose(p.outputs()["y"], u[0] - u[1] + u[2], rtol=1e-15, atol=1e-15)


@pytest.mark.parametrize("signs", ["-", "--", "+-", "-+-+"])
def test_sum_sign_strings(signs):
    n = len(signs)
    p = Probe("Sum", {"signs": signs}, sizes={f"u{i + 1}": 2 for i in range(n)})
    u = RNG.normal(size=(n, 2))
    for i, v in enumerate(u):
        p.set_input(f"u{i + 1}", v)
    s = np.array([1.0 if c == "+" else -1.0 for c in signs])
    np.testing.assert_allclose(p.outputs()["y"], s @ u, rtol=1e-14, atol=1e-15)


@pytest.mark.parametrize("signs", ["", "+*", "+ -"])
def test_sum_rejects_bad_signs(signs):
    with pytest.raises(ParameterError, match="signs"):
        spidersim.loads(f"blocks:\n  s: {{type: Sum, signs: '{signs}'}}\n")


def test_sum_rejects_different_input_sizes():
    text = ("blocks:\n  a: {type: Constant, value: [1, 2]}\n  b: {type: Constant, value: 3}\n"
            "  s: {type: Sum, signs: '+-'}\nconnections:\n  - a.y -> s.u1\n  - b.y -> s.u2\n")
    with pytest.raises(ParameterError, match="same size"):
        spidersim.loads(text)


def test_product_multiply_divide():
    p = Probe("Product", {"ops": "*/"}, sizes={"u1": 3, "u2": 3})
    a, b = np.array([2.0, -3.0, 0.5]), np.array([4.0, 0.25, -2.0])
    p.set_input("u1", a)
    p.set_input("u2", b)
    np.testing.assert_allclose(p.outputs()["y"], a / b, rtol=1e-15)


@pytest.mark.parametrize("ops", ["/", "**", "**/", "/*/"])
def test_product_operator_strings(ops):
    n = len(ops)
    p = Probe("Product", {"ops": ops}, sizes={f"u{i + 1}": 2 for i in range(n)})
    u = RNG.uniform(0.5, 2.0, size=(n, 2)) * RNG.choice([-1.0, 1.0], size=(n, 2))
    expect = np.ones(2)
    for i, (o, v) in enumerate(zip(ops, u)):
        p.set_input(f"u{i + 1}", v)
        expect = expect * v if o == "*" else expect / v
    np.testing.assert_allclose(p.outputs()["y"], expect, rtol=1e-14)


FUNCS = {"sin": np.sin, "cos": np.cos, "tan": np.tan, "tanh": np.tanh, "atan": np.arctan,
         "exp": np.exp, "log": np.log, "sqrt": np.sqrt, "abs": np.abs, "square": np.square}


@pytest.mark.parametrize("fn", sorted(FUNCS))
def test_function_elementwise(fn):
    u = np.array([0.1, 0.7, 1.3, 2.9]) * (1 if fn in ("log", "sqrt") else np.array(
        [-1, 1, -1, 1]))
    p = Probe("Function", {"fn": fn}, sizes={"u": 4})
    p.set_input("u", u)
    np.testing.assert_allclose(p.outputs()["y"], FUNCS[fn](u), rtol=1e-15, atol=0)


def test_function_domain_errors_give_nan_and_are_reported():
    p = Probe("Function", {"fn": "log"}, sizes={"u": 3})
    p.set_input("u", [0.0, -1.0, 1.0])
    y = p.outputs()["y"]
    assert y[0] == -np.inf and np.isnan(y[1]) and y[2] == 0.0
    p = Probe("Function", {"fn": "sqrt"})
    p.set_input("u", -4.0)
    assert np.isnan(p.outputs()["y"][0])
    d = spidersim.loads("blocks:\n  s: {type: Sine, offset: 0.5}\n"
                        "  f: {type: Function, fn: sqrt}\n  i: {type: Integrator}\n"
                        "connections:\n  - s.y -> f.u\n  - f.y -> i.u\n")
    with pytest.raises(spidersim.IntegrationError, match="f.y"):
        d.simulate(t_end=1.0, jit=False)


def test_function_rejects_unknown_name():
    with pytest.raises(ParameterError, match="must be one of"):
        spidersim.loads("blocks:\n  f: {type: Function, fn: sinh}\n  c: {type: Constant}\n"
                        "connections:\n  - c.y -> f.u\n")


def _constraint(z0, c):
    """f = z*z - c = 0 through an AlgebraicConstraint (Newton from z0)."""
    return (f"blocks:\n  c: {c}\n  sq: {{type: Product}}\n  res: {{type: Sum, signs: '+-'}}\n"
            f"  ac: {{type: AlgebraicConstraint, z0: {z0}}}\nconnections:\n"
            "  - ac.z -> sq.u1, sq.u2\n  - sq.y -> res.u1\n  - c.y -> res.u2\n"
            "  - res.y -> ac.f\n")


@pytest.mark.parametrize("z0,sign", [(1.0, 1.0), (-1.0, -1.0)])
def test_algebraic_constraint_square_root(z0, sign):
    """z^2 = 2 + sin(2 pi t): z = +-sqrt(2 + sin(2 pi t)), the root nearest the guess."""
    r = simulate(_constraint(z0, "{type: Sine, offset: 2}"), t_end=1.0, output_interval=0.01)
    np.testing.assert_allclose(r["ac.z"], sign * np.sqrt(2 + np.sin(2 * np.pi * r.t)),
                               rtol=1e-9, atol=1e-12)


def test_algebraic_constraint_vector():
    r = simulate(_constraint([1.0, -1.0], "{type: Constant, value: [4, 9]}"), t_end=0.5)
    np.testing.assert_allclose(r["ac.z"], np.tile([2.0, -3.0], (len(r.t), 1)), rtol=1e-10)


def test_algebraic_constraint_needs_a_loop():
    with pytest.raises(spidersim.AlgebraicLoopError, match="nothing to solve"):
        spidersim.loads("blocks:\n  c: {type: Constant}\n  ac: {type: AlgebraicConstraint}\n"
                        "connections:\n  - c.y -> ac.f\n")
