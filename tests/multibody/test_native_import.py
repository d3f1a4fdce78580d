"""Importing spidersim runs no kinematics; code calling the arm's C kernels always finds them.

Importing spidersim used to build the default arm's kinematic chain and run its jitted
kinematics while the arm blocks were checked (their ``derive`` on the default model): the
blocks now declare what ``derive`` returns (``Block.derives``). The four C kernels of
:mod:`spidersim.multibody.native` stay registered when :mod:`spidersim.multibody.kernels` is
imported: any machine code calling them through their symbols -- spidersim's diagrams, a
user's own ``@njit(cache=True)`` function, a user block -- may be loaded from a cache in a
fresh process at any time after that import, and an unregistered symbol aborts the process
(a lazy registration tried in session 12 did: "LLVM ERROR: Symbol not found", SIGSEGV).
"""
from __future__ import annotations

import os
import subprocess
import sys

import numpy as np

_WATCH = r"""
from numba.core import caching, event
loads, compiles = [], []
orig = caching.Cache.load_overload
def load(self, *a, **k):
    loads.append(str(self._name).split()[1].rsplit(".", 1)[-1])
    return orig(self, *a, **k)
caching.Cache.load_overload = load
class L(event.Listener):
    def on_start(self, ev): compiles.append(str(ev.data["dispatcher"]))
    def on_end(self, ev): pass
event.register("numba:compile", L())
import spidersim, spidersim.cli
print(len(compiles), *sorted(loads))
"""


def test_import_loads_the_c_kernels_only_and_runs_no_kinematics():
    """A second import (numba's caches warm) compiles nothing and loads the four C
    kernels only: no ``fk`` or ``mass_matrix`` of a default chain."""
    for _ in range(2):
        res = subprocess.run([sys.executable, "-c", _WATCH], capture_output=True, text=True,
                             timeout=600)
        assert res.returncode == 0, res.stderr
    compiles, *loads = res.stdout.split()
    assert compiles == "0", res.stdout
    assert loads == ["cholesky_solve_c", "forward_dynamics_c", "impact_projection_c",
                     "mass_matrix_c"], res.stdout


ARM_ONLY = """\
name: arm_only
blocks:
  tau: {type: Constant, value: [0, 0, 0, 0, 0, 0, 0]}
  arm: {type: Arm, q0: [0, 0.5, 0, -1.0, 0, 0.6, 0], gravity: [0, 0, -9.81]}
connections:
  - tau.y -> arm.tau
log: [arm.q]
"""


def test_arm_diagram_compiled_then_loaded_from_the_cache_in_fresh_processes(tmp_path):
    """The arm's outputs call ``forward_dynamics`` through its symbol: the second process
    loads the diagram's machine code from the cache. Both runs give the same free fall."""
    path = tmp_path / "arm_only.yaml"
    path.write_text(ARM_ONLY)
    env = dict(os.environ, SPIDERSIM_CACHE=str(tmp_path / "cache"))
    runs = []
    for k in (1, 2):
        out = tmp_path / f"o{k}"
        res = subprocess.run([sys.executable, "-m", "spidersim.cli", "run", str(path),
                              "--t-end", "0.05", "--no-plots", "--out", str(out)],
                             capture_output=True, text=True, env=env, timeout=600)
        assert res.returncode == 0, res.stderr
        runs.append((res.stderr, np.load(out / "result.npz")["arm.q"]))
    assert "compiled in" in runs[0][0]
    assert "loaded from the cache in" in runs[1][0], runs[1][0]
    assert np.array_equal(runs[0][1], runs[1][1])
    assert np.abs(runs[1][1][-1] - runs[1][1][0]).max() > 1e-4      # it falls


_USER_CACHED = r"""
import sys
import numpy as np
from numba import njit
from spidersim.multibody import kernels as K
from spidersim.multibody.chain import Chain

@njit(cache=True)
def diag_mass(q, P, ws, M, tmp, bw):
    K.mass_matrix(q, P, ws, M, tmp, bw)
    return np.diag(M).copy()

@njit(cache=True)
def project(n, qd, c, M, J, Jc, Y, A, r, x):
    K.impact_projection(n, qd, c, M, J, Jc, Y, A, r, x)

ch = Chain.from_yaml()
n = ch.n
q = np.array([0.1, 0.6, -0.2, -1.2, 0.3, 0.7, 0.1])
d = diag_mass(q, ch.P, np.zeros(48 * (n + 1)), np.zeros((n, n)), np.zeros(6 * n), np.zeros(6))
M = ch.mass_matrix(q)
J = np.ascontiguousarray(ch.jacobian(q)).ravel()
c = np.zeros(15); c[:3] = 1.0; c[6:15] = np.eye(3).ravel()
qd = np.linspace(0.1, 0.7, n)
project(n, qd, c, M.copy(), J, np.zeros(6 * n), np.zeros(6 * n), np.zeros(36), np.zeros(6),
        np.zeros(6))
print(abs(d - np.diag(M)).max(), abs(J.reshape(6, n)[:3] @ qd).max())
"""


def test_user_cached_functions_calling_the_kernels_in_fresh_processes(tmp_path):
    """A user's ``@njit(cache=True)`` functions calling ``mass_matrix`` and
    ``impact_projection`` (which calls ``cholesky_solve`` through its symbol): compiled in
    the first process, loaded from numba's cache in the second; both agree with the Chain
    and stop the flange's translation."""
    script = tmp_path / "user_kernels.py"
    script.write_text(_USER_CACHED)
    for _ in range(2):
        res = subprocess.run([sys.executable, str(script)], capture_output=True, text=True,
                             timeout=600, cwd=tmp_path)
        assert res.returncode == 0, res.stderr
        mass_err, flange_v = (float(v) for v in res.stdout.split())
        assert mass_err < 1e-12 and flange_v < 1e-12
    assert list((tmp_path / "__pycache__").glob("user_kernels.*.nbi"))
