"""Each layout pass alone, on tiny flat diagrams built by hand (no YAML).

Passes: 1 port sizes (:mod:`spidersim.diagram.sizes`), 2 port graph
(:mod:`spidersim.diagram.portgraph`), 3 schedule (:mod:`spidersim.diagram.schedule`),
4 slots (:mod:`spidersim.diagram.slots`); :func:`spidersim.diagram.graph.build_layout` runs
them in that order.
"""
import dataclasses

import pytest

from spidersim.blocks import REGISTRY
from spidersim.diagram.flatten import Flat, FlatConn, Instance, Range
from spidersim.diagram.graph import build_layout
from spidersim.diagram.portgraph import Node, check_constraints, port_graph
from spidersim.diagram.schedule import Step, Tear, schedule
from spidersim.diagram.sizes import port_sizes
from spidersim.diagram.slots import Loc, Span, allocate
from spidersim.errors import ParameterError, WiringError


def flat(blocks, wires):
    """A Flat from ``{path: (type, params)}`` and ``"a.y -> b.u"`` wires."""
    inst = {}
    for k, (path, (typ, prm)) in enumerate(blocks.items()):
        cls = REGISTRY[typ]
        inst[path] = Instance(path, cls, cls.validate_params(prm), "t.yaml", k + 1)
    conns = []
    for k, w in enumerate(wires):
        src, dst = (s.strip() for s in w.split("->"))
        (sp, sport), (dp, dport) = src.split("."), dst.split(".")
        conns.append(FlatConn((sp, sport, None, None), (dp, dport), "t.yaml", 100 + k, w))
    return Flat(inst, conns, {})


def chain():
    """c (Constant, 2 values) -> g (Gain) -> i (Integrator)."""
    return flat({"c": ("Constant", {"value": [1.0, 2.0]}), "g": ("Gain", {"k": 3.0}),
                 "i": ("Integrator", {})}, ["c.y -> g.u", "g.y -> i.u"])


def algebraic():
    """u -> s.u1; s = u + f(s): Sum s and Gain f in a feedthrough cycle."""
    return flat({"u": ("Constant", {"value": 1.0}), "s": ("Sum", {"signs": "++"}),
                 "f": ("Gain", {"k": 0.5})},
                ["u.y -> s.u1", "s.y -> f.u", "f.y -> s.u2"])


def through_state():
    """The same cycle with an Integrator in it: no algebraic loop."""
    return flat({"u": ("Constant", {"value": 1.0}), "s": ("Sum", {"signs": "+-"}),
                 "i": ("Integrator", {})},
                ["u.y -> s.u1", "s.y -> i.u", "i.y -> s.u2"])


def test_sizes_of_a_chain():
    """Pass 1 alone: a Constant's size reaches a Gain and an Integrator through
    ``size=None`` inputs and ``@u`` outputs; sources are indexed by input."""
    ps = port_sizes(chain())
    assert ps.size("c", "out", "y") == 2
    assert [ps.size(p, k, n) for p, k, n in (("g", "in", "u"), ("g", "out", "y"),
                                             ("i", "in", "u"), ("i", "out", "y"))] == [2] * 4
    assert ps.source("g", "u").src[:2] == ("c", "y")
    assert ps.source("c", "u") is None
    assert ps.blocks["g"].inputs == ("u",) and ps.blocks["g"].declared[("in", "u")] is None


def test_sizes_propagate_backwards_into_a_cycle():
    """Pass 1: sizes of a feedthrough cycle come from the one input fed from outside; the
    records are frozen (no pass can change them)."""
    ps = port_sizes(flat({"u": ("Constant", {"value": [1.0, 2.0, 3.0]}),
                          "s": ("Sum", {"signs": "++"}), "f": ("Gain", {"k": 0.5})},
                         ["f.y -> s.u2", "s.y -> f.u", "u.y -> s.u1"]))
    assert {ps.size("f", k, n) for k, n in (("in", "u"), ("out", "y"))} == {3}
    assert ps.size("s", "in", "u2") == 3
    with pytest.raises(dataclasses.FrozenInstanceError):
        ps.sizes = {}
    with pytest.raises(TypeError):
        ps.sizes[("s", "in", "u2")] = 4


def test_unconnected_input_is_an_error():
    """Pass 1: a required input left unconnected is a WiringError at the block's line."""
    f = flat({"g": ("Gain", {}), "c": ("Constant", {"value": 1.0})}, [])
    with pytest.raises(WiringError) as exc:
        port_sizes(f)
    assert "input 'u'" in exc.value.message and "is not connected" in exc.value.message
    assert exc.value.block == "g" and exc.value.line == 1
    assert "c.y" in exc.value.message             # a candidate source is suggested


def test_element_ranges_are_resolved_into_the_flat_diagram():
    """Pass 1 checks the ranges as written (innermost first, negative bounds from the end)
    and writes them resolved into each connection and alias: [1:3] of an exposed [-3:]
    (c.y has 4) is c.y[2:4]; the alias s.z = c.y[-1] is c.y[3:4]."""
    f = flat({"c": ("Constant", {"value": [1.0, 2.0, 3.0, 4.0]}), "g": ("Gain", {})},
             ["c.y -> g.u"])
    f.conns[0].ranges = (Range(-3, None, "[-3]", "c.y", "exposed output 'y'", "s.yaml", 3),
                         Range(1, 3, "[1:3]", "s.y", "connection source", "t.yaml", 100))
    f.aliases["s.z"] = ("c", "y", None, None)
    f.out_ranges["s.z"] = ("c", "y", (Range(-1, None, "[-1]", "c.y", "exposed output 'z'",
                                            "s.yaml", 4),))
    ps = port_sizes(f)
    assert ps.size("g", "in", "u") == 2
    assert (f.conns[0].src, f.conns[0].ranges) == (("c", "y", 2, 4), ())
    assert f.aliases["s.z"] == ("c", "y", 3, 4) and f.out_ranges == {}
    assert port_sizes(f).size("g", "in", "u") == 2          # resolved once, not twice


def test_size_mismatch_is_an_error():
    """Pass 1: a 2-element source wired into a declared scalar input is refused at the
    wire's line; unequal Sum inputs are refused by the block's own size check."""
    f = flat({"a": ("Constant", {"value": [1.0, 2.0]}), "d": ("NRPIDriver", {})},
             ["a.y -> d.i_cmd"])
    with pytest.raises(WiringError, match="size mismatch") as exc:
        port_sizes(f)
    assert exc.value.line == 100
    f = flat({"a": ("Constant", {"value": [1.0, 2.0]}), "b": ("Constant", {"value": 1.0}),
              "s": ("Sum", {"signs": "++"})}, ["a.y -> s.u1", "b.y -> s.u2"])
    with pytest.raises(ParameterError, match="same size"):
        port_sizes(f)


def test_graph_of_a_chain():
    """Pass 2 alone: wires and feedthrough edges; a state output has no incoming edge."""
    ps = port_sizes(chain())
    pg = port_graph(ps)
    g = pg.graph
    assert g.edges[Node("out", "c", "y"), Node("in", "g", "u")]["kind"] == "wire"
    assert g.edges[Node("in", "g", "u"), Node("out", "g", "y")]["kind"] == "feedthrough"
    assert g.in_degree(Node("out", "i", "y")) == 0
    assert pg.flow["i"].state_outputs == frozenset({"y"})
    assert pg.flow["i"].feedthrough["y"] == ()
    assert dict(pg.flow["i"].state_sizes) == {"y": 2}


def test_schedule_of_a_chain():
    """Pass 3 alone: one call per block in wiring order; the Integrator (a state output)
    is not called; no loops."""
    ps = port_sizes(chain())
    sched = schedule(port_graph(ps), ps)
    assert sched.steps == (Step("call", "c"), Step("call", "g"))
    assert sched.loops == ()


def test_feedthrough_cycle_is_an_algebraic_loop():
    """Pass 3: a feedthrough cycle is one loop, torn at one output, run as a loop step
    after what feeds it."""
    ps = port_sizes(algebraic())
    pg = port_graph(ps)
    check_constraints(pg, ps, algebraic())
    sched = schedule(pg, ps)
    assert len(sched.loops) == 1
    lp = sched.loops[0]
    assert set(lp.nodes) == {Node("in", "s", "u2"), Node("out", "s", "y"),
                             Node("in", "f", "u"), Node("out", "f", "y")}
    assert lp.tears == (Tear("s", "y", "signal"),)
    assert lp.calls == ("f", "s")
    assert "->" in lp.walk and "=>" in lp.walk
    assert sched.steps == (Step("call", "u"), Step("loop", 0))


def test_cycle_through_a_state_is_no_loop():
    """Pass 3: a cycle broken by a state is scheduled without a loop."""
    ps = port_sizes(through_state())
    sched = schedule(port_graph(ps), ps)
    assert sched.loops == ()
    assert sched.steps == (Step("call", "u"), Step("call", "s"))


def test_block_called_at_two_depths():
    """Pass 3: a block whose output feeds back into another of its inputs (through a
    Gain) is called twice: once for the outputs its ready inputs allow, once after the
    Gain. The first call is not partial (contract item 5): the output it makes valid has
    feedthrough (from the inputs already computed)."""
    f = flat({"c": ("Constant", {"value": 1.0}), "d": ("NRPIDriver", {}),
              "g": ("Gain", {"k": 1.0})},
             ["c.y -> d.i_cmd", "c.y -> d.theta_e", "c.y -> d.i_b", "d.i_a_ref -> g.u",
              "g.y -> d.i_a"])
    ps = port_sizes(f)
    sched = schedule(port_graph(ps), ps)
    assert sched.loops == ()
    calls = [s.what for s in sched.steps]
    assert calls.count("d") == 2
    assert calls.index("g") > calls.index("d")
    assert calls[-1] == "d"
    assert sched.partial == frozenset()


def test_slots_of_a_chain():
    """Pass 4 alone: states in x, outputs in sig in call order, state outputs point at their
    state, inputs read their sources, numeric parameters get p slots, then loop tolerances."""
    f = chain()
    ps = port_sizes(f)
    pg = port_graph(ps)
    slots = allocate(f, ps, pg, schedule(pg, ps))
    assert slots.n_x == 2 and slots.blocks["i"].states["y"] == Span(0, 2)
    assert slots.blocks["c"].outputs["y"] == Loc("sig", 0, 2)
    assert slots.blocks["g"].outputs["y"] == Loc("sig", 2, 4)
    assert slots.blocks["i"].outputs["y"] == Loc("x", 0, 2)
    assert slots.blocks["i"].input_src["u"] == Loc("sig", 2, 4)
    assert slots.zero_slot == Loc("sig", 4, 4)          # no unconnected input
    assert slots.n_sig == 4
    assert slots.blocks["g"].pslots["k"].stop - slots.blocks["g"].pslots["k"].start == 1
    assert slots.p_loop_tol == Span(slots.n_p - 2, slots.n_p - 1)


def test_slots_of_a_loop():
    """Pass 4: a signal tear gets its own sig slot, the Sum's input u2 reads Gain's output,
    the residual compares the tear with the recomputed output, the workspace comes last."""
    f = algebraic()
    ps = port_sizes(f)
    pg = port_graph(ps)
    slots = allocate(f, ps, pg, schedule(pg, ps))
    ls = slots.loops[0]
    z = ls.zslots[("s", "y")]
    assert slots.blocks["f"].input_src["u"] == Loc("sig", z.start, z.stop)
    assert ls.zidx == (z.start,)
    out = slots.blocks["s"].outputs["y"]
    assert [tuple(r) for r in ls.residual] == [("signal", z.start, out.start)]
    assert ls.names == ("s.y",)
    assert ls.ws0 >= z.stop and slots.n_sig > ls.ws0


def test_build_layout_assembles_the_passes():
    """build_layout: the public records read the passes' results (schedule, slots, sizes)."""
    L = build_layout(algebraic())
    assert L.calls == [("call", "u"), ("loop", 0)]
    assert L.loops[0].tears == [("s", "y", "signal")]
    bl = L.blocks["s"]
    assert bl.ports[("out", "y")].size == 1
    assert bl.ports[("out", "y")].loc == tuple(bl.ports[("out", "y")].loc)
    assert bl.input_src["u2"] == L.blocks["f"].ports[("out", "y")].loc


def test_partial_calls_are_early_calls_repeated_later():
    """Contract item 5 alone: a call is partial when it made only outputs without
    feedthrough valid and its block is called again later; the last call of a block, a
    call with feedthrough outputs and a loop step never are."""
    from spidersim.diagram.schedule import partial_calls
    steps = [Step("call", "arm"), Step("call", "g"), Step("loop", 0), Step("call", "arm"),
             Step("call", "m"), Step("call", "m")]
    direct = [False, False, True, True, True, False]
    assert partial_calls(steps, direct) == frozenset({0})
    assert partial_calls(steps, [True] * 6) == frozenset()
