"""The exported multibody kernels are built on first need, not when spidersim is imported.

Importing spidersim used to compile (first run after installing) or load (later) the four C
functions of :mod:`spidersim.multibody.native` and to run the arm's kinematics while the
block classes were checked: a first ``spidersim --help`` took 14 s, every later start
0.5 s more. Guarded here: the import builds no machine code; a diagram whose blocks call an
exported kernel registers the symbols before its machine code is compiled or loaded from the
cache (a fresh process loading it from the cache would otherwise stop in LLVM on an
unresolved symbol); :func:`native.calls_exported` finds such calls through helpers.
"""
from __future__ import annotations

import os
import subprocess
import sys

import numpy as np
from numba import njit

from spidersim.multibody import kernels as K
from spidersim.multibody import native

_WATCH = r"""
from numba.core import caching, event
loads, compiles = [], []
orig = caching.Cache.load_overload
def load(self, *a, **k):
    loads.append(str(self))
    return orig(self, *a, **k)
caching.Cache.load_overload = load
class L(event.Listener):
    def on_start(self, ev): compiles.append(str(ev.data["dispatcher"]))
    def on_end(self, ev): pass
event.register("numba:compile", L())
import spidersim, spidersim.cli
print(len(loads), len(compiles), loads[:3], compiles[:3])
"""


def test_import_compiles_and_loads_no_machine_code():
    res = subprocess.run([sys.executable, "-c", _WATCH], capture_output=True, text=True,
                         timeout=300)
    assert res.returncode == 0, res.stderr
    assert res.stdout.startswith("0 0 "), res.stdout


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
    loads the diagram's machine code from the cache and must have registered the symbol
    first. Both runs give the same free fall under gravity."""
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


def _plain(a):
    return a + 1.0


@njit
def _helper_calling_mass_matrix(q, P, ws, M, tmp, base):
    K.mass_matrix(q, P, ws, M, tmp, base)


def _kernel_through_helper(q, P, ws, M, tmp, base):
    _helper_calling_mass_matrix(q, P, ws, M, tmp, base)


def _kernel_with_nested_call(q):
    def inner():
        return K.fk
    return inner


def test_calls_exported_follows_helpers_and_jitted_functions():
    assert native.calls_exported([_kernel_through_helper])
    assert native.calls_exported([_helper_calling_mass_matrix])
    assert not native.calls_exported([_plain, np.sum, len])
    assert not native.calls_exported([_kernel_with_nested_call])       # fk is linked
    from spidersim.blocks import REGISTRY
    from spidersim.blocks.base import KERNELS
    assert native.calls_exported([getattr(REGISTRY["Arm"], k) for k in KERNELS
                                  if REGISTRY["Arm"].has_kernel(k)])
    assert not native.calls_exported([getattr(REGISTRY["Gain"], "output")])


_FRESH_IMPACT = r"""
import numpy as np
from spidersim.multibody import Chain
from spidersim.multibody import kernels as K
ch = Chain.from_yaml()
n = ch.n
q = np.array([0.1, 0.6, -0.2, -1.2, 0.3, 0.7, 0.1])
M = ch.mass_matrix(q)
J = np.ascontiguousarray(ch.jacobian(q)).ravel()
c = np.zeros(15); c[:3] = 1.0; c[6:15] = np.eye(3).ravel()
qd = np.linspace(0.1, 0.7, n)
K.impact_projection(n, qd, c, M.copy(), J, np.zeros(6 * n), np.zeros(6 * n), np.zeros(36),
                    np.zeros(6), np.zeros(6))
v = J.reshape(6, n)[:3] @ qd
print(abs(v).max())
"""


def test_python_call_of_a_kernel_calling_a_symbol_in_fresh_processes(tmp_path):
    """``impact_projection`` calls ``cholesky_solve`` through its symbol: called from
    Python in a fresh process (its machine code compiled, then loaded from numba's cache in
    the second), it registers the symbols first, and stops the flange's translation."""
    for _ in range(2):
        res = subprocess.run([sys.executable, "-c", _FRESH_IMPACT], capture_output=True,
                             text=True, timeout=300)
        assert res.returncode == 0, res.stderr
        assert float(res.stdout) < 1e-12
