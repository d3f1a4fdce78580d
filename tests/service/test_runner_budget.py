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
    """The worker sets the budget in its own environment before any job."""
    monkeypatch.setenv(rb.ENV, "999")
    R._worker_main(_Closed(), os.getppid(), 12.5)
    assert os.environ[rb.ENV] == "12.5" and rb.budget_bytes() == 12.5e6
