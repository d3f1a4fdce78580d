"""The CLI reports user errors as ``spidersim: error: file:line: block 'path': message``
on stderr, without a traceback, and returns exit status 2; a run that fails part-way writes
the data computed up to the failure (``result.npz``, ``report.txt`` with status failed).

Runs are interpreted (``--no-jit``) and short.
"""
from __future__ import annotations

import os
import re
import textwrap

import numpy as np
import pytest

import spidersim.cli
from spidersim.cli import main

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
LAG = os.path.join(ROOT, "diagrams", "lib", "lag.yaml")


def write(tmp_path, text, name="main.yaml"):
    p = tmp_path / name
    p.parent.mkdir(parents=True, exist_ok=True)
    p.write_text(textwrap.dedent(text))
    return p


def line_of(path, needle):
    for k, ln in enumerate(open(path).read().splitlines()):
        if needle in ln:
            return k + 1
    raise AssertionError(f"{needle!r} not in {path}")


def run_cli(argv, capsys):
    """Exit code and the (stdout, stderr) of ``spidersim <argv>``; exceptions other than
    SystemExit escaping ``main`` are failures (a raw traceback for the user)."""
    try:
        rc = main([str(a) for a in argv])
    except SystemExit as exc:           # argparse
        rc = exc.code
    out, err = capsys.readouterr()
    return rc, out, err


def assert_clean_error(rc, out, err, where=None, *parts):
    """Exit 2, one ``spidersim: error:`` report naming ``where`` and every part; no
    traceback on either stream."""
    assert rc == 2, f"exit code {rc}\n{out}\n{err}"
    assert "Traceback" not in out and "Traceback" not in err, err
    assert "spidersim: error: " in err, err
    report = err.split("spidersim: error: ", 1)[1]
    if where is not None:
        # ``file: `` also accepts ``file:LINE: `` (a --set error points at the block's line)
        ok = report.startswith(where) or (
            where.endswith(": ") and re.match(re.escape(where[:-2]) + r":\d+: ", report))
        assert ok, f"expected {where!r} at the start of: {report}"
    for part in parts:
        assert part in report, f"{part!r} not in: {report}"


# ---------------------------------------------------------------------------- load errors
CASES = {
    "unknown_type": ("""\
        blocks:
          src: {type: Constant, value: 1}
          g:   {type: Gian, k: 2}
        connections:
          - src.y -> g.u
        """, "type: Gian", ["block 'g': ", "unknown block type 'Gian'", "Gain"]),
    "out_of_bounds": ("""\
        blocks:
          v: {type: Constant, value: 1}
          motor:
            type: DCMotor
            R: -1
        connections:
          - v.y -> motor.v
        """, "R: -1", ["block 'motor': ", "parameter 'R' must be > 0, got -1"]),
    "choices": ("""\
        blocks:
          e: {type: Constant, value: 1}
          pi: {type: PI, antiwindup: clamp}
        connections:
          - e.y -> pi.e
        """, "antiwindup: clamp", ["block 'pi': ", "'clamp'", "clamping"]),
    "unsafe_expression": ("""\
        parameters:
          a: "().__class__"
        blocks:
          src: {type: Constant, value: 1}
          g: {type: Gain, k: a}
        connections:
          - src.y -> g.u
        """, "a: ", ["not allowed"]),
    "unknown_port": ("""\
        blocks:
          src: {type: Constant, value: 1}
          g: {type: Gain, k: 2}
        connections:
          - src.y -> g.in
        """, "src.y -> g.in", ["no input 'in'", "inputs: u"]),
    "size_mismatch": ("""\
        blocks:
          c: {type: Constant, value: [1, 2]}
          ss: {type: StateSpace, A: [[-1]], B: [[1]], C: [[1]]}
        connections:
          - c.y -> ss.u
        """, "c.y -> ss.u", ["size mismatch", "gives 2", "expects 1"]),
    "two_sources": ("""\
        blocks:
          a: {type: Constant, value: 1}
          b: {type: Constant, value: 2}
          g: {type: Gain}
        connections:
          - a.y -> g.u
          - b.y -> g.u
        """, "b.y -> g.u", ["two sources", "a.y", "b.y"]),
    "unconnected": ("""\
        blocks:
          st: {type: Step}
          ss: {type: StateSpace, A: [[-1]], B: [[1]], C: [[1]]}
        """, "ss: {type", ["block 'ss': ", "input 'u'", "not connected", "st.y"]),
    "duplicate_block": ("""\
        blocks:
          g: {type: Gain}
          src: {type: Constant, value: 1}
          g: {type: Gain, k: 3}
        connections:
          - src.y -> g.u
        """, "g: {type: Gain, k: 3}", ["duplicate key 'g'"]),
    "yaml_syntax": ("""\
        blocks:
          a: {type: Constant, value: 1}
          g: {type: Gain, k: [1, 2}
        """, "k: [1, 2}", ["YAML syntax error"]),
    "unknown_section": ("""\
        blocks:
          a: {type: Constant, value: 1}
        conections: []
        """, "conections:", ["unknown section 'conections'", "did you mean 'connections'"]),
    "unknown_setting": ("""\
        blocks:
          a: {type: Constant, value: 1}
        simulation: {t_end: 1, rel_tol: 1e-6}
        """, "simulation:", ["unknown simulation setting 'rel_tol'"]),
    "missing_subsystem": ("""\
        subsystems:
          lag: lib/nolag.yaml
        blocks:
          step: {type: Step}
          l: {type: lag}
        connections:
          - step.y -> l.u
        """, "lag: lib/nolag.yaml", ["not found", "nolag.yaml"]),
    "huge_integer": ("""\
        blocks:
          src: {type: Constant, value: 1}
          g: {type: Gain, k: 2**10000}
        connections:
          - src.y -> g.u
        """, "k: 2**10000", ["block 'g': ", "2**10000"]),
}


@pytest.mark.parametrize("command", ["check", "run"])
@pytest.mark.parametrize("case", list(CASES))
def test_load_error_is_reported_without_traceback(tmp_path, capsys, case, command):
    text, needle, parts = CASES[case]
    p = write(tmp_path, text)
    extra = ["--no-jit", "--no-plots", "--out", tmp_path / "out"] if command == "run" else []
    rc, out, err = run_cli([command, p] + extra, capsys)
    assert_clean_error(rc, out, err, f"{p}:{line_of(p, needle)}: ", *parts)
    assert not (tmp_path / "out").exists()        # nothing written for a diagram not loaded


def test_missing_diagram_file(tmp_path, capsys):
    rc, out, err = run_cli(["check", tmp_path / "nope.yaml"], capsys)
    assert_clean_error(rc, out, err, None, "not found", "nope.yaml")


def _special(tmp_path, kind):
    """A path of the given kind: a FIFO (no writer: opening it to read would block), a
    character device, a folder."""
    if kind == "fifo":
        os.mkfifo(tmp_path / "pipe.yaml")
        return str(tmp_path / "pipe.yaml")
    return {"null": "/dev/null", "zero": "/dev/zero", "folder": str(tmp_path)}[kind]


@pytest.mark.parametrize("kind, words", [
    ("null", "diagram file is not a regular file (a character device): /dev/null"),
    ("zero", "diagram file is not a regular file (a character device): /dev/zero"),
    ("fifo", "diagram file is not a regular file (a FIFO, a named pipe)"),
    ("folder", "diagram file is a folder, not a file"),
])
@pytest.mark.parametrize("command", ["check", "run"])
def test_diagram_path_that_is_not_a_regular_file(tmp_path, capsys, kind, words, command):
    """``check /dev/zero``, ``/dev/null`` or a FIFO said "not found"; each says what the
    path is instead, and none is opened (a FIFO would block the read)."""
    rc, out, err = run_cli([command, _special(tmp_path, kind)], capsys)
    assert_clean_error(rc, out, err, None, words)


@pytest.mark.parametrize("kind, words", [
    ("null", "subsystem file for type 'S' is not a regular file (a character device)"),
    ("fifo", "subsystem file for type 'S' is not a regular file (a FIFO, a named pipe)"),
])
def test_subsystem_path_that_is_not_a_regular_file(tmp_path, capsys, kind, words):
    main_yaml = write(tmp_path, f"""\
        subsystems: {{S: {_special(tmp_path, kind)}}}
        blocks:
          s: {{type: S}}
        """)
    rc, out, err = run_cli(["check", main_yaml], capsys)
    assert_clean_error(rc, out, err, f"{main_yaml}:1: ", words)


def test_a_fifo_swapped_in_after_the_check_is_not_read(tmp_path):
    """The reader itself opens without blocking and refuses what is not a regular file
    (a FIFO put in place between a check by name and the read would wait forever)."""
    from spidersim.errors import DiagramError
    from spidersim.text.yamlio import read_file
    with pytest.raises(DiagramError, match=r"file is not a regular file \(a FIFO"):
        read_file(_special(tmp_path, "fifo"))
    with pytest.raises(DiagramError, match=r"file is not a regular file \(a character"):
        read_file("/dev/zero")


# ---------------------------------------------------------------------------- --set
@pytest.fixture
def set_diagram(tmp_path):
    write(tmp_path, open(LAG).read(), "lib/lag.yaml")
    return write(tmp_path, """\
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
        """)


@pytest.mark.parametrize("command", ["check", "run"])
def test_set_unknown_top_level_parameter(set_diagram, tmp_path, capsys, command):
    extra = ["--no-jit", "--no-plots", "--out", tmp_path / "out"] if command == "run" else []
    rc, out, err = run_cli([command, set_diagram, "--set", "gian=3"] + extra, capsys)
    assert_clean_error(rc, out, err, f"{set_diagram}: ", "gian", "did you mean gain")


def test_set_unknown_block_parameter(set_diagram, capsys):
    rc, out, err = run_cli(["check", set_diagram, "--set", "g.kk=3"], capsys)
    assert_clean_error(rc, out, err, f"{set_diagram}: ", "block 'g': ", "g.kk", "'kk'")


def test_set_unknown_subsystem_parameter(set_diagram, capsys):
    rc, out, err = run_cli(["check", set_diagram, "--set", "l.tauu=3"], capsys)
    assert_clean_error(rc, out, err, f"{set_diagram}: ", "l.tauu")
    assert "tau" in err.replace("tauu", ""), err         # suggests the near name


def test_set_nested_block_parameter(set_diagram, capsys):
    rc, out, err = run_cli(["check", set_diagram, "--set", "l.gain.kk=3"], capsys)
    assert_clean_error(rc, out, err, None, "l.gain.kk")


def test_set_without_equals_sign(set_diagram, capsys):
    rc, out, err = run_cli(["check", set_diagram, "--set", "gain"], capsys)
    assert_clean_error(rc, out, err, None, "--set expects path=value", "'gain'")


@pytest.mark.parametrize("item, words", [("gain=.nan", "--set gain must not be NaN"),
                                         ("l.tau=.nan", "--set l.tau must not be NaN")])
def test_set_nan_is_refused(set_diagram, capsys, item, words):
    """``--set gain=.nan`` was accepted (a NaN diagram parameter vanished in min/max)."""
    rc, out, err = run_cli(["check", set_diagram, "--set", item], capsys)
    assert_clean_error(rc, out, err, None, words)


def test_set_valid_value_still_works(set_diagram, capsys):
    rc, out, err = run_cli(["check", set_diagram, "--set", "gain=3", "--set", "l.tau=0.2"],
                           capsys)
    assert rc == 0, err
    assert "OK" in out


# ---------------------------------------------------------------------------- run failures
class Stalled(Exception):
    pass


class GuardedProgress(spidersim.cli.Progress):
    """The CLI's progress bar, stopping a run after 50000 steps (a hang guard)."""

    def __init__(self, *a, **kw):
        super().__init__(*a, **kw)
        self.n = 0

    def __call__(self, t):
        self.n += 1
        if self.n > 50000:
            raise Stalled(f"the integrator took 50000 steps and stands at t = {t!r}")
        super().__call__(t)


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


def _run_guarded(argv, capsys, monkeypatch):
    monkeypatch.setattr(spidersim.cli, "Progress", GuardedProgress)
    try:
        return run_cli(argv, capsys)
    except Stalled as exc:
        pytest.fail(f"the run hangs instead of failing: {exc}")


def test_run_failure_writes_partial_data_and_exits_non_zero(tmp_path, capsys, monkeypatch):
    p = write(tmp_path, DIVISION)
    out_dir = tmp_path / "out"
    rc, out, err = _run_guarded(["run", p, "--no-jit", "--no-plots", "--out", out_dir],
                                capsys, monkeypatch)
    assert rc != 0 and rc is not None, err
    assert "Traceback" not in out + err
    assert "spidersim: error: " in err and "div" in err.split("spidersim: error: ", 1)[1]
    assert "partial data" in err
    with np.load(out_dir / "result.npz") as z:
        t = z["t"]
        assert len(t) > 2 and abs(t[-1] - 0.5) < 1e-3
        assert "int.y" in z.files and len(z["int.y"]) == len(t)
    report = (out_dir / "report.txt").read_text()
    assert "status: failed" in report


ALGEBRAIC_LOOP = open(os.path.join(os.path.dirname(__file__), "data",
                                   "unsolvable_loop.yaml")).read()


def test_run_unsolvable_loop_is_reported_and_keeps_data(tmp_path, capsys, monkeypatch):
    p = write(tmp_path, ALGEBRAIC_LOOP)
    out_dir = tmp_path / "out"
    rc, out, err = _run_guarded(["run", p, "--no-jit", "--no-plots", "--t-end", "0.1",
                                 "--out", out_dir], capsys, monkeypatch)
    assert_clean_error(rc, out, err, None, "algebraic loop", "sum.y -> fb.u",
                       "fb.y -> sum.u2")
    assert (out_dir / "result.npz").exists()
    assert "status: failed" in (out_dir / "report.txt").read_text()


@pytest.mark.parametrize("argv, words", [
    (["run", "d.yaml", "--t-end", "nan"], "argument --t-end: expected a finite number > 0"),
    (["run", "d.yaml", "--t-end", "true"], "argument --t-end: expected a number > 0"),
    (["run", "d.yaml", "--t-end", "-1"], "argument --t-end: expected a finite number > 0"),
    (["sweep", "d.yaml", "--vary", "k=1", "--t-end", "inf"],
     "argument --t-end: expected a finite number > 0, got 'inf'"),
    (["sweep", "d.yaml", "--vary", "k=1", "--workers", "-1"],
     "argument --workers: expected an integer in 0..256, got -1"),
    (["sweep", "d.yaml", "--vary", "k=1", "--workers", "100000"],
     "argument --workers: expected an integer in 0..256, got 100000"),
    (["run", "d.yaml", "--remote", "http://x", "--timeout", "nan"], "argument --timeout"),
    (["serve", "--max-t-end", "nan"], "argument --max-t-end: expected a finite number > 0"),
    (["serve", "--job-timeout", "0"], "argument --job-timeout: expected a finite number > 0"),
    (["serve", "--max-jobs", "0"], "argument --max-jobs: expected an integer >= 1"),
    (["serve", "--max-body", "1.5"], "argument --max-body: expected an integer >= 1"),
    (["serve", "--port", "70000"], "argument --port: expected an integer in 1..65535"),
    (["serve", "--max-record-mb", "inf"], "argument --max-record-mb: expected a finite"),
    (["serve", "--keep-days", "0"], "argument --keep-days: expected a finite number > 0"),
    (["serve", "--max-points", "10"], "argument --max-points: expected an integer >= 1000"),
    (["serve", "--add-user", "a", "--revoke-user", "a"], "not allowed with argument"),
    # -o "" wrote the schema to standard output (as --out "" once meant the default folder)
    (["schema", "-o", ""], "argument -o/--output: must name a file, got an empty text"),
    (["schema", "--output", " "], "argument -o/--output: must name a file"),
])
def test_numeric_options_refuse_nan_inf_and_out_of_range(argv, words, capsys):
    """Numeric options are finite and in range before anything runs: ``--max-t-end nan``
    made every run pass the service's limit (``t_end > nan`` is False), ``--job-timeout
    nan`` never timed out, ``--t-end true`` and ``-1`` are no times. Exit status 2 and the
    option's name, no traceback."""
    with pytest.raises(SystemExit) as ei:
        main(argv)
    err = capsys.readouterr().err
    assert ei.value.code == 2 and words in err and "Traceback" not in err


OSCILLATOR = """\
    blocks:
      x: {type: Integrator, x0: 1}
      v: {type: Integrator, x0: 0}
      k: {type: Gain, k: -1}
    connections: [x.y -> k.u, k.y -> v.u, v.y -> x.u]
    simulation: {t_end: 1000, max_step: 1e-9}
    """


def test_run_whose_rows_cannot_fit_in_memory_is_refused(tmp_path, capsys, monkeypatch):
    """``max_step: 1e-9`` over 1000 s records at least 1e12 rows: refused before the run
    with what to change (this file once grew to 23 GB until the kernel killed it)."""
    p = write(tmp_path, OSCILLATOR)
    rc, out, err = _run_guarded(["run", p, "--no-jit", "--no-plots", "--out",
                                 tmp_path / "out"], capsys, monkeypatch)
    assert_clean_error(rc, out, err, f"{p}: ", "would not fit in memory",
                       "max_step = 1e-09 s over 1000 s", "output_interval")


def test_run_at_the_recording_budget_stops_and_keeps_data(tmp_path, capsys, monkeypatch):
    """A budget of 0.1 MB (SPIDERSIM_RECORD_LIMIT_MB) reached part-way: exit 2, the rows
    so far in result.npz, status failed."""
    monkeypatch.setenv("SPIDERSIM_RECORD_LIMIT_MB", "0.1")
    p = write(tmp_path, OSCILLATOR.replace("max_step: 1e-9", "rtol: 1e-9"))
    out_dir = tmp_path / "out"
    rc, out, err = _run_guarded(["run", p, "--no-jit", "--no-plots", "--out", out_dir],
                                capsys, monkeypatch)
    assert_clean_error(rc, out, err, f"{p}: ", "reached the memory budget",
                       "SPIDERSIM_RECORD_LIMIT_MB")
    with np.load(out_dir / "result.npz") as z:
        t = z["t"]
        assert 1000 < len(t) <= 0.1e6 // 32 and t[-1] < 1000
        assert np.max(np.abs(z["x.y"] - np.cos(t))) < 1e-4       # 470 s of LSODA at 1e-9
    assert "status: failed" in (out_dir / "report.txt").read_text()


@pytest.mark.parametrize("where, argv", [("--t-end", ["--t-end", "5e-324"]),
                                         ("simulation.t_end", [])])
def test_run_shorter_than_the_stall_step_is_refused(tmp_path, capsys, monkeypatch, where,
                                                    argv):
    """A run of 5e-324 s made the default max_step (t_end / 50) zero and was refused as
    'max_step must be > 0' (never set by the user); one of 1e-300 s was reported as a
    stall. Both are refused as too short, naming the setting; 1e-7 s runs."""
    p = write(tmp_path, """\
        blocks:
          u: {type: Step, t_step: 0.5}
          x: {type: Integrator}
        connections: [u.y -> x.u]
        simulation: {t_end: 1e-9}
        """)
    rc, out, err = _run_guarded(["run", p, "--no-jit", "--no-plots", "--out",
                                 tmp_path / "out"] + argv, capsys, monkeypatch)
    assert_clean_error(rc, out, err, f"{p}", f"{where}: t_end must be at least 1e-07 s")
    rc, out, err = _run_guarded(["run", p, "--no-jit", "--no-plots", "--out",
                                 tmp_path / "out", "--t-end", "1e-7"], capsys, monkeypatch)
    assert rc == 0, err


def test_argument_that_is_not_utf8_is_refused(capsys):
    """A byte that is not UTF-8 on the command line arrives as a lone surrogate
    (``--set V_max=$'\\xff'``): a clear error and status 2, not an internal error."""
    servo = os.path.join(os.path.dirname(os.path.dirname(os.path.abspath(__file__))),
                         "diagrams", "servo.yaml")
    code = main(["check", servo, "--set", "V_max=\udcff"])
    err = capsys.readouterr().err
    assert code == 2 and "not UTF-8 text" in err and "V_max=" in err, err


def test_scipy_failure_warning_is_part_of_the_error_not_raw_lines(tmp_path):
    """``--set motor.b=1e300``: LSODA fails, and SciPy's own warning ("lsoda: Repeated
    convergence failures ...") printed as two raw lines (file path, source line) before
    the clean error; it is now in the error's message. A real process: pytest catches
    warnings itself."""
    import subprocess
    import sys
    res = subprocess.run([sys.executable, "-m", "spidersim.cli", "run",
                          os.path.join(ROOT, "diagrams", "servo.yaml"), "--set",
                          "motor.b=1e300", "--no-jit", "--no-plots", "--out",
                          str(tmp_path / "out")], capture_output=True, text=True, timeout=300)
    assert res.returncode == 2 and "Traceback" not in res.stderr
    assert "UserWarning" not in res.stderr and "integrator.run" not in res.stderr
    assert ("Unexpected istate in LSODA. (SciPy: lsoda: Repeated convergence failures"
            in res.stderr.split("spidersim: error: ", 1)[1])
