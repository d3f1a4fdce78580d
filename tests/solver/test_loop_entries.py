"""The compiled loop's entry per method (issue 14): a run compiles, or loads, only the code
of its own method.

``loop_body.run_loop_dp54``, ``run_loop_ros34pw2`` and ``run_loop_ndf`` pass their method to
the shared loop as a compile-time constant; the method-specific parts (``_advance``,
``_dense``, the first step) are typed for that method alone (``_jit.for_method``), so a DP54
run never types, compiles or loads the stiff solvers (:mod:`.bdf`, :mod:`.rosenbrock`, the
ROS34PW2 and NDF steps): about half of the loop's cold compile before the split.
"""
import json
import os
import subprocess
import sys

import numpy as np
import pytest

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))

# A fresh process: which dispatchers have machine code (compiled or loaded from numba's
# cache) after a DP54 run, then after a ROS34PW2 run; and every numba compile's module.
_CHILD = r"""
import json, sys
from numba.core import event

compiled = []

class _Listener(event.Listener):
    def on_start(self, ev):
        py = getattr(ev.data["dispatcher"], "py_func", None)
        compiled.append(f"{getattr(py, '__module__', '?')}.{getattr(py, '__qualname__', '?')}")

    def on_end(self, ev):
        pass

event.register("numba:compile", _Listener())
import spidersim
from spidersim.solver import bdf, rosenbrock, loop_body as L

def overloads():
    named = {"run_loop_dp54": L.run_loop_dp54, "run_loop_ros34pw2": L.run_loop_ros34pw2,
             "run_loop_ndf": L.run_loop_ndf, "_advance_ros34pw2": L._advance_ros34pw2,
             "_advance_ndf": L._advance_ndf, "_jacobian": L._jacobian,
             "_step_ros34pw2": L._step_ros34pw2, "bdf.advance": bdf.advance,
             "bdf.dense": bdf.dense, "bdf.first_step": bdf.first_step,
             "rosenbrock.dense": rosenbrock.dense}
    return {k: len(d.overloads) for k, d in named.items()}

d = spidersim.load(sys.argv[1], set={"ball.e": 0.8, "ball.v_rest": 0})
out = {}
r = d.simulate(t_end=6.0, method="DP54", rtol=1e-9, atol=1e-12)
out["dp54"] = overloads()
out["dp54_events"] = [e[0] for e in r.events]
out["dp54_compiled"] = list(compiled)
r = d.simulate(t_end=6.0, method="ROS34PW2", rtol=1e-7, atol=1e-10)
out["ros"] = overloads()
out["ros_events"] = [e[0] for e in r.events]
print(json.dumps(out))
"""

STIFF = ("run_loop_ros34pw2", "run_loop_ndf", "_advance_ros34pw2", "_advance_ndf",
         "_jacobian", "_step_ros34pw2", "bdf.advance", "bdf.dense", "bdf.first_step",
         "rosenbrock.dense")


def _impacts(e, g=9.81, h0=10.0, n=3):
    """Impact times of a ball dropped from ``h0`` with restitution ``e`` (closed form:
    ``t1 = sqrt(2 h0 / g)``, then flights of ``2 e^k sqrt(2 g h0) / g``)."""
    t1 = np.sqrt(2 * h0 / g)
    return t1 + np.concatenate(([0.0], np.cumsum([2 * e ** k * t1 for k in range(1, n)])))


@pytest.fixture(scope="module")
def child():
    res = subprocess.run([sys.executable, "-c", _CHILD,
                          os.path.join(ROOT, "diagrams", "bouncing_ball.yaml")],
                         capture_output=True, text=True, timeout=600,
                         env=dict(os.environ, PYTHONPATH=ROOT + os.pathsep
                                  + os.environ.get("PYTHONPATH", "")))
    assert res.returncode == 0, res.stderr[-3000:]
    return json.loads(res.stdout.strip().splitlines()[-1])


def test_dp54_run_has_no_stiff_code(child):
    """A DP54 run in a fresh process gives its entry machine code and none to the stiff
    entries and solvers (neither compiled nor loaded from the cache), and no numba compile
    of the process is in :mod:`.bdf` or :mod:`.rosenbrock`; the run itself is right (the
    ball's first impacts at the closed-form times, to 1e-7 s)."""
    ov = child["dp54"]
    assert ov["run_loop_dp54"] == 1
    assert {k: ov[k] for k in STIFF} == {k: 0 for k in STIFF}
    stiff_compiles = [c for c in child["dp54_compiled"]
                      if c.startswith(("spidersim.solver.bdf.", "spidersim.solver.rosenbrock."))
                      or c.startswith("spidersim.solver.loop_body.")
                      and ("ros34pw2" in c or "ndf" in c)]
    assert stiff_compiles == []
    t = np.array(child["dp54_events"][:3])
    assert np.allclose(t, _impacts(0.8), rtol=0, atol=1e-7)


def test_ros34pw2_run_adds_only_its_entry(child):
    """A ROS34PW2 run after it gives the ROS34PW2 entry machine code, and still none to the
    NDF entry and the NDF method's solver; its impacts at the closed-form times too (1e-5 s:
    rtol 1e-7)."""
    ov = child["ros"]
    assert ov["run_loop_dp54"] == 1 and ov["run_loop_ros34pw2"] == 1
    assert ov["run_loop_ndf"] == 0 and ov["_advance_ndf"] == 0 and ov["bdf.advance"] == 0
    t = np.array(child["ros_events"][:3])
    assert np.allclose(t, _impacts(0.8), rtol=0, atol=1e-5)


def test_method_chosen_at_compile_time_only_for_literals():
    """The typing rule of the method-specific parts: an integer-literal method selects its
    own implementation; any other type (a method known at run time only) the generic one,
    which branches at run time."""
    from numba.core import types
    from spidersim.solver._jit import literal_method
    impls = ("dp54", "ros34pw2", "ndf")
    assert [literal_method(types.literal(m), impls, "generic") for m in range(3)] == list(impls)
    assert literal_method(types.int64, impls, "generic") == "generic"
