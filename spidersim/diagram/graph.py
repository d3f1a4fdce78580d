"""The flat array layout of a diagram: four passes from the flat diagram to a :class:`Layout`.

Contract
--------
:func:`build_layout` runs these passes in order; each takes the frozen results of the ones
before and returns a new frozen record, and none modifies its inputs or the flat diagram.

1. Port sizes (:mod:`.sizes`, :func:`~.sizes.port_sizes` -> ``PortSizes``): declared
   ports, wiring checks, sizes propagated along the wires, unconnected-input and size checks.
2. Port graph (:mod:`.portgraph`, :func:`~.portgraph.port_graph` -> ``PortGraph``): nodes
   ``("out"|"in", block, port)``; wires and each block's direct feedthrough as edges; then
   :func:`~.portgraph.check_constraints` (each implicit output reaches its residual),
   :func:`~.portgraph.check_sampled_loops` (no discrete algebraic loop).
3. Schedule (:mod:`.schedule`, :func:`~.schedule.schedule` -> ``Schedule``): algebraic loops
   (strongly connected components), their tears and inner calls, the call order.
4. Slots (:mod:`.slots`, :func:`~.slots.allocate` -> ``Slots``): offsets of states,
   signals, zero slot, scratch, tears, guards, modes, parameters, input sources and loop
   workspaces.

The results are then copied into the records the code generator and the diagram read
(:class:`Layout`, :class:`BlockLayout`, :class:`PortInfo`, :class:`Loop`). Two fields of
those stay writable after the layout: :attr:`PortInfo.unit` (unit inference replaces the
declared unit) and :attr:`BlockLayout.params` (``Diagram.set`` replaces parameter values).
"""
from __future__ import annotations

from dataclasses import dataclass

import networkx as nx
import numpy as np

from .flatten import Flat
from .portgraph import check_constraints, check_sampled_loops, port_graph
from .schedule import describe_loops, schedule  # noqa: F401  (describe_loops: public)
from .sizes import port_sizes
from .slots import Loc, Span, allocate


@dataclass
class PortInfo:
    """One port: its size, unit (declared, then inferred), kind and, for an output, where
    its value lives (``Loc(array, start, stop)``, array ``"x"`` or ``"sig"``)."""

    size: int
    unit: str
    kind: str                 # "out" | "in"
    loc: Loc | None = None


@dataclass
class BlockLayout:
    """Where a block's ports, states, modes and parameters live in the flat arrays.

    Slices are ``Span(start, stop)``; parameter slots ``ParamSlot(start, stop, shape)``;
    input sources ``Loc(array, start, stop)``. ``params`` are the validated parameters
    merged with the derived ones.
    """

    path: str
    cls: type
    params: dict
    inputs: list
    outputs: list
    ports: dict           # (kind, name) -> PortInfo
    states: dict          # name -> Span in x
    modes: dict           # name -> Span in modes
    pslots: dict          # param name -> ParamSlot in p
    constants: dict       # int/bool params
    feedthrough: dict     # output -> tuple of inputs
    state_outputs: frozenset
    input_src: dict       # input -> Loc
    guard_slice: Span     # this block's events in the guard array
    event_sizes: list     # guards per declared event
    scratch: dict         # name -> Span in sig


@dataclass(frozen=True)
class Loop:
    """An algebraic loop: its ports, tear unknowns, inner calls and workspace."""

    index: int
    nodes: list                 # port nodes of the strongly connected component
    tears: list                 # Tear(path, port, kind): kind "signal" or "constraint"
    calls: list                 # block paths, in evaluation order inside the loop
    walk: str                   # the loop port by port, for messages
    zslots: dict                # (path, port) -> Span of z in sig
    zidx: list                  # sig indices of all unknowns
    residual: list              # Residual(kind, index, other) per unknown element
    names: list                 # a name per unknown element
    ws0: int                    # start of the Newton workspace in sig (newton.Workspace)


@dataclass(frozen=True)
class Layout:
    """Sizes, schedule and offsets of a whole diagram."""

    blocks: dict                # path -> BlockLayout
    n_x: int
    n_sig: int
    n_p: int
    n_modes: int
    calls: list                 # schedule: Step("call", path) or Step("loop", k)
    loops: list                 # Loop
    graph: nx.DiGraph
    zero_slot: Loc
    p_loop_tol: Span            # p indices of the loop atol and rtol
    n_g: int = 0                # number of zero-crossing guards
    partial: frozenset = frozenset()   # indices in ``calls`` of partial calls (schedule 5)


def build_layout(flat: Flat) -> Layout:
    """Sizes, graph, schedule and offsets of every port, state, mode and parameter.

    Parameters
    ----------
    flat : Flat
        The flat diagram.

    Returns
    -------
    Layout

    Raises
    ------
    WiringError, ParameterError, AlgebraicLoopError
        At the first problem met, pass by pass (see the module contract).
    """
    ps = port_sizes(flat)
    pg = port_graph(ps)
    check_constraints(pg, ps, flat)
    check_sampled_loops(pg, ps, flat)
    sched = schedule(pg, ps)
    slots = allocate(flat, ps, pg, sched)
    blocks = {}
    for path, bp in ps.blocks.items():
        bs, flow = slots.blocks[path], pg.flow[path]
        ports = {(kind, n): PortInfo(ps.size(path, kind, n), bp.units[(kind, n)], kind,
                                     bs.outputs[n] if kind == "out" else None)
                 for kind, n in bp.declared}
        blocks[path] = BlockLayout(
            path, bp.cls, bs.params, list(bp.inputs), list(bp.outputs), ports,
            dict(bs.states), dict(bs.modes), dict(bs.pslots), dict(bs.constants),
            dict(flow.feedthrough), flow.state_outputs, dict(bs.input_src), bs.guards,
            list(bs.event_sizes), dict(bs.scratch))
    loops = [Loop(lp.index, list(lp.nodes), list(lp.tears), list(lp.calls), lp.walk,
                  dict(ls.zslots), list(ls.zidx), list(ls.residual), list(ls.names), ls.ws0)
             for lp, ls in zip(sched.loops, slots.loops)]
    return Layout(blocks, slots.n_x, slots.n_sig, slots.n_p, slots.n_modes,
                  list(sched.steps), loops, pg.graph, slots.zero_slot, slots.p_loop_tol,
                  slots.n_g, sched.partial)


def port_state_deps(layout: Layout):
    """Port node -> the set of state indices its value can depend on (structurally):
    through the wires, each block's declared feedthrough and, for a block's outputs, all of
    its own states (an output that *is* a state depends on that state only). Computed
    component by component of the condensation: every port of an algebraic loop depends on
    everything the loop reads."""
    info = layout.blocks
    g = layout.graph
    cond = nx.condensation(g)
    comp_deps = {}
    for c in nx.topological_sort(cond):
        d = set()
        for node in cond.nodes[c]["members"]:
            kind, path, port = node
            bl = info[path]
            if kind == "out" and port in bl.state_outputs:
                d.update(range(*bl.states[port]))
            elif kind == "out":
                for a, b in bl.states.values():
                    d.update(range(a, b))
        for pred in cond.predecessors(c):
            d |= comp_deps[pred]
        comp_deps[c] = d
    mapping = cond.graph["mapping"]
    return {node: comp_deps[mapping[node]] for node in g.nodes}


def block_columns(layout: Layout, deps, bl):
    """The states a block's derivatives can depend on: its own and those its inputs
    depend on (``deps`` from :func:`port_state_deps`); one row set of the pattern."""
    cols = set()
    for a, b in bl.states.values():
        cols.update(range(a, b))
    for i in bl.inputs:
        cols |= deps[("in", bl.path, i)]
    return cols


def jacobian_sparsity(layout: Layout):
    """Boolean (n_x, n_x) pattern: which states can move each state's derivative."""
    deps = port_state_deps(layout)
    pattern = np.zeros((layout.n_x, layout.n_x), dtype=bool)
    for bl in layout.blocks.values():
        cols = np.fromiter(block_columns(layout, deps, bl), dtype=np.intp)
        for a, b in bl.states.values():
            pattern[a:b, cols] = True
    return pattern
