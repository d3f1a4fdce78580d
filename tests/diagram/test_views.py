"""The borrowed views that generated modules pass to kernels (spidersim.diagram.views)."""
import os
import re

import numpy as np
from numba import njit

import spidersim
from spidersim.diagram.views import _view_py, view

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))


@njit
def _double(u, y):
    for i in range(y.size):
        y[i] = 2.0 * u[i]


@njit
def _view_sum(a, start, stop):
    v = view(a, start, stop)
    s = 0.0
    for i in range(v.size):
        s += v[i]
    return s, v.size


@njit
def _write_through(a, start, stop, value):
    v = view(a, start, stop)
    for i in range(v.size):
        v[i] = value


def test_view_is_the_slice_and_writes_through():
    """view(a, i, j) reads exactly a[i:j] (same length, same elements) and writes land in
    a[i:j] and nowhere else; also on a strided (non-contiguous) array, where the view must
    step by a's stride, not by the item size."""
    a = np.arange(10.0) ** 2
    for i, j in ((0, 1), (3, 7), (9, 10), (4, 4)):
        s, n = _view_sum(a, i, j)
        assert n == j - i and s == a[i:j].sum()
    b = a.copy()
    _write_through(b, 2, 5, -1.0)
    expect = a.copy()
    expect[2:5] = -1.0
    assert np.array_equal(b, expect)
    strided = np.arange(20.0)[::2]                       # 0, 2, 4, ... (layout 'A')
    s, n = _view_sum(strided, 1, 4)
    assert (s, n) == (2.0 + 4.0 + 6.0, 3)
    base = np.arange(20.0)
    _write_through(base[::2], 1, 3, -5.0)
    assert base[2] == base[4] == -5.0 and base[3] == 3.0 and base[6] == 6.0
    assert np.array_equal(_view_py(a, 3, 7), a[3:7])


def _nrt_calls(fn, *args):
    """Calls of NRT_incref/NRT_decref in the body of ``fn``'s own LLVM function."""
    fn(*args)
    ll = next(iter(fn.inspect_llvm().values()))
    name = fn.__name__
    bodies = re.split(r"^define ", ll, flags=re.M)
    own = [b for b in bodies if re.match(rf"[^@]*@_ZN[^(]*{name}", b)
           and "cpython" not in b.split("(")[0]]
    return sum(len(re.findall(r"call void @NRT_(?:inc|dec)ref", b)) for b in own)


def test_views_touch_no_reference_count():
    """Kernel calls on borrowed views add no reference counting: three calls cost as many
    NRT_incref/decref as one (those of the function's own array arguments), while the same
    calls on numba slices add some for every view (the per-call cost this module removes)."""
    def one(x, y):
        _double(view(x, 0, 1), view(y, 0, 1))

    def three(x, y):
        _double(view(x, 0, 1), view(y, 0, 1))
        _double(view(x, 1, 2), view(y, 1, 2))
        _double(view(x, 2, 3), view(y, 2, 3))

    def three_sliced(x, y):
        _double(x[0:1], y[0:1])
        _double(x[1:2], y[1:2])
        _double(x[2:3], y[2:3])

    x, y = np.arange(3.0), np.zeros(3)
    n1, n3, n3s = (_nrt_calls(njit(f), x, y) for f in (one, three, three_sliced))
    assert np.array_equal(y, 2.0 * x)
    assert n3 == n1
    assert n3s > n3


def test_generated_kernel_arguments_are_borrowed_views():
    """Every port, state, mode and vector parameter a generated module hands a kernel is a
    borrowed view (``_v(arr, a, b)``), never a slice ``arr[a:b]`` of the flat arrays; every
    generated function that calls kernels or ``outputs`` first rebinds its array arguments
    to borrowed views of themselves; the interpreted module (JIT = False) gets plain slices
    under the same name."""
    d = spidersim.load(os.path.join(ROOT, "diagrams", "servo.yaml"))
    src = d.source()
    body = src[src.index("def outputs"):src.index("if JIT:\n    from numba import carray")]
    assert "_v(x, 2, 3)" in body and "_v(xdot, " in body
    assert not re.search(r"\b(x|sig|modes|xdot|p|g|out)\[\d+:\d+\]", body)
    for fn in ("outputs", "evaluate"):
        head = src[src.index(f"def {fn}("):]
        head = head[:head.index("\n\n")]
        assert all(f"    {a} = _v({a}, 0, {a}.size)\n" in head
                   for a in ("x", "sig", "p", "modes") + (("out",) if fn == "evaluate" else ())
                   ), fn
    assert "_view_py as _v" in d.source(jit=False)


def test_system_function_is_compiled_once_from_the_body_of_evaluate():
    """The compiled system function ``_system`` is ``evaluate``'s body on carrays of the
    pointers (compiled once there: no separate jitted ``evaluate`` whose code numba would
    link in and optimise a second time), and it computes what the interpreted ``evaluate``
    computes: the servo's derivatives from both agree to 1e-12 relative."""
    d = spidersim.load(os.path.join(ROOT, "diagrams", "servo.yaml"))
    src = d.source()
    assert "_jit(evaluate)" not in src and "_evaluate" not in src
    ev = src[src.index("def evaluate("):src.index("\n\nif JIT:\n    from numba import carray")]
    ev_body = ev[ev.index("    out = _v(out, 0, out.size)\n") + 31:]
    sy = src[src.index("def _system("):src.index("\n    SYSTEM = _system.address")]
    marker = "else N_TIMED))\n"                  # the end of the carray of ``out``
    sy_body = sy[sy.index(marker) + len(marker):]
    assert sy_body.replace("\n        ", "\n    ").strip() == ev_body.strip()
    xdot = {}
    for jit in (True, False):
        s = d.compile(jit=jit)
        x = s.x0 + np.linspace(0.1, 0.5, s.x0.size)
        xdot[jit] = s.rhs(0.02, x)
    assert np.allclose(xdot[True], xdot[False], rtol=1e-12, atol=1e-300)
    assert np.any(xdot[True] != 0.0)
