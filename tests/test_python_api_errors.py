"""The Python API refuses wrong arguments with a spidersim error naming the argument, what
was expected and what was found (no raw TypeError or AttributeError from deep inside, no
silent reading of ``True`` as 1 s or of a text as a list of letters), and the valid forms
(NumPy scalars, ints where floats are expected, a tuple of names, one name for a list of
one, a pathlib.Path) still work and give the closed-form answers.

The diagram is a first-order lag: ``x' = k (c - x)``, ``x(0) = 0`` with ``c = 2``, ``k = 4``
1/s, so ``x(t) = c (1 - exp(-k t))``; from ``r.y`` to ``x.y`` the transfer is
``k / (s + k)``; the loop opened at ``g.y`` is ``L = k / s`` (``|L(j k)| = 1``); its
equilibrium is ``x = c``. Runs are interpreted (``jit=False``) and short.
"""
from __future__ import annotations

import math
import pathlib

import numpy as np
import pytest

import spidersim
from spidersim import DiagramError, ParameterError, SpidersimError

SERVO = str(pathlib.Path(__file__).parents[1] / "diagrams" / "servo.yaml")
C, K = 2.0, 4.0
LAG = f"""
name: lag
blocks:
  r: {{type: Constant, value: {C}}}
  e: {{type: Sum, signs: "+-"}}
  g: {{type: Gain, k: {K}}}
  x: {{type: Integrator}}
connections: [r.y -> e.u1, x.y -> e.u2, e.y -> g.u, g.y -> x.u]
simulation: {{t_end: 0.5, rtol: 1e-8, atol: 1e-10}}
"""


@pytest.fixture(scope="module")
def d():
    return spidersim.loads(LAG)


@pytest.fixture(scope="module")
def r(d):
    return d.simulate(t_end=0.1, jit=False)


def _sim(**kw):
    return lambda d, r, p: d.simulate(jit=False, **{"t_end": 0.1, **kw})


#: (id, call(d, r, tmp_path), exception class, words the message must contain)
CASES = [
    # load / loads: the path, the text, the set mapping
    ("load(None)", lambda d, r, p: spidersim.load(None), DiagramError,
     ["load: path", "file path", "got None"]),
    ("load(123)", lambda d, r, p: spidersim.load(123), DiagramError,
     ["load: path", "file path", "123 (int)"]),
    ("load(set=str)", lambda d, r, p: spidersim.load(SERVO, set="motor.R=1"),
     ParameterError, ["load: set", "mapping", "the string 'motor.R=1'"]),
    ("load(set={5: 1})", lambda d, r, p: spidersim.load(SERVO, set={5: 1}),
     ParameterError, ["keys of set", "'block.param'", "5 (int)"]),
    ("loads(None)", lambda d, r, p: spidersim.loads(None), DiagramError,
     ["loads: text", "(a str)", "got None"]),
    ("loads(bytes)", lambda d, r, p: spidersim.loads(LAG.encode()), DiagramError,
     ["loads: text", "the bytes", "decode"]),
    ("loads(dict)", lambda d, r, p: spidersim.loads({"blocks": {}}), DiagramError,
     ["loads: text", "a mapping"]),
    ("loads(file=None)", lambda d, r, p: spidersim.loads(LAG, file=None), DiagramError,
     ["loads: file", "file path", "got None"]),
    ("set(5, 1)", lambda d, r, p: d.set(5, 1), ParameterError,
     ["set: path", "'block.param'", "5 (int)"]),
    # simulate: the simulation section's rules, a text or a list refused
    ("t_end='1'", _sim(t_end="1"), DiagramError,
     ["t_end (simulated time [s])", "must be a number", "the string '1'"]),
    ("t_end=True", _sim(t_end=True), DiagramError,
     ["t_end (simulated time [s])", "must be a number", "the boolean True"]),
    ("t_end=[1]", _sim(t_end=[1]), DiagramError, ["t_end", "must be a number", "a list of 1"]),
    ("t_end=array([.1])", _sim(t_end=np.array([0.1])), DiagramError,
     ["t_end", "must be a number", "an array of shape (1,)"]),
    ("t_end=-1", _sim(t_end=-1), DiagramError, ["t_end must be > 0", "got -1"]),
    ("t_end=inf", _sim(t_end=math.inf), DiagramError, ["t_end", "must be finite", "inf"]),
    ("method=5", _sim(method=5), DiagramError, ["method must be a name", "got 5"]),
    ("rtol='x'", _sim(rtol="x"), DiagramError, ["rtol (relative tolerance)", "the string"]),
    ("rtol=2", _sim(rtol=2), DiagramError, ["rtol must be in [1e-14, 1]", "got 2.0"]),
    ("atol='1e-6'", _sim(atol="1e-6"), DiagramError,
     ["atol (absolute tolerance)", "must be a number", "the string '1e-6'"]),
    ("atol=list", _sim(atol=[1e-6, 1e-6]), DiagramError, ["atol", "a list of 2"]),
    ("max_step='0.1'", _sim(max_step="0.1"), DiagramError,
     ["max_step (largest step [s])", "the string '0.1'"]),
    ("max_step=nan", _sim(max_step=math.nan), DiagramError, ["max_step must be > 0", "nan"]),
    ("output_interval='0.1'", _sim(output_interval="0.1"), DiagramError,
     ["output_interval (spacing of output samples [s])", "the string '0.1'"]),
    ("progress=5", _sim(progress=5), DiagramError,
     ["progress must be a function progress(t) or None", "5 (int)"]),
    ("should_stop=5", _sim(should_stop=5), DiagramError,
     ["should_stop must be a function", "5 (int)"]),
    ("jit='no'", lambda d, r, p: d.simulate(t_end=0.1, jit="no"), DiagramError,
     ["jit must be True", "the string 'no'"]),
]


@pytest.mark.parametrize("call, exc, words", [c[1:] for c in CASES],
                         ids=[c[0] for c in CASES])
def test_wrong_argument_is_a_spidersim_error_naming_it(d, r, tmp_path, call, exc, words):
    """Each wrong argument of the public API raises the given SpidersimError subclass (not
    a raw TypeError/AttributeError/KeyError from inside) whose message names the argument,
    what was expected and what was found."""
    with pytest.raises(exc) as info:
        call(d, r, tmp_path)
    assert isinstance(info.value, SpidersimError)
    msg = str(info.value)
    for w in words:
        assert w in msg, f"{w!r} not in {msg!r}"


@pytest.mark.parametrize("key, value, line", [
    ("t_end", True, "true"), ("atol", -1, "-1"), ("max_step", 0, "0"), ("rtol", 2, "2"),
    ("t_end", [1], "[1]")])
def test_simulate_arguments_follow_the_simulation_section(d, key, value, line):
    """simulate(key=value) is refused with the message the file's ``simulation: {key:
    value}`` gets, its ``simulation.`` prefix left out (one checker for both): booleans,
    non-positive values, rtol outside [1e-14, 1] and a list."""
    with pytest.raises(DiagramError) as in_file:
        spidersim.loads(LAG.replace("t_end: 0.5, rtol: 1e-8, atol: 1e-10", f"{key}: {line}"))
    with pytest.raises(DiagramError) as in_call:
        d.simulate(jit=False, **{key: value})
    want = in_file.value.message.replace(f"simulation.{key}", key)
    if isinstance(value, list):      # a list is shown by its repr in the file, described here
        want = want.replace("[1]", "a list of 1 [1]")
    assert in_call.value.message == want


def test_valid_simulate_forms(d):
    """NumPy scalars and ints where floats are expected, math.inf as max_step (no limit),
    a pathlib.Path and a NumPy value in load's set: accepted, and the run is the closed form
    of the lag x' = k (c - x): x(t) = c (1 - exp(-k t)) on the requested output grid."""
    r = d.simulate(t_end=1, output_interval=np.float32(0.25), rtol=np.float64(1e-9),
                   atol=np.float32(1e-11), max_step=math.inf, jit=False)
    np.testing.assert_allclose(r.t, [0, 0.25, 0.5, 0.75, 1.0], rtol=0, atol=1e-12)
    np.testing.assert_allclose(r["x.y"], C * (1 - np.exp(-K * r.t)), rtol=0, atol=1e-7)
    r2 = d.simulate(t_end=np.float32(0.25), max_step=np.int64(1), jit=False)
    assert r2.t[-1] == 0.25 and abs(r2["x.y"][-1] - C * (1 - math.exp(-K * 0.25))) < 1e-6
    d2 = spidersim.load(pathlib.Path(SERVO), set={"motor.R": np.float64(1.5)})
    assert d2.blocks["motor"].params["R"] == 1.5
