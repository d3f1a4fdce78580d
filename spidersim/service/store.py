"""The service's database: users, API tokens and jobs in SQLite (stdlib ``sqlite3``).

One file ``<data>/service.sqlite`` in WAL mode (readers never wait for the writer) with a
busy timeout; each thread has its own connection. A job is written *before* the submit is
answered, and claimed by a worker with ``BEGIN IMMEDIATE`` so that two workers never take the
same job.

Tokens have the form ``sst_<id>_<secret>``; only a per-token random salt and the scrypt hash
of the secret are stored (``hashlib.scrypt``, n = 2^14, r = 8, p = 1). The token is shown once,
when it is made. Verified tokens are remembered in memory (keyed by their SHA-256) so that a
client polling a job does not pay the scrypt cost on every request; every request still
looks the token's row up (one indexed query), so a token deleted from the database
(:meth:`Store.revoke_user`, ``spidersim serve --revoke-user NAME``) is refused from the next
request on, without a restart.

Retention: :meth:`Store.expire` marks finished jobs past the retention time ``expired``
(their files are removed by the app; the record stays and its result routes answer 410);
:meth:`Store.mark_deleted` does the same for one job its user deletes.

Disk use: ``bytes`` is the size of a finished job's folder, measured when the job reaches
its final state (after its files are written); 0 once expired or deleted. A user's stored
bytes plus a reservation per active job are held to a quota at submit
(:meth:`Store.create_job`, :class:`OverQuota`).

Job states: ``queued`` -> ``running`` -> ``done`` | ``failed`` | ``cancelled`` (a queued job
may be cancelled directly). ``progress`` is the simulated time reached [s]; ``t_end`` the
simulated time asked for [s]. ``done`` is set only after the result files are written.
"""
from __future__ import annotations

import hashlib
import hmac
import json
import os
import re
import secrets
import sqlite3
import threading
import time
import uuid

STATES = ("queued", "running", "done", "failed", "cancelled")
ACTIVE = ("queued", "running")
_USER = re.compile(r"^[A-Za-z0-9_.-]{1,64}\Z")

SCHEMA = """
CREATE TABLE IF NOT EXISTS users(
    id INTEGER PRIMARY KEY, name TEXT UNIQUE NOT NULL, created REAL NOT NULL);
CREATE TABLE IF NOT EXISTS tokens(
    id TEXT PRIMARY KEY, user_id INTEGER NOT NULL REFERENCES users(id),
    salt BLOB NOT NULL, hash BLOB NOT NULL, created REAL NOT NULL);
CREATE TABLE IF NOT EXISTS jobs(
    seq INTEGER PRIMARY KEY AUTOINCREMENT, id TEXT UNIQUE NOT NULL,
    user_id INTEGER NOT NULL REFERENCES users(id), model TEXT NOT NULL,
    request TEXT NOT NULL, state TEXT NOT NULL, t_end REAL NOT NULL,
    progress REAL NOT NULL DEFAULT 0, message TEXT NOT NULL DEFAULT '',
    created REAL NOT NULL, started REAL, finished REAL,
    version TEXT, diagram_hash TEXT, idem_key TEXT, cancel INTEGER NOT NULL DEFAULT 0,
    expired REAL, bytes INTEGER);
CREATE UNIQUE INDEX IF NOT EXISTS jobs_idem ON jobs(user_id, idem_key)
    WHERE idem_key IS NOT NULL;
CREATE INDEX IF NOT EXISTS jobs_state ON jobs(state, seq);
CREATE INDEX IF NOT EXISTS jobs_user ON jobs(user_id, seq);
"""

_JOB_COLS = ("id", "user_id", "model", "request", "state", "t_end", "progress", "message",
             "created", "started", "finished", "version", "diagram_hash", "idem_key",
             "expired", "bytes")


def folder_bytes(folder) -> int:
    """Bytes of the files under ``folder`` (0 if it does not exist); files that vanish
    while it is walked are skipped."""
    total = 0
    for root, _dirs, names in os.walk(folder):
        for n in names:
            try:
                total += os.lstat(os.path.join(root, n)).st_size
            except OSError:
                pass
    return total


def _scrypt(secret: str, salt: bytes) -> bytes:
    return hashlib.scrypt(secret.encode(), salt=salt, n=2 ** 14, r=8, p=1, dklen=32)


class Store:
    """Users, tokens and jobs of one data folder."""

    def __init__(self, data_dir):
        self.data_dir = os.path.abspath(data_dir)
        os.makedirs(self.data_dir, exist_ok=True)
        self.path = os.path.join(self.data_dir, "service.sqlite")
        self._local = threading.local()
        self._verified = {}          # sha256(token) -> (token id, (user_id, name))
        with self._conn() as c:
            c.executescript(SCHEMA)
            cols = {r[1] for r in c.execute("PRAGMA table_info(jobs)")}
            if "expired" not in cols:            # a database of an earlier version
                c.execute("ALTER TABLE jobs ADD COLUMN expired REAL")
            if "bytes" not in cols:
                self._add_bytes_column(c)

    def _add_bytes_column(self, c):
        """Migration of a database made before the quota: add ``jobs.bytes`` and measure
        the folder of every finished job whose files are kept (0 for expired ones; active
        jobs are measured when they finish)."""
        c.execute("BEGIN IMMEDIATE")
        try:
            if "bytes" not in {r[1] for r in c.execute("PRAGMA table_info(jobs)")}:
                c.execute("ALTER TABLE jobs ADD COLUMN bytes INTEGER")
            rows = c.execute("SELECT id, expired FROM jobs WHERE state IN ('done', 'failed', "
                             "'cancelled') AND bytes IS NULL").fetchall()
            c.executemany("UPDATE jobs SET bytes = ? WHERE id = ?",
                          [(0 if r["expired"] else folder_bytes(self.job_dir(r["id"])),
                            r["id"]) for r in rows])
            c.execute("COMMIT")
        except BaseException:
            c.execute("ROLLBACK")
            raise

    # ------------------------------------------------------------------ plumbing
    def _conn(self) -> sqlite3.Connection:
        c = getattr(self._local, "conn", None)
        if c is None:
            c = sqlite3.connect(self.path, timeout=30.0, isolation_level=None)
            c.row_factory = sqlite3.Row
            c.execute("PRAGMA journal_mode=WAL")
            c.execute("PRAGMA busy_timeout=30000")
            c.execute("PRAGMA synchronous=NORMAL")
            c.execute("PRAGMA foreign_keys=ON")
            self._local.conn = c
        return c

    def job_dir(self, job_id):
        return os.path.join(self.data_dir, "jobs", job_id)

    # ------------------------------------------------------------------ users, tokens
    def add_user(self, name) -> str:
        """Create ``name`` if new and give it a new token; return the token (shown once)."""
        if not _USER.match(name or ""):
            raise ValueError(f"user name must be 1-64 letters, digits, '_', '.', '-', got "
                             f"{name!r}")
        c = self._conn()
        c.execute("BEGIN IMMEDIATE")
        try:
            row = c.execute("SELECT id FROM users WHERE name = ?", (name,)).fetchone()
            uid = row["id"] if row else c.execute(
                "INSERT INTO users(name, created) VALUES (?, ?)", (name, time.time())).lastrowid
            tid = secrets.token_hex(8)
            secret = secrets.token_urlsafe(32)
            salt = os.urandom(16)
            c.execute("INSERT INTO tokens(id, user_id, salt, hash, created) VALUES (?,?,?,?,?)",
                      (tid, uid, salt, _scrypt(secret, salt), time.time()))
            c.execute("COMMIT")
        except BaseException:
            c.execute("ROLLBACK")
            raise
        return f"sst_{tid}_{secret}"

    def user_for_token(self, token):
        """``(user_id, name)`` of a valid token, else None."""
        if not token or len(token) > 200:
            return None
        key = hashlib.sha256(token.encode()).digest()
        hit = self._verified.get(key)
        if hit is not None:                     # verified before: is it still there?
            row = self._conn().execute("SELECT 1 FROM tokens WHERE id = ?",
                                       (hit[0],)).fetchone()
            if row is not None:
                return hit[1]
            self._verified.pop(key, None)
            return None
        parts = token.split("_", 2)
        if len(parts) != 3 or parts[0] != "sst":
            return None
        row = self._conn().execute(
            "SELECT t.salt, t.hash, u.id, u.name FROM tokens t JOIN users u ON u.id = t.user_id"
            " WHERE t.id = ?", (parts[1],)).fetchone()
        if row is None or not hmac.compare_digest(_scrypt(parts[2], row["salt"]), row["hash"]):
            return None
        self._verified[key] = (parts[1], (row["id"], row["name"]))
        return self._verified[key][1]

    def revoke_user(self, name) -> int:
        """Delete every token of user ``name`` (the user and its jobs stay; ``add_user``
        gives a new token); return the number deleted. Effective on the next request of a
        running server. Raises KeyError for an unknown user."""
        c = self._conn()
        row = c.execute("SELECT id FROM users WHERE name = ?", (name,)).fetchone()
        if row is None:
            raise KeyError(name)
        return c.execute("DELETE FROM tokens WHERE user_id = ?", (row["id"],)).rowcount

    # ------------------------------------------------------------------ jobs
    def create_job(self, user_id, model, request: dict, t_end, version, diagram_hash,
                   idem_key=None, max_active=None, quota=None):
        """Insert a queued job; return ``(job, created)``.

        With ``idem_key`` an earlier job of the same user with the same key is returned
        instead (``created`` False) when it was the same request; a different request
        under a key already used raises :class:`KeyReused` (a client's bug: the key names
        one request). With ``max_active`` raise :class:`TooManyJobs` when the
        user already has that many queued or running jobs. With ``quota = (limit bytes,
        reservation bytes per active job, since)`` raise :class:`OverQuota` when the
        user's stored bytes (jobs finished at or after ``since``, not expired) plus a
        reservation for each active job and for this one would exceed the limit; checked
        in the insert's transaction, so that parallel submits cannot all pass.
        """
        c = self._conn()
        c.execute("BEGIN IMMEDIATE")
        try:
            if idem_key is not None:
                row = c.execute("SELECT * FROM jobs WHERE user_id = ? AND idem_key = ?",
                                (user_id, idem_key)).fetchone()
                if row is not None:
                    job = self._job(row)
                    if job["model"] != model or job["request"] != json.loads(
                            json.dumps(request)):
                        raise KeyReused(idem_key)             # rolled back below
                    c.execute("COMMIT")
                    return job, False
            if max_active is not None:
                n = c.execute("SELECT COUNT(*) FROM jobs WHERE user_id = ? AND state IN "
                              "('queued', 'running')", (user_id,)).fetchone()[0]
                if n >= max_active:
                    raise TooManyJobs(n)
            if quota is not None:
                limit, reserve, since = quota
                use = self.usage(user_id, since, reserve)
                if use["used"] + reserve > limit:
                    raise OverQuota(use, reserve, limit)
            jid = uuid.uuid4().hex
            c.execute("INSERT INTO jobs(id, user_id, model, request, state, t_end, created, "
                      "version, diagram_hash, idem_key) VALUES (?,?,?,?,?,?,?,?,?,?)",
                      (jid, user_id, model, json.dumps(request), "queued", float(t_end),
                       time.time(), version, diagram_hash, idem_key))
            c.execute("COMMIT")
        except BaseException:
            c.execute("ROLLBACK")
            raise
        return self.get_job(jid), True

    @staticmethod
    def _job(row):
        if row is None:
            return None
        j = {k: row[k] for k in _JOB_COLS}
        if j["request"] is not None:
            j["request"] = json.loads(j["request"])
        j["cancel"] = bool(row["cancel"])
        return j

    def expire(self, cutoff):
        """Mark jobs finished before ``cutoff`` (a time.time()) expired; return their ids."""
        c = self._conn()
        c.execute("BEGIN IMMEDIATE")
        try:
            ids = [r[0] for r in c.execute(
                "SELECT id FROM jobs WHERE expired IS NULL AND finished IS NOT NULL AND "
                "finished < ? AND state IN ('done', 'failed', 'cancelled')", (cutoff,))]
            c.executemany("UPDATE jobs SET expired = ?, bytes = 0 WHERE id = ?",
                          [(time.time(), i) for i in ids])
            c.execute("COMMIT")
        except BaseException:
            c.execute("ROLLBACK")
            raise
        return ids

    def mark_deleted(self, job_id):
        """Mark a finished job expired, its bytes 0 (its user deleted it; the caller
        removes its folder); True if it was finished and not yet expired."""
        cur = self._conn().execute(
            "UPDATE jobs SET expired = ?, bytes = 0 WHERE id = ? AND expired IS NULL AND "
            "state IN ('done', 'failed', 'cancelled')", (time.time(), job_id))
        return cur.rowcount == 1

    def usage(self, user_id, since, reserve):
        """A user's disk use: ``{"stored": bytes of its finished jobs that ended at or
        after ``since`` and are not expired, "active": queued + running jobs, "used":
        stored + active x reserve}``."""
        c = self._conn()
        stored = c.execute(
            "SELECT COALESCE(SUM(bytes), 0) FROM jobs WHERE user_id = ? AND expired IS NULL "
            "AND finished >= ? AND state IN ('done', 'failed', 'cancelled')",
            (user_id, since)).fetchone()[0]
        active = c.execute("SELECT COUNT(*) FROM jobs WHERE user_id = ? AND state IN "
                           "('queued', 'running')", (user_id,)).fetchone()[0]
        return {"stored": int(stored), "active": int(active),
                "used": int(stored) + int(active * reserve)}

    def largest_jobs(self, user_id, since, n=3):
        """``[(id, model, bytes, finished)]`` of a user's ``n`` largest stored jobs (as
        counted by :meth:`usage`), largest first."""
        return [tuple(r) for r in self._conn().execute(
            "SELECT id, model, bytes, finished FROM jobs WHERE user_id = ? AND expired IS NULL"
            " AND finished >= ? AND state IN ('done', 'failed', 'cancelled') AND bytes > 0 "
            "ORDER BY bytes DESC, seq LIMIT ?", (user_id, since, n))]

    def release(self, job_id):
        """Put a job claimed while the server began to stop back in the queue."""
        self._conn().execute("UPDATE jobs SET state = 'queued', started = NULL, progress = 0 "
                             "WHERE id = ? AND state = 'running'", (job_id,))

    def get_job(self, job_id, user_id=None):
        q, args = "SELECT * FROM jobs WHERE id = ?", [job_id]
        if user_id is not None:
            q += " AND user_id = ?"
            args.append(user_id)
        return self._job(self._conn().execute(q, args).fetchone())

    def list_jobs(self, user_id, limit=100, request=True):
        """The user's ``limit`` newest jobs, newest first; with ``request=False`` without
        their requests (neither read nor parsed: up to 256 KiB each)."""
        cols = "*" if request else \
            ", ".join(c for c in _JOB_COLS if c != "request") + ", cancel, NULL AS request"
        rows = self._conn().execute(f"SELECT {cols} FROM jobs WHERE user_id = ? ORDER BY "
                                    f"seq DESC LIMIT ?", (user_id, limit)).fetchall()
        return [self._job(r) for r in rows]

    def claim_next(self):
        """Take the oldest queued job and mark it running; None when there is none."""
        c = self._conn()
        c.execute("BEGIN IMMEDIATE")
        try:
            row = c.execute("SELECT * FROM jobs WHERE state = 'queued' ORDER BY seq "
                            "LIMIT 1").fetchone()
            if row is not None:
                c.execute("UPDATE jobs SET state = 'running', started = ?, progress = 0 "
                          "WHERE id = ?", (time.time(), row["id"]))
            c.execute("COMMIT")
        except BaseException:
            c.execute("ROLLBACK")
            raise
        return None if row is None else self.get_job(row["id"])

    def set_progress(self, job_id, t):
        self._conn().execute("UPDATE jobs SET progress = ? WHERE id = ? AND state = 'running'",
                             (float(t), job_id))

    def finish(self, job_id, state, message="", progress=None):
        """Move a job to a final state (only from queued or running); True if it moved."""
        assert state in ("done", "failed", "cancelled")
        sets, args = "state = ?, message = ?, finished = ?, bytes = ?", [
            state, message, time.time(), folder_bytes(self.job_dir(job_id))]
        if progress is not None:
            sets += ", progress = ?"
            args.append(float(progress))
        cur = self._conn().execute(
            f"UPDATE jobs SET {sets} WHERE id = ? AND state IN ('queued', 'running')",
            args + [job_id])
        return cur.rowcount == 1

    def request_cancel(self, job_id):
        """Flag a job for cancellation; a queued job is cancelled at once. Returns its state."""
        c = self._conn()
        c.execute("BEGIN IMMEDIATE")
        try:
            c.execute("UPDATE jobs SET cancel = 1 WHERE id = ?", (job_id,))
            c.execute("UPDATE jobs SET state = 'cancelled', finished = ?, message = ?, "
                      "bytes = 0 WHERE id = ? AND state = 'queued'",
                      (time.time(), "cancelled before it started", job_id))
            c.execute("COMMIT")
        except BaseException:
            c.execute("ROLLBACK")
            raise
        return self.get_job(job_id)["state"]

    def cancel_requested(self, job_id):
        row = self._conn().execute("SELECT cancel FROM jobs WHERE id = ?", (job_id,)).fetchone()
        return bool(row and row[0])

    def recover(self):
        """At start-up: jobs left running by a stopped server are failed; return the number
        of those and of the queued jobs (which the workers will run)."""
        c = self._conn()
        ids = [r[0] for r in c.execute("SELECT id FROM jobs WHERE state = 'running'")]
        n = 0
        for jid in ids:                 # the files a run wrote before the stop count
            n += c.execute("UPDATE jobs SET state = 'failed', finished = ?, message = ?, "
                           "bytes = ? WHERE id = ? AND state = 'running'",
                           (time.time(), "server stopped while running",
                            folder_bytes(self.job_dir(jid)), jid)).rowcount
        n_queued = c.execute("SELECT COUNT(*) FROM jobs WHERE state = 'queued'").fetchone()[0]
        return n, n_queued

    def active_count(self, user_id):
        return self._conn().execute("SELECT COUNT(*) FROM jobs WHERE user_id = ? AND state IN "
                                    "('queued', 'running')", (user_id,)).fetchone()[0]


class KeyReused(Exception):
    """An idempotency key already used for a different request of the same user."""

    def __init__(self, key):
        super().__init__(key)
        self.key = key


class TooManyJobs(Exception):
    def __init__(self, n):
        super().__init__(n)
        self.n = n


class OverQuota(Exception):
    """A submit that would take a user's disk use over its quota: ``usage`` (as
    :meth:`Store.usage` gives it), the new job's ``reserve`` and the ``limit`` [bytes]."""

    def __init__(self, usage, reserve, limit):
        super().__init__(usage, reserve, limit)
        self.usage, self.reserve, self.limit = usage, reserve, limit
