"""The integration loop's entry compiled in a second process while the diagram compiles.

The first run after installing compiles two independent things: the diagram's system
function (its generated module) and the compiled integration loop's entry of the run's
method (:mod:`.loop_body`, one for every diagram, cached by numba with spidersim's own
kernels). They share nothing until the run starts (the loop calls the system function
through its address), so on a machine with two cores or more they are compiled at the same
time: :func:`start` launches ``python -m spidersim.solver.loop_warm METHOD``, which compiles
the entry into numba's cache and exits, while this process compiles the diagram; then
:func:`finish` waits for it and this process loads the entry from the cache
(:meth:`~.system.CompiledSystem.warm_up_loop`). Should the second process fail for any
reason, this process compiles the entry itself, as it always did.

Contract:

1. Only when both are to be compiled (the caller checks: the diagram's module and the
   entry not in the cache), with numba, and with at least two cores available; otherwise
   :func:`start` returns None and nothing changes.
2. The second process imports the same spidersim as this one (its folder first on the
   path, started in that folder) and inherits the environment (``NUMBA_CACHE_DIR``): it
   writes only numba's cache files of the entry (atomically: numba writes a temporary file
   and renames it), where this process would have written them.
3. It is stopped (killed) when this process stops waiting for it because of an error or an
   interrupt, at this process's exit, and (Linux) when this process dies without exiting
   normally (``PR_SET_PDEATHSIG``).

The argument types of the entry are those of any compiled system (:func:`loop_types`:
arrays of fixed dtypes and dimensions, the system function's address an integer); a
stand-in system of one state gives them without compiling a diagram.
"""
from __future__ import annotations

import atexit
import functools
import os
import subprocess
import sys
import types

import numpy as np

#: how long :func:`finish` waits for the second process [s] before compiling here anyway
WAIT_LIMIT = 900.0


def _cores():
    """The cores this process may run on."""
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:          # pragma: no cover - not on Linux
        return os.cpu_count() or 1


def _stand_in():
    """A system of one state, no guard and no timed block with the arrays a compiled
    system hands the loop (their dtypes and dimensions are the same for every diagram)."""
    return types.SimpleNamespace(
        n_x=1, x0=np.zeros(1), n_g=0, event_table=[], timed=[], record_size=1,
        _s_idx=np.zeros(0, dtype=np.int64), _x_idx=np.zeros(1, dtype=np.int64),
        sig=np.zeros(1), p=np.zeros(1), modes=np.zeros(1), jac_sparsity=None, shared={})


def loop_types(method, system=None, fn=0):
    """The numba types of the loop entry's arguments for ``method`` (``DP54``,
    ``ROS34PW2``, ``NDF``), from ``system`` (default: a stand-in of one state) and the
    system function's address ``fn``."""
    import numba
    from .loop import CompiledLoop
    system = _stand_in() if system is None else system
    run = CompiledLoop(fn, system, 0.0, 1.0, 1e-6, 1e-8, np.inf, None, None, capacity=1,
                       method=method, jacobian="fd")
    return tuple(numba.typeof(a) for a in (fn,) + run.arguments(1))


def compile_entry(method):
    """Compile (or load from numba's cache) the loop entry of ``method``; return
    ``"hit"`` when it was loaded from the cache, ``"compiled"`` otherwise."""
    from .loop_body import entry as loop_entry    # (not .system: it imports this module)
    entry = loop_entry(method)
    entry.compile(loop_types(method))
    return "hit" if sum(entry.stats.cache_hits.values()) else "compiled"


def start(method):
    """Launch the second process compiling the entry of ``method``; None when there are
    fewer than two cores or the process cannot be started (then nothing changes)."""
    if _cores() < 2 or os.environ.get("SPIDERSIM_PARALLEL_COMPILE", "1") == "0":
        return None
    here = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
    try:
        proc = subprocess.Popen([sys.executable, "-m", "spidersim.solver.loop_warm", method],
                                cwd=here, env=child_environment(here),
                                stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL,
                                stderr=subprocess.DEVNULL, preexec_fn=_die_with_parent())
    except OSError:
        return None
    proc.stop_at_exit = functools.partial(_stop, proc)
    atexit.register(proc.stop_at_exit)
    return proc


def child_environment(here):
    """This process's environment for the second process, which runs in ``here`` (the
    folder holding spidersim): ``here`` first on ``PYTHONPATH``, and the paths that name
    folders relative to this process's working folder (``NUMBA_CACHE_DIR``,
    ``SPIDERSIM_CACHE``, ``PYTHONPATH`` entries) made absolute, so that it imports the same
    spidersim and writes numba's files where this process reads them (a relative
    ``NUMBA_CACHE_DIR`` put them beside the package and this process compiled again)."""
    env = dict(os.environ)
    for key in ("NUMBA_CACHE_DIR", "SPIDERSIM_CACHE"):
        if env.get(key):
            env[key] = os.path.abspath(env[key])
    path = [os.path.abspath(p) for p in env.get("PYTHONPATH", "").split(os.pathsep) if p]
    env["PYTHONPATH"] = os.pathsep.join([here] + path)
    return env


def _die_with_parent():
    """The ``preexec_fn`` that makes the second process receive a SIGKILL when this process
    dies (Linux ``prctl(PR_SET_PDEATHSIG)``), also when it is killed without running
    ``atexit`` (SIGTERM, SIGKILL: it was left compiling for half a minute on its own);
    None elsewhere. The C function is looked up here, in this process: between ``fork``
    and ``exec`` the child only calls it (no import, as ``preexec_fn`` must be with other
    threads running)."""
    try:
        import ctypes
        import signal
        return functools.partial(ctypes.CDLL(None).prctl, 1, int(signal.SIGKILL))
    except (OSError, AttributeError):       # pragma: no cover - not Linux
        return None


def finish(proc, ok=True):
    """Wait for ``proc`` (from :func:`start`) when ``ok``; stop it otherwise (an error or
    an interrupt in this process). Returns whether it ended with success."""
    if proc is None:
        return False
    try:
        if not ok:
            _stop(proc)
            return False
        return proc.wait(timeout=WAIT_LIMIT) == 0
    except subprocess.TimeoutExpired:
        _stop(proc)
        return False
    except BaseException:           # an interrupt while waiting
        _stop(proc)
        raise
    finally:
        atexit.unregister(proc.stop_at_exit)


def _stop(proc):
    """Kill ``proc`` if it still runs and reap it."""
    if proc.poll() is None:
        proc.kill()
        proc.wait()


if __name__ == "__main__":          # the second process: python -m spidersim.solver.loop_warm
    print(compile_entry(sys.argv[1]))
