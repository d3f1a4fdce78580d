"""Stopping: the wall-time limit keeps the data a run computed; a SIGTERM to the server's
whole process group (systemd's stop) leaves queued jobs queued (a slot claimed one during
the shutdown, which after the restart showed "failed: server stopped while running")."""
from __future__ import annotations

import os
import signal
import time

import numpy as np

from spidersim.service.store import Store

from .conftest import Server, add_user, wait_state


def test_timeout_keeps_data_and_sigterm_to_the_group_keeps_queued_jobs(tmp_path, models_dir):
    """(a) a slow run past --job-timeout 4 fails saying so, with result.npz holding the
    rows up to the progress reached; (b) SIGTERM to the group while a job runs and one
    waits: the running one is 'server stopped while running', the waiting one is still
    queued, and runs after the restart."""
    data = tmp_path / "data"
    srv = Server(data, models_dir, ["--workers", "1", "--job-timeout", "4",
                                    "--max-t-end", "1000"], new_session=True)
    tok = add_user(data, "dan")
    srv.start()
    try:
        http = srv.client(tok)
        a = http.post("/jobs", json={"model": "slow", "t_end": 900}).json()["id"]
        j = wait_state(http, a, timeout=90)
        assert j["state"] == "failed" and "wall-time limit of 4 s" in j["message"], j
        assert "result.npz" in j["files"]["data"] and 0 < j["progress"] < 900, j
        with np.load(os.path.join(data, "jobs", a, "result.npz")) as z:
            assert z["t"][-1] == j["progress"]

        b = http.post("/jobs", json={"model": "slow", "t_end": 900}).json()["id"]
        q = http.post("/jobs", json={"model": "servo", "t_end": 0.1}).json()["id"]
        t0 = time.time()
        while http.get(f"/jobs/{b}").json()["progress"] <= 0 and time.time() - t0 < 60:
            time.sleep(0.1)
        os.killpg(srv.proc.pid, signal.SIGTERM)
        srv.proc.wait(30)
        st = Store(str(data))
        assert st.get_job(q)["state"] == "queued", st.get_job(q)
        jb = st.get_job(b)
        assert jb["state"] == "failed" and jb["message"] == "server stopped while running"
    finally:
        srv.stop()
    srv.start()
    try:
        assert wait_state(srv.client(tok), q, timeout=90)["state"] == "done"
    finally:
        srv.stop()
