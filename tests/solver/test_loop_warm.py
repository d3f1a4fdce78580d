"""The integration loop's entry compiled in a second process while the diagram compiles
(:mod:`spidersim.solver.loop_warm`, issue 14: the first run after installing on two cores).

Guarded here: the stand-in system gives exactly the argument types a compiled system hands
the loop (otherwise the second process would compile an entry no run uses, and the first
run would compile the real one again after waiting); the second process loads the cached
entry it was asked for; a diagram compile starts it only when both the module and the
entry are to be compiled, waits for it, and stops it after an error; one core: no second
process.
"""
import os
import subprocess
import sys
import time

import pytest

import spidersim
from spidersim.diagram import model
from spidersim.solver import loop_warm

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
METHODS = ["DP54", "ROS34PW2", "NDF"]

LAG = """\
name: lag{n}
blocks:
  u: {{type: Step, t_step: 0.1}}
  g: {{type: Gain, k: {k}}}
  x: {{type: Integrator}}
connections: [u.y -> g.u, g.y -> x.u]
simulation: {{t_end: 1, method: DP54}}
"""


@pytest.fixture(scope="module")
def system():
    return spidersim.loads(LAG.format(n=0, k=1.5)).compile()


@pytest.mark.parametrize("method", METHODS)
def test_the_stand_in_gives_a_compiled_systems_argument_types(system, method):
    """The types the second process compiles for equal those of a real diagram's run
    (fails when the stand-in's arrays differ in dtype or dimension from a system's)."""
    real = loop_warm.loop_types(method, system, system.fn)
    assert loop_warm.loop_types(method) == real


def test_the_second_process_loads_the_entry_the_runs_use():
    """``python -m spidersim.solver.loop_warm DP54``, twice in fresh processes: the first
    compiles the entry or finds it cached, the second finds it in numba's cache for the
    types it computes (so they are the types a run asks for: the types test above)."""
    outs = []
    for _ in range(2):
        res = subprocess.run([sys.executable, "-m", "spidersim.solver.loop_warm", "DP54"],
                             capture_output=True, text=True, timeout=900, cwd=ROOT)
        assert res.returncode == 0, res.stderr[-2000:]
        outs.append(res.stdout.strip())
    assert outs[0] in ("hit", "compiled") and outs[1] == "hit", outs


class _Proc:
    """A stand-in for the second process (what :func:`loop_warm.finish` is given)."""

    def __init__(self):
        self.waited = self.killed = False


def _spy(monkeypatch, cached_module=False, cached_loop=False):
    calls = []
    monkeypatch.setattr(model, "is_cached", lambda text: cached_module)
    monkeypatch.setattr(model, "loop_cached", lambda method: cached_loop)
    monkeypatch.setattr(model, "loop_compiled", lambda method: False)
    monkeypatch.setattr(model.loop_warm, "start",
                        lambda method: calls.append(("start", method)) or _Proc())
    monkeypatch.setattr(model.loop_warm, "finish",
                        lambda proc, ok=True: calls.append(("finish", ok)) or True)
    monkeypatch.setattr(spidersim.solver.system.CompiledSystem, "warm_up_loop",
                        lambda self, method="DP54": calls.append(("warm_up_loop", method)))
    return calls


def test_a_new_diagram_and_loop_compile_side_by_side(monkeypatch):
    """Both to be compiled: the second process starts before the module compiles, this
    process waits for it (finish with ok) and then loads the entry (warm_up_loop)."""
    calls = _spy(monkeypatch)
    spidersim.loads(LAG.format(n=1, k=2.5)).compile(loop="NDF")
    assert calls == [("start", "NDF"), ("finish", True), ("warm_up_loop", "NDF")]


@pytest.mark.parametrize("cached_module, cached_loop", [(True, False), (False, True)])
def test_no_second_process_when_either_is_cached(monkeypatch, cached_module, cached_loop):
    """Either one in the cache: nothing to overlap, no second process (finish(None))."""
    calls = _spy(monkeypatch, cached_module, cached_loop)
    spidersim.loads(LAG.format(n=2, k=3.5)).compile(loop="DP54")
    assert ("start", "DP54") not in calls


def test_no_second_process_without_the_loop(monkeypatch):
    """``compile()`` without ``loop`` (the loop compiles on first use): none."""
    calls = _spy(monkeypatch)
    spidersim.loads(LAG.format(n=3, k=4.5)).compile()
    assert not any(c[0] == "start" for c in calls)


def test_an_error_in_the_diagram_compile_stops_the_second_process(monkeypatch):
    """The module fails to load: the second process is stopped (finish with ok False)
    and the error is the caller's."""
    calls = _spy(monkeypatch)

    def broken(*a, **k):
        raise RuntimeError("boom")
    monkeypatch.setattr(model, "load_module", broken)
    with pytest.raises(RuntimeError, match="boom"):
        spidersim.loads(LAG.format(n=4, k=5.5)).compile(loop="DP54")
    assert calls == [("start", "DP54"), ("finish", False)]


def test_finish_stops_a_process_after_an_error():
    """``finish(proc, ok=False)`` kills a running process at once and reaps it."""
    proc = subprocess.Popen([sys.executable, "-c", "import time; time.sleep(60)"])
    proc.stop_at_exit = lambda: None
    t0 = time.perf_counter()
    assert loop_warm.finish(proc, ok=False) is False
    assert proc.poll() is not None and time.perf_counter() - t0 < 30


def test_one_core_starts_no_second_process(monkeypatch):
    """With one core the two compiles would only take turns: none is started."""
    monkeypatch.setattr(loop_warm, "_cores", lambda: 1)
    assert loop_warm.start("DP54") is None


def test_the_opt_out_starts_no_second_process(monkeypatch):
    """``SPIDERSIM_PARALLEL_COMPILE=0`` turns it off."""
    monkeypatch.setattr(loop_warm, "_cores", lambda: 2)
    monkeypatch.setenv("SPIDERSIM_PARALLEL_COMPILE", "0")
    assert loop_warm.start("DP54") is None


def test_relative_cache_folders_are_made_absolute_for_the_second_process(monkeypatch,
                                                                          tmp_path):
    """The second process runs in spidersim's parent folder: a relative NUMBA_CACHE_DIR
    put numba's files beside the package (and this process, not finding them, compiled
    the entry again); relative PYTHONPATH entries pointed elsewhere."""
    monkeypatch.chdir(tmp_path)
    monkeypatch.setenv("NUMBA_CACHE_DIR", "nb")
    monkeypatch.setenv("SPIDERSIM_CACHE", "sc")
    monkeypatch.setenv("PYTHONPATH", "lib" + os.pathsep + "/abs")
    env = loop_warm.child_environment("/here")
    assert env["NUMBA_CACHE_DIR"] == str(tmp_path / "nb")
    assert env["SPIDERSIM_CACHE"] == str(tmp_path / "sc")
    assert env["PYTHONPATH"].split(os.pathsep) == ["/here", str(tmp_path / "lib"), "/abs"]


_PARENT = r"""
import subprocess, sys
sys.path.insert(0, {root!r})
from spidersim.solver.loop_warm import _die_with_parent
child = subprocess.Popen([sys.executable, "-c", "import time; time.sleep(60)"],
                         preexec_fn=_die_with_parent())
print(child.pid, flush=True)
time_to_die = sys.stdin.readline()
"""


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="prctl is Linux's")
def test_the_second_process_dies_with_a_killed_parent():
    """A parent killed without running atexit (SIGKILL; SIGTERM's default) takes the
    second process with it (it was left compiling for half a minute, reparented to
    init)."""
    parent = subprocess.Popen([sys.executable, "-c", _PARENT.format(root=ROOT)],
                              stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True)
    pid = int(parent.stdout.readline())
    parent.kill()
    parent.wait()
    for _ in range(100):
        try:
            os.kill(pid, 0)
        except ProcessLookupError:
            break
        time.sleep(0.05)
    else:
        os.kill(pid, 9)
        pytest.fail("the child outlived its killed parent")
