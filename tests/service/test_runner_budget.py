"""Local worker slots share the recording budget (spidersim.solver.record_budget): each
worker process gets the budget divided by the number of slots, so that jobs running at once
cannot together take more memory for their rows than one run may."""
import os

from spidersim.service import runner as R
from spidersim.solver import record_budget as rb


def test_each_slot_gets_its_share_of_the_budget(monkeypatch):
    monkeypatch.setenv(rb.ENV, "1200")
    assert R.LocalRunner(None, None, workers=4).record_mb == 300.0
    monkeypatch.delenv(rb.ENV)
    r = R.LocalRunner(None, None, workers=3)
    assert abs(r.record_mb - rb.budget_bytes() / 1e6 / 3) < 1e-9


class _Closed:
    """A pipe whose server end is gone: the worker returns at once."""

    def recv(self):
        raise EOFError


def test_worker_process_applies_its_share(monkeypatch):
    """The worker sets the budget in its own environment before any job (called here in
    the test process: its SIGINT and SIGTERM handlers, which the worker sets to ignore, are
    restored)."""
    import signal
    monkeypatch.setenv(rb.ENV, "999")
    before = {s: signal.getsignal(s) for s in (signal.SIGINT, signal.SIGTERM)}
    try:
        R._worker_main(_Closed(), os.getppid(), 12.5)
    finally:                    # both handlers it sets to ignore (SIGTERM was left ignored)
        for s, h in before.items():
            signal.signal(s, h)
    assert os.environ[rb.ENV] == "12.5" and rb.budget_bytes() == 12.5e6


def test_the_share_is_handed_to_the_worker_process(monkeypatch):
    """The slot's process is started with the share as ``_worker_main``'s argument (a
    fake process context records the arguments instead of spawning)."""
    monkeypatch.setenv(rb.ENV, "1200")
    r = R.LocalRunner(None, None, workers=4)
    started = []

    class _Proc:
        def __init__(self, target, args, daemon, name):
            started.append((target, args))

        def start(self):
            pass

        def is_alive(self):
            return True

    class _Conn:
        def close(self):
            pass

    class _Flag:
        def __init__(self, typecode, value):
            self.value = value

    class _Ctx:
        Process = _Proc
        RawValue = _Flag                  # the slot's cancel flag

        @staticmethod
        def Pipe():
            return _Conn(), _Conn()

    r._ctx = _Ctx()
    r._process(0)
    (target, args), = started
    assert target is R._worker_main and args[2] == 300.0
    assert args[3].value == 0             # the cancel flag, clear


def test_the_services_budget_per_job_caps_the_share(monkeypatch):
    """``serve --max-record-mb`` bounds each worker's share: the smaller of the two."""
    monkeypatch.setenv(rb.ENV, "1200")
    assert R.LocalRunner(None, None, workers=4, job_record_mb=100).record_mb == 100.0
    assert R.LocalRunner(None, None, workers=4, job_record_mb=1000).record_mb == 300.0
