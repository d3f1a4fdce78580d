"""The parts of linearization and trim (spidersim.diagram.analysis) that work on the flat
diagram or on plain arrays: analysis-point insertion, derivative selection, residual check.
Nothing is compiled; whole linearizations are tests/solver/test_linearize.py."""
from types import SimpleNamespace

import numpy as np
import pytest

import spidersim
from spidersim.diagram import analysis as A
from spidersim.diagram.analysis import AnalysisError

CHAIN = """\
blocks:
  u: {type: Constant, value: [1, 2]}
  g: {type: Gain, k: 2}
  h: {type: Gain, k: 3}
  s: {type: Selector, index: [1]}
connections: [u.y -> g.u, u.y -> s.u, g.y -> h.u]
"""


def test_input_point_feeds_every_reader_of_the_signal_through_a_sum():
    """An input at ``u.y`` adds a Constant perturbation and a Sum; both readers of u.y now
    read the Sum, which reads u.y itself; nothing else is rewired."""
    d = spidersim.loads(CHAIN)
    blocks = dict(d.flat.blocks)
    conns, p = A._insert_point(blocks, list(d.flat.conns), 0, "u.y", "input",
                               A._signal_ref(d, "u.y"), d)
    assert (p.delta, p.op_const, p.kind) == ("__lin_d0", None, "input")
    assert blocks["__lin_d0"].params["value"].tolist() == [0.0, 0.0]
    edges = {(c.src[0], c.dst) for c in conns}
    assert {("__lin_s0", ("g", "u")), ("__lin_s0", ("s", "u")), ("u", ("__lin_s0", "u1")),
            ("__lin_d0", ("__lin_s0", "u2")), ("g", ("h", "u"))} == edges
    assert len(d.flat.conns) == 3                     # the diagram's own list is untouched
    # an element: the Sum still spans the whole port (g and s read all of u.y), the
    # perturbation of element 1 is entry 1 of the Constant
    conns, p = A._insert_point(dict(d.flat.blocks), list(d.flat.conns), 0, "u.y[1]",
                               "input", A._signal_ref(d, "u.y[1]"), d)
    assert ("u", "y", None, None) in [c.src for c in conns if c.dst == ("__lin_s0", "u1")]
    assert p.offset == 1
    assert {c.dst for c in conns if c.src[0] == "__lin_s0"} == {("g", "u"), ("s", "u")}


def test_opening_reads_the_operating_value_and_needs_a_reader():
    """An opening at ``g.y`` feeds h from a Constant (the operating value) plus the
    perturbation, so g.y no longer reaches h; a signal nobody reads cannot be opened."""
    d = spidersim.loads(CHAIN)
    conns, p = A._insert_point(dict(d.flat.blocks), list(d.flat.conns), 1, "g.y", "open",
                               A._signal_ref(d, "g.y"), d)
    assert p.op_const == "__lin_op1"
    assert not any(c.src[0] == "g" for c in conns)
    assert any(c.src[0] == "__lin_op1" and c.dst == ("__lin_s1", "u1") for c in conns)
    with pytest.raises(AnalysisError, match="cannot open 'h.y': it is not a connection"):
        A._insert_point({}, list(d.flat.conns), 0, "h.y", "open", A._signal_ref(d, "h.y"), d)


def test_consumers_are_the_readers_of_any_overlapping_slice():
    """A connection reading a slice that shares an element with the signal is a consumer of
    it (the reader of ``u.y`` is one of ``u.y[1]``: an exact match left the element-wise
    gains at 0); a reader of ``u.y[0]`` only is not a consumer of ``u.y[1]``."""
    d = spidersim.loads(CHAIN)
    whole = {("g", "u"), ("s", "u")}
    for name in ("u.y", "u.y[1]"):
        assert {c.dst for c in A._consumers(d.flat.conns, A._signal_ref(d, name), d)} == whole
    first = A.FlatConn(("u", "y", 0, 1), ("x", "u"), d.file, 0, "")
    conns = list(d.flat.conns) + [first]
    assert first not in A._consumers(conns, A._signal_ref(d, "u.y[1]"), d)
    assert first in A._consumers(conns, A._signal_ref(d, "u.y[0]"), d)


def test_opening_an_element_rebuilds_the_port_with_a_mux():
    """Opening ``u.y[1]``, read whole by g and s: they read a Mux of the live ``u.y[0]``
    and the operating value plus perturbation of element 1."""
    d = spidersim.loads(CHAIN)
    blocks = dict(d.flat.blocks)
    conns, p = A._insert_point(blocks, list(d.flat.conns), 0, "u.y[1]", "open",
                               A._signal_ref(d, "u.y[1]"), d)
    assert blocks["__lin_op0"].params["value"].tolist() == [0.0]
    assert {c.dst for c in conns if c.src[0] == "__lin_m0"} == {("g", "u"), ("s", "u")}
    assert {(c.src, c.dst[1]) for c in conns if c.dst[0] == "__lin_m0"} == {
        (("u", "y", 0, 1), "u1"), (("__lin_s0", "y", None, None), "u2")}


def test_derivative_rows():
    """``"all"`` is every state; ``block.state`` covers all its elements, ``[i]`` one; an
    unknown name suggests near ones."""
    d = SimpleNamespace(layout=SimpleNamespace(n_x=5), file="d.yaml")
    names = ["m.w", "arm.q[0]", "arm.q[1]", "m.i", "m.w2"]
    assert A._derivative_rows(d, "all", names) == [0, 1, 2, 3, 4]
    assert A._derivative_rows(d, ["arm.q", "m.i"], names) == [1, 2, 3]
    assert A._derivative_rows(d, ["m.w"], names) == [0]
    assert A._derivative_rows(d, ["arm.q[1]"], names) == [2]
    with pytest.raises(AnalysisError, match="unknown state 'm.ww'; did you mean m.w"):
        A._derivative_rows(d, ["m.ww"], names)


def test_trim_residual_check_names_the_largest():
    """Residuals within the tolerance pass; otherwise the error lists the largest first
    with the solver's message; a NaN residual never passes."""
    d, sol = SimpleNamespace(file="d.yaml"), SimpleNamespace(message="stalled")
    resid = {"d/dt a": 1e-12, "d/dt b": -3e-3, "y": 2e-4}
    A._check_trim_residuals(d, np.array([1e-12]), {"d/dt a": 1e-12}, sol, 1e-10)
    with pytest.raises(AnalysisError, match=r"\(stalled\); largest residuals: d/dt b = "
                                            r"-0\.003, y = 0\.0002, d/dt a = 1e-12"):
        A._check_trim_residuals(d, np.array(list(resid.values())), resid, sol, 1e-10)
    with pytest.raises(AnalysisError):
        A._check_trim_residuals(d, np.array([np.nan]), {"x": np.nan}, sol, 1e-10)


def test_named_inputs_scalars_and_vectors():
    """The free inputs' solution is split by name: a scalar input as a float, a vector as
    an array of its size."""
    lin = SimpleNamespace(in_p=[("a", 10, 11), ("b", 20, 23)])
    out = A._named_inputs(lin, np.array([1.5, 2.0, 3.0, 4.0]))
    assert out["a"] == 1.5 and isinstance(out["a"], float)
    np.testing.assert_array_equal(out["b"], [2.0, 3.0, 4.0])


@pytest.mark.parametrize("name,s0", [("u.y[-1]", 1), ("u.y[-2]", 0), ("u.y[ -1 ]", 1),
                                     ("u.y[1]", 1)])
def test_a_signal_index_counts_from_the_end(name, s0):
    """``u.y[-1]`` is the last element, as in connections, plots and metrics (it was
    'index out of range (size 2)')."""
    d = spidersim.loads(CHAIN)
    assert A._signal_ref(d, name)[2:5] == (s0, s0 + 1, 1)


@pytest.mark.parametrize("name,words", [
    ("u.y[-3]", "signal 'u.y[-3]': index -3 out of range (size 2: 0..1, or -2..-1 from the "
                "end)"),
    ("u.y[2]", "index 2 out of range (size 2"),
    ("u.y[١]", "signal 'u.y[١]': non-ASCII character '١' (U+0661 ARABIC-INDIC DIGIT ONE) at "
               "character 5: names and indices are ASCII"),
    ("u.y[𝟏]", "non-ASCII character '𝟏' (U+1D7CF MATHEMATICAL BOLD DIGIT ONE)"),
    ("u.y[1_0]", "cannot read signal 'u.y[1_0]' (use block.port or block.port[i]"),
    ("u.y[0:1]", "cannot read signal 'u.y[0:1]'"),
])
def test_signal_index_errors(name, words):
    """Past either end; digits ``int`` reads but that are not ASCII (``[١]`` was 1) or not
    an index (``[1_0]`` was 10)."""
    d = spidersim.loads(CHAIN)
    with pytest.raises(AnalysisError) as ei:
        A._signal_ref(d, name)
    assert words in str(ei.value)
