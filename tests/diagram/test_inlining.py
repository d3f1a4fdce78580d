"""Small kernels inlined by LLVM into the generated system function
(spidersim.blocks.inlining): the calls are gone, the numbers are the same."""
import importlib
import os
import re
import sys

import numpy as np
import pytest

import spidersim
from spidersim.blocks import inlining

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))


def _fresh_module(text, tmp_path, name):
    """The generated module ``text`` imported from ``tmp_path`` (numba compiles it there, so
    its LLVM code can be inspected: code loaded from a cache cannot)."""
    (tmp_path / f"{name}.py").write_text(text)
    sys.path.insert(0, str(tmp_path))
    try:
        return importlib.import_module(name)
    finally:
        sys.path.remove(str(tmp_path))


def test_servo_system_function_calls_no_kernel(tmp_path):
    """In the servo's compiled system function (outputs, derivatives, time events,
    initialisation) no call to a block kernel or to ``outputs`` is left: every kernel is
    below the size limit, so LLVM inlined them all. Before, ``outputs`` was called (and
    called ``Gain.output``) and ``DCMotor.derivative`` was a call passing 7 arrays as their
    fields, 43 ns per derivatives evaluation instead of 11 ns (tools/bench_rhs.py)."""
    d = spidersim.load(os.path.join(ROOT, "diagrams", "servo.yaml"))
    name = f"inline_servo_{os.getpid()}"
    assert "@_jit_kernel\ndef _s0_Sum_output" in d.source(jit=True)  # one is specialised
    mod = _fresh_module(d.source(jit=True), tmp_path, name)
    llvm = mod._system.inspect_llvm()
    calls = re.findall(r"call [^@\n]*@\"?([\w.$]+)", llvm)
    # a library kernel (spidersim.blocks...) or any function of the generated module
    # (outputs, the kernels specialised there such as _s0_Sum_output) other than the
    # system function's own body, which its C wrapper calls
    kernels = [c for c in calls if ("spidersim6blocks" in c or name in c)
               and f"{name}7_system" not in c]
    assert calls is not None and "_system" in llvm       # the IR was there to read
    assert not kernels, f"kernel calls left in the system function: {kernels}"


def test_large_functions_are_not_marked():
    """Above the size limit a function stays a call (the multibody dynamics would multiply
    LLVM's work): ``mark_alwaysinline`` refuses it and leaves no attribute."""
    from numba import njit

    @njit
    def kernel(u, y):
        for i in range(y.size):
            y[i] = 2.0 * u[i] + 1.0

    u, y = np.ones(3), np.zeros(3)
    kernel(u, y)
    cres = next(iter(kernel.overloads.values()))
    fn = cres.library._get_module_for_linking().get_function(cres.fndesc.llvm_func_name)
    size = sum(1 for b in fn.blocks for _ in b.instructions)
    assert not inlining.mark_alwaysinline(cres, limit=size - 1)
    assert "alwaysinline" not in " ".join(str(a) for a in fn.attributes)
    assert inlining.mark_alwaysinline(cres, limit=size)
    assert "alwaysinline" in " ".join(str(a) for a in fn.attributes)


@pytest.mark.parametrize("path,n", [("servo.yaml", 40), ("bouncing_ball.yaml", 40)])
def test_inlined_kernels_compute_what_python_computes(path, n):
    """Inlining moves machine code, it does not change arithmetic (no fastmath: no
    reassociation, no fused multiply-add): the compiled system function gives bit for bit
    the derivatives, signals and guards of the same module interpreted by Python, at random
    states (servo: voltage saturated and not, before and after the reference step)."""
    d = spidersim.load(os.path.join(ROOT, "diagrams", path))
    sj, sp = d.compile(True), d.compile(False)
    rng = np.random.default_rng(14)
    for k in range(n):
        t = rng.uniform(0.0, 0.02)
        x = rng.normal(size=sj.x0.size) * (10.0 ** rng.integers(-3, 3))
        fj = sj.rhs(t, x.copy())
        fp = sp.rhs(t, x.copy())
        assert np.array_equal(fj, fp), (path, t, x, fj - fp)
        assert np.array_equal(sj.sig, sp.sig), (path, t, x)
        if sj.n_g:
            assert np.array_equal(sj.guards(t, x), sp.guards(t, x))
