"""Every bad input gets a clear, specific error.

Each test writes a small diagram into ``tmp_path`` and checks

* the exception class from :mod:`spidersim.errors`,
* ``err.file`` and the 1-based ``err.line`` of the offending YAML entry,
* ``err.block`` (the dotted block path) whenever a block is involved,
* a message that says what was expected and what was found (key substrings, such as the
  suggested near name).

Line numbers are looked up in the written text (:func:`line_of`) rather than hard-coded.
Runs are interpreted (``jit=False``) and short.
"""
from __future__ import annotations

import os
import re
import subprocess
import sys
import textwrap
from typing import NamedTuple

import pytest

import spidersim
from spidersim.errors import (AlgebraicLoopError, BlockTypeError, DiagramError,
                              IntegrationError, ParameterError, SpidersimError, WiringError)


# ---------------------------------------------------------------------------- helpers
def write(tmp_path, text, name="main.yaml"):
    """Write dedented ``text`` to ``tmp_path/name`` (folders created); return the path."""
    p = tmp_path / name
    p.parent.mkdir(parents=True, exist_ok=True)
    p.write_text(textwrap.dedent(text))
    return p


def line_of(path, needle, nth=1):
    """1-based number of the ``nth`` line of ``path`` that contains ``needle``."""
    hits = [k + 1 for k, ln in enumerate(open(path).read().splitlines()) if needle in ln]
    assert len(hits) >= nth, f"{needle!r} not found {nth} time(s) in {path}"
    return hits[nth - 1]


def load_error(path, cls, **kw):
    """The ``cls`` error raised by ``spidersim.load(path, **kw)``."""
    with pytest.raises(cls) as ei:
        spidersim.load(str(path), **kw)
    return ei.value


def assert_where(err, path, line, block=None):
    """``err`` points at ``path:line`` (and at ``block``), and says so in ``str(err)``."""
    assert err.file is not None, f"no file in: {err}"
    assert os.path.samefile(err.file, path), (err.file, str(path))
    assert err.line == line, f"line {err.line}, expected {line}: {err}"
    assert err.block == block, f"block {err.block!r}, expected {block!r}: {err}"
    text = str(err)
    assert text.startswith(f"{err.file}:{line}: "), text
    if block is not None:
        assert f"block '{block}': " in text, text


# ---------------------------------------------------------------------------- block types


def test_unknown_block_type_suggests_subsystem_types(tmp_path):
    write(tmp_path, open(os.path.join(os.path.dirname(__file__), "..", "..", "diagrams",
                                      "lib", "lag.yaml")).read(), "lib/lag.yaml")
    p = write(tmp_path, """\
        subsystems:
          lag: lib/lag.yaml
        blocks:
          step: {type: Step}
          f:    {type: lagg, tau: 0.1}
        connections:
          - step.y -> f.u
        """)
    err = load_error(p, BlockTypeError)
    assert_where(err, p, line_of(p, "type: lagg"), block="f")
    assert "'lagg'" in err.message and "lag" in err.message.split("'lagg'", 1)[1]


# ---------------------------------------------------------------------------- parameters


def test_state_matrix_not_square(tmp_path):
    p = write(tmp_path, """\
        blocks:
          u: {type: Constant, value: 1}
          ss:
            type: StateSpace
            A: [[1, 2, 3], [4, 5, 6]]
            B: [[1], [1]]
            C: [[1, 0]]
        connections:
          - u.y -> ss.u
        """)
    err = load_error(p, ParameterError)
    # a cross-parameter check: the block's line or the line of A are both fine
    assert err.line in (line_of(p, "ss:"), line_of(p, "A: [[1, 2, 3]"))
    assert_where(err, p, err.line, block="ss")
    assert "square" in err.message and "(2, 3)" in err.message


@pytest.mark.parametrize("block, entry, value", [
    ("g", "k: fast", "fast"),
    ("motor", "R: 1 Ohm", "1 Ohm"),
])
def test_string_where_a_number_is_needed(tmp_path, block, entry, value):
    p = write(tmp_path, f"""\
        blocks:
          src: {{type: Constant, value: 1}}
          g:
            type: Gain
            {entry if block == "g" else "k: 2"}
          motor:
            type: DCMotor
            {entry if block == "motor" else "R: 1"}
        connections:
          - src.y -> g.u
          - g.y -> motor.v
        """)
    err = load_error(p, ParameterError)
    assert_where(err, p, line_of(p, entry), block=block)
    assert f"'{entry.split(':')[0]}'" in err.message          # the parameter
    assert "number" in err.message                             # what was expected
    assert value in err.message                                # what was found


# ---------------------------------------------------------------------------- expressions


UNSAFE = [
    "__import__('os').system('touch {mark}')",
    "open('{mark}', 'w')",
    "().__class__",
    "().__class__.__bases__[0].__subclasses__()",
    "(lambda: __import__('os').system('touch {mark}'))()",
    "[__import__('os').system('touch {mark}') for _ in [1]]",
    "sqrt.__globals__",
    "pi.__class__",
]


@pytest.mark.parametrize("expr", UNSAFE)
def test_unsafe_expression_is_rejected_and_not_executed(tmp_path, expr):
    mark = tmp_path / "executed"
    text = expr.format(mark=mark)
    p = write(tmp_path, f"""\
        parameters:
          a: "{text}"
        blocks:
          src: {{type: Constant, value: 1}}
          g: {{type: Gain, k: 1}}
        connections:
          - src.y -> g.u
        """)
    err = load_error(p, ParameterError)
    assert_where(err, p, line_of(p, "a: "))
    assert "'a'" in err.message
    assert "not allowed" in err.message or "unknown function" in err.message
    assert not mark.exists(), "the expression was executed"


def test_unsafe_expression_in_block_parameter(tmp_path):
    mark = tmp_path / "executed"
    p = write(tmp_path, f"""\
        blocks:
          src: {{type: Constant, value: 1}}
          g:
            type: Gain
            k: "__import__('os').system('touch {mark}')"
        connections:
          - src.y -> g.u
        """)
    err = load_error(p, ParameterError)
    assert_where(err, p, line_of(p, "k: "), block="g")
    assert "not allowed" in err.message
    assert not mark.exists()


def test_huge_power_is_rejected_quickly(tmp_path):
    """``9**9**9`` is a 370-million-digit integer: the evaluator must refuse it instead of
    computing it for minutes (a denial of service through a parameter file)."""
    p = write(tmp_path, """\
        parameters:
          a: 9**9**9
        blocks:
          src: {type: Constant, value: 1}
          g: {type: Gain, k: a}
        connections:
          - src.y -> g.u
        """)
    code = ("import sys, spidersim\n"
            "try:\n"
            "    spidersim.load(sys.argv[1])\n"
            "except spidersim.ParameterError as e:\n"
            "    print('ParameterError', e.line, e.message)\n")
    try:
        out = subprocess.run([sys.executable, "-c", code, str(p)], capture_output=True,
                             text=True, timeout=10)
    except subprocess.TimeoutExpired:
        pytest.fail("evaluating 9**9**9 did not finish within 10 s")
    assert out.stdout.startswith(f"ParameterError {line_of(p, 'a: 9**9**9')} "), \
        out.stdout + out.stderr
    assert "9**9**9" in out.stdout


# ---------------------------------------------------------------------------- wiring


def test_unknown_output_port_suggests_near_name(tmp_path):
    p = write(tmp_path, """\
        blocks:
          v: {type: Constant, value: 1}
          motor: {type: DCMotor}
          g: {type: Gain}
        connections:
          - v.y -> motor.v
          - motor.ww -> g.u
        """)
    err = load_error(p, WiringError)
    assert_where(err, p, line_of(p, "motor.ww -> g.u"), block="motor")
    assert "no output 'ww'" in err.message and "did you mean w" in err.message
    listed = err.message.split("outputs:", 1)[-1]
    assert all(n in listed for n in ("phi", "tau")), err.message       # the outputs


def test_selector_index_beyond_input_size(tmp_path):
    p = write(tmp_path, """\
        blocks:
          c: {type: Constant, value: [1, 2, 3]}
          sel:
            type: Selector
            index: [5]
          g: {type: Gain}
        connections:
          - c.y -> sel.u
          - sel.y -> g.u
        """)
    err = load_error(p, ParameterError)           # from Selector.check_sizes
    assert err.line in (line_of(p, "sel:"), line_of(p, "index: [5]"))
    assert_where(err, p, err.line, block="sel")
    assert "index" in err.message and "3" in err.message and "5" in err.message


def test_two_sources_into_one_input(tmp_path):
    p = write(tmp_path, """\
        blocks:
          a: {type: Constant, value: 1}
          b: {type: Constant, value: 2}
          g: {type: Gain}
        connections:
          - a.y -> g.u
          - b.y -> g.u
        """)
    err = load_error(p, WiringError)
    assert_where(err, p, line_of(p, "b.y -> g.u"), block="g")
    assert "two sources" in err.message and "'g.u'" in err.message
    assert "a.y" in err.message and "b.y" in err.message
    assert f"line {line_of(p, 'a.y -> g.u')}" in err.message      # where the first one is


def test_unconnected_input_lists_outputs_of_matching_size(tmp_path):
    p = write(tmp_path, """\
        blocks:
          c3: {type: Constant, value: [1, 2, 3]}
          st: {type: Step}
          ss: {type: StateSpace, A: [[-1]], B: [[1]], C: [[1]]}
        """)
    err = load_error(p, WiringError)
    assert_where(err, p, line_of(p, "ss: {type: StateSpace"), block="ss")
    assert "input 'u'" in err.message and "not connected" in err.message
    assert "st.y" in err.message              # size 1, like ss.u
    assert "c3.y" not in err.message          # size 3


def test_unconnected_motor_voltage_lists_dimensionless_sources(tmp_path):
    """A dimensionless ("1") output is what usually drives an input with a unit (servo.yaml
    wires ``sat.y -> motor.v``): the hint must list it, not say that nothing matches."""
    p = write(tmp_path, """\
        blocks:
          ref: {type: Step}
          sat: {type: Saturation, lower: -24, upper: 24}
          c3: {type: Constant, value: [1, 2, 3]}
          motor: {type: DCMotor}
        connections:
          - ref.y -> sat.u
        """)
    err = load_error(p, WiringError)
    assert_where(err, p, line_of(p, "motor: {type: DCMotor}"), block="motor")
    assert "input 'v'" in err.message and "not connected" in err.message
    assert "sat.y" in err.message and "ref.y" in err.message
    assert "c3.y" not in err.message


def test_duplicate_block_names(tmp_path):
    p = write(tmp_path, """\
        blocks:
          g: {type: Gain}
          src: {type: Constant, value: 1}
          g: {type: Gain, k: 3}
        connections:
          - src.y -> g.u
        """)
    err = load_error(p, DiagramError)
    assert_where(err, p, line_of(p, "g: {type: Gain, k: 3}"))
    assert "duplicate" in err.message and "'g'" in err.message
    assert f"line {line_of(p, 'g: {type: Gain}')}" in err.message


# ---------------------------------------------------------------------------- subsystems
def test_subsystem_file_does_not_exist(tmp_path):
    p = write(tmp_path, """\
        subsystems:
          lag: lib/nolag.yaml
        blocks:
          step: {type: Step}
          l: {type: lag, tau: 1}
        connections:
          - step.y -> l.u
        """)
    err = load_error(p, DiagramError)
    assert err.line in (line_of(p, "lag: lib/nolag.yaml"), line_of(p, "l: {type: lag"))
    assert_where(err, p, err.line, block="l")
    assert "not found" in err.message and "nolag.yaml" in err.message
    assert "'lag'" in err.message


def test_subsystem_includes_itself_through_another_file(tmp_path):
    write(tmp_path, """\
        subsystems:
          b: sub/b.yaml
        blocks:
          y: {type: b}
        inputs:
          u: y.u
        outputs:
          y: y.y
        """, "a.yaml")
    b = write(tmp_path, """\
        subsystems:
          a: ../a.yaml
        blocks:
          g: {type: Gain}
          z: {type: a}
        connections:
          - g.y -> z.u
        inputs:
          u: g.u
        outputs:
          y: z.y
        """, "sub/b.yaml")
    p = write(tmp_path, """\
        subsystems:
          a: a.yaml
        blocks:
          step: {type: Step}
          x: {type: a}
        connections:
          - step.y -> x.u
        """)
    err = load_error(p, DiagramError)
    assert_where(err, b, line_of(b, "z: {type: a}"), block="x.y.z")
    assert "includes itself" in err.message
    assert "a.yaml -> b.yaml -> a.yaml" in err.message


# ---------------------------------------------------------------------------- file level
@pytest.mark.parametrize("text, needle", [
    ("""\
     blocks:
       a: {type: Constant, value: 1}
       g: {type: Gain, k: [1, 2}
     connections:
       - a.y -> g.u
     """, "k: [1, 2}"),
    ("""\
     blocks:
       a: {type: Constant, value: 1}
       g:
         type: Gain
        k: 2
     connections:
       - a.y -> g.u
     """, "k: 2"),
], ids=["flow", "indentation"])
def test_yaml_syntax_error_has_line(tmp_path, text, needle):
    p = write(tmp_path, text)
    err = load_error(p, DiagramError)
    assert_where(err, p, line_of(p, needle))
    assert "YAML syntax error" in err.message


# ---------------------------------------------------------------------------- --set / set=
SET_DIAGRAM = """\
    parameters:
      gain: 2
    subsystems:
      lag: lib/lag.yaml
    blocks:
      a: {type: Constant, value: 1}
      g: {type: Gain, k: gain}
      l: {type: lag, tau: 0.1}
    connections:
      - a.y -> g.u
      - g.y -> l.u
    """


@pytest.fixture
def set_diagram(tmp_path):
    lag = os.path.join(os.path.dirname(__file__), "..", "..", "diagrams", "lib", "lag.yaml")
    write(tmp_path, open(lag).read(), "lib/lag.yaml")
    return write(tmp_path, SET_DIAGRAM)


def test_set_unknown_top_level_parameter(set_diagram):
    err = load_error(set_diagram, ParameterError, set={"gian": 3})
    assert err.file and os.path.samefile(err.file, set_diagram)
    assert "gian" in err.message and "did you mean gain" in err.message


def test_set_unknown_block_parameter(set_diagram):
    err = load_error(set_diagram, ParameterError, set={"g.kk": 3})
    assert err.block == "g"
    assert err.file and os.path.samefile(err.file, set_diagram), f"no file: {err!r}"
    assert "g.kk" in err.message and "'kk'" in err.message and "Gain" in err.message
    assert "k" in err.message.split("'kk'", 1)[1]                      # the valid ones


def test_set_unknown_subsystem_parameter_suggests_near_name(set_diagram):
    err = load_error(set_diagram, ParameterError, set={"l.tauu": 3})
    assert "l.tauu" in err.message
    assert "tau" in err.message.replace("tauu", ""), err.message      # the near name


def test_set_nested_block_parameter_names_the_full_path(set_diagram):
    err = load_error(set_diagram, ParameterError, set={"l.gain.kk": 3})
    assert err.block == "l.gain"
    assert "l.gain.kk" in err.message, err.message


def test_set_unknown_block(set_diagram):
    err = load_error(set_diagram, ParameterError, set={"h.k": 3})
    assert "h.k" in err.message
    assert "'h'" in err.message, err.message        # says that there is no block 'h'


def test_set_bad_value(set_diagram):
    err = load_error(set_diagram, ParameterError, set={"g.k": "fast"})
    assert err.block == "g" and "g.k" in err.message and "fast" in err.message


# ---------------------------------------------------------------------------- during a run
class Stalled(Exception):
    pass


def step_guard(limit=50000):
    """A progress callback that stops a run that takes ``limit`` steps (a hang guard)."""
    n = [0]

    def progress(t):
        n[0] += 1
        if n[0] > limit:
            raise Stalled(f"the integrator took {limit} steps and stands at t = {t!r}")
    return progress


DIVISION = """\
    name: division
    blocks:
      one:  {type: Constant, value: 1}
      ramp: {type: Ramp, slope: 1, offset: -0.5}   # crosses zero at t = 0.5
      div:  {type: Product, ops: "*/"}
      int:  {type: Integrator}
    connections:
      - one.y -> div.u1
      - ramp.y -> div.u2
      - div.y -> int.u
    simulation: {t_end: 1.0}
    """


def test_non_finite_values_during_a_run_keep_partial_data(tmp_path):
    p = write(tmp_path, DIVISION)
    d = spidersim.load(str(p))
    try:
        with pytest.raises(IntegrationError) as ei:
            d.simulate(jit=False, progress=step_guard())
    except Stalled as exc:
        pytest.fail(f"no IntegrationError: the run hangs at the singularity ({exc})")
    err = ei.value
    msg = str(err)
    assert "div" in msg, msg                                     # the block / signal
    times = [float(s) for s in re.findall(r"t = ([-+0-9.eE]+) s", msg)]
    assert times and abs(times[0] - 0.5) < 1e-3, msg              # where it failed
    r = err.partial
    assert r is not None and r.status == "failed"
    assert len(r.t) > 2 and abs(r.t[-1] - 0.5) < 1e-3
    assert r.t[0] == 0.0


ALGEBRAIC_LOOP = open(os.path.join(os.path.dirname(__file__), "..", "data",
                                   "unsolvable_loop.yaml")).read()


def test_unsolvable_algebraic_loop_walks_the_loop(tmp_path):
    p = write(tmp_path, ALGEBRAIC_LOOP)
    with pytest.raises(AlgebraicLoopError) as ei:
        spidersim.load(str(p)).simulate(t_end=0.1, jit=False, progress=step_guard())
    err = ei.value
    msg = str(err)
    # the walk, port by port, through both blocks
    for port in ("sum.y", "fb.u", "fb.y", "sum.u2"):
        assert port in msg, msg
    assert "sum.y -> fb.u" in msg and "fb.y -> sum.u2" in msg
    assert err.partial is not None and err.partial.status == "failed"
    # where: the diagram file, at a block or a connection of the loop
    loop_lines = {line_of(p, s) for s in ("sum: {type: Sum", "fb:  {type: Gain",
                                          "sum.y -> fb.u", "fb.y -> sum.u2")}
    assert err.file and os.path.samefile(err.file, p), f"no file: {err!r}"
    assert err.line in loop_lines, f"line {err.line} not one of {sorted(loop_lines)}"
    assert err.block in ("sum", "fb")


def test_every_error_is_a_spidersim_error():
    for cls in (DiagramError, BlockTypeError, ParameterError, WiringError,
                AlgebraicLoopError, IntegrationError):
        assert issubclass(cls, SpidersimError) and cls.exit_code == 2
    assert issubclass(BlockTypeError, DiagramError)


# ---------------------------------------------------------------------------- the table
class Case(NamedTuple):
    """One bad diagram: the error class, the line (the first line containing ``needle``),
    the block, and substrings the message must contain (what was expected and found)."""
    id: str
    text: str
    error: type
    needle: str
    block: str | None
    contains: tuple
    guards: str | None = None    # what the case guards, when the id does not say it


CASES = [
    Case(
        'unknown_block_type_suggests_nearest_names',
        """\
        blocks:
          src: {type: Constant, value: 1}
          g:   {type: Gian, k: 2}
        connections:
          - src.y -> g.u
        """,
        BlockTypeError, 'type: Gian', 'g',
        ("unknown block type 'Gian'", 'Gain', 'spidersim blocks')),
    Case(
        'unknown_parameter_suggests_near_name',
        """\
        blocks:
          src: {type: Constant, value: 1}
          g:
            type: Gain
            kk: 2
        connections:
          - src.y -> g.u
        """,
        ParameterError, 'kk: 2', 'g',
        ("unknown parameter 'kk'", "'k'")),
    Case(
        'missing_required_parameter',
        """\
        blocks:
          u:  {type: Constant, value: 1}
          ss:
            type: StateSpace
            A: [[-1]]
            B: [[1]]
        connections:
          - u.y -> ss.u
        """,
        ParameterError, 'ss:', 'ss',
        ("missing parameter 'C'", 'StateSpace')),
    Case(
        'parameter_out_of_bounds',
        """\
        blocks:
          v: {type: Constant, value: 1}
          motor:
            type: DCMotor
            R: -1
        connections:
          - v.y -> motor.v
        """,
        ParameterError, 'R: -1', 'motor',
        ("'R'", '> 0', '-1')),
    Case(
        'time_table_value_length_differs_from_time',
        """\
        blocks:
          tt:
            type: TimeTable
            time: [0, 1, 2]
            value: [0, 1]
        """,
        ParameterError, 'value: [0, 1]', 'tt',
        ("'value'", '3', '2')),
    Case(
        'string_parameter_not_in_choices_suggests_nearest',
        """\
        blocks:
          e: {type: Constant, value: 1}
          pi:
            type: PI
            antiwindup: clamp
        connections:
          - e.y -> pi.e
        """,
        ParameterError, 'antiwindup: clamp', 'pi',
        ("'clamp'", 'clamping', 'backcalc', 'none')),
    Case(
        'expression_syntax_error',
        """\
        parameters:
          K: 2
        blocks:
          src: {type: Constant, value: 1}
          g:
            type: Gain
            k: 2*(K+
        connections:
          - src.y -> g.u
        """,
        ParameterError, 'k: 2*(K+', 'g',
        ("'k'", '2*(K+', 'parse')),
    Case(
        'expression_unknown_name_suggests_parameter',
        """\
        parameters:
          gain_K: 2
        blocks:
          src: {type: Constant, value: 1}
          g:
            type: Gain
            k: 3*gain_k
        connections:
          - src.y -> g.u
        """,
        ParameterError, 'k: 3*gain_k', 'g',
        ("unknown name 'gain_k'", 'gain_K')),
    Case(
        'parameters_section_unknown_name_suggests_earlier_parameter',
        """\
        parameters:
          tau: 0.1
          k: 2*taux
        blocks:
          src: {type: Constant, value: 1}
          g: {type: Gain, k: k}
        connections:
          - src.y -> g.u
        """,
        ParameterError, 'k: 2*taux', None,
        ("unknown name 'taux'", 'tau')),
    Case(
        'integer_too_large_for_a_float',
        """\
        blocks:
          src: {type: Constant, value: 1}
          g:
            type: Gain
            k: 2**10000
        connections:
          - src.y -> g.u
        """,
        ParameterError, 'k: 2**10000', 'g',
        ('2**10000',),
        guards='A huge integer result must be a ParameterError, not a raw OverflowError.'),
    Case(
        'unknown_port_names_available_ports',
        """\
        blocks:
          src: {type: Constant, value: 1}
          g: {type: Gain, k: 2}
        connections:
          - src.y -> g.in
        """,
        WiringError, 'src.y -> g.in', 'g',
        ("no input 'in'", 'inputs: u')),
    Case(
        'size_mismatch_mux_into_state_space',
        """\
        blocks:
          a: {type: Constant, value: 1}
          b: {type: Constant, value: 2}
          mux: {type: Mux, n: 2}
          ss: {type: StateSpace, A: [[-1]], B: [[1]], C: [[1]]}
        connections:
          - a.y -> mux.u1
          - b.y -> mux.u2
          - mux.y -> ss.u
        """,
        WiringError, 'mux.y -> ss.u', 'ss',
        ('size mismatch', 'mux.y -> ss.u', 'gives 2', 'expects 1')),
    Case(
        'subsystem_includes_itself_directly',
        """\
        subsystems:
          me: main.yaml
        blocks:
          step: {type: Step}
          inner: {type: me}
        connections:
          - step.y -> inner.u
        """,
        DiagramError, 'inner: {type: me}', 'inner',
        ('includes itself', 'main.yaml -> main.yaml')),
    Case(
        'unknown_top_level_section_suggests_near_name',
        """\
        blocks:
          a: {type: Constant, value: 1}
          g: {type: Gain}
        conections:
          - a.y -> g.u
        """,
        DiagramError, 'conections:', None,
        ("unknown section 'conections'", "did you mean 'connections'")),
    Case(
        'unknown_simulation_setting',
        """\
        blocks:
          a: {type: Constant, value: 1}
          g: {type: Gain}
        connections:
          - a.y -> g.u
        simulation:
          t_end: 1
          rel_tol: 1e-6
        """,
        DiagramError, 'rel_tol:', None,
        ("unknown simulation setting 'rel_tol'", 'rtol', 't_end')),
]


@pytest.mark.parametrize("case", CASES, ids=[c.id for c in CASES])
def test_bad_diagram_is_reported_where_it_is(tmp_path, case):
    """Each case of the table: the error's class, file:line and block, and the message's
    key words (the expected and the found value, the suggested near name)."""
    p = write(tmp_path, case.text)
    err = load_error(p, case.error)
    assert_where(err, p, line_of(p, case.needle), block=case.block)
    for s in case.contains:
        assert s in err.message, (s, err.message)
