"""SIMECS-RI: the remote simulation service (``spidersim serve``).

An HTTP service (FastAPI on uvicorn) that lets authorized users run the models of a library
from a browser or from :class:`spidersim.remote.Client`: see the README's "Remote simulation
service" section. Modules: :mod:`.store` (SQLite: users, tokens, jobs), :mod:`.library`
(models and their descriptions), :mod:`.commands` (run requests -> diagrams),
:mod:`.execute` (the job function), :mod:`.runner` (worker processes or Dask),
:mod:`.app` (routes) and ``static/`` (the web page).

Nothing else in spidersim imports this package; it uses the public API like any user.
"""
from __future__ import annotations

import os
import sys

DEFAULT_DATA = os.path.join(os.path.expanduser("~"), ".spidersim", "service")


def add_user(name, data_dir=None):
    """Create user ``name`` (or give it another token); return the new token."""
    from .store import Store
    return Store(data_dir or DEFAULT_DATA).add_user(name)


def revoke_user(name, data_dir=None):
    """Delete every token of user ``name``; return how many (KeyError: no such user)."""
    from .store import Store
    return Store(data_dir or DEFAULT_DATA).revoke_user(name)


def serve(host="127.0.0.1", port=8050, models=None, data_dir=None, workers=2, scheduler=None,
          limits=None, job_timeout=3600.0, jit=True, log_level="info"):
    """Run the service until interrupted (SIGINT or SIGTERM: from the signal on, no worker
    claims a queued job; the running ones are stopped and marked failed)."""
    import uvicorn

    from .app import Limits, create_app
    from .runner import DaskRunner, LocalRunner

    data_dir = os.path.abspath(data_dir or DEFAULT_DATA)
    limits = limits or Limits()
    runners = []

    def runner(store, library):
        if scheduler:
            r = DaskRunner(store, library, scheduler, slots=workers,
                           job_timeout=job_timeout, jit=jit)
        else:
            r = LocalRunner(store, library, workers=workers or 2, job_timeout=job_timeout,
                            jit=jit, job_record_mb=limits.max_record_mb)
        runners.append(r)
        return r

    class _Server(uvicorn.Server):
        """Stops the runner's claims at the signal, before uvicorn's graceful shutdown (a
        slot that lost its worker to a process-group SIGTERM claimed the next queued job
        during those seconds, which then showed as failed after the restart)."""

        def handle_exit(self, sig, frame):
            for r in runners:
                r.begin_stop()
            super().handle_exit(sig, frame)

    app = create_app(data_dir, models, runner, limits)
    lib = app.state.library
    where = f"Dask scheduler {scheduler}" if scheduler else f"{workers or 2} worker process(es)"
    print(f"spidersim serve: {len(lib.models)} model(s) ({', '.join(lib.names())}); data in "
          f"{data_dir}; {where}; http://{host}:{port}/ (API docs at /docs)", flush=True)
    for f, why in lib.skipped:
        print(f"spidersim serve: skipped {f}: {why}", file=sys.stderr)
    _Server(uvicorn.Config(app, host=host, port=port, log_level=log_level,
                           timeout_graceful_shutdown=5)).run()
