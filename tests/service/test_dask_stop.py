"""Stopping a job on a Dask cluster (``serve --scheduler``) keeps its data, as in the local
pool: a cancel or the wall-time limit sets an Event named after the job, the task's
integration loop reads it (``should_stop``, at most every STOP_READ s), the run returns its
rows so far as files and the job ends 'cancelled' (or 'failed' for the limit) with them;
the Dask worker is free for the next job. (Before, the runner cancelled the future and
dropped the result; the task ran to its end on the worker.)

The server runs interpreted (``--no-jit``): no compile on the fresh Dask worker, and the
slow model runs about 8 simulated s (40,000 steps) per s of wall time on a Dask worker."""
from __future__ import annotations

import io
import json
import logging
import os
import re
import time

import numpy as np
import pytest

import spidersim
from spidersim.service.runner import CANCEL_GRACE, _dask_names, _dask_task

from spidersim.service.store import Store

from .conftest import Server, add_user, wait_progress, wait_state


@pytest.fixture(scope="module")
def cluster():
    """A Dask scheduler on 127.0.0.1 with one worker process of one thread (a task still
    running would hold the next one back)."""
    distributed = pytest.importorskip("distributed")
    c = distributed.LocalCluster(n_workers=1, threads_per_worker=1, processes=True,
                                 host="127.0.0.1", dashboard_address=None,
                                 silence_logs=logging.ERROR)
    yield c
    c.close()


def _wait_progress(http, job, timeout=60):
    """The job once its run has passed t = 0.5 s (its steps at max_step: the rows of a
    cancelled run then equal a run to that time)."""
    return wait_progress(http, job, above=0.5, timeout=timeout)


def _npz(http, job):
    r = http.get(f"/jobs/{job}/result.npz")
    assert r.status_code == 200, r.text
    with np.load(io.BytesIO(r.content)) as z:
        return z["t"], z["sys.y"]


def test_cancel_and_wall_time_limit_keep_the_data_on_dask(tmp_path, models_dir, cluster):
    from distributed import Client
    """(a) a slow run cancelled part-way ends 'cancelled' within CANCEL_GRACE (stopped by
    the Event, not given up), saying at what simulated time; result.npz ends there and its
    rows equal a local interpreted run to that time; (b) the next job runs to its end on
    the same single-threaded worker (the cancelled task is not still running); (c) a slow
    run past --job-timeout 5 fails saying so, with its rows up to the progress reached and
    meta.json saying 'interrupted'; (d) a server stop fails the running job without data
    (as the local pool's) and its task stops on the cluster (its cancel Event set)."""
    data = tmp_path / "data"
    srv = Server(data, models_dir, ["--scheduler", cluster.scheduler_address, "--no-jit",
                                    "--max-t-end", "1000", "--job-timeout", "5"])
    tok = add_user(data, "fay")
    srv.start()
    try:
        http = srv.client(tok)
        job = http.post("/jobs", json={"model": "slow", "t_end": 900}).json()["id"]
        assert _wait_progress(http, job)["state"] == "running"
        t_cancel = time.time()
        http.post(f"/jobs/{job}/cancel")
        j = wait_state(http, job, timeout=30)
        took = time.time() - t_cancel
        assert j["state"] == "cancelled", j
        assert took < CANCEL_GRACE, (took, j["message"])
        m = re.search(r"stopped at t = (\S+) s; the data computed up to there are kept",
                      j["message"])
        assert m, j["message"]
        assert 0 < j["progress"] < 900
        assert "result.npz" in j["files"]["data"], j
        t, y = _npz(http, job)
        assert t[-1] == j["progress"]
        assert abs(float(m.group(1)) - t[-1]) <= 1e-8 * t[-1]
        assert http.get(f"/jobs/{job}/result.json").json()["status"] == "cancelled"
        print(f"cancel ended the job in {took:.2f} s at t = {t[-1]:.4g} s ({len(t)} rows)")
        ref = spidersim.load(os.path.join(models_dir[1], "slow.yaml")).simulate(
            t_end=float(t[-1]), jit=False)
        assert ref.t.shape == t.shape and np.allclose(ref.t, t, rtol=1e-12, atol=0)
        assert np.max(np.abs(ref["sys.y"] - y)) <= 1e-12 * np.max(np.abs(ref["sys.y"]))

        nxt = http.post("/jobs", json={"model": "slow", "t_end": 0.5}).json()["id"]
        jn = wait_state(http, nxt, timeout=30)
        assert jn["state"] == "done" and jn["progress"] == 0.5, jn

        lim = http.post("/jobs", json={"model": "slow", "t_end": 900}).json()["id"]
        jl = wait_state(http, lim, timeout=60)
        assert jl["state"] == "failed", jl
        assert re.fullmatch(r"stopped: the wall-time limit of 5 s per job was reached at "
                            r"t = \S+ s; the data computed so far are kept",
                            jl["message"]), jl["message"]
        assert 0 < jl["progress"] < 900 and "result.npz" in jl["files"]["data"], jl
        t, _ = _npz(http, lim)
        assert t[-1] == jl["progress"]
        assert http.get(f"/jobs/{lim}/result.json").json()["status"] == "interrupted"

        last = http.post("/jobs", json={"model": "slow", "t_end": 900}).json()["id"]
        assert _wait_progress(http, last)["state"] == "running"
    finally:
        srv.stop()
    assert Store(str(data)).get_job(last)["message"] == "server stopped while running"
    t_stop = time.time()
    with Client(cluster.scheduler_address) as c:     # the task stopped on the cluster too:
        assert c.submit(abs, -1, pure=False).result(timeout=20) == 1   # its thread is free
    print(f"worker thread free {time.time() - t_stop:.2f} s after the server stopped")
    assert time.time() - t_stop < 1.5               # not at its own 5 s limit (> 3 s later)


def test_limit_event_stops_the_task_and_it_clears_its_state(cluster, models_dir):
    """The task side alone: with its own wall-time limit of an hour, the run stops when the
    runner's limit Event is set (status 'interrupted', the files returned with the rows up
    to ``t_reached``), and removes the job's Events and Variable from the scheduler when
    it ends."""
    from distributed import Client, Event, Variable
    task = {"id": "lim1", "model": "slow", "path": os.path.join(models_dir[1], "slow.yaml"),
            "jit": False, "wall_limit": 3600.0, "out": None,
            "request": {"model": "slow", "t_end": 900, "plots": False}}
    names = _dask_names(task["id"])
    with Client(cluster.scheduler_address) as c:
        fut = c.submit(_dask_task, task, pure=False)
        var = Variable(names["progress"], client=c)
        t0 = time.time()
        while True:
            try:
                if var.get(timeout=0.05) > 0:
                    break
            except TimeoutError:
                pass
            assert time.time() - t0 < 60 and not fut.done(), fut
        Event(names["limit"], client=c).set()
        res = fut.result(timeout=20)
        assert res["status"] == "interrupted" and 0 < res["t_reached"] < 900, res
        with np.load(io.BytesIO(res["files"]["result.npz"])) as z:
            assert z["t"][-1] == res["t_reached"]
        assert json.loads(res["files"]["meta.json"])["status"] == "interrupted"
        assert not Event(names["limit"], client=c).is_set()
        with pytest.raises(TimeoutError):
            var.get(timeout=0.2)


def test_event_reader_asks_the_scheduler_at_most_every_period():
    """The task's ``should_stop`` reads its Events through ``_event_reader``: one read per
    STOP_READ s however often the loop asks, true for good from the first set answer, a
    failed read taken as not set."""
    from spidersim.service.runner import STOP_READ, _event_reader

    class Fake:
        def __init__(self):
            self.reads, self.value = 0, False

        def is_set(self):
            self.reads += 1
            if self.value is None:
                raise OSError("scheduler gone")
            return self.value

    ev = Fake()
    read = _event_reader(ev)
    assert not any(read() for _ in range(1000)) and ev.reads == 1
    ev.value = True
    assert not read() and ev.reads == 1              # not asked again yet
    time.sleep(STOP_READ + 0.05)
    assert read() and ev.reads == 2
    ev.value = False
    time.sleep(STOP_READ + 0.05)
    assert read() and ev.reads == 2                  # set once: stays set, no more reads
    bad = Fake()
    bad.value = None
    assert not _event_reader(bad)() and bad.reads == 1
