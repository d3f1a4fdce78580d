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


@pytest.mark.parametrize("sig,code", [(signal.SIGINT, 130), (signal.SIGTERM, 143)])
def test_signal_keeps_the_results_up_to_the_interrupt(tmp_path, sig, code):
    proc, out = _start(tmp_path)
    time.sleep(4.0)                  # compile (interpreted: quick) and integrate a while
    proc.send_signal(sig)
    stdout, stderr = proc.communicate(timeout=120)
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
    real_savez = np.savez

    def full_disk(fh, **arrays):
        real_savez(fh, **arrays)
        raise OSError(errno.ENOSPC, "No space left on device")
    monkeypatch.setattr(result_mod.np, "savez", full_disk)
    with pytest.raises(OSError, match="result.npz.*No space left"):
        r.save(tmp_path)
    assert sorted(os.listdir(tmp_path)) == ["report.json", "report.txt", "result.csv",
                                             "result.npz"]
    assert (tmp_path / "result.csv").read_bytes() == before
    np.load(tmp_path / "result.npz")                 # the earlier complete file
