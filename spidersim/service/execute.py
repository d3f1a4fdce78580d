"""The job function: one run request -> result files. The same function runs in the local
worker processes and on a Dask cluster.

Files of a job (the job folder under ``--data``, or returned as bytes from a Dask worker)::

    result.npz     t and every logged signal (as ``Result.save`` writes it)
    result.csv     the same, one column per element
    report.txt     solver statistics and events
    meta.json      status, message, units, sizes, events and statistics: with result.npz
                   it rebuilds the :class:`spidersim.Result` (``spidersim.remote``)
    signals.json   units and sizes only (what a signal answer reads)

result.csv is left out when it would be larger than :data:`MAX_CSV_MB` (about 24 bytes a
value: the 193 MB NPZ of a run stopped at its budget made a 438 MB CSV); the NPZ holds the
same data. Every JSON file is strict JSON (non-finite numbers as null).
    plots/         the model's plots (PNG) and arm animation (GIF)
"""
from __future__ import annotations

import json
import os
import shutil
import tempfile
import time

from spidersim.errors import IntegrationError
from spidersim.solver import record_budget
from spidersim.solver.result import finite_json, write_meta_json  # noqa: F401 (re-exported)

from .commands import prepare
from .library import Model

#: seconds between two progress reports of a run
PROGRESS_EVERY = 0.25
#: events written into meta.json and the report files (the rest counted in
#: ``stats["events_total"]``): a run of millions of sampler events wrote 39 MB of them
MAX_EVENTS = 100_000
#: MB above which result.csv is not written (estimated at 24 bytes a value)
MAX_CSV_MB = 64.0


def _meta(r, status, message):
    """meta.json without its events (written in blocks by ``write_meta_json``: a list of
    millions of events as Python lists took ten times the memory the budget counts)."""
    return finite_json({"status": status, "message": message, "units": dict(r.units),
            "sizes": {n: (1 if r[n].ndim == 1 else int(r[n].shape[1])) for n in r.names},
            "stats": {k: (v if isinstance(v, (int, float, str, bool)) or v is None
                          else str(v)) for k, v in r.stats.items()}})


def run_job(task, report=None, out=None, cancel=None, stopped=None, limit=None):
    """Run ``task`` = ``{"id", "model", "path", "request", "jit"}``.

    ``report(t)`` receives the simulated time reached every :data:`PROGRESS_EVERY` seconds.
    With ``task["wall_limit"]`` [s] the run stops (the loop's ``should_stop``) when that
    much wall time has passed, status ``"interrupted"``, keeping its rows. With
    ``cancel() -> bool`` (a flag check: the loop calls it every few steps) the run stops
    when it turns true, status ``"cancelled"``, keeping its rows and writing its files as a
    finished run's; true before the run begins: nothing is run or written, status
    ``"cancelled"`` with ``t_reached`` None. ``limit() -> bool``: a wall-time limit counted
    elsewhere (the Dask runner's, from the job's submission; read as ``cancel``): when it
    turns true the run stops as at ``task["wall_limit"]``, status ``"interrupted"``.
    ``stopped(t)`` is called once the
    integration loop has returned (before the files are written), with the time reached. A run stopped
    at the recording budget (``SPIDERSIM_RECORD_LIMIT_MB``, which the service sets per
    worker) keeps its rows too, status ``"failed"``. At most :data:`MAX_EVENTS` events
    are written.
    With ``out`` the files are written there; without, they are returned as
    ``{"files": {relative name: bytes}}`` (a Dask worker's disk is not the server's).
    Returns ``{"status": "ok" | "failed" | "interrupted" | "cancelled", "message", "t_reached", "wall_time", ...}``;
    errors in the request raise :class:`~spidersim.errors.SpidersimError`.
    """
    model = Model(task["model"], task["path"])
    d, t_end = prepare(model, task["request"])
    if cancel is not None and cancel():
        return {"status": "cancelled", "message": "", "plot_error": "", "t_reached": None,
                "wall_time": 0.0, "t_end": t_end}
    t0 = time.perf_counter()
    r, status, message = _simulate(model, d, t_end, task, report, cancel, limit)
    if stopped is not None:
        stopped(float(r.t[-1]) if len(r.t) else 0.0)
    message = _cap_events(r, message)
    wall = time.perf_counter() - t0
    folder = out or tempfile.mkdtemp(prefix="spidersim-job-")
    try:
        message, plot_error = _write_files(model, d, r, task, folder, status, message)
        res = {"status": status, "message": message, "plot_error": plot_error,
               "t_reached": float(r.t[-1]) if len(r.t) else 0.0, "wall_time": wall,
               "t_end": t_end}
        if out is None:
            res["files"] = _read_files(folder)
        return res
    finally:
        if out is None:
            shutil.rmtree(folder, ignore_errors=True)


def _simulate(model, d, t_end, task, report, cancel=None, limit=None):
    """``(result, status, message)`` of the run: ``"ok"``, ``"interrupted"`` (the wall-time
    limit, its own or ``limit()``, rows kept), ``"cancelled"`` (``cancel()`` turned true, rows kept) or
    ``"failed"`` (an integration failure or the recording budget, rows kept);
    ``report(t)`` every :data:`PROGRESS_EVERY` s of wall time."""
    last = [0.0]

    def progress(t):
        now = time.monotonic()
        if report is not None and now - last[0] >= PROGRESS_EVERY:
            last[0] = now
            report(float(t))

    should_stop = _stop_check(task.get("wall_limit"), _either(cancel, limit))
    status, message = "ok", ""
    try:
        r = d.simulate(t_end=t_end, jit=task.get("jit", True), progress=progress,
                       should_stop=should_stop)
    except IntegrationError as exc:
        if exc.partial is None:
            raise
        r, status, message = exc.partial, "failed", model.public_message(exc)
        message = message.replace(f"or set {record_budget.ENV}",
                                  "or ask the service's administrator (its recording budget "
                                  "per job: serve --max-record-mb)")
    if status == "ok" and r.status == "interrupted":
        if cancel is not None and cancel():
            status, message = "cancelled", (f"cancelled at t = "
                                           f"{float(r.t[-1]) if len(r.t) else 0.0:.9g} s")
        else:
            status, message = "interrupted", r.message
    return r, status, message


def _stop_check(limit, cancel):
    """The loop's ``should_stop``: true once ``limit`` s of wall time have passed from now
    or ``cancel()`` is true (either may be None); None when neither applies."""
    if limit is None:
        return cancel
    deadline = time.monotonic() + float(limit)
    if cancel is None:
        return lambda: time.monotonic() > deadline
    return lambda: cancel() or time.monotonic() > deadline


def _either(a, b):
    """``() -> bool``, true when ``a()`` or ``b()`` is (either may be None; None if both)."""
    if a is None or b is None:
        return a if b is None else b
    return lambda: a() or b()


def _note(message, note):
    return f"{message}; {note}" if message else note


def _cap_events(r, message):
    """At most :data:`MAX_EVENTS` events kept (the total in ``stats["events_total"]``)."""
    if len(r.events) > MAX_EVENTS:
        r.stats["events_total"] = len(r.events)
        r.events = r.events[:MAX_EVENTS]
        message = _note(message, f"only the first {MAX_EVENTS} of "
                                 f"{r.stats['events_total']} events are written")
    return message


def _write_files(model, d, r, task, folder, status, message):
    """The job's files in ``folder`` (data, reports, plots, meta.json, signals.json);
    returns ``(message, plot_error)``."""
    csv_max = int(MAX_CSV_MB * 1e6 / 24)
    if not r.csv_written(csv_max):
        message = _note(message, f"result.csv not written ({r.csv_values()} values, over the "
                                 f"service's {MAX_CSV_MB:g} MB for it): the data are in "
                                 f"result.npz")
    r.save(folder, csv_max_values=csv_max)
    meta = _meta(r, status, message)
    plot_error = ""
    if task["request"].get("plots", True) and len(r.t) > 1 and d.spec.plots:
        from spidersim.plots import make_plots
        try:
            make_plots(r, d.spec.plots, os.path.join(folder, "plots"))
        except Exception as exc:        # plots are a convenience: the data stand
            plot_error = f"plots not drawn: {model.public_message(exc)}"
    meta["plot_error"] = plot_error
    with open(os.path.join(folder, "meta.json"), "w") as fh:
        write_meta_json(fh, meta, r.events)
    with open(os.path.join(folder, "signals.json"), "w") as fh:
        json.dump({"units": meta["units"], "sizes": meta["sizes"]}, fh)
    return message, plot_error


def _read_files(folder):
    """Every file under ``folder`` as ``{relative name: bytes}`` (a Dask worker's)."""
    files = {}
    for root, _dirs, names in os.walk(folder):
        for n in names:
            p = os.path.join(root, n)
            with open(p, "rb") as fh:
                files[os.path.relpath(p, folder)] = fh.read()
    return files
