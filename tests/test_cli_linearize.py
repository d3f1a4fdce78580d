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
