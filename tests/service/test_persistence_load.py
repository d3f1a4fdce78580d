"""Restart and load: jobs survive a crash of the server (running -> failed with the reason,
queued -> run after the restart); 20 concurrent clients submit 100 jobs, none lost or
duplicated, every result identical to a local run; the same jobs on a Dask cluster."""
from __future__ import annotations

import sqlite3
import threading
import time

import httpx
import numpy as np
import pytest

import spidersim
from spidersim.remote import Client

from .conftest import SERVO, Server, add_user, wait_state


def test_restart_fails_running_and_runs_queued_jobs(tmp_path, models_dir):
    data = tmp_path / "data"
    srv = Server(data, models_dir, ["--workers", "1", "--max-t-end", "1000"])
    tok = add_user(data, "carol")
    srv.start()
    http = srv.client(tok)
    long = http.post("/jobs", json={"model": "slow", "t_end": 900}).json()["id"]
    queued = [http.post("/jobs", json={"model": "servo", "t_end": 0.1 * (k + 1)}).json()["id"]
              for k in range(3)]
    wait_state(http, long, states=("running",))
    workers = srv.workers()
    assert workers
    srv.kill()                                   # a crash: no clean-up at all
    # the database says what the crash left: one running, three queued
    db = sqlite3.connect(str(data / "service.sqlite"))
    states = dict(db.execute("SELECT id, state FROM jobs").fetchall())
    db.close()
    assert states[long] == "running" and all(states[q] == "queued" for q in queued)
    # orphaned workers notice their server is gone and exit
    import psutil
    t0 = time.time()
    while any(psutil.pid_exists(p) and psutil.Process(p).status() != psutil.STATUS_ZOMBIE
              for p in workers):
        assert time.time() - t0 < 30, "worker outlived its server"
        time.sleep(0.2)
    srv.start()
    try:
        http = srv.client(tok)
        st = http.get(f"/jobs/{long}").json()
        assert st["state"] == "failed" and st["message"] == "server stopped while running"
        for k, q in enumerate(queued):
            st = wait_state(http, q)
            assert st["state"] == "done", st
            r = Client(srv.url, tok).result(q)
            ref = spidersim.load(SERVO).simulate(t_end=0.1 * (k + 1))
            assert np.array_equal(r["motor.phi"], ref["motor.phi"])
        assert len(http.get("/jobs").json()) == 4
    finally:
        srv.stop()


def test_twenty_clients_hundred_jobs(tmp_path, models_dir):
    """20 threads, 4 users, 100 jobs through a server with 2 workers and 10 active jobs per
    user: every submit accepted (429 answers retried as told), no id duplicated, each user
    lists exactly their own jobs, and every result equals a local run bit for bit. The jobs
    ask for no plots (``plots: false``): drawing the servo's three PNGs took 95 % of a job's
    time and nothing here looks at them (test_api and the Dask test check the plots)."""
    data = tmp_path / "data"
    srv = Server(data, models_dir, ["--workers", "2", "--max-jobs", "10"])
    tokens = [add_user(data, f"user{k}") for k in range(4)]
    srv.start()
    R = [1.0, 1.1, 1.2, 1.3, 1.4]
    refs = {r: spidersim.load(SERVO, set={"motor.R": r}).simulate(t_end=0.05) for r in R}
    submitted, errors, lock = [], [], threading.Lock()

    def client(k):
        http = srv.client(tokens[k % 4])
        for n in range(5):
            val = R[(k + n) % 5]
            while True:
                r = http.post("/jobs", json={"model": "servo", "t_end": 0.05,
                                             "parameters": {"motor.R": val},
                                             "plots": False})
                if r.status_code == 429:              # per-user limit: wait as told
                    time.sleep(float(r.headers["retry-after"]) / 10)
                    continue
                break
            if r.status_code != 202:
                with lock:
                    errors.append(r.text)
                return
            with lock:
                submitted.append((k % 4, r.json()["id"], val))

    t0 = time.time()
    threads = [threading.Thread(target=client, args=(k,)) for k in range(20)]
    for t in threads:
        t.start()
    for t in threads:
        t.join(300)
    try:
        assert not errors, errors[:3]
        assert len(submitted) == 100
        assert len({j for _, j, _ in submitted}) == 100          # no duplicates
        for u in range(4):
            listed = {j["id"] for j in srv.client(tokens[u]).get("/jobs",
                                                                 params={"limit": 1000}).json()}
            mine = {j for uu, j, _ in submitted if uu == u}
            assert listed == mine                               # none lost, none foreign
        for u, job, val in submitted:
            c = Client(srv.url, tokens[u])
            st = c.wait(job, timeout=300)
            assert st["state"] == "done", st
            r = c.result(job)
            for n in refs[val].names:
                assert np.array_equal(r[n], refs[val][n]), (job, n)
        print(f"100 jobs in {time.time() - t0:.1f} s")
    finally:
        srv.stop()


def test_dask_scheduler_runs_the_same_jobs(tmp_path, models_dir):
    distributed = pytest.importorskip("distributed")
    cluster = distributed.LocalCluster(n_workers=1, threads_per_worker=1, processes=True,
                                       dashboard_address=None)
    data = tmp_path / "data"
    srv = Server(data, models_dir, ["--scheduler", cluster.scheduler_address,
                                    "--max-t-end", "1000"])
    tok = add_user(data, "dave")
    try:
        srv.start()
        assert httpx.get(srv.url + "/health").json()["workers"] == 1
        c = Client(srv.url, tok)
        job = c.submit("servo", parameters={"motor.R": 1.2}, t_end=0.3)
        st = c.wait(job, timeout=180)
        assert st["state"] == "done", st
        r = c.result(job)
        ref = spidersim.load(SERVO, set={"motor.R": 1.2}).simulate(t_end=0.3)
        for n in ref.names:
            assert np.array_equal(r[n], ref[n])
        assert len(st["files"]["plots"]) == 3
        bad = c.submit("slow", t_end=900)
        seen = 0.0
        t0 = time.time()
        while seen <= 0 and time.time() - t0 < 120:
            seen = c.status(bad)["progress"]          # progress comes through the Variable
            time.sleep(0.2)
        assert seen > 0
        c.cancel(bad)
        assert c.wait(bad, 60)["state"] == "cancelled"
    finally:
        srv.stop()
        cluster.close()
