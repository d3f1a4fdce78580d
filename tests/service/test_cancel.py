"""Cancel of a running job in the local pool is cooperative: the slot sets its worker's
cancel flag, the integration loop stops at its next pause, the rows so far are the job's
results (readable through the same routes as a finished job's), the job ends 'cancelled'
saying at what simulated time, and the worker lives on for the next job. A worker that does
not stop within CANCEL_GRACE (still compiling its model) is killed: no data.
(Before, a cancel killed the worker at once and the job kept nothing.)"""
from __future__ import annotations

import io
import json
import os
import re
import time

import numpy as np
import pytest

import spidersim
from spidersim.service import execute
from spidersim.service.runner import CANCEL_GRACE

from .conftest import ROOT, SLOW, Server, add_user, wait_progress, wait_state

RIGID = os.path.join(ROOT, "diagrams", "force_control_rigid.yaml")


def _wait_progress(http, job, timeout=60):
    return wait_progress(http, job, timeout=timeout)


@pytest.fixture(scope="module")
def one_slot(tmp_path_factory, models_dir):
    """A server with one worker (so the next job runs on the same worker process)."""
    data = tmp_path_factory.mktemp("cancel")
    s = Server(data, models_dir, ["--workers", "1", "--max-t-end", "1000"])
    s.tok = add_user(data, "carol")
    s.start()
    yield s
    s.stop()


def test_cancel_mid_run_keeps_the_data_and_the_worker(one_slot, models_dir):
    """A slow run cancelled part-way: state 'cancelled' within about a second; the message's
    stop time equals the stored record's last time and the job's progress, 0 < t < t_end;
    the record is served by /signals, result.npz and the job's file list; its rows equal a
    local run of the same diagram to that time (round-off: the same steps, max_step bound);
    the worker process was not killed and its next job runs to t_end (no stale flag)."""
    srv = one_slot
    http = srv.client(srv.tok)
    job = http.post("/jobs", json={"model": "slow", "t_end": 900}).json()["id"]
    assert _wait_progress(http, job)["state"] == "running"
    pids = srv.workers()
    t_cancel = time.time()
    http.post(f"/jobs/{job}/cancel")
    j = wait_state(http, job, timeout=60)
    took = time.time() - t_cancel
    assert j["state"] == "cancelled", j
    assert took < 5, took                       # stopped at a pause, not at the grace kill
    m = re.search(r"stopped at t = (\S+) s; the data computed up to there are kept",
                  j["message"])
    assert m, j["message"]
    t_msg = float(m.group(1))
    assert 0 < j["progress"] < 900
    assert j["files"]["data"] == ["result.npz", "result.csv", "report.txt", "meta.json"]
    r = http.get(f"/jobs/{job}/result.npz")
    assert r.status_code == 200
    with np.load(io.BytesIO(r.content)) as z:
        t, y = z["t"], z["sys.y"]
    assert t[-1] == j["progress"]
    assert abs(t_msg - t[-1]) <= 1e-8 * t[-1]          # printed with 9 digits
    s = http.get(f"/jobs/{job}/signals/sys.y.json", params={"points": 1000})
    assert s.status_code == 200, s.text
    sig = s.json()
    assert np.array_equal(sig["t"], t[::sig["stride"]])
    assert np.array_equal(sig["values"], y[::sig["stride"]])
    assert http.get(f"/jobs/{job}/result.json").json()["status"] == "cancelled"
    from spidersim.remote import Client          # the Python client reads it too
    rc = Client(srv.url, srv.tok).result(job)
    assert rc.status == "cancelled" and np.array_equal(rc.t, t)
    assert np.array_equal(rc["sys.y"], y.reshape(rc["sys.y"].shape))

    slow = os.path.join(models_dir[1], "slow.yaml")
    ref = spidersim.load(slow).simulate(t_end=float(t[-1]))
    assert ref.t.shape == t.shape
    assert np.allclose(ref.t, t, rtol=1e-12, atol=0)
    scale = np.max(np.abs(ref["sys.y"]))
    assert np.max(np.abs(ref["sys.y"] - y)) <= 1e-12 * scale     # 7e-15 measured

    assert srv.workers() == pids                # the worker was not killed
    nxt = http.post("/jobs", json={"model": "slow", "t_end": 0.5}).json()["id"]
    jn = wait_state(http, nxt, timeout=60)
    assert jn["state"] == "done" and jn["progress"] == 0.5 and not jn["message"], jn
    assert srv.workers() == pids


def test_cancel_while_compiling_kills_after_the_grace(tmp_path, models_dir, monkeypatch):
    """A cancel while the worker compiles a model (force_control_rigid from an empty numba
    cache: 14 s measured; a warm-up job has started the worker) ends the job within
    CANCEL_GRACE + 2 s as 'cancelled', killed, without data (409 on its results, no files
    listed); the slot's next job runs to its end in a fresh worker."""
    monkeypatch.setenv("SPIDERSIM_CACHE", str(tmp_path / "cache"))   # the server's children
    data = tmp_path / "data"
    srv = Server(data, models_dir + [RIGID], ["--workers", "1"])
    tok = add_user(data, "erin")
    srv.start()
    try:
        http = srv.client(tok)
        warm = http.post("/jobs", json={"model": "trajectory", "plots": False}).json()["id"]
        assert wait_state(http, warm, timeout=90)["state"] == "done"   # worker up
        job = http.post("/jobs", json={"model": "force_control_rigid", "plots": False}).json()["id"]
        t0 = time.time()
        while http.get(f"/jobs/{job}").json()["state"] == "queued":
            assert time.time() - t0 < 30
            time.sleep(0.05)
        time.sleep(0.5)                         # past loading the file: compiling
        assert http.get(f"/jobs/{job}").json()["progress"] == 0
        t_cancel = time.time()
        http.post(f"/jobs/{job}/cancel")
        j = wait_state(http, job, timeout=30)
        took = time.time() - t_cancel
        assert j["state"] == "cancelled", j
        assert CANCEL_GRACE < took < CANCEL_GRACE + 2, (took, j["message"], j["progress"])
        assert j["message"] == (f"cancelled while running: the run did not stop within "
                                f"{CANCEL_GRACE:g} s (its model was still being loaded or "
                                f"compiled): killed, no data"), j["message"]
        assert "files" not in j
        r = http.get(f"/jobs/{job}/result.npz")
        assert r.status_code == 409 and "no results" in r.json()["detail"]
        nxt = http.post("/jobs", json={"model": "trajectory", "plots": False}).json()["id"]
        assert wait_state(http, nxt, timeout=90)["state"] == "done"
    finally:
        srv.stop()


def test_run_job_cancel_flag(tmp_path):
    """``run_job`` in this process: a flag that turns true after 50 checks stops the run
    there, status 'cancelled', rows written up to ``t_reached`` (meta.json saying
    'cancelled'), ``stopped(t)`` called once with that time; the cancel is not taken for
    the wall-time limit (one of 1 h is set too); a flag already true before the run
    writes nothing and reports no time."""
    slow = tmp_path / "slow.yaml"
    slow.write_text(SLOW)
    task = {"id": "x", "model": "slow", "path": str(slow), "jit": True, "wall_limit": 3600.0,
            "request": {"model": "slow", "t_end": 900, "plots": False}}
    checks, stops = [0], []

    def cancel():
        checks[0] += 1
        return checks[0] > 50

    res = execute.run_job(task, out=str(tmp_path / "out"), cancel=cancel,
                          stopped=stops.append)
    assert res["status"] == "cancelled" and 0 < res["t_reached"] < 900, res
    assert stops == [res["t_reached"]]
    with np.load(tmp_path / "out" / "result.npz") as z:
        assert z["t"][-1] == res["t_reached"]
    meta = json.loads((tmp_path / "out" / "meta.json").read_text())
    assert meta["status"] == "cancelled"
    assert meta["message"] == f"cancelled at t = {res['t_reached']:.9g} s"

    res = execute.run_job(task, out=str(tmp_path / "none"), cancel=lambda: True,
                          stopped=stops.append)
    assert res["status"] == "cancelled" and res["t_reached"] is None
    assert not (tmp_path / "none").exists() and len(stops) == 1
