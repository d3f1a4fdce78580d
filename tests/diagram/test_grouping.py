"""The grouping pass (spidersim/diagram/grouping.py) on hand-made calls, no diagram, no numba:
identical calls become one loop over offset tables, and only when no call they move over
reads or writes what they touch."""
import os

import numpy as np

import spidersim
from spidersim.diagram.grouping import Call, conflict, emit, group, table_text

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))


def cells(arr, a, b):
    return frozenset((arr, i) for i in range(a, b))


def gain(src, dst, k):
    """``dst = p[k] * src`` as a Call (reads src, p[k]; writes dst)."""
    return Call("gain", (f"_v(sig, {src}, {src + 1})", f"p[{k}]", f"_v(sig, {dst}, {dst + 1})"),
                cells("sig", src, src + 1) | {("p", k)}, cells("sig", dst, dst + 1))


def run(lines, tables, sig, p):
    """Execute emitted lines in plain Python (views are slices)."""
    def _v(a, i, j):
        return a[i:j]

    def gain_(u, k, y):
        y[0] = k * u[0]
    env = {"_v": _v, "gain": gain_, "sig": sig, "p": p}
    exec(table_text(tables) + "\n".join(s[4:] for s in lines), env)  # test-only text
    return sig


def test_independent_identical_calls_become_one_loop():
    """Three gains of three instances, with an unrelated call between them, are one loop
    over offset tables, and computing it gives what the calls gave one by one."""
    other = Call("gain", ("_v(sig, 9, 10)", "p[5]", "_v(sig, 8, 10)"),
                 cells("sig", 9, 10), cells("sig", 8, 10))   # a different key (width 2)
    calls = [gain(0, 3, 0), other, gain(1, 4, 1), gain(2, 5, 2)]
    groups = group(calls)
    assert [len(g) for g in groups] == [3, 1]
    tables = {}
    lines = emit(groups, tables)
    assert lines[0] == "    for _i in range(3):" and len(tables) == 3
    assert tables["_g0"] == (0, 1, 2) and tables["_g2"] == (3, 4, 5)
    p = np.array([2.0, 3.0, 4.0, 0, 0, 0])
    a = run(lines[:2], tables, np.arange(10.0), p)
    b = np.arange(10.0)
    for c in calls[0::2] + calls[3:]:
        run(emit([[c]], {}), {}, b, p)
    assert np.array_equal(a[:6], b[:6]) and a[3] == 0.0 and a[5] == 8.0


def test_a_call_does_not_move_over_a_writer_of_its_input():
    """gain(3 -> 6) reads sig[3], which gain(0 -> 3) writes: the second call of key
    'width 1' after a writer of its input stays after it (read after write)."""
    first = gain(0, 3, 0)
    writer = Call("set", ("_v(sig, 7, 8)",), frozenset(), cells("sig", 7, 8))
    later = gain(7, 6, 1)                # reads sig[7], written by `writer`
    assert conflict(later, writer)
    groups = group([first, writer, later])
    assert [len(g) for g in groups] == [1, 1, 1]
    # without the conflict it joins
    assert [len(g) for g in group([first, writer, gain(1, 6, 1)])] == [2, 1]


def test_write_after_read_and_barriers_keep_the_order():
    """A call that would overwrite what a skipped call still reads may not move over it;
    nothing moves over a barrier (a Newton solve)."""
    reader = Call("use", ("_v(sig, 4, 5)",), cells("sig", 4, 5), frozenset())
    assert [len(g) for g in group([gain(0, 3, 0), reader, gain(1, 4, 1)])] == [1, 1, 1]
    solve = Call("_loop0_solve", ("t", "x", "sig", "p", "modes"), None, None)
    assert [len(g) for g in group([gain(0, 3, 0), solve, gain(1, 5, 1)])] == [1, 1, 1]


def test_spider_compiles_each_joint_kernel_once_per_schedule_depth():
    """The seven joints of spider.yaml: the generated text calls each joint kernel once per
    schedule depth (a loop over the seven instances), not seven times."""
    src = spidersim.load(os.path.join(ROOT, "spider.yaml")).source()
    outputs = src[src.index("def outputs"):src.index("def evaluate")]
    assert outputs.count("_k_BrushlessMotor_output(") == 2
    assert outputs.count("for _i in range(7):") >= 8
    # the system function's body (written twice: on arrays, and in the compiled _system)
    evaluate = src[src.index("def evaluate"):src.index("if JIT:\n    from numba import carray")]
    assert evaluate.count("_k_HarmonicDrive_derivative(") == 1
    compiled = src[src.index("def _system"):]
    assert compiled.count("_k_HarmonicDrive_derivative(") == 1
