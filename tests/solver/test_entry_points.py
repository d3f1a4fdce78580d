"""The system ``simulate()`` uses calls numba's machine code directly (issue #14 defect:
the fast path was bound on the warm-up object only)."""
import os

import numpy as np

import spidersim

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))


def test_every_compiled_system_is_bound():
    d = spidersim.load(os.path.join(ROOT, "diagrams", "three_lags.yaml"))
    first = d.compile(jit=True)
    second = d.compile(jit=True)       # what simulate() gets: a new system object
    mod = second.module
    assert second is not first
    for system in (first, second):
        assert system._record is not mod.record          # the entry point, not the dispatcher
        assert system._record is next(iter(mod.record.overloads.values())).entry_point
    # and the bound path computes what the dispatcher computes
    x = second.x0 + 0.1
    np.testing.assert_array_equal(second.rhs(0.3, x),
                                  mod.rhs(0.3, x, second.sig, second.p, second.modes))
