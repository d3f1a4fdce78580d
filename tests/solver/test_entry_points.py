"""The system ``simulate()`` uses calls numba's machine code directly (issue #14 defect:
the fast path was bound on the warm-up object only)."""
import os

import numpy as np

import spidersim
from spidersim.solver import sysfn

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))


def test_every_compiled_system_is_bound():
    d = spidersim.load(os.path.join(ROOT, "diagrams", "three_lags.yaml"))
    first = d.compile(jit=True)
    second = d.compile(jit=True)       # what simulate() gets: a new system object
    assert second is not first
    for system in (first, second):
        for name in ("rhs", "record", "guards", "record_guards"):
            # the machine code's entry point, not numba's dispatcher
            assert system._ops[name] is not getattr(sysfn, name)
            assert system._ops[name] in [o.entry_point for o in
                                         getattr(sysfn, name).overloads.values()]
    # and the bound path computes what the dispatcher computes
    x = second.x0 + 0.1
    np.testing.assert_array_equal(second.rhs(0.3, x),
                                  sysfn.rhs(second.fn, 0.3, x, second.sig, second.p,
                                            second.modes))
