"""`spidersim linearize`: named analyses, ad-hoc signals, files written, errors."""
import json
import os
import re

import numpy as np
import pytest

from spidersim.cli import main

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
SERVO = os.path.join(ROOT, "diagrams", "servo.yaml")


def _run(capsys, *argv):
    rc = main([str(a) for a in argv])
    out, err = capsys.readouterr()
    return rc, out, err


def test_named_analysis_prints_figures_and_writes_files(tmp_path, capsys):
    rc, out, err = _run(capsys, "linearize", SERVO, "speed_closed", "--no-jit", "--out",
                        tmp_path)
    assert rc == 0, err
    # speed loop closed, position loop opened: unity DC gain, a finite bandwidth
    assert re.search(r"DC gain:\s+1\b", out), out
    bw = float(re.search(r"-3 dB bandwidth:\s+([0-9.eE+-]+) rad/s", out).group(1))
    assert 10 < bw < 200
    data = np.load(tmp_path / "linearization.npz")
    assert data["A"].shape == (5, 5) and list(data["inputs"]) == ["pos_ctrl/y"]
    js = json.loads((tmp_path / "linearization.json").read_text())
    assert js["outputs"] == ["motor/w"] and len(js["states"]) == 5
    assert (tmp_path / "bode.png").stat().st_size > 10000


def test_loop_transfer_from_the_command_line(tmp_path, capsys):
    rc, out, err = _run(capsys, "linearize", SERVO, "--loop", "pos_ctrl.y", "--no-jit",
                        "--out", tmp_path)
    assert rc == 0, err
    assert "integrator" in out          # the position loop transfer has a free integrator
    pm = float(re.search(r"phase margin:\s+([0-9.eE+-]+) deg", out).group(1))
    assert 20 < pm < 90


def test_ad_hoc_signals(tmp_path, capsys):
    rc, out, err = _run(capsys, "linearize", SERVO, "--input", "sat.y", "--output",
                        "motor.i", "--output", "motor.w", "--no-jit", "--out", tmp_path)
    assert rc == 0, err
    assert "sat/y -> motor/i" in out and "sat/y -> motor/w" in out


def test_every_analysis_without_a_name(tmp_path, capsys):
    """No name: every analysis of the file, each in its own folder; margins only for the
    loop transfers, bandwidth and peak for the closed-loop pair."""
    rc, out, err = _run(capsys, "linearize", SERVO, "--no-jit", "--out", tmp_path)
    assert rc == 0, err
    blocks = out.split("linear model ")[1:]
    assert [b.split(":")[0] for b in blocks] == ["current_loop", "speed_closed",
                                                 "position_loop"]
    closed = blocks[1]
    assert "phase margin" not in closed and "peak gain" in closed and "bandwidth" in closed
    assert "phase margin" in blocks[0] and "conditionally stable" in blocks[0]
    assert "phase margin" in blocks[2] and "Hz)" in blocks[2]
    for name in ("current_loop", "speed_closed", "position_loop"):
        assert (tmp_path / name / "bode.png").exists()


LIN3 = """\
blocks:
  c: {type: Constant, value: [1, 2, 3]}
  g: {type: Gain, k: [2, 3, 5]}
  i: {type: Integrator, x0: [0, 0, 0]}
connections: [c.y -> g.u, g.y -> i.u]
simulation: {t_end: 1}
"""


@pytest.mark.parametrize("inp,out,dc", [("c.y[-1]", "g.y[-1]", 5), ("c.y[-3]", "g.y[0]", 2),
                                        ("c.y[-1]", "g.y[1]", 0)])
def test_ad_hoc_signals_count_from_the_end(tmp_path, capsys, inp, out, dc):
    """``c.y[-1]`` is the last element, as in connections (it was 'index out of range
    (size 3)'); the model's names are the ones given."""
    f = tmp_path / "lin3.yaml"
    f.write_text(LIN3)
    rc, text, err = _run(capsys, "linearize", f, "--input", inp, "--output", out,
                         "--no-jit", "--out", tmp_path / "o")
    assert rc == 0, err
    assert f"{inp.replace('.', '/')} -> {out.replace('.', '/')}" in text
    data = np.load(tmp_path / "o" / "linearization.npz")
    np.testing.assert_allclose(np.asarray(data["D"]).ravel(), [dc], atol=1e-8)


@pytest.mark.parametrize("inp,words", [
    ("c.y[-4]", "signal 'c.y[-4]': index -4 out of range (size 3: 0..2, or -3..-1 from the "
                "end)"),
    ("c.y[١]", "signal 'c.y[١]': non-ASCII character '١' (U+0661 ARABIC-INDIC DIGIT ONE) at "
               "character 5"),
])
def test_ad_hoc_signal_index_errors(tmp_path, capsys, inp, words):
    f = tmp_path / "lin3.yaml"
    f.write_text(LIN3)
    rc, text, err = _run(capsys, "linearize", f, "--input", inp, "--output", "g.y[0]",
                         "--no-jit", "--out", tmp_path / "o")
    assert rc == 2 and words in err and "Traceback" not in err
    assert not (tmp_path / "o").exists()


def test_errors(tmp_path, capsys):
    rc, out, err = _run(capsys, "linearize", SERVO, "speed_closd", "--no-jit")
    assert rc == 2 and "did you mean speed_closed" in err
    rc, out, err = _run(capsys, "linearize", SERVO, "--input", "sat.yy", "--output", "motor.w",
                        "--no-jit")
    assert rc == 2 and "unknown signal 'sat.yy'" in err and "Traceback" not in err
    rc, out, err = _run(capsys, "linearize", SERVO, "--at", "soon", "--loop", "pos_ctrl.y")
    assert rc == 2 and "--at expects" in err


@pytest.mark.parametrize("at", ["nan", "inf", "-0.1", "1.5", "1e300", "1e-9"])
def test_at_outside_the_run_is_refused(capsys, at):
    """``--at nan`` was reported as 't_end must be > 0.0, got nan'; ``1e300`` simulated to
    1e300 s; ``1e-9`` failed as a run too short, without naming ``--at``. A time must lie
    in [0, t_end] (servo.yaml: 1 s), 0 or at least 1e-7 s, as in an analysis entry."""
    rc, out, err = _run(capsys, "linearize", SERVO, "--at", at, "--loop", "pos_ctrl.y",
                        "--no-jit")
    assert rc == 2 and "--at: the operating point's time must be in [0, t_end] = [0, 1] s" \
        in err and "Traceback" not in err


def _servo_with_analysis(tmp_path, entry):
    """servo.yaml with its analysis section replaced by one entry ``x``."""
    text = open(SERVO).read().split("\nanalysis:")[0]
    path = tmp_path / "servo_x.yaml"
    path.write_text(text + "\nanalysis:\n  x: " + entry + "\n")
    return str(path)


@pytest.mark.parametrize("entry, words", [
    ("{loop: pos_ctrl.y, at: {trim: {targets: {motor.w: 1e9}, derivatives: 7}}}",
     "'derivatives' ('all' or a list) must be a list"),
    ("{loop: pos_ctrl.y, at: {trim: {targetz: {motor.w: 1}}}}", "unknown key 'targetz'"),
    ("{loop: pos_ctrl.y, at: {trim: {targets: {motor.w: .nan}}}}",
     "target 'motor.w' must be a finite number"),
    ("{loop: pos_ctrl.y, at: {trim: {free_inputs: sat.y}}}",
     "'free_inputs' must be a list"),
    ("{loop: pos_ctrl.y, inputs: [pos_ctrl.y], outputs: [motor.w]}",
     "give either 'loop' or 'inputs' and 'outputs', not both"),
    # a list target was broadcast against its signal (a 1-element signal "trimmed" to
    # three values, then a residual of 1 reported as non-convergence); x0 of the wrong size
    ("{loop: pos_ctrl.y, at: {trim: {targets: {motor.w: [1, 2, 3]}}}}",
     "target 'motor.w' has 3 values, the signal has 1"),
    ("{loop: pos_ctrl.y, at: {trim: {x0: [0, 1]}}}", "'x0' has 2 value(s), the diagram has"),
    ("{loop: pos_ctrl.y, at: {trim: {targets: {motor.ww: 1}}}}", "unknown signal 'motor.ww'"),
])
def test_check_refuses_bad_trim_and_analysis_entries(tmp_path, capsys, entry, words):
    """``check`` refuses what ``linearize`` would fail on, with the entry's line: a trim
    mapping's keys and values (each of these was an internal error, or was accepted by
    check), and an entry with both a loop and inputs/outputs (the latter were dropped)."""
    path = _servo_with_analysis(tmp_path, entry)
    for argv in (["check", path], ["linearize", path, "x", "--no-jit", "--out",
                                   str(tmp_path / "out")]):
        assert main(argv) == 2
        err = capsys.readouterr().err
        assert words in err and "servo_x.yaml:" in err, err
    assert not (tmp_path / "out").exists()


def test_trim_target_written_as_text_is_a_number(tmp_path, capsys):
    """``motor.w: 1e9`` (text to YAML 1.1) is a number here as everywhere else: an
    unreachable target is a clear 'trim did not converge', not an internal error."""
    path = _servo_with_analysis(tmp_path, "{loop: pos_ctrl.y, at: {trim: {targets: "
                                           "{motor.w: 1e9}}}}")
    assert main(["linearize", path, "x", "--no-jit", "--out", str(tmp_path / "o")]) == 2
    assert "trim did not converge" in capsys.readouterr().err


@pytest.mark.parametrize("argv, words", [
    (["current_loop", "--loop", "pos_ctrl.y"], "give an analysis name or --loop, not both"),
    (["--loop", "motor.w", "--input", "pos_ctrl.y", "--output", "motor.w"],
     "give --loop or --input/--output, not both"),
    (["--output", "motor.w"], "--output and --open need at least one --input"),
])
def test_conflicting_linearize_options_are_refused(tmp_path, capsys, argv, words):
    """Options that choose different linearizations are refused (the later ones were
    dropped without a word)."""
    assert main(["linearize", SERVO] + argv + ["--out", str(tmp_path / "o")]) == 2
    assert words in capsys.readouterr().err


def test_analysis_name_with_math_text_is_refused_before_any_folder(tmp_path, capsys):
    """An analysis name titles the Bode plot and names a folder: '$\\foo$' was an internal
    error in matplotlib after an empty folder had been made; now check and linearize refuse
    it with the file and line, and nothing is written."""
    path = tmp_path / "lin.yaml"
    path.write_text("blocks:\n  c: {type: Step}\n  g: {type: TransferFunction, num: [1], "
                    "den: [1, 1]}\nconnections:\n  - c.y -> g.u\nanalysis:\n  ok: {inputs: "
                    "[c.y], outputs: [g.y]}\n  '$\\foo$': {inputs: [c.y], outputs: [g.y]}\n")
    out = tmp_path / "out"
    for argv in (["check", path], ["linearize", path, "--no-jit", "--out", out]):
        rc, _out, err = _run(capsys, *argv)
        assert rc == 2 and "lin.yaml:8" in err and "an analysis name is an identifier" in err
    assert not out.exists()


@pytest.mark.parametrize("J, rc, expect", [
    (1e-160, 2, "the frequency response cannot be evaluated"),   # internal error before
    (1e-30, 0, "poles [rad/s]"),                                  # figures, with the note
])
def test_a_badly_scaled_model_is_named_not_crashed(tmp_path, capsys, J, rc, expect):
    """A motor inertia 150 orders of magnitude off: a note names the fastest pole and says
    the figures are not reliable; where no frequency can be evaluated the run stops with a
    clear error (exit 2), never an internal error or numpy's raw overflow warnings. The
    shipped value gives no note."""
    code, out, err = _run(capsys, "linearize", SERVO, "--input", "ref.y", "--output",
                          "motor.phi", "--set", f"motor.J={J}", "--out", tmp_path / "o")
    assert code == rc
    assert "badly scaled" in err and "rad/s" in err
    assert expect in out + err
    assert "RuntimeWarning" not in err and "internal error" not in err
    code, out, err = _run(capsys, "linearize", SERVO, "--input", "ref.y", "--output",
                          "motor.phi", "--out", tmp_path / "p")
    assert code == 0 and "badly scaled" not in err


with open(os.path.join(os.path.dirname(__file__), "data", "lag_loop.yaml")) as _fh:
    LAG = _fh.read() + """simulation: {t_end: 0.5}
analysis:
  free: {inputs: [r.y], outputs: [x.y], at: {trim: {free_inputs: [r.y]}}}
  huge: {inputs: [r.y], outputs: [x.y], at: {trim: {x0: [1e308]}}}
"""


@pytest.mark.parametrize("name, rc, words", [
    ("free", 0, "DC gain:"),
    ("huge", 2, "trim cannot start from the given x0: the residuals there are not finite "
                "(d/dt x.y = -inf)"),
])
def test_trim_entries_that_were_internal_errors(tmp_path, capsys, name, rc, words):
    """Free inputs without targets (a ValueError from an empty list of outputs) and an x0
    whose residuals overflow (SciPy's ValueError): exit 3 'internal error' before."""
    path = tmp_path / "lag.yaml"
    path.write_text(LAG)
    got, out, err = _run(capsys, "linearize", path, name, "--no-jit", "--out", tmp_path / "o")
    assert got == rc and words in out + err and "internal error" not in err, err
