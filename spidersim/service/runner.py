"""Job runners: a pool of local worker processes (default) or an existing Dask cluster.

Local pool: ``workers`` slots, each a server thread owning one worker process (started with
``spawn``: no fork of a threaded server). A slot claims the oldest queued job from the store,
sends it to its process and relays progress to the store. Stopping a run is cooperative,
with a kill as backup (a process pool cannot stop a running future; this one can):

* *cancel* of a running job sets the slot's cancel flag (a byte of shared memory the worker
  was started with; the worker is busy integrating and does not read its pipe). The
  integration loop's ``should_stop`` reads it every few steps, the run stops, its rows so
  far are written as a finished job's files and the job ends ``cancelled`` saying at what
  simulated time. A worker that has not stopped its loop :data:`CANCEL_GRACE` seconds after
  the cancel (still loading or compiling the model: a first run of a structure compiles
  for up to tens of seconds, and compiling cannot be interrupted) is killed: no data, the
  next job starts a fresh process. A run that has stopped gets :data:`KILL_GRACE` seconds
  to write its files. A cancel that arrives before the run begins ends the job without
  data and keeps the process. The slot clears the flag before each job.
* the *wall-time limit* stops a run the same way (the rows so far are saved, the job fails
  saying which limit) and kills the process only :data:`KILL_GRACE` seconds later.

A process that dies for any other reason fails its job with the exit status, and the slot
starts a fresh process for the next job. Workers ignore SIGINT and SIGTERM (a
stop of the whole process group, as systemd does, is the server's to handle): once the
server begins to stop no slot claims a job, queued jobs stay queued for the next start,
and a job claimed at that moment goes back to the queue. Worker
processes keep the compiled diagrams they have loaded (and share the numba disk cache
``SPIDERSIM_CACHE``), so only the first run of a structure compiles. A worker exits when the
server's end of its pipe closes or its parent changes (server killed).

Dask (``--scheduler ADDR``): the same :func:`~spidersim.service.execute.run_job` runs as a Dask
task that returns the files' bytes; progress goes through a ``distributed.Variable`` per job.
Dask cannot stop a running task from outside, so stopping is cooperative as in the local pool,
through two ``distributed.Event`` named after the job (:func:`_dask_names`) that the task's
``should_stop`` reads at most every :data:`STOP_READ` s (a round trip each time the loop
asks made runs 50-300 times slower):

* *cancel* sets the job's cancel Event; the run stops, returns its rows so far as files, the
  runner writes them and the job ends ``cancelled`` saying at what simulated time. A run
  whose loop has not stopped :data:`CANCEL_GRACE` s later (the task not begun yet, or still
  loading or compiling its model) is given up: its future is cancelled, the job ends
  cancelled without data; a task already running goes on until it reaches its loop, finds
  the Event set and stops (holding its worker thread until then).
* the *wall-time limit* (counted from the submission) sets the limit Event: the rows so far
  come back, the job fails saying which limit, as in the local pool; the task is given up
  (no data) only :data:`KILL_GRACE` s later.
* a server stop gives the running tasks up (the job fails, no data, as a killed worker's)
  with their cancel Event set, so that they stop on the cluster too.

A task removes its Events and Variable from the scheduler when it ends.
"""
from __future__ import annotations

import multiprocessing as mp
import os
import shutil
import signal
import sys
import threading
import time
import traceback

from spidersim.errors import SpidersimError

from .execute import run_job

POLL = 0.2           # s between checks of cancel flags and process health
#: s after the wall-time limit before a run that did not stop (or is still writing its
#: files) is killed
KILL_GRACE = 60.0
#: s after a cancel before a run that has not stopped its integration loop (still loading
#: or compiling its model) is killed
CANCEL_GRACE = 3.0
#: s of wall time between two reads of a Dask job's stop Events by its run
STOP_READ = 0.3
STOPPED = "stopped"  # the Dask task's progress Variable, once its loop has returned
GIVEN_UP = object()  # a Dask job finished without its task's result


def _worker_main(conn, parent_pid, record_mb=None, cancel_flag=None):
    """Entry point of a local worker process; ``record_mb``: its share of the recording
    budget (:mod:`spidersim.solver.record_budget`), so that the slots' runs together stay
    within it; ``cancel_flag``: the slot's shared byte, nonzero when the running job is
    cancelled (read by the run's ``should_stop``)."""
    if record_mb is not None:
        from spidersim.solver import record_budget
        os.environ[record_budget.ENV] = f"{record_mb:.6g}"
    import spidersim  # noqa: F401  (import once, before the first job)
    signal.signal(signal.SIGINT, signal.SIG_IGN)      # the server handles Ctrl-C and
    signal.signal(signal.SIGTERM, signal.SIG_IGN)     # a stop of the process group
    while True:
        try:
            task = conn.recv()
        except (EOFError, OSError):
            return
        if task is None:
            return

        def report(t):
            if os.getppid() != parent_pid:             # server gone: stop at once
                os._exit(3)
            conn.send(("progress", t))

        def stopped(t):                               # the loop has returned: say so
            conn.send(("stopped", t))

        cancel = None if cancel_flag is None else (lambda: cancel_flag.value != 0)
        try:
            res = run_job(task, report, out=task["out"], cancel=cancel, stopped=stopped)
            conn.send(("done", res))
        except SpidersimError as exc:
            from .library import Model
            conn.send(("error", Model(task["model"], task["path"]).public_message(exc)))
        except Exception as exc:    # a bug: say so, keep the worker
            traceback.print_exc(file=sys.stderr)
            conn.send(("error", f"internal error: {type(exc).__name__}: {exc}"))


def _cancel_overdue(now, t_cancel, t_stopped):
    """Which grace a cancelled run has overrun at ``now`` (monotonic s), or None:
    ``"stop"``, its loop has not stopped :data:`CANCEL_GRACE` s after the cancel at
    ``t_cancel``; ``"write"``, it stopped at ``t_stopped`` and has not written its files
    :data:`KILL_GRACE` s later."""
    if t_cancel is None:
        return None
    if t_stopped is None and now - t_cancel > CANCEL_GRACE:
        return "stop"
    if t_stopped is not None and now - t_stopped > KILL_GRACE:
        return "write"
    return None


def _died_message(code):
    if code is not None and code < 0:
        try:
            name = signal.Signals(-code).name
        except ValueError:
            name = f"signal {-code}"
        return f"worker process killed by {name} while running the job"
    return f"worker process exited (status {code}) while running the job"


class Runner:
    """Common part: slots that claim queued jobs and finish them in the store."""

    def __init__(self, store, library, n_slots, job_timeout=3600.0, jit=True,
                 job_record_mb=None):
        self.store = store
        self.library = library
        self.n_slots = max(1, int(n_slots))
        self.job_timeout = float(job_timeout)
        self.jit = jit
        self.job_record_mb = job_record_mb
        self._wake = threading.Condition()
        self._stopping = False
        self._threads = []
        self.running = {}            # job id -> slot index

    def start(self):
        for k in range(self.n_slots):
            th = threading.Thread(target=self._loop, args=(k,), daemon=True,
                                  name=f"spidersim-slot-{k}")
            th.start()
            self._threads.append(th)

    def wake(self):
        with self._wake:
            self._wake.notify_all()

    def begin_stop(self):
        """No more claims; running jobs are stopped by their slots."""
        self._stopping = True
        self.wake()

    def stop(self, wait=10.0):
        """Stop claiming; wait up to ``wait`` s for the slots to stop their jobs and mark
        them failed (the server's exit otherwise left them 'running' in the store)."""
        self.begin_stop()
        t_end = time.monotonic() + wait
        for th in self._threads:
            th.join(max(0.0, t_end - time.monotonic()))

    def _task(self, job):
        model = self.library.models.get(job["model"])
        return {"id": job["id"], "model": job["model"],
                "path": model.path if model else None, "request": job["request"],
                "jit": self.jit, "out": self.store.job_dir(job["id"]),
                "wall_limit": self.job_timeout}

    def _loop(self, k):
        while not self._stopping:
            try:
                job = self.store.claim_next()
            except Exception:                 # database busy beyond the timeout: retry
                traceback.print_exc(file=sys.stderr)
                job = None
            if job is None:
                with self._wake:
                    self._wake.wait(1.0)
                continue
            if self._stopping:                # claimed as the server began to stop
                self.store.release(job["id"])
                return
            self.running[job["id"]] = k
            try:
                if job["model"] not in self.library.models:
                    self.store.finish(job["id"], "failed", f"model '{job['model']}' is no "
                                      f"longer in the library")
                else:
                    self._run(k, job)
            except Exception as exc:
                traceback.print_exc(file=sys.stderr)
                self.store.finish(job["id"], "failed", f"internal error: {exc}")
            finally:
                self.running.pop(job["id"], None)

    def _finish_result(self, job, res):
        msg = res.get("message") or ""
        if res.get("plot_error"):
            msg = (msg + "; " if msg else "") + res["plot_error"]
        state = {"ok": "done", "cancelled": "cancelled"}.get(res["status"], "failed")
        if res["status"] == "cancelled":      # stopped by a cancel, data kept (or none)
            if res.get("t_reached") is None:
                msg = "cancelled before its run began (no data)"
            else:
                msg = (f"cancelled while running: the run stopped at t = "
                       f"{res['t_reached']:.9g} s; the data computed up to there are kept"
                       + (f"; {res['plot_error']}" if res.get("plot_error") else ""))
        if res["status"] == "interrupted":    # stopped by the wall-time limit, data kept
            msg = (f"stopped: the wall-time limit of {self.job_timeout:g} s per job was "
                   f"reached at t = {res.get('t_reached', 0.0):.6g} s; the data computed "
                   f"so far are kept")
        self.store.finish(job["id"], state, msg, progress=res.get("t_reached"))


class LocalRunner(Runner):
    """Worker processes on this machine, one per slot."""

    #: why a cancelled run was killed, by :func:`_cancel_overdue`'s answer
    OVERDUE = {"stop": f"the run did not stop within {CANCEL_GRACE:g} s (its model was "
                       f"still being loaded or compiled): killed",
               "write": f"its files were not written within {KILL_GRACE:g} s: killed"}

    def __init__(self, store, library, workers=2, **kw):
        super().__init__(store, library, workers, **kw)
        self._ctx = mp.get_context("spawn")
        self._procs = [None] * self.n_slots
        from spidersim.solver import record_budget
        #: each worker's share of the recording budget [MB]: the budget (the machine's, or
        #: the server's SPIDERSIM_RECORD_LIMIT_MB) divided among the slots
        self.record_mb = record_budget.budget_bytes() / 1e6 / self.n_slots
        if self.job_record_mb is not None:    # the service's per-job budget
            self.record_mb = min(self.record_mb, float(self.job_record_mb))

    def _process(self, k):
        """``(process, pipe, cancel flag)`` of slot ``k``, started if it is not alive."""
        p = self._procs[k]
        if p is None or not p[0].is_alive():
            parent, child = self._ctx.Pipe()
            flag = self._ctx.RawValue("b", 0)      # shared byte: no lock, read every pause
            proc = self._ctx.Process(target=_worker_main,
                                     args=(child, os.getpid(), self.record_mb, flag),
                                     daemon=True, name=f"spidersim-worker-{k}")
            proc.start()
            child.close()
            self._procs[k] = (proc, parent, flag)
        return self._procs[k]

    def worker_pids(self):
        return [p[0].pid for p in self._procs if p is not None and p[0].is_alive()]

    def _kill(self, k):
        p = self._procs[k]
        if p is not None:
            p[0].kill()
            p[0].join(5)
            p[1].close()
            self._procs[k] = None

    def stop(self):
        super().stop()                # each slot kills its own process and marks its job
        for k in range(self.n_slots):
            if self._procs[k] is not None:
                self._kill(k)

    def _cancel_killed(self, k, jid, why):
        """Kill slot ``k``'s process for a cancel; the job ends cancelled without data (any
        file the run began to write is removed: a cancelled job's results are its
        complete files or none)."""
        if k is not None:
            self._kill(k)
        folder = self.store.job_dir(jid)
        shutil.rmtree(folder, ignore_errors=True)
        os.makedirs(folder, exist_ok=True)
        self.store.finish(jid, "cancelled", f"cancelled while running: {why}, no data")

    def _run(self, k, job):
        jid = job["id"]
        os.makedirs(self.store.job_dir(jid), exist_ok=True)
        proc, conn, flag = self._process(k)
        flag.value = 0                      # no stale cancel of an earlier job
        conn.send(self._task(job))
        t0 = time.monotonic()
        t_cancel = None                     # when the cancel flag was set
        t_stopped = None                    # when the worker said its loop had returned
        while True:
            try:
                ready = conn.poll(POLL)
                msg = conn.recv() if ready else None
            except (EOFError, OSError):
                msg, ready = None, False
                proc.join(2)
            if msg is not None:
                kind, val = msg
                if kind == "progress":
                    self.store.set_progress(jid, val)
                    continue
                if kind == "stopped":
                    t_stopped = time.monotonic()
                    continue
                if kind == "done":
                    self._finish_result(job, val)
                else:
                    self.store.finish(jid, "failed", val)
                return
            if self._stopping:
                self._kill(k)
                self.store.finish(jid, "failed", "server stopped while running")
                return
            if not proc.is_alive():
                code = proc.exitcode
                self._procs[k] = None
                if self.store.cancel_requested(jid):
                    self._cancel_killed(None, jid, "the worker process ended")
                else:
                    self.store.finish(jid, "failed", _died_message(code))
                return
            now = time.monotonic()
            if t_cancel is None and self.store.cancel_requested(jid):
                flag.value = 1              # the run stops at its loop's next pause
                t_cancel = now
            why = _cancel_overdue(now, t_cancel, t_stopped)
            if why:
                self._cancel_killed(k, jid, self.OVERDUE[why])
                return
            if now - t0 > self.job_timeout + KILL_GRACE:
                self._kill(k)               # it did not stop at the limit: no data
                self.store.finish(jid, "failed", f"stopped: the wall-time limit of "
                                  f"{self.job_timeout:g} s per job was reached (the run "
                                  f"did not stop within {KILL_GRACE:g} s: killed, no data)")
                return


def _dask_names(jid):
    """Names of a Dask job's shared state on the scheduler: ``progress`` (a
    ``distributed.Variable`` the task sets: the time reached, then ``[STOPPED, t]`` once its
    loop has returned), ``cancel`` and ``limit`` (two ``distributed.Event`` the runner
    sets to stop the run: a cancel, the wall-time limit)."""
    return {k: f"spidersim-{k}-{jid}" for k in ("progress", "cancel", "limit")}


def _event_reader(event, every=STOP_READ):
    """``() -> bool``: whether ``event`` (a ``distributed.Event``) is set, asked of the
    scheduler at most every ``every`` s of wall time (the loop asks every few steps: a
    network round trip each would slow it) and true from the first answer that says so. A
    read that fails counts as not set (the run goes on)."""
    state = {"next": 0.0, "set": False}

    def read():
        now = time.monotonic()
        if not state["set"] and now >= state["next"]:
            state["next"] = now + every
            try:
                state["set"] = bool(event.is_set())
            except Exception:
                pass
        return state["set"]
    return read


def _dask_task(task):
    """``run_job`` on a Dask worker: progress and the loop's stop through the job's
    :func:`_dask_names` (its ``should_stop`` reads the cancel and limit Events); the job's
    state on the scheduler is removed when the task ends (a task the runner gave up on is
    still running and stops at the Event it finds set)."""
    from distributed import Event, Variable
    names = _dask_names(task["id"])
    var = Variable(names["progress"])
    cancel, limit = Event(names["cancel"]), Event(names["limit"])
    try:
        return run_job(task, var.set, out=None, cancel=_event_reader(cancel),
                       limit=_event_reader(limit),
                       stopped=lambda t: var.set([STOPPED, t]))
    finally:
        _dask_clear(var, cancel, limit)


def _give_up(fut, cancel):
    """Drop a Dask job's result: set its cancel Event (a running task cannot be stopped
    from outside; it stops at its next read of the Event) and cancel its future."""
    try:
        cancel.set()
    except Exception:
        pass
    fut.cancel()


def _dask_clear(var, *events):
    """Remove a job's Variable and Events from the scheduler (best effort)."""
    for f in [var.delete] + [e.clear for e in events]:
        try:
            f()
        except Exception:
            pass


class DaskRunner(Runner):
    """Jobs as tasks on an existing Dask cluster (the one sweeps use)."""

    #: why a cancelled run's result was dropped, by :func:`_cancel_overdue`'s answer
    OVERDUE = {"stop": f"the Dask task did not stop its run within {CANCEL_GRACE:g} s (not "
                       f"begun yet, or its model was still being loaded or compiled): "
                       f"its result is dropped",
               "write": f"its files did not come back within {KILL_GRACE:g} s: its result "
                        f"is dropped"}

    def __init__(self, store, library, scheduler, slots=None, **kw):
        from distributed import Client
        try:
            self.client = Client(scheduler, timeout="10s")
        except Exception as exc:
            raise SpidersimError(f"cannot connect to the Dask scheduler at {scheduler}: "
                                 f"{type(exc).__name__}: {exc}") from None
        if slots is None:
            info = self.client.scheduler_info()
            slots = sum(w.get("nthreads", 1) for w in info.get("workers", {}).values()) or 1
        super().__init__(store, library, slots, **kw)

    def stop(self):
        super().stop()
        try:
            self.client.close()
        except Exception:
            pass

    def _run(self, k, job):
        from distributed import Event, Variable
        jid = job["id"]
        task = self._task(job)
        task["out"] = None
        names = _dask_names(jid)
        var = Variable(names["progress"], client=self.client)
        cancel = Event(names["cancel"], client=self.client)
        limit = Event(names["limit"], client=self.client)
        fut = self.client.submit(_dask_task, task, key=f"spidersim-{jid}", pure=False)
        try:
            res = self._await(job, fut, var, cancel, limit)
        except BaseException:
            _give_up(fut, cancel)
            raise
        if res is GIVEN_UP:
            # a running task stops at its Event and clears it when it ends; one that never
            # started (cancelled while queued on the cluster) never would: clear them once
            # any task has had time to read the Event
            t = threading.Timer(KILL_GRACE, _dask_clear, args=(var, cancel, limit))
            t.daemon = True
            t.start()
            return
        _dask_clear(var, cancel, limit)
        if res is None:                     # finished in the store already
            return
        self._write_files(jid, res.pop("files", {}))
        self._finish_result(job, res)

    def _await(self, job, fut, var, cancel, limit):
        """The task's result; None once the job is finished in the store because the task
        failed; :data:`GIVEN_UP` once it is finished because the server stops or the run
        did not return in time after a cancel or the wall-time limit (the future is
        cancelled, the cancel Event set: a running task stops at it). A cancel or the
        limit sets the job's Event and waits for the run to return its data, with the
        local pool's graces (:func:`_cancel_overdue`; the limit's :data:`KILL_GRACE`)."""
        from distributed import TimeoutError as DTimeout
        jid = job["id"]
        t0 = time.monotonic()
        t_cancel = t_stopped = None
        limited = False
        while True:
            try:
                return fut.result(timeout=POLL)
            except DTimeout:
                pass
            except SpidersimError as exc:
                self.store.finish(jid, "failed",
                                  self.library.models[job["model"]].public_message(exc))
                return None
            except Exception as exc:
                self.store.finish(jid, "failed", f"Dask task failed: "
                                  f"{type(exc).__name__}: {exc}")
                return None
            t = self._progress(jid, var)
            if t is not None and t_stopped is None:
                t_stopped = time.monotonic()
            now = time.monotonic()
            if self._stopping:              # no data, as the local pool's killed worker
                _give_up(fut, cancel)
                self.store.finish(jid, "failed", "server stopped while running")
                return GIVEN_UP
            if t_cancel is None and self.store.cancel_requested(jid):
                cancel.set()                # the run stops at its next read of the Event
                t_cancel = now
            why = _cancel_overdue(now, t_cancel, t_stopped)
            if why:
                _give_up(fut, cancel)
                self.store.finish(jid, "cancelled",
                                  f"cancelled while running: {self.OVERDUE[why]}, no data")
                return GIVEN_UP
            if not limited and now - t0 > self.job_timeout:
                limit.set()
                limited = True
            if now - t0 > self.job_timeout + KILL_GRACE:
                _give_up(fut, cancel)
                self.store.finish(jid, "failed", f"stopped: the wall-time limit of "
                                  f"{self.job_timeout:g} s per job was reached (the Dask "
                                  f"task did not return within {KILL_GRACE:g} s: its "
                                  f"result is dropped, no data)")
                return GIVEN_UP

    def _progress(self, jid, var):
        """Relay the task's progress to the store; the time its loop stopped at once it
        says so, else None."""
        try:
            val = var.get(timeout=0.01)
        except Exception:
            return None
        if isinstance(val, (list, tuple)) and len(val) == 2 and val[0] == STOPPED:
            return float(val[1])
        try:
            self.store.set_progress(jid, float(val))
        except (TypeError, ValueError):
            pass
        return None

    def _write_files(self, jid, files):
        """The files a Dask task returned (``{relative name: bytes}``) into the job's
        folder (a name that would leave it is skipped)."""
        out = self.store.job_dir(jid)
        for rel, data in files.items():
            p = os.path.normpath(os.path.join(out, rel))
            if not p.startswith(out + os.sep):
                continue
            os.makedirs(os.path.dirname(p), exist_ok=True)
            with open(p, "wb") as fh:
                fh.write(data)
