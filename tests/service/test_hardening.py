"""The service against what the third hostile-input hunt found (in-process app, no workers:
fast): non-finite numbers refused at submit and never in an answer, a signal answer
bounded (413 naming the way out), results removed after the retention time (410), the
per-job recording budget and the wall-time limit keeping their data, a shipped model with
a long log list runnable, a revoked token refused at once, a too-short run refused."""
from __future__ import annotations

import contextlib
import io
import json
import os
import sqlite3
import time

import numpy as np
import pytest
from fastapi.testclient import TestClient

import spidersim
from spidersim.service import execute
from spidersim.service.app import Limits, create_app, read_rows
from spidersim.service.library import default_dirs
from spidersim.solver import record_budget as rb

from .conftest import SERVO


def strict(text):
    """Parse ``text`` as strict JSON: the Infinity/NaN tokens raise."""
    def bad(tok):
        raise AssertionError(f"non-JSON token {tok} in an answer")
    return json.loads(text, parse_constant=bad)


@contextlib.contextmanager
def app(tmp_path, models=None, **limits):
    """The app on ``tmp_path`` (no runner: jobs stay queued unless a test runs them) and
    a token of user 'eve'."""
    from spidersim.service.store import Store
    tok = Store(str(tmp_path)).add_user("eve")
    a = create_app(str(tmp_path), models or [SERVO], None, Limits(**limits))
    with TestClient(a) as c:
        c.headers["Authorization"] = f"Bearer {tok}"
        yield c, a.state.store


def run_done(store, model, path, request, state="done"):
    """A job run in this process (``execute.run_job`` into its folder), then finished."""
    job, _ = store.create_job(1, model, request, request.get("t_end", 1.0), "x", "h")
    assert store.claim_next()["id"] == job["id"]
    res = execute.run_job({"id": job["id"], "model": model, "path": path,
                           "request": request, "jit": True}, out=store.job_dir(job["id"]))
    store.finish(job["id"], state, res["message"], progress=res["t_reached"])
    return job["id"], res


# ---------------------------------------------------------------- 1. non-finite numbers
@pytest.mark.parametrize("text, field", [
    ('{"model": "servo", "t_end": 0.1, "parameters": {"V_max": 1e999}}',
     "body.parameters.V_max"),
    ('{"model": "servo", "t_end": 0.1, "parameters": {"motor.R": -Infinity}}',
     "body.parameters.motor.R"),
    ('{"model": "servo", "t_end": NaN}', "body.t_end"),
    ('{"model": "servo", "command": {"kind": "table", "time": [0, 1], "value": [0, '
     'Infinity]}}', "body.command.value[1]"),
])
def test_non_finite_numbers_are_refused_at_submit(tmp_path, text, field):
    """A JSON number overflowing to inf (1e999), Infinity or NaN is a 422 naming its field,
    in strict JSON, and nothing is stored (it was stored and run, and the user's job
    list answered 500 from then on)."""
    with app(tmp_path) as (c, store):
        r = c.post("/jobs", content=text, headers={"Content-Type": "application/json"})
        assert r.status_code == 422, r.text
        detail = json.dumps(strict(r.text))
        assert field in detail and "non-finite" in detail
        assert store.list_jobs(1) == []
        # an infinite parameter value is given as a text, which the loader reads
        r = c.post("/jobs", json={"model": "servo", "t_end": 0.1,
                                  "parameters": {"V_max": "inf"}})
        assert r.status_code == 202, r.text


def test_a_stored_non_finite_value_never_poisons_an_answer(tmp_path):
    """A job stored with inf in its request and progress (a database of the old
    version) is listed, shown and streamed as strict JSON with null in their place."""
    with app(tmp_path) as (c, store):
        job, _ = store.create_job(1, "servo", {"model": "servo", "parameters":
                                               {"V_max": float("inf")}}, 0.1, "x", "h")
        store.finish(job["id"], "failed", "boom")
        with sqlite3.connect(store.path) as db:
            db.execute("UPDATE jobs SET progress = ? WHERE id = ?", (float("inf"), job["id"]))
        for route in ("/jobs", f"/jobs/{job['id']}"):
            r = c.get(route)
            assert r.status_code == 200, r.text
            j = strict(r.text)
            j = j[0] if isinstance(j, list) else j
            assert j["progress"] is None
            if route != "/jobs":            # the list leaves the requests out
                assert j["request"]["parameters"]["V_max"] is None
        ev = c.get(f"/jobs/{job['id']}/events").text
        data = [ln[6:] for ln in ev.splitlines() if ln.startswith("data: ")]
        assert len(data) == 1 and strict(data[0])["progress"] is None


def test_signal_rows_holding_nan_are_answered_with_null(tmp_path):
    """The reviewer's failed servo run (a 1e308 set point) recorded nan in sat.y: the
    signal answer is strict JSON with null exactly where the recorded value is not
    finite, the finite values unchanged (it was a 500)."""
    with app(tmp_path) as (c, store):
        jid, _ = run_done(store, "servo", SERVO, {
            "model": "servo", "t_end": 0.1, "plots": False,
            "parameters": {"ref.before": 1e308, "pos_ctrl.k": 10}}, state="failed")
        with np.load(os.path.join(store.job_dir(jid), "result.npz")) as z:
            y = z["sat.y"]
        assert not np.all(np.isfinite(y))
        r = c.get(f"/jobs/{jid}/signals/sat.y.json")
        assert r.status_code == 200, r.text
        got = strict(r.text)["values"]
        assert [v is None for v in got] == (~np.isfinite(y)).tolist()
        assert np.array_equal([v for v in got if v is not None], y[np.isfinite(y)])
        strict(c.get(f"/jobs/{jid}/result.json").text)      # meta.json: strict too


# ---------------------------------------------------------------- 2. result sizes
def test_signal_answer_over_the_point_limit_is_413_naming_stride_and_downloads(tmp_path):
    """A signal answer of more than max_points values is a 413 that names ?stride=,
    ?points= and the download routes; the stride it suggests fits and gives exactly the
    rows [::stride] of the record (read from the file in blocks)."""
    with app(tmp_path, max_points=500) as (c, store):
        jid, _ = run_done(store, "servo", SERVO, {"model": "servo", "t_end": 3.0,
                                                  "plots": False})
        with np.load(os.path.join(store.job_dir(jid), "result.npz")) as z:
            t, w = z["t"], z["motor.w"]
        assert len(t) > 500
        r = c.get(f"/jobs/{jid}/signals/motor.w.json")
        assert r.status_code == 413
        msg = r.json()["detail"]
        assert "?stride=" in msg and "?points=" in msg and "result.npz" in msg
        need = int(msg.split("?stride=")[1].split()[0])
        assert -(-len(t) // need) <= 500 < -(-len(t) // (need - 1))
        s = strict(c.get(f"/jobs/{jid}/signals/motor.w.json?stride={need}").text)
        assert np.array_equal(s["t"], t[::need]) and np.array_equal(s["values"], w[::need])
        assert c.get(f"/jobs/{jid}/signals/motor.w.json?points=400").status_code == 200
        assert c.get(f"/jobs/{jid}/signals/motor.w.json?points=5000").status_code == 413


def test_read_rows_of_a_matrix_signal_in_blocks(tmp_path):
    """Rows of a 3-column signal read in blocks of 7 rows, for strides on and off the
    block size, equal numpy's slicing of the loaded array."""
    t = np.linspace(0, 1, 101)
    data = np.column_stack([np.sin(t), t, t ** 2, -t])
    r = spidersim.Result(t, data, {"a": (0, 1), "q": (1, 4)}, {"a": "1", "q": "rad"}, [], {})
    r.save(str(tmp_path))
    npz = str(tmp_path / "result.npz")
    for s in (1, 2, 7, 13, 100, 500):
        n, q = read_rows(npz, "q", s, chunk_rows=7)
        assert n == 101 and np.array_equal(q, data[::s, 1:4])
        assert np.array_equal(read_rows(npz, "a", s, chunk_rows=7)[1], data[::s, 0])


def test_results_past_the_retention_time_are_removed_and_gone(tmp_path):
    """A job finished longer ago than keep_days loses its files at start-up; it stays in
    the list marked expired, and its result, signal and plot routes answer 410; a recent
    job's results are untouched."""
    with app(tmp_path) as (c, store):
        old, _ = run_done(store, "servo", SERVO, {"model": "servo", "t_end": 0.1})
        new, _ = run_done(store, "servo", SERVO, {"model": "servo", "t_end": 0.1})
    with sqlite3.connect(store.path) as db:
        db.execute("UPDATE jobs SET finished = ? WHERE id = ?", (time.time() - 2.1 * 86400,
                                                                   old))
    plot = sorted(os.listdir(os.path.join(store.job_dir(old), "plots")))[0]
    with app(tmp_path, keep_days=2) as (c, store):
        assert not os.path.exists(store.job_dir(old))
        j = c.get(f"/jobs/{old}").json()
        assert j["expired"] and j["files"] == {"data": [], "plots": []}
        for route in ("result.npz", "result.json", "signals/motor.w.json", f"plots/{plot}"):
            r = c.get(f"/jobs/{old}/{route}")
            assert r.status_code == 410 and "2 day(s)" in r.json()["detail"], route
        assert not c.get(f"/jobs/{new}").json()["expired"]
        assert c.get(f"/jobs/{new}/result.npz").status_code == 200


def test_a_job_stopped_at_the_recording_budget_keeps_its_rows_and_says_which(
        tmp_path, monkeypatch):
    """At a 0.05 MB budget a servo run stops before t_end: failed, the rows so far saved
    (their last time is the time reached), the message naming the service's option
    rather than an environment variable of the server."""
    # the pulse train: two rows and two events every 5 ms, so the 0.05 MB are full within
    # the first second (the servo's 50 s are 879 LSODA rows, within the 1024 rows every
    # run may record: it stopped at 0.01 s only because the event log reserved 1024
    # entries ahead at its first event, "0 entries")
    monkeypatch.setenv(rb.ENV, "0.05")
    (tmp_path / "pulses.yaml").write_text(PULSES)
    res = execute.run_job({"id": "x", "model": "pulses", "jit": True,
                           "path": str(tmp_path / "pulses.yaml"),
                           "request": {"model": "pulses", "t_end": 50, "plots": False}},
                          out=str(tmp_path / "out"))
    assert res["status"] == "failed" and 0.05 < res["t_reached"] < 50
    assert "memory budget" in res["message"] and "serve --max-record-mb" in res["message"]
    assert rb.ENV not in res["message"]
    with np.load(tmp_path / "out" / "result.npz") as z:
        assert z["t"][-1] == res["t_reached"] and z["t"].nbytes < 0.05e6


PULSES = """\
name: pulses
description: a pulse train (two events a period)
blocks:
  p: {type: Pulse, amplitude: 1, period: 0.01, duty: 0.5}
  i: {type: Integrator}
connections:
  - p.y -> i.u
simulation: {t_end: 1}
log: [p.y, i.y]
"""


def test_events_written_are_bounded(tmp_path, monkeypatch):
    """Only the first MAX_EVENTS events go into meta.json and the reports; the total is
    in stats.events_total and the message says so."""
    (tmp_path / "pulses.yaml").write_text(PULSES)
    monkeypatch.setattr(execute, "MAX_EVENTS", 10)
    res = execute.run_job({"id": "x", "model": "pulses", "jit": True,
                           "path": str(tmp_path / "pulses.yaml"),
                           "request": {"model": "pulses", "plots": False}},
                          out=str(tmp_path / "out"))
    meta = strict(open(tmp_path / "out" / "meta.json").read())
    assert len(meta["events"]) == 10 and meta["stats"]["events_total"] >= 199
    assert "first 10 of" in res["message"] and res["status"] == "ok"
    assert len(strict(open(tmp_path / "out" / "report.json").read())["events"]) == 10


# ---------------------------------------------------------------- 3. limits, models
def test_wall_time_limit_keeps_the_data(tmp_path):
    """A run past its wall-time limit stops cooperatively: status interrupted, the rows
    computed so far saved with the time reached (the killed job kept nothing)."""
    slow = tmp_path / "slow.yaml"
    from .conftest import SLOW
    slow.write_text(SLOW)
    t0 = time.monotonic()
    res = execute.run_job({"id": "x", "model": "slow", "path": str(slow), "jit": True,
                           "wall_limit": 1.0, "request": {"model": "slow", "plots": False}},
                          out=str(tmp_path / "out"))
    assert time.monotonic() - t0 < 30
    assert res["status"] == "interrupted" and 0 < res["t_reached"] < 1000
    with np.load(tmp_path / "out" / "result.npz") as z:
        assert z["t"][-1] == pytest.approx(res["t_reached"], rel=1e-12)


def test_shipped_model_with_a_long_log_list_is_runnable(tmp_path):
    """payload_capture logs more than 64 signals of its own: the README's named command is
    accepted (it was a 422 on every submit); the limit applies to a request's 'log'."""
    with app(tmp_path, models=default_dirs(), max_signals=2) as (c, store):
        r = c.post("/jobs", json={"model": "payload_capture", "command": {
            "kind": "named", "name": "capture_payload", "arguments": {"t_latch": 3}}})
        assert r.status_code == 202, r.text
        r = c.post("/jobs", json={"model": "servo", "t_end": 0.1,
                                  "log": ["motor.w", "motor.i", "ref.y"]})
        assert r.status_code == 422 and "'log' names 3 signals" in r.json()["detail"]


# ---------------------------------------------------------------- 4. tokens, t_end
def test_revoked_token_is_refused_at_once(tmp_path):
    """``serve --revoke-user`` deletes the user's tokens; the running app refuses the
    token on the next request although it had verified (and cached) it."""
    from spidersim.cli import main
    with app(tmp_path) as (c, store):
        assert c.get("/models").status_code == 200
        out = io.StringIO()
        with contextlib.redirect_stdout(out):
            assert main(["serve", "--revoke-user", "eve", "--data", str(tmp_path)]) == 0
        assert "1 token(s) revoked" in out.getvalue()
        assert c.get("/models").status_code == 401
        with contextlib.redirect_stderr(io.StringIO()):
            assert main(["serve", "--revoke-user", "nobody", "--data", str(tmp_path)]) == 1


def test_too_short_run_is_refused_at_submit(tmp_path):
    """t_end below the solvers' shortest run (1e-7 s) is a 422 at submit, as in the CLI
    (1e-300 was accepted and failed when it ran); 1e-7 s itself is accepted."""
    with app(tmp_path) as (c, store):
        r = c.post("/jobs", json={"model": "servo", "t_end": 1e-300})
        assert r.status_code == 422 and "at least 1e-07 s" in r.json()["detail"]
        assert c.post("/jobs", json={"model": "servo", "t_end": 1e-7}).status_code == 202


def test_a_large_csv_is_not_written(tmp_path, monkeypatch):
    """Over MAX_CSV_MB (24 bytes a value) result.csv is left out, the NPZ and reports
    written as Result.save does, and the message says where the data are."""
    monkeypatch.setattr(execute, "MAX_CSV_MB", 1e-4)
    res = execute.run_job({"id": "x", "model": "servo", "path": SERVO, "jit": True,
                           "request": {"model": "servo", "t_end": 0.1, "plots": False}},
                          out=str(tmp_path))
    assert res["status"] == "ok" and "result.csv not written" in res["message"]
    assert sorted(os.listdir(tmp_path)) == ["meta.json", "report.json", "report.txt",
                                            "result.npz", "signals.json"]
    r = spidersim.Result.load(str(tmp_path))
    ref = spidersim.load(SERVO).simulate(t_end=0.1)
    assert np.array_equal(r.t, ref.t) and np.array_equal(r["motor.w"], ref["motor.w"])
