"""The job function: one run request -> result files. The same function runs in the local
worker processes and on a Dask cluster.

Files of a job (the job folder under ``--data``, or returned as bytes from a Dask worker)::

    result.npz     t and every logged signal (as ``Result.save`` writes it)
    result.csv     the same, one column per element
    report.txt     solver statistics and events
    meta.json      status, message, units, sizes, events and statistics: with result.npz
                   it rebuilds the :class:`spidersim.Result` (``spidersim.remote``)
    plots/         the model's plots (PNG) and arm animation (GIF)
"""
from __future__ import annotations

import os
import shutil
import tempfile
import time

from spidersim.errors import IntegrationError
from spidersim.solver.result import write_meta_json

from .commands import prepare
from .library import Model

#: seconds between two progress reports of a run
PROGRESS_EVERY = 0.25


def _meta(r, status, message):
    """meta.json without its events (written in blocks by ``write_meta_json``: a list of
    millions of events as Python lists took ten times the memory the budget counts)."""
    return {"status": status, "message": message, "units": dict(r.units),
            "sizes": {n: (1 if r[n].ndim == 1 else int(r[n].shape[1])) for n in r.names},
            "stats": {k: (v if isinstance(v, (int, float, str, bool)) or v is None
                          else str(v)) for k, v in r.stats.items()}}


def run_job(task, report=None, out=None):
    """Run ``task`` = ``{"id", "model", "path", "request", "jit"}``.

    ``report(t)`` receives the simulated time reached every :data:`PROGRESS_EVERY` seconds.
    With ``out`` the files are written there; without, they are returned as
    ``{"files": {relative name: bytes}}`` (a Dask worker's disk is not the server's).
    Returns ``{"status": "ok" | "failed", "message", "t_reached", "wall_time", ...}``;
    errors in the request raise :class:`~spidersim.errors.SpidersimError`.
    """
    model = Model(task["model"], task["path"])
    d, t_end = prepare(model, task["request"])
    last = [0.0]

    def progress(t):
        now = time.monotonic()
        if report is not None and now - last[0] >= PROGRESS_EVERY:
            last[0] = now
            report(float(t))

    status, message = "ok", ""
    t0 = time.perf_counter()
    try:
        r = d.simulate(t_end=t_end, jit=task.get("jit", True), progress=progress)
    except IntegrationError as exc:
        if exc.partial is None:
            raise
        r, status, message = exc.partial, "failed", model.public_message(exc)
    wall = time.perf_counter() - t0
    folder = out or tempfile.mkdtemp(prefix="spidersim-job-")
    try:
        r.save(folder)
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
        res = {"status": status, "message": message, "plot_error": plot_error,
               "t_reached": float(r.t[-1]) if len(r.t) else 0.0, "wall_time": wall,
               "t_end": t_end}
        if out is None:
            files = {}
            for root, _dirs, names in os.walk(folder):
                for n in names:
                    p = os.path.join(root, n)
                    with open(p, "rb") as fh:
                        files[os.path.relpath(p, folder)] = fh.read()
            res["files"] = files
        return res
    finally:
        if out is None:
            shutil.rmtree(folder, ignore_errors=True)
