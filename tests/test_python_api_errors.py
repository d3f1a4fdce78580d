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
from spidersim import (AnalysisError, DiagramError, ParameterError, ResultError, SignalError,
                       SpidersimError)

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


@pytest.fixture
def garbage(tmp_path):
    """A folder whose result.npz starts as a zip file and is not one."""
    (tmp_path / "result.npz").write_bytes(b"PK\x03\x04garbage")
    return tmp_path


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
    ("linearize(jit='no')", lambda d, r, p: d.linearize("r.y", "x.y", jit="no"),
     DiagramError, ["jit must be True", "the string 'no'"]),
    ("trim(jit=1)", lambda d, r, p: d.trim(jit=1), DiagramError, ["jit must be True", "1"]),
    # results: names, plots, files
    ("r[5]", lambda d, r, p: r[5], SignalError, ["named by a text 'block.port'", "5 (int)"]),
    ("r[None]", lambda d, r, p: r[None], SignalError, ["'block.port'", "got None"]),
    ("r['nope']", lambda d, r, p: r["x.yy"], SignalError,
     ["no logged signal 'x.yy'", "did you mean x.y"]),
    ("r.plot([])", lambda d, r, p: r.plot([]), SignalError,
     ["plot: signals", "non-empty list", "a list of 0"]),
    ("r.plot([5])", lambda d, r, p: r.plot([5]), SignalError, ["plot", "'block.port'", "5"]),
    ("r.plot(5)", lambda d, r, p: r.plot(5), SignalError, ["plot: signals", "5 (int)"]),
    ("r.plot('x.y[1]')", lambda d, r, p: r.plot("x.y[1]"), SignalError,
     ["'x.y[1]'", "index 1 out of range", "1 element(s)", "-1..-1 from the end"]),
    ("r.plot('x.y[-2]')", lambda d, r, p: r.plot("x.y[-2]"), SignalError,
     ["'x.y[-2]'", "index -2 out of range", "1 element(s)"]),
    ("r.plot(['nope'])", lambda d, r, p: r.plot(["nope.y"]), SignalError,
     ["no logged signal 'nope.y'"]),
    ("r.save(None)", lambda d, r, p: r.save(None), ResultError,
     ["Result.save: folder", "folder path", "got None"]),
    ("Result.load(None)", lambda d, r, p: spidersim.Result.load(None), ResultError,
     ["Result.load: folder", "folder path", "got None"]),
    ("Result.load(missing)", lambda d, r, p: spidersim.Result.load(p / "none"), ResultError,
     ["Result.load", "no such folder", "none"]),
    ("Result.load(file)", lambda d, r, p: spidersim.Result.load(__file__), ResultError,
     ["Result.load", "a file, not a results folder", "test_python_api_errors.py"]),
    ("Result.load(empty folder)", lambda d, r, p: spidersim.Result.load(p), ResultError,
     ["Result.load", "no result.npz in"]),
    # linearize, loop_transfer, trim
    ("linearize(5, 5)", lambda d, r, p: d.linearize(5, 5), AnalysisError,
     ["linearize: inputs", "a signal name 'block.port' or a list of them", "5 (int)"]),
    ("linearize(outputs={})", lambda d, r, p: d.linearize("r.y", {"x.y": 1}), AnalysisError,
     ["linearize: outputs", "a mapping"]),
    ("linearize(open=5)", lambda d, r, p: d.linearize("r.y", "x.y", open=5), AnalysisError,
     ["linearize: open", "5 (int)"]),
    ("linearize(at=-1)", lambda d, r, p: d.linearize("r.y", "x.y", at=-1), AnalysisError,
     ["operating point at = -1", "time >= 0 s"]),
    ("linearize(at=nan)", lambda d, r, p: d.linearize("r.y", "x.y", at=math.nan),
     AnalysisError, ["at = nan", "time >= 0 s"]),
    ("loop_transfer(5)", lambda d, r, p: d.loop_transfer(5), AnalysisError,
     ["loop_transfer: signal", "one signal name", "5 (int)"]),
    ("loop_transfer(list)", lambda d, r, p: d.loop_transfer(["g.y"]), AnalysisError,
     ["loop_transfer: signal", "a list of 1"]),
    ("spidersim.linearize(None)", lambda d, r, p: spidersim.linearize(None, ["a"], ["b"]),
     AnalysisError, ["linearize: the first argument", "diagram", "got None"]),
    ("spidersim.loop_transfer(None)", lambda d, r, p: spidersim.loop_transfer(None, "g.y"),
     AnalysisError, ["loop_transfer: the first argument", "got None"]),
    ("spidersim.trim('x')", lambda d, r, p: spidersim.trim("x"), AnalysisError,
     ["trim: the first argument", "diagram", "the string 'x'"]),
    ("trim(targets=5)", lambda d, r, p: d.trim(targets=5), AnalysisError,
     ["trim: targets", "mapping", "5 (int)"]),
    ("trim(targets={5: 1})", lambda d, r, p: d.trim(targets={5: 1}), AnalysisError,
     ["trim: a target", "'block.port'", "5 (int)"]),
    ("trim(target 'a')", lambda d, r, p: d.trim(targets={"x.y": "a"}), AnalysisError,
     ["trim: target 'x.y'", "a number or a list of numbers", "the string 'a'"]),
    ("trim(free_inputs=5)", lambda d, r, p: d.trim(free_inputs=5), AnalysisError,
     ["trim: free_inputs", "5 (int)"]),
    ("trim(derivatives=5)", lambda d, r, p: d.trim(derivatives=5), AnalysisError,
     ["trim: derivatives", "state name", "5 (int)"]),
    ("trim(x0='abc')", lambda d, r, p: d.trim(x0="abc"), AnalysisError,
     ["trim: x0", "list of finite numbers", "the string 'abc'"]),
    ("trim(x0=[nan])", lambda d, r, p: d.trim(x0=[math.nan]), AnalysisError,
     ["trim: x0", "finite numbers", "a list of 1 [nan]"]),
    ("trim(t='0')", lambda d, r, p: d.trim(t="0"), AnalysisError,
     ["trim: t", "finite number", "the string '0'"]),
    ("trim(tol=-1)", lambda d, r, p: d.trim(tol=-1), AnalysisError,
     ["trim: tol", "finite number > 0", "-1 (int)"]),
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


def test_damaged_result_npz_is_a_result_error(garbage):
    """A result.npz that is not a zip (BadZipFile inside numpy) is a ResultError naming the
    file and the cause."""
    with pytest.raises(ResultError, match=r"cannot read .*result\.npz: not a result saved "
                                          r"by Result\.save, or damaged \(BadZipFile"):
        spidersim.Result.load(garbage)


def _rewrite_meta(folder, change):
    """Rewrite the metadata of ``folder/result.npz`` with ``change(meta)`` applied."""
    import json
    path = folder / "result.npz"
    with np.load(path) as z:
        arrays = {k: z[k] for k in z.files}
    meta = json.loads(arrays["__meta__"].tobytes().decode("utf-8"))
    change(meta)
    arrays["__meta__"] = np.frombuffer(json.dumps(meta).encode("utf-8"), dtype=np.uint8)
    np.savez(path, **arrays)


@pytest.mark.parametrize("change, words", [
    # raised a raw AttributeError ('list' object has no attribute 'items')
    (lambda m: m.update(sizes=[1, 1]), "'sizes' must be a mapping, got a list of 2"),
    # loaded: the column reshaped to (n, -1), a signal of the wrong shape
    (lambda m: m["sizes"].update({"x.y": -1}),
     "'sizes' must give each signal its number of columns (a whole number >= 0), got -1 "
     "for 'x.y'"),
    (lambda m: m["sizes"].update({"x.y": 1.5}), "got 1.5 for 'x.y'"),
    (lambda m: m["sizes"].update({"x.y": True}), "got True for 'x.y'"),
    (lambda m: m.pop("units"), "no 'units'"),
    (lambda m: m.update(status=3), "'status' must be a text, got 3"),
    (lambda m: m.update(events=[[0.0, "x"]]), "each event must be [t, block, event]"),
    (lambda m: m.update(provenance=[]), "'provenance' must be a mapping"),
])
def test_result_with_malformed_metadata_is_a_result_error(r, tmp_path, change, words):
    """A result.npz whose __meta__ is JSON but not what Result.save writes is a
    ResultError naming the file and the problem; the file as saved loads unchanged."""
    r.save(tmp_path)
    assert np.array_equal(spidersim.Result.load(tmp_path)["x.y"], r["x.y"])
    _rewrite_meta(tmp_path, change)
    with pytest.raises(ResultError) as info:
        spidersim.Result.load(tmp_path)
    msg = str(info.value)
    assert msg.startswith(f"Result.load: cannot read {tmp_path / 'result.npz'}: its "
                          f"metadata (__meta__) is not one Result.save writes: ")
    assert words in msg, msg


def test_signal_error_is_a_key_error_too(r):
    """A missing signal stays a KeyError (code catching KeyError keeps working) and is a
    SpidersimError whose text is the message, not its repr."""
    with pytest.raises(KeyError) as info:
        r["zzz.q"]
    assert isinstance(info.value, SignalError)
    assert str(info.value) == "no logged signal 'zzz.q'"


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


@pytest.mark.parametrize("method", ["NDF", "LSODA"])
def test_first_step_below_the_stall_step_is_refused(method):
    """A first_step of 1e-300 s passed check, then the run stalled (NDF, LSODA: 500
    consecutive steps shorter than 1e-10 s while the step grew): refused at its line by the
    run's rule, first_step >= 1e-10 s; 1e-10 s itself runs to the closed form x(t) = c (1 -
    exp(-k t))."""
    text = LAG.replace("rtol: 1e-8", f"method: {method}, first_step: %s, rtol: 1e-8")
    for tiny in ("1e-300", "9.99e-11"):
        with pytest.raises(DiagramError, match=r"simulation\.first_step must be at least "
                                               r"1e-10 s \(the solvers take 500 consecutive "
                                               r"steps shorter than 1e-10 s as a stall\)") as e:
            spidersim.loads(text % tiny)
        assert e.value.line == 9
    r = spidersim.loads(text % "1e-10").simulate(jit=False)
    assert r["x.y"][-1] == pytest.approx(C * (1 - math.exp(-K * 0.5)), rel=1e-6)


def test_simulate_t_end_below_the_shortest_run_is_refused(d):
    """simulate(t_end=1e-9) is refused by the rule a command's t_end follows (one checker:
    at least 1e-7 s, the shortest run), naming the argument; 1e-7 s runs."""
    with pytest.raises(DiagramError, match=r": t_end must be at least 1e-07 s \(the shortest "
                                           r"run: the solvers take steps shorter than 1e-10 s "
                                           r"as a stall\), got 1e-09$"):
        d.simulate(t_end=1e-9, jit=False)
    assert d.simulate(t_end=1e-7, jit=False).t[-1] == 1e-7


def test_valid_simulate_forms(d):
    """NumPy scalars and ints where floats are expected (a NumPy boolean for jit), math.inf
    as max_step (no limit),
    a pathlib.Path and a NumPy value in load's set: accepted, and the run is the closed form
    of the lag x' = k (c - x): x(t) = c (1 - exp(-k t)) on the requested output grid."""
    r = d.simulate(t_end=1, output_interval=np.float32(0.25), rtol=np.float64(1e-9),
                   atol=np.float32(1e-11), max_step=math.inf, jit=False)
    np.testing.assert_allclose(r.t, [0, 0.25, 0.5, 0.75, 1.0], rtol=0, atol=1e-12)
    np.testing.assert_allclose(r["x.y"], C * (1 - np.exp(-K * r.t)), rtol=0, atol=1e-7)
    r2 = d.simulate(t_end=np.float32(0.25), max_step=np.int64(1), jit=np.False_)
    assert r2.t[-1] == 0.25 and abs(r2["x.y"][-1] - C * (1 - math.exp(-K * 0.25))) < 1e-6
    d2 = spidersim.load(pathlib.Path(SERVO), set={"motor.R": np.float64(1.5)})
    assert d2.blocks["motor"].params["R"] == 1.5


def test_valid_analysis_and_result_forms(d, tmp_path):
    """One name where a list is expected, a tuple of names, NumPy scalars for times and
    tolerances, a pathlib.Path folder: accepted, with the closed forms G(s) = k / (s + k),
    |L(j k)| = 1 at the loop opened at g.y, the equilibrium x = c (or a target value) from
    trim, one plotted line per named signal and a saved result read back unchanged."""
    r = d.simulate(t_end=0.5, jit=False)
    for ins, outs in ((("r.y",), "x.y"), ("r.y", ["x.y"])):
        for G in (d.linearize(ins, outs, at=np.int64(0), open=(), jit=False),
                  spidersim.linearize(d, ins, outs, jit=False)):
            np.testing.assert_allclose([G.A[0, 0], G.B[0, 0] * G.C[0, 0], G.D[0, 0]],
                                       [-K, K, 0.0], rtol=1e-6, atol=1e-8)
    L = d.loop_transfer("g.y", at=np.float64(0.0), jit=False)
    assert abs(abs(complex(L(1j * K))) - 1.0) < 1e-6
    op = d.trim(derivatives="x.y", x0=(0.5,), t=np.float64(0.0), tol=np.float32(1e-9),
                jit=False)
    assert abs(op.x[0] - C) < 1e-9
    op = d.trim(targets={"x.y": np.float64(1.5)}, derivatives=(), x0=np.array([0.2]),
                jit=False)
    assert abs(op.x[0] - 1.5) < 1e-9
    import matplotlib.pyplot as plt
    fig = r.plot("x.y")
    assert [ln.get_label() for ln in fig.axes[0].lines] == ["x.y"]
    plt.close(fig)
    fig = r.plot(("x.y", "g.y"), one_panel=True)
    assert [ln.get_label() for ln in fig.axes[0].lines] == ["x.y", "g.y"]
    plt.close(fig)
    r.save(tmp_path / "res")
    back = spidersim.Result.load(tmp_path / "res")
    np.testing.assert_array_equal(back["x.y"], r["x.y"])


def test_diagram_methods_mirror_the_analysis_functions():
    """Diagram.linearize, loop_transfer and trim take exactly the arguments (names and
    defaults) of the functions of spidersim.diagram.analysis they call, so that an unknown
    keyword (d.trim(x=1)) is refused at the call, with Python's TypeError naming it."""
    import inspect

    from spidersim.diagram import analysis
    for name in ("linearize", "loop_transfer", "trim"):
        method = list(inspect.signature(getattr(spidersim.Diagram, name)).parameters.values())
        func = list(inspect.signature(getattr(analysis, name)).parameters.values())
        assert [(p.name, p.default) for p in method[1:]] == \
            [(p.name, p.default) for p in func[1:]], name
    with pytest.raises(TypeError, match="unexpected keyword argument 'x'"):
        spidersim.loads(LAG).trim(x=1)


SET_DIAGRAM = f"""
parameters: {{k0: 3}}
subsystems: {{lag: {pathlib.Path(__file__).parents[1] / "diagrams" / "lib" / "lag.yaml"}}}
blocks:
  c: {{type: Constant, value: k0}}
  sat: {{type: Saturation, lower: -1, upper: 1}}
  f: {{type: lag, tau: 0.5}}
connections: [c.y -> sat.u, sat.y -> f.u]
"""


@pytest.mark.parametrize("path, value, words", [
    # said "no block ''"
    ("k0", 10, "set k0: 'k0' is a parameter of the diagram, not of a block: its value went "
               "into the blocks' values (and later parameters) when the diagram was loaded; "
               "to change it, reload with spidersim.load(file, set={'k0': ...})"),
    ("f.tau", 1.0, "set f.tau: 'f' is a subsystem instance: its parameters went into its "
                   "blocks' values when the diagram was loaded; to change 'tau', reload with "
                   "spidersim.load(file, set={'f.tau': ...}) (or set a block parameter "
                   "inside it: f.<block>.<param>)"),
    ("sat", 1.0, "set sat: 'sat' is a block; write sat.<param> (e.g. sat.lower)"),
    ("f", 1.0, "set f: 'f' is a subsystem instance; write f.<block>.<param>"),
    ("kk0", 1.0, "set kk0: the diagram has no block or parameter 'kk0'; did you mean k0?"),
    ("satt.lower", 1.0, "set satt.lower: the diagram has no block 'satt'; did you mean sat?"),
    # said "must not be NaN, got None"
    ("sat.lower", None, "block 'sat': set sat.lower: parameter 'lower' must be a number, "
                        "got None"),
    # named no block
    ("sat.lower", 100, "block 'sat': set sat.lower: lower (100.0) must be below upper (1.0)"),
    # NumPy booleans were read as 1 (Python's True is refused): refused alike
    *[("sat.lower", v, "block 'sat': set sat.lower: parameter 'lower' must be a number, got "
                       f"a boolean ({shown}; write 1 or 0 if you mean a number)")
      for v, shown in ((True, "True"), (np.True_, "True"), (np.array(False), "False"))],
    *[("c.value", v, "block 'c': set c.value: parameter 'value' must be a number, got a "
                     f"boolean ({shown}; write 1 or 0 if you mean a number)")
      for v, shown in (([np.True_], "[True]"), (np.array([True]), "[True]"),
                       (np.array([1.0, np.False_], dtype=object), "[1.0, False]"))],
])
def test_set_says_what_is_wrong_with_its_target_or_value(path, value, words):
    """``Diagram.set`` changes block parameters only; each other target says what it is
    and how to change it, and a refused value names the block and the call. A refused
    call leaves the parameters as they were."""
    d = spidersim.loads(SET_DIAGRAM)
    p0 = d.p.copy()
    with pytest.raises(ParameterError) as info:
        d.set(path, value)
    assert words in str(info.value)
    assert np.array_equal(d.p, p0)
    d.set("f.gain.k", 3.0)                 # a block inside a subsystem instance: settable
    assert not np.array_equal(d.p, p0)


@pytest.mark.parametrize("bad", ["x", -1, 2.5, True, None.__class__, [10]])
def test_result_save_refuses_a_bad_csv_limit_and_stays_usable(bad, tmp_path):
    """Result.save(csv_max_values=...) checks the value before keeping it: a ResultError,
    nothing written, and the Result saves and reports as before (a text was kept: a raw
    TypeError after result.npz, then every later save and report failed)."""
    r = spidersim.load(SERVO).simulate(jit=False, t_end=0.1)
    with pytest.raises(ResultError, match="csv_max_values"):
        r.save(tmp_path / "a", csv_max_values=bad)
    assert not (tmp_path / "a").exists()
    r.save(tmp_path / "b")
    assert (tmp_path / "b" / "result.csv").exists() and "status" in r.report()
    r.save(tmp_path / "c", csv_max_values=0)
    assert not (tmp_path / "c" / "result.csv").exists()


@pytest.mark.parametrize("value", [np.complex128(1.5 + 2j), np.array([1.5 + 2j]),
                                   [np.complex64(1 + 1j)], np.array(1.5 + 0j)])
def test_set_refuses_numpy_complex_numbers(value):
    """NumPy complex numbers are refused as Python's 1+2j is (they were stored as their
    real part, with only a ComplexWarning)."""
    d = spidersim.load(SERVO)
    with pytest.raises(ParameterError, match="numeric"):
        d.set("motor.R", value)


@pytest.mark.parametrize("value, stored", [(np.int64(2), 2), (np.float32(1.5), 1.5),
                                           (np.array(1.25), 1.25)])
def test_load_set_takes_numpy_numbers_as_diagram_set_does(value, stored):
    """load(set=) takes NumPy real scalars, 0-d arrays and arrays of numbers as
    Diagram.set does (they were "unsupported value"); booleans and complex stay refused."""
    d = spidersim.load(SERVO, set={"motor.R": value})
    assert d.blocks["motor"].params["R"] == pytest.approx(stored)
    assert type(d.blocks["motor"].params["R"]) is not type(value)


@pytest.mark.parametrize("value, words", [(np.True_, "boolean"), (np.array(True), "boolean"),
                                          (np.complex128(1 + 2j), "unsupported value")])
def test_load_set_still_refuses_numpy_booleans_and_complex(value, words):
    with pytest.raises(ParameterError, match=words):
        spidersim.load(SERVO, set={"motor.R": value})


def test_operating_point_at_a_0d_array_is_that_time(d):
    """at=np.array(0.25) is the time 0.25 s (it was refused): the state of the lag then,
    x = C (1 - exp(-K t)); a 1-element array or a 0-d boolean stays refused."""
    from spidersim.diagram.analysis import operating_point
    op = operating_point(d, np.array(0.25), jit=False)
    assert op.t == pytest.approx(0.25)
    assert op.x[0] == pytest.approx(C * (1 - math.exp(-K * 0.25)), rel=1e-6)
    G = d.linearize("r.y", "x.y", at=np.array(0.25), jit=False)
    assert G.A[0, 0] == pytest.approx(-K)
    for bad in (np.array([0.25]), np.array(True)):
        with pytest.raises(AnalysisError, match="operating point"):
            d.linearize("r.y", "x.y", at=bad, jit=False)


def test_a_run_after_compile_reports_that_compile():
    """compile() then simulate(): the run's stats (and so report.txt/json) carry the
    compile's time (the CLI printed "compiled in 68.9 s" and reported compile_time 0);
    a second run reports 0."""
    d = spidersim.load(SERVO)
    d.compile(jit=False)
    spent = d._compile_time
    assert spent > 0
    assert d.simulate(jit=False, t_end=0.01).stats["compile_time"] == spent
    assert d.simulate(jit=False, t_end=0.01).stats["compile_time"] == 0.0


def test_result_plot_counts_negative_indexes_from_the_end():
    """``Result.plot("c.y[-1]")`` draws the last element, as a plot section, a metric and
    a connection read it (it was refused as "index out of range")."""
    pytest.importorskip("matplotlib")
    r = spidersim.loads("blocks:\n  c: {type: Constant, value: [1, 2, 7]}\n"
                        "simulation: {t_end: 0.1, method: LSODA}\n").simulate(jit=False)
    fig = r.plot("c.y[-1]")
    line = fig.axes[0].get_lines()[0]
    assert set(line.get_ydata()) == {7.0}
