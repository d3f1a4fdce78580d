"""The per-user disk quota (``Limits.max_user_mb``, ``serve --max-user-mb``): a submit that
would take a user's stored results plus the reservations of its active jobs over the quota
is refused with 507 saying what is used and how to free it; deleting a job
(``DELETE /jobs/{id}``) or its expiry frees its bytes; ``GET /usage``; a database of the
version before the quota is migrated. In-process app, no workers, jobs of a few hundred kB
written by hand: fast."""
from __future__ import annotations

import math
import os
import sqlite3
import time

import pytest

from spidersim.service.store import Store, folder_bytes

from .conftest import Server, add_user
from .test_hardening import app

BODY = {"model": "servo", "t_end": 0.05, "plots": False}


def finished_job(store, nbytes, state="done", user_id=1):
    """A job of ``user_id`` that ended ``state`` with ``nbytes`` bytes in its folder
    (result.npz of zeros and an empty plot), finished through the store as a runner does."""
    job, _ = store.create_job(user_id, "servo", dict(BODY), 0.05, "x", "h")
    assert store.claim_next()["id"] == job["id"]
    folder = store.job_dir(job["id"])
    os.makedirs(os.path.join(folder, "plots"))
    with open(os.path.join(folder, "result.npz"), "wb") as fh:
        fh.write(bytes(nbytes))
    open(os.path.join(folder, "plots", "a.png"), "wb").close()
    assert store.finish(job["id"], state, "")
    return job["id"]


def test_a_submit_over_the_quota_is_507_naming_the_use_and_the_way_out(tmp_path):
    """Stored 0.8 MB + 0.2 MB reserved for the new job = the 1 MB quota: accepted (the
    quota is not exceeded); the next submit (0.8 + 0.2 active + 0.2) is refused with a
    message giving the figures, the largest jobs and how to free them; nothing stored."""
    with app(tmp_path, max_user_mb=1.0, max_record_mb=0.2) as (c, store):
        big = finished_job(store, 500_000)
        small = finished_job(store, 300_000, state="failed")
        assert store.get_job(big)["bytes"] == 500_000          # the folder, measured
        r = c.post("/jobs", json=BODY)
        assert r.status_code == 202, r.text
        r = c.post("/jobs", json=BODY)
        assert r.status_code == 507, r.text
        msg = r.json()["detail"]
        for part in ("quota of 1 MB", "stored results take 0.8 MB",
                     "1 queued or running job(s) reserve 0.2 MB", "this job 0.2 MB",
                     "DELETE /jobs/{id}", f"{big} (servo, 0.5 MB), {small} (servo, 0.3 MB)",
                     "removed 7 day(s) after", "wait for your active jobs", "GET /usage"):
            assert part in msg, (part, msg)
        assert len(store.list_jobs(1)) == 3


def test_active_jobs_reserve_their_recording_budget(tmp_path):
    """With nothing stored, each queued job reserves max_record_mb: two of 0.4 MB fit a
    1 MB quota, a third does not; cancelling one frees its reservation."""
    with app(tmp_path, max_user_mb=1.0, max_record_mb=0.4) as (c, store):
        first = c.post("/jobs", json=BODY).json()["id"]
        assert c.post("/jobs", json=BODY).status_code == 202
        r = c.post("/jobs", json=BODY)
        assert r.status_code == 507, r.text
        assert "your 2 queued or running job(s) reserve 0.8 MB" in r.json()["detail"]
        assert "DELETE" not in r.json()["detail"]          # nothing stored to delete
        assert c.post(f"/jobs/{first}/cancel").json()["state"] == "cancelled"
        assert c.post("/jobs", json=BODY).status_code == 202


def test_deleting_a_job_frees_its_space_and_its_results_are_gone(tmp_path):
    """DELETE /jobs/{id} of a finished job removes its folder, marks it expired (410 for its
    results) and frees its bytes: the refused submit is accepted. An active job is 409,
    another user's 404, a second delete changes nothing."""
    with app(tmp_path, max_user_mb=1.0, max_record_mb=0.2) as (c, store):
        jid = finished_job(store, 900_000)
        assert c.post("/jobs", json=BODY).status_code == 507
        store.add_user("mallory")                           # user 2
        other = finished_job(store, 10, user_id=2)
        assert c.delete(f"/jobs/{other}").status_code == 404
        assert os.path.isdir(store.job_dir(other))
        r = c.delete(f"/jobs/{jid}")
        assert r.status_code == 200, r.text
        assert r.json()["expired"] and r.json()["bytes"] == 0
        assert not os.path.exists(store.job_dir(jid))
        assert c.get(f"/jobs/{jid}/result.npz").status_code == 410
        active = c.post("/jobs", json=BODY)
        assert active.status_code == 202, active.text
        r = c.delete(f"/jobs/{active.json()['id']}")
        assert r.status_code == 409 and "cancel it first" in r.json()["detail"]
        assert c.delete(f"/jobs/{jid}").status_code == 200
        assert store.usage(1, 0.0, 0)["stored"] == 0


def test_expired_jobs_no_longer_count(tmp_path):
    """A job finished longer ago than keep_days stops counting at once (before the sweeper
    removes its files: it runs every tenth of keep_days, at most every 10 min), and the
    sweep marks it expired with 0 bytes."""
    with app(tmp_path, max_user_mb=1.0, max_record_mb=0.2) as (c, store):
        jid = finished_job(store, 900_000)
        assert c.post("/jobs", json=BODY).status_code == 507
        with sqlite3.connect(store.path) as db:
            db.execute("UPDATE jobs SET finished = ? WHERE id = ?",
                       (time.time() - 7.01 * 86400, jid))
        assert os.path.isdir(store.job_dir(jid))             # not swept yet
        assert c.post("/jobs", json=BODY).status_code == 202
    with app(tmp_path, max_user_mb=1.0, max_record_mb=0.2, keep_days=7) as (c, store):
        assert store.get_job(jid)["expired"] and store.get_job(jid)["bytes"] == 0
        assert not os.path.exists(store.job_dir(jid))
    with app(tmp_path, max_user_mb=1.0, max_record_mb=0.2, keep_days=30) as (c, store):
        assert c.get("/usage").json()["stored_bytes"] == 0     # expired stays expired


def test_a_job_left_running_by_a_stop_counts_the_files_it_wrote(tmp_path):
    """At start-up a job the stopped server left running is failed with the bytes its
    folder holds (a run stopped while writing its files leaves some)."""
    store = Store(str(tmp_path))
    store.add_user("eve")
    job, _ = store.create_job(1, "servo", dict(BODY), 0.05, "x", "h")
    store.claim_next()
    os.makedirs(store.job_dir(job["id"]))
    with open(os.path.join(store.job_dir(job["id"]), "result.npz"), "wb") as fh:
        fh.write(bytes(1234))
    assert Store(str(tmp_path)).recover() == (1, 0)
    assert store.get_job(job["id"])["bytes"] == 1234


def test_usage_route_gives_the_figures(tmp_path):
    """GET /usage: stored bytes of finished jobs, active jobs' reservations, the quota,
    what is free and the largest jobs with their expiry time."""
    with app(tmp_path, max_user_mb=2.0, max_record_mb=0.25) as (c, store):
        a = finished_job(store, 400_000)
        b = finished_job(store, 100_000, state="cancelled")
        assert c.post("/jobs", json=BODY).status_code == 202
        u = c.get("/usage").json()
        assert u["user"] == "eve" and u["quota_bytes"] == 2_000_000
        assert u["stored_bytes"] == 500_000 and u["active_jobs"] == 1
        assert u["reserved_bytes"] == u["reserve_per_job_bytes"] == 250_000
        assert u["used_bytes"] == 750_000 and u["free_bytes"] == 1_250_000
        assert [(j["id"], j["bytes"]) for j in u["largest"]] == [(a, 400_000), (b, 100_000)]
        fin = store.get_job(a)["finished"]
        assert u["largest"][0]["expires"] == pytest.approx(fin + 7 * 86400)
        assert c.get("/jobs").json()[1]["bytes"] == 100_000
        c.headers.pop("Authorization")
        assert c.get("/usage").status_code == 401


#: the jobs table as the version before the quota made it (no ``bytes`` column)
OLD_JOBS = """
CREATE TABLE users(id INTEGER PRIMARY KEY, name TEXT UNIQUE NOT NULL, created REAL NOT NULL);
CREATE TABLE tokens(id TEXT PRIMARY KEY, user_id INTEGER NOT NULL REFERENCES users(id),
    salt BLOB NOT NULL, hash BLOB NOT NULL, created REAL NOT NULL);
CREATE TABLE jobs(
    seq INTEGER PRIMARY KEY AUTOINCREMENT, id TEXT UNIQUE NOT NULL,
    user_id INTEGER NOT NULL REFERENCES users(id), model TEXT NOT NULL,
    request TEXT NOT NULL, state TEXT NOT NULL, t_end REAL NOT NULL,
    progress REAL NOT NULL DEFAULT 0, message TEXT NOT NULL DEFAULT '',
    created REAL NOT NULL, started REAL, finished REAL,
    version TEXT, diagram_hash TEXT, idem_key TEXT, cancel INTEGER NOT NULL DEFAULT 0,
    expired REAL);
"""


def test_a_database_of_the_previous_version_is_migrated(tmp_path):
    """A database without jobs.bytes gains the column; each kept finished job is measured
    from its folder, an expired one counts 0, a queued one is measured when it ends; the
    quota then holds against the measured bytes, and opening it again changes nothing."""
    db = sqlite3.connect(str(tmp_path / "service.sqlite"))
    db.executescript(OLD_JOBS)
    db.execute("INSERT INTO users(id, name, created) VALUES (1, 'eve', 0)")  # app()'s user
    now = time.time()
    rows = [("a" * 32, "done", now, None), ("b" * 32, "failed", now, now),
            ("c" * 32, "queued", None, None)]
    for jid, st, fin, exp in rows:
        db.execute("INSERT INTO jobs(id, user_id, model, request, state, t_end, created, "
                   "finished, expired) VALUES (?, 1, 'servo', '{}', ?, 1, ?, ?, ?)",
                   (jid, st, now, fin, exp))
    db.commit()
    db.close()
    os.makedirs(tmp_path / "jobs" / ("a" * 32))
    (tmp_path / "jobs" / ("a" * 32) / "result.npz").write_bytes(bytes(700_000))
    store = Store(str(tmp_path))
    assert [store.get_job(j)["bytes"] for j, *_ in rows] == [700_000, 0, None]
    assert store.usage(1, 0.0, 0) == {"stored": 700_000, "active": 1, "used": 700_000}
    Store(str(tmp_path))                              # a second open: nothing to migrate
    assert store.get_job("a" * 32)["bytes"] == 700_000
    with app(tmp_path, max_user_mb=1.0, max_record_mb=0.2) as (c, store):
        r = c.post("/jobs", json=BODY)              # 0.7 stored + 0.2 queued + 0.2 new
        assert r.status_code == 507 and "stored results take 0.7 MB" in r.json()["detail"]
        assert store.request_cancel("c" * 32) == "cancelled"
        assert c.post("/jobs", json=BODY).status_code == 202


def test_folder_bytes_counts_every_file_below():
    """The measure the store records: the files under a folder, none when it is missing."""
    assert folder_bytes("/nonexistent/spidersim/quota") == 0


def test_folder_bytes_of_a_tree(tmp_path):
    (tmp_path / "p").mkdir()
    (tmp_path / "a").write_bytes(b"x" * 10)
    (tmp_path / "p" / "b").write_bytes(b"y" * 5)
    assert folder_bytes(str(tmp_path)) == 15


def test_serve_refuses_a_quota_below_one_job(tmp_path, capsys, monkeypatch):
    """--max-user-mb below --max-record-mb could accept no job: exit 2 saying so (a server
    it would start raises instead of serving)."""
    from spidersim import service
    from spidersim.cli import main

    def serve(*a, **k):
        raise AssertionError("the server was started")
    monkeypatch.setattr(service, "serve", serve)
    rc = main(["serve", "--data", str(tmp_path), "--max-user-mb", "10", "--max-record-mb",
               "20"])
    assert rc == 2
    assert "no job could be submitted" in capsys.readouterr().err
    from spidersim.service.app import Limits
    with pytest.raises(ValueError, match="no job could be submitted"):
        Limits(max_user_mb=1, max_record_mb=2)
    with pytest.raises(SystemExit) as ei:
        main(["serve", "--data", str(tmp_path), "--max-user-mb", "nan"])
    assert ei.value.code == 2
    assert "argument --max-user-mb: expected a finite number > 0" in capsys.readouterr().err


def test_the_remote_client_shows_the_quota_message(tmp_path, models_dir, capsys):
    """The real server with --max-user-mb: a job running (its reservation) leaves no room
    for a second one; Client.submit raises RemoteError 507 with the service's message,
    `spidersim run --remote` prints it and exits 2; after the cancel, Client.usage says
    what is used and Client.delete frees it."""
    from spidersim.cli import main
    from spidersim.remote import Client, RemoteError
    data = tmp_path / "data"
    srv = Server(data, models_dir, ["--workers", "1", "--max-t-end", "1000",
                                    "--max-record-mb", "0.6", "--max-user-mb", "1"])
    tok = add_user(data, "quinn")
    srv.start()
    try:
        c = Client(srv.url, tok)
        slow = c.submit("slow", t_end=900, plots=False)
        with pytest.raises(RemoteError) as exc:
            c.submit("servo", t_end=0.05)
        assert exc.value.status == 507
        assert "HTTP 507: this job would take your disk use over your quota of 1 MB" in \
            str(exc.value) and "wait for your active jobs" in str(exc.value)
        capsys.readouterr()
        rc = main(["run", "servo", "--remote", srv.url, "--token", tok, "--out",
                   str(tmp_path / "out"), "--t-end", "0.05"])
        err = capsys.readouterr().err
        assert rc == 2 and "quota of 1 MB" in err and "Traceback" not in err, err
        c.cancel(slow)
        st = c.wait(slow, timeout=60)
        assert st["state"] == "cancelled"
        u = c.usage()
        assert u["active_jobs"] == 0 and u["stored_bytes"] == st["bytes"]
        assert c.delete(slow)["expired"] and c.usage()["stored_bytes"] == 0
    finally:
        srv.stop()


@pytest.mark.parametrize("field", ["max_user_mb", "max_record_mb", "keep_days", "max_t_end"])
@pytest.mark.parametrize("value", [math.inf, math.nan, 0.0, -1.0])
def test_limits_refuse_values_that_switch_a_limit_off(field, value):
    """``Limits`` from Python refuses what ``serve`` refuses on its command line: a nan
    quota was never exceeded (``x > nan`` is false) and an infinite one made ``GET /usage``
    answer 500."""
    from pydantic import ValidationError

    from spidersim.service.app import Limits
    kw = {field: value}
    if field == "max_record_mb":
        kw["max_user_mb"] = 1e9
    with pytest.raises(ValidationError, match=f"{field} must be a finite number > 0"):
        Limits(**kw)
