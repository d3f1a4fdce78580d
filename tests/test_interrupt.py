"""Nothing computed is lost (issue #12 item 5): SIGINT/SIGTERM during a run stop the
integration at the current step, the results up to there are written (data, report with
``status: interrupted``, plots) and the exit status is 130/143."""
import os
import signal
import subprocess
import sys
import time

import numpy as np
import pytest

SLOW = """\
name: slow
blocks:
  src: {type: Sine, amplitude: 1, f: 3}
  lag: {type: TransferFunction, num: [1], den: [0.01, 1]}
connections:
  - src.y -> lag.u
simulation: {t_end: 10, max_step: 2.0e-5}
plots:
  - signals: [lag.y]
"""


def _start(tmp_path):
    path = tmp_path / "slow.yaml"
    path.write_text(SLOW)
    out = tmp_path / "out"
    proc = subprocess.Popen([sys.executable, "-m", "spidersim.cli", "run", str(path),
                             "--no-jit", "--out", str(out)], stderr=subprocess.PIPE,
                            stdout=subprocess.PIPE, text=True, cwd=tmp_path)
    return proc, out


def _wait_for_integration(proc, timeout=120):
    """Read stderr up to the line announcing the (interpreted) set-up; return it. Loading
    and imports take seconds on a busy machine: a fixed sleep would race with them."""
    deadline = time.monotonic() + timeout
    seen = []
    while time.monotonic() < deadline:
        line = proc.stderr.readline()
        if not line:
            break
        seen.append(line)
        if "interpreted mode" in line:
            return "".join(seen)
    raise AssertionError("the run did not start: " + "".join(seen))


@pytest.mark.parametrize("sig,code", [(signal.SIGINT, 130), (signal.SIGTERM, 143)])
def test_signal_keeps_the_results_up_to_the_interrupt(tmp_path, sig, code):
    proc, out = _start(tmp_path)
    head = _wait_for_integration(proc)
    time.sleep(2.5)                  # integrate a while (the whole run takes far longer)
    proc.send_signal(sig)
    stdout, stderr = proc.communicate(timeout=120)
    stderr = head + stderr
    assert proc.returncode == code, stderr
    assert "Traceback" not in stderr and "interrupted" in stderr
    report = (out / "report.txt").read_text()
    assert "status: interrupted" in report
    data = np.load(out / "result.npz")
    t = data["t"]
    assert 0 < t[-1] < 10 and len(t) > 100          # stopped part-way, with data
    assert np.all(np.diff(t) > 0) and np.all(np.isfinite(data["lag.y"]))
    assert (out / "result.csv").read_text().count("\n") == len(t) + 1
    assert any(f.endswith(".png") for f in os.listdir(out))
    assert not [f for f in os.listdir(out) if ".tmp" in f]


def test_full_disk_leaves_no_truncated_file(tmp_path, monkeypatch):
    """ENOSPC while writing: an error naming the file, the previous complete file kept,
    no temporary left behind."""
    import errno

    import spidersim
    from spidersim.solver import result as result_mod
    d = spidersim.loads(SLOW.replace("t_end: 10", "t_end: 0.01"))
    r = d.simulate(jit=False)
    r.save(tmp_path)
    before = (tmp_path / "result.csv").read_bytes()
    real_write = result_mod.Result._write_npz       # the NPZ's writer (streams its entries)

    def full_disk(self, fh, arrays):
        real_write(self, fh, arrays)
        raise OSError(errno.ENOSPC, "No space left on device")
    monkeypatch.setattr(result_mod.Result, "_write_npz", full_disk)
    with pytest.raises(OSError, match="result.npz.*No space left"):
        r.save(tmp_path)
    assert sorted(os.listdir(tmp_path)) == ["report.json", "report.txt", "result.csv",
                                             "result.npz"]
    assert (tmp_path / "result.csv").read_bytes() == before
    np.load(tmp_path / "result.npz")                 # the earlier complete file


# ------------------------------------------------------------- the phases of a signal
def test_stop_request_phases():
    """Before the integration a signal ends the command at once; during it, it only asks
    the integration to stop; while writing it lets the writing finish; a second signal
    always ends the command at once."""
    from spidersim.cli import StopRequest, _Interrupted
    stop = StopRequest()
    with pytest.raises(_Interrupted) as exc:
        stop._handle(signal.SIGTERM, None)
    assert exc.value.exit_code == 143 and "before the integration" in exc.value.message
    assert not stop.requested
    assert stop() is False                          # the integration polls: phase starts
    stop._handle(signal.SIGINT, None)
    assert stop() is True and stop.exit_code == 130
    with pytest.raises(_Interrupted, match="again"):
        stop._handle(signal.SIGINT, None)
    late = StopRequest()
    late()
    late.writing()
    late._handle(signal.SIGTERM, None)
    assert late.requested and late.exit_code == 143


def _slow_file(tmp_path):
    path = tmp_path / "short.yaml"
    path.write_text(SLOW.replace("t_end: 10, max_step: 2.0e-5", "t_end: 0.05"))
    return path


def test_signal_while_writing_lets_the_files_complete(tmp_path, monkeypatch, capsys):
    """SIGINT after the integration, while the results are written: every file is written
    completely (status ok: the run finished), then the command exits 130."""
    from spidersim import cli
    real = cli._write_results

    def interrupted_write(*a, **kw):
        os.kill(os.getpid(), signal.SIGINT)
        return real(*a, **kw)
    monkeypatch.setattr(cli, "_write_results", interrupted_write)
    out = tmp_path / "out"
    before = signal.getsignal(signal.SIGINT)
    code = cli.main(["run", str(_slow_file(tmp_path)), "--no-jit", "--out", str(out)])
    err = capsys.readouterr().err
    assert code == 130, err
    assert "finishing writing" in err and "are complete" in err
    assert "status: ok" in (out / "report.txt").read_text()
    t = np.load(out / "result.npz")["t"]
    assert t[-1] == pytest.approx(0.05)
    assert any(f.endswith(".png") for f in os.listdir(out))
    assert not [f for f in os.listdir(out) if "tmp" in f]
    assert signal.getsignal(signal.SIGINT) is before     # restored (whatever it was)


def test_second_signal_while_writing_stops_at_once(tmp_path, monkeypatch, capsys):
    """A second signal in the middle of writing a file: the command ends at once, the
    file being written is absent (its temporary removed), never truncated."""
    from spidersim import cli
    from spidersim.solver import result as result_mod
    real_write = result_mod.Result._write_npz       # the NPZ's writer (streams its entries)

    def write_interrupted(self, fh, arrays):
        real_write(self, fh, arrays)
        os.kill(os.getpid(), signal.SIGINT)        # the first: finish writing ...
        os.kill(os.getpid(), signal.SIGINT)        # ... the second: stop now
    monkeypatch.setattr(result_mod.Result, "_write_npz", write_interrupted)
    out = tmp_path / "out"
    code = cli.main(["run", str(_slow_file(tmp_path)), "--no-jit", "--out", str(out)])
    err = capsys.readouterr().err
    assert code == 130 and "Traceback" not in err and "again" in err, err
    assert os.listdir(out) == []                   # nothing half-written


# ------------------------------------------------------------------ interrupted sweeps
# run 0 (Ts = 0.1) takes milliseconds, run 1 (Ts = 1e-8: 1e8 samples, the most a run may take) far longer
# than the test: the signal comes while run 1 integrates
with open(os.path.join(os.path.dirname(__file__), "data", "held_sweep.yaml")) as _fh:
    SWEEP = _fh.read()


def _sweep_interrupted(tmp_path, workers, sig=signal.SIGINT):
    """Start a sweep of three runs (fast, endless, fast) in a child, send ``sig`` once
    the first run is in the table; return (exit status, stderr, rows of sweep.csv)."""
    import csv
    path = tmp_path / "held.yaml"
    path.write_text(SWEEP)
    out = tmp_path / "out"
    proc = subprocess.Popen([sys.executable, "-m", "spidersim.cli", "sweep", str(path),
                             "--vary", "z.Ts=0.1,1e-8,0.2", "--workers", str(workers),
                             "--out", str(out), "--no-plots"], stderr=subprocess.PIPE,
                            stdout=subprocess.PIPE, text=True, cwd=tmp_path)
    seen = []
    deadline = time.monotonic() + 120
    while time.monotonic() < deadline and not any("run 0:" in s for s in seen):
        seen.append(proc.stderr.readline())
    time.sleep(1.0)                          # run 1 is integrating (serial) or running
    proc.send_signal(sig)
    _stdout, stderr = proc.communicate(timeout=120)
    stderr = "".join(seen) + stderr
    rows = list(csv.DictReader(open(out / "sweep.csv"))) if (out / "sweep.csv").exists() \
        else []
    return proc.returncode, stderr, rows


@pytest.mark.parametrize("sig,code", [(signal.SIGINT, 130), (signal.SIGTERM, 143)])
def test_interrupted_serial_sweep_keeps_the_finished_runs(tmp_path, sig, code):
    rc, err, rows = _sweep_interrupted(tmp_path, 0, sig)
    assert rc == code, err
    assert "Traceback" not in err and "stopped after 1 of 3 run(s)" in err
    assert [r["status"] for r in rows] == ["ok", "interrupted", "not run"], err
    assert float(rows[0]["x_end"]) == pytest.approx(np.exp(-1), rel=1e-3)
    assert rows[1]["x_end"] == "" and 0 < float(rows[1]["t_reached"]) < 1
    assert "stopped by the interrupt" in rows[1]["message"]
    assert rows[2]["x_end"] == "" and "not run" in rows[2]["message"]


def test_interrupted_dask_sweep_keeps_the_finished_runs(tmp_path):
    """One worker: run 0 finished, run 1 running, run 2 queued; the signal cancels both."""
    rc, err, rows = _sweep_interrupted(tmp_path, 1)
    assert rc == 130, err
    assert "Traceback" not in err and "stopped after 1 of 3 run(s)" in err
    assert [r["status"] for r in rows] == ["ok", "interrupted", "interrupted"], err
    assert float(rows[0]["x_end"]) == pytest.approx(np.exp(-1), rel=1e-3)
    assert rows[1]["x_end"] == rows[2]["x_end"] == ""
