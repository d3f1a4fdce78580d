"""Layout pass 3: algebraic loops, their tear variables and the evaluation schedule.

Contract
--------
1. :func:`schedule` ``(pg: PortGraph, ps: PortSizes) -> Schedule`` is the pass; it does not
   modify its inputs.
2. Strongly connected components of the port graph with more than one node are algebraic
   loops, numbered in the order of their smallest node.
3. Tears of a loop (:func:`plan_loop`): every implicit output of the loop (kind
   ``"constraint"``), then outputs chosen greedily until no cycle is left (kind
   ``"signal"``, :func:`choose_tears`). The calls inside the loop follow the torn loop's
   topological order.
4. Schedule: the condensation (one node per loop, one per other port) is sorted
   topologically and walked node by node. Reaching an output that is not yet valid emits a
   call of its block; every output of that block whose feedthrough inputs are all ready
   becomes valid (:func:`outputs_after_call`). A loop emits one ``("loop", k)`` step and
   makes all its outputs valid. Most blocks are called once; a block whose outputs are
   needed at different depths (a motor whose speed feeds the loop that computes its own
   voltage) is called once per depth.
5. A call is *partial* (``Schedule.partial``, step indices) when every output it makes valid
   has no feedthrough and the same block is called again later: the block's kernel may then
   skip the work of its other outputs (``inputs_ready`` in :mod:`spidersim.blocks.base`).
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import NamedTuple

import networkx as nx

from .portgraph import Node, PortGraph
from .sizes import PortSizes


class Tear(NamedTuple):
    """A loop unknown: output ``port`` of block ``path``; ``kind`` is ``"signal"`` (a torn
    output) or ``"constraint"`` (an implicit output solved for its residual)."""

    path: str
    port: str
    kind: str


class Step(NamedTuple):
    """One schedule item: ``("call", block path)`` or ``("loop", loop index)``."""

    kind: str
    what: object


@dataclass(frozen=True)
class LoopPlan:
    """An algebraic loop as pass 3 finds it (slots come in pass 4).

    Attributes
    ----------
    index : int
        Loop number.
    nodes : tuple of Node
        Ports of the strongly connected component, sorted.
    tears : tuple of Tear
        Unknowns: constraint tears first, then signal tears.
    calls : tuple of str
        Block paths called inside the loop, in evaluation order.
    walk : str
        The loop port by port, for messages (:func:`describe_loops`).
    """

    index: int
    nodes: tuple
    tears: tuple
    calls: tuple
    walk: str


@dataclass(frozen=True)
class Schedule:
    """Result of pass 3: ``steps`` (tuple of Step), ``loops`` (tuple of LoopPlan) and
    ``partial`` (frozenset of the indices of partial calls in ``steps``, contract item 5)."""

    steps: tuple
    loops: tuple
    partial: frozenset = frozenset()


def schedule(pg: PortGraph, ps: PortSizes) -> Schedule:
    """Pass 3: find the algebraic loops, tear them and order the calls.

    Parameters
    ----------
    pg : PortGraph
        Result of pass 2.
    ps : PortSizes
        Result of pass 1.

    Returns
    -------
    Schedule
    """
    loops = find_loops(pg, ps)
    steps, partial = call_order(pg, ps, loops)
    return Schedule(steps, loops, partial)


def find_loops(pg: PortGraph, ps: PortSizes):
    """The algebraic loops of the port graph, planned (contract items 2 and 3).

    Returns
    -------
    tuple of LoopPlan
        Numbered in the order of their smallest node.
    """
    g = pg.graph
    comps = [c for c in nx.strongly_connected_components(g) if len(c) > 1]
    return tuple(plan_loop(k, g, tuple(sorted(c)), pg, ps) for k, c in enumerate(
        sorted(comps, key=lambda c: sorted(c)[0])))


def call_order(pg: PortGraph, ps: PortSizes, loops):
    """The schedule (contract item 4): a tuple of :class:`Step`, and the frozenset of the
    indices of its partial calls (item 5)."""
    g = pg.graph
    node_loop = {n: lp for lp in loops for n in lp.nodes}
    cond = nx.condensation(g, scc=[set(lp.nodes) for lp in loops] + [
        {n} for n in g.nodes if n not in node_loop])
    valid, steps, direct = set(), [], []
    for cnode in nx.topological_sort(cond):
        first = Node(*next(iter(cond.nodes[cnode]["members"])))
        if first in node_loop:
            lp = node_loop[first]
            steps.append(Step("loop", lp.index))
            direct.append(True)
            valid.update(n for n in lp.nodes if n.kind == "out")
        elif _needs_call(first, pg, valid):
            steps.append(Step("call", first.path))
            new = outputs_after_call(first.path, pg, ps, valid) - valid
            feedthrough = pg.flow[first.path].feedthrough
            direct.append(any(feedthrough[n.port] for n in new))
            valid |= new
            assert first in valid, first
    return tuple(steps), partial_calls(steps, direct)


def partial_calls(steps, direct):
    """Indices of the partial calls (contract item 5): call ``i`` made only outputs
    without feedthrough valid (``direct[i]`` False) and its block is called again later."""
    later, partial = set(), set()
    for i in range(len(steps) - 1, -1, -1):
        if steps[i].kind == "call":
            if not direct[i] and steps[i].what in later:
                partial.add(i)
            later.add(steps[i].what)
    return frozenset(partial)


def _needs_call(node, pg: PortGraph, valid):
    """True if ``node`` is an output, not a state, not yet computed."""
    return node.kind == "out" and node.port not in pg.flow[node.path].state_outputs \
        and node not in valid


def outputs_after_call(path, pg: PortGraph, ps: PortSizes, available):
    """Outputs of block ``path`` that one call computes.

    Parameters
    ----------
    path : str
        The block called.
    pg, ps : PortGraph, PortSizes
        Results of passes 2 and 1.
    available : set of Node
        Outputs already valid (or known: torn unknowns, values from outside a loop).

    Returns
    -------
    set of Node
        Each output of the block, not a state, whose feedthrough inputs (and implicit
        outputs) are all ready: unconnected, fed by an available output or by a state.
    """
    bp, flow = ps.blocks[path], pg.flow[path]
    ready = set()
    for i in bp.inputs:
        c = ps.source(path, i)
        if c is None or Node("out", c.src[0], c.src[1]) in available or \
                c.src[1] in pg.flow[c.src[0]].state_outputs:
            ready.add(i)
    for o in bp.cls.implicit:
        if Node("out", path, o) in available:
            ready.add(o)                       # a solved (torn) unknown of the block
    return {Node("out", path, o) for o in bp.outputs if o not in flow.state_outputs
            and all(i in ready for i in flow.feedthrough[o])}


def choose_tears(sub):
    """Greedy feedback set over output ports.

    Tear the output with the largest (in-degree x out-degree) inside the remaining cycles
    (ties: the largest node) until no cycle is left. ``sub`` is not modified.

    Returns
    -------
    list of Node
    """
    sub = sub.copy()
    tears = []
    while True:
        cyc = [c for c in nx.strongly_connected_components(sub) if len(c) > 1]
        if not cyc:
            return tears
        cands = [n for c in cyc for n in c if n.kind == "out"]
        best = max(cands, key=lambda n: (sub.in_degree(n) * sub.out_degree(n), n))
        tears.append(best)
        sub.remove_edges_from(list(sub.out_edges(best)))


def plan_loop(k, g, nodes, pg: PortGraph, ps: PortSizes) -> LoopPlan:
    """Tears and inner calls of the loop ``k`` made of the ports ``nodes`` (sorted)."""
    sub = g.subgraph(nodes).copy()
    forced = [n for n in nodes if n.kind == "out"
              and n.port in getattr(ps.blocks[n.path].cls, "implicit", {})]
    for n in forced:
        sub.remove_edges_from(list(sub.out_edges(n)))
    tears = forced + choose_tears(sub)
    for n in tears:
        sub.remove_edges_from(list(sub.out_edges(n)))
    # inputs fed from outside the loop are ready; so are torn signals
    outside = {Node("out", c.src[0], c.src[1]) for c in ps.sources.values()} - set(nodes)
    known = set(tears) | outside
    valid, calls = set(), []
    for node in nx.topological_sort(sub):
        if node.kind == "in" or node in valid or node in forced:
            continue
        calls.append(node.path)
        valid |= outputs_after_call(node.path, pg, ps, valid | known)
    tear_list = tuple(Tear(n.path, n.port, "constraint" if n in forced else "signal")
                      for n in tears)
    return LoopPlan(k, nodes, tear_list, tuple(calls), describe_loops(g, [nodes]))


def describe_loops(g, loops):
    """Walk each loop port by port: ``a.y -> b.u => b.y -> a.u => a.y`` (``->`` a wire,
    ``=>`` a block's direct feedthrough)."""
    lines = []
    for comp in loops:
        # a plain graph in a fixed order (a subgraph view iterates the component's set,
        # whose order changes with the hash seed): the same walk in every process
        nodes = sorted(comp)
        sub = nx.DiGraph()
        sub.add_nodes_from(nodes)
        sub.add_edges_from((u, v) for u, v in g.edges if u in comp and v in comp)
        cycle = nx.find_cycle(sub, source=nodes[0])
        text = f"{cycle[0][0][1]}.{cycle[0][0][2]}"
        for u, v in cycle:
            arrow = "->" if g.edges[u, v].get("kind") == "wire" else "=>"
            text += f" {arrow} {v[1]}.{v[2]}"
        lines.append(f"{len(comp)} ports: {text}")
    return "\n".join(lines)
