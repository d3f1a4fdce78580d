"""Layout pass 2: the port-level graph of the diagram.

Contract
--------
1. :func:`port_graph` ``(ps: PortSizes) -> PortGraph`` is the pass; it does not modify its
   input.
2. Nodes are :class:`Node` ``(kind, path, port)``: ``("out", block, port)`` and
   ``("in", block, port)``, added block by block (outputs, then inputs, in declaration
   order).
3. Edges are each block's direct feedthrough (input -> output, kind ``"feedthrough"``; from
   the block's own implicit output when the feedthrough names one), each implicit output's
   constraint (residual -> implicit output, kind ``"constraint"``) and the wires (output ->
   input, kind ``"wire"``, with the connection's file and line), in that order.
4. An output that *is* a state (a state of the same name and size) has no feedthrough and so
   no incoming edge: a cycle through a state is not a cycle of this graph.
5. Edge order fixes which of several valid schedules is chosen. Each implicit output's
   direct edge to its own residual, if any, comes last (after the wires).
6. :func:`check_constraints` ``(pg, ps, flat)`` checks, without changing the graph, that each
   implicit output reaches its residual through the diagram.
"""
from __future__ import annotations

from dataclasses import dataclass
from types import MappingProxyType
from typing import Mapping, NamedTuple

import networkx as nx

from ..errors import AlgebraicLoopError
from .sizes import BlockPorts, PortSizes


class Node(NamedTuple):
    """A port of the graph: ``kind`` is ``"out"`` or ``"in"``."""

    kind: str
    path: str
    port: str


@dataclass(frozen=True)
class BlockFlow:
    """How values pass through one block.

    Attributes
    ----------
    state_sizes : Mapping
        ``state name -> size``, in declaration order.
    state_outputs : frozenset
        Outputs that are states (same name and size): known without a call.
    feedthrough : Mapping
        ``output -> tuple`` of the inputs (or implicit outputs) it reads directly; empty for
        a state output.
    """

    state_sizes: Mapping
    state_outputs: frozenset
    feedthrough: Mapping


@dataclass(frozen=True)
class PortGraph:
    """Result of pass 2.

    Attributes
    ----------
    graph : networkx.DiGraph
        Port graph (see the module contract); not modified by later passes.
    flow : Mapping
        ``path -> BlockFlow``, in block order.
    """

    graph: nx.DiGraph
    flow: Mapping


def port_graph(ps: PortSizes) -> PortGraph:
    """Pass 2: the port graph and each block's :class:`BlockFlow`.

    Parameters
    ----------
    ps : PortSizes
        Result of pass 1.

    Returns
    -------
    PortGraph
    """
    g = nx.DiGraph()
    flow = {}
    for bp in ps.blocks.values():
        flow[bp.path] = block_flow(bp, ps)
        _add_block(g, bp, flow[bp.path])
    for (dp, dport), c in ps.sources.items():
        g.add_edge(Node("out", c.src[0], c.src[1]), Node("in", dp, dport), kind="wire",
                   line=c.line, file=c.file)
    for bp in ps.blocks.values():
        for o, (i, _guess) in bp.cls.implicit.items():
            src, res = Node("out", bp.path, o), _residual_node(bp, i)
            if g.has_edge(src, res):            # contract item 5: this edge last
                data = dict(g.edges[src, res])
                g.remove_edge(src, res)
                g.add_edge(src, res, **data)
    return PortGraph(g, MappingProxyType(flow))


def state_sizes(bp: BlockPorts, ps: PortSizes):
    """``state name -> size`` of block ``bp`` (``@input`` sizes follow that input)."""
    out = {}
    for s, decl in bp.cls.states.items():
        spec = decl.size
        if isinstance(spec, str) and spec.startswith("@"):
            out[s] = ps.size(bp.path, "in", spec[1:])
        else:
            out[s] = bp.cls.size_of(spec, bp.params)
    return MappingProxyType(out)


def block_flow(bp: BlockPorts, ps: PortSizes) -> BlockFlow:
    """State sizes, state outputs and direct feedthrough of one block."""
    sizes = state_sizes(bp, ps)
    state_outputs, feedthrough = set(), {}
    for o in bp.outputs:
        if o in sizes and sizes[o] == ps.size(bp.path, "out", o):
            state_outputs.add(o)
            feedthrough[o] = ()
        else:
            feedthrough[o] = bp.cls.feedthrough_of(o, bp.params)
    return BlockFlow(sizes, frozenset(state_outputs), MappingProxyType(feedthrough))


def _residual_node(bp: BlockPorts, name):
    """Node of residual ``name``: an output of the block, or else an input."""
    return Node("out" if name in bp.outputs else "in", bp.path, name)


def _add_block(g, bp: BlockPorts, flow: BlockFlow):
    """Add the nodes of ``bp`` and its feedthrough and constraint edges to ``g``."""
    for o in bp.outputs:
        g.add_node(Node("out", bp.path, o))
    for i in bp.inputs:
        g.add_node(Node("in", bp.path, i))
    implicit = bp.cls.implicit
    for o, fts in flow.feedthrough.items():
        for i in fts:
            # an output may depend directly on an implicit output of its own block
            # (a contact force on the unknown multiplier)
            src = Node("out" if i in implicit else "in", bp.path, i)
            g.add_edge(src, Node("out", bp.path, o), kind="feedthrough")
    for o, (i, _guess) in implicit.items():
        # the residual is an input, or an output of the block computed from its inputs
        g.add_edge(_residual_node(bp, i), Node("out", bp.path, o), kind="constraint")


def check_constraints(pg: PortGraph, ps: PortSizes, flat):
    """Check that each implicit output's residual depends on it through the diagram.

    The residual ``i`` of the implicit output ``o`` must depend on ``o`` through a path that
    leaves the block by a wire, not only through the block's own ``o -> i`` feedthrough (a
    residual that is an output, equal to ``o`` when the constraint is inactive).

    Raises
    ------
    AlgebraicLoopError
        At the first block (in block order) whose constraint has nothing to solve.
    """
    for bp in ps.blocks.values():
        for o, (i, _guess) in bp.cls.implicit.items():
            src, res = Node("out", bp.path, o), _residual_node(bp, i)
            view = nx.restricted_view(pg.graph, (), [(src, res)])
            if not nx.has_path(view, src, res):
                inst = flat.blocks[bp.path]
                raise AlgebraicLoopError(
                    f"residual '{i}' does not depend on output '{o}' through the diagram: "
                    f"the constraint {i}({o}) = 0 has nothing to solve "
                    f"({_constraint_hint(bp, pg.flow[bp.path], o, i)})",
                    block=bp.path, file=inst.file, line=inst.line)


def check_sampled_loops(pg: PortGraph, ps: PortSizes, flat):
    """Check that no sampled block with a discrete-time feedthrough reads its own output.

    A block whose held output depends on the sample it takes
    (:meth:`~spidersim.blocks.base.Block.sample_feedthrough`) and whose output reaches its
    own input through wires and direct feedthrough only (no state between) would need its
    output to take its sample: a discrete algebraic loop, not solved (the sample would read
    the previous output, a delay nobody wrote).

    Raises
    ------
    AlgebraicLoopError
        At the first such block (in block order), walking the loop.
    """
    for bp in ps.blocks.values():
        if not bp.cls.sample_feedthrough(bp.params):
            continue
        ins = [Node("in", bp.path, i) for i in bp.inputs]
        for o in bp.outputs:
            src = Node("out", bp.path, o)
            if src not in pg.graph:
                continue
            reach = nx.descendants(pg.graph, src)
            back = next((n for n in ins if n in reach), None)
            if back is None:
                continue
            walk = " -> ".join(f"{n.path}.{n.port}"
                               for n in nx.shortest_path(pg.graph, src, back))
            inst = flat.blocks[bp.path]
            raise AlgebraicLoopError(
                f"discrete algebraic loop: {bp.cls.type_name} '{bp.path}' samples its input "
                f"from its own output through blocks without a state ({walk}): the value it "
                f"holds would depend on itself; spidersim does not solve it (the sample "
                f"would read the previous output, a delay the diagram does not show). Put a "
                f"UnitDelay (y[k] = u[k-1]) or a block with a state in the loop",
                block=bp.path, file=inst.file, line=inst.line)


def _constraint_hint(bp: BlockPorts, flow: BlockFlow, o, i):
    """What to wire so that residual ``i`` depends on implicit output ``o``."""
    if i in bp.outputs:
        outs = [x for x, fts in flow.feedthrough.items() if o in fts and x != i]
        ins = [x for x in flow.feedthrough.get(i, ()) if x in bp.inputs]
        return (f"wire its outputs computed from {o} ({', '.join(outs) or 'none'}) into the "
                f"blocks that produce its inputs {', '.join(ins)}")
    return f"wire {o} into the blocks that compute {i}"
