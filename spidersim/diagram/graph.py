"""Port sizes, the port-level graph, the evaluation schedule and the flat array layout.

Nodes of the graph are ``("out", block, port)`` and ``("in", block, port)``. Edges are the
wires (output -> input) and each block's declared direct feedthrough (input -> output). An
output that *is* a state has no incoming edge, so a cycle through a state is not a cycle of
this graph. Strongly connected components with more than one node are algebraic loops.

Schedule: the condensation is sorted topologically and walked node by node. Reaching an output
that is not yet valid emits a call of its block's ``output`` kernel; every output of that block
whose feedthrough inputs are all ready at that point becomes valid. Most blocks are called once;
a block whose outputs are needed at different depths (a motor whose speed feeds the loop that
computes its own voltage) is called once per depth.
"""
from __future__ import annotations

import difflib
import os
from dataclasses import dataclass, field

import networkx as nx
import numpy as np

from ..errors import AlgebraicLoopError, ParameterError, WiringError
from .flatten import Flat


@dataclass
class PortInfo:
    size: int
    unit: str
    kind: str                 # "out" | "in"
    loc: tuple | None = None  # ("x"|"sig", start, stop) for outputs


@dataclass
class BlockLayout:
    """Where a block's ports, states, modes and parameters live in the flat arrays."""

    path: str
    cls: type
    params: dict
    inputs: list
    outputs: list
    ports: dict = field(default_factory=dict)        # (kind, name) -> PortInfo
    states: dict = field(default_factory=dict)       # name -> (start, stop)
    modes: dict = field(default_factory=dict)        # name -> (start, stop)
    pslots: dict = field(default_factory=dict)       # param name -> (start, stop, shape)
    constants: dict = field(default_factory=dict)    # int/bool params
    feedthrough: dict = field(default_factory=dict)  # output -> tuple of inputs
    state_outputs: set = field(default_factory=set)
    input_src: dict = field(default_factory=dict)    # input -> ("x"|"sig", start, stop)
    guard_slice: tuple = (0, 0)                      # this block's events in the guard array
    event_sizes: list = field(default_factory=list)  # guards per declared event
    scratch: dict = field(default_factory=dict)      # name -> (start, stop) in sig


@dataclass
class Loop:
    """An algebraic loop: its ports, tear unknowns, inner calls and workspace."""

    index: int
    nodes: list                 # port nodes of the strongly connected component
    tears: list                 # (path, port, kind): kind "signal" or "constraint"
    calls: list                 # block paths, in evaluation order inside the loop
    walk: str                   # the loop port by port, for messages
    zslots: dict = field(default_factory=dict)   # (path, port) -> (start, stop) of z in sig
    zidx: list = field(default_factory=list)     # sig indices of all unknowns
    residual: list = field(default_factory=list)  # (kind, a, b) per unknown element
    names: list = field(default_factory=list)    # a name per unknown element
    ws0: int = 0                # offset in sig of its Newton workspace (newton.Workspace)


@dataclass
class Layout:
    blocks: dict                # path -> BlockLayout
    n_x: int
    n_sig: int
    n_p: int
    n_modes: int
    calls: list                 # schedule: ("call", path) or ("loop", k)
    loops: list                 # Loop
    graph: nx.DiGraph
    zero_slot: tuple
    p_loop_tol: tuple = (0, 0)  # p indices of the loop atol and rtol
    n_g: int = 0                # number of zero-crossing guards


def _out_size_spec(cls, name):
    return cls.output_decl(name).size


def infer_sizes(flat: Flat):
    """Port sizes of every block (declared, from parameters, or propagated along wires)."""
    info = {}
    for path, inst in flat.blocks.items():
        cls, prm = inst.cls, inst.params
        ins, outs = cls.input_names(prm), cls.output_names(prm)
        bl = BlockLayout(path, cls, prm, ins, outs)
        for n in ins:
            d = cls.input_decl(n)
            bl.ports[("in", n)] = PortInfo(cls.size_of(d.size, prm), cls.unit_of(d, prm), "in")
        for n in outs:
            d = cls.output_decl(n)
            bl.ports[("out", n)] = PortInfo(cls.size_of(d.size, prm), cls.unit_of(d, prm),
                                            "out")
        info[path] = bl

    # wiring checks: known ports, single source per input
    dst_seen = {}
    for c in flat.conns:
        sp, sport, s0, s1 = c.src
        dp, dport = c.dst
        if sp not in info:
            raise WiringError(f"unknown block '{sp}'", file=c.file, line=c.line)
        if dp not in info:
            raise WiringError(f"unknown block '{dp}'", file=c.file, line=c.line)
        for path, port, kind in ((sp, sport, "out"), (dp, dport, "in")):
            bl = info[path]
            if (kind, port) not in bl.ports:
                names = bl.outputs if kind == "out" else bl.inputs
                other = bl.inputs if kind == "out" else bl.outputs
                near = difflib.get_close_matches(port, names, n=2)
                hint = f"; did you mean {', '.join(near)}?" if near else ""
                extra = (f" ('{port}' is an {'input' if kind == 'out' else 'output'})"
                         if port in other else "")
                word = "output" if kind == "out" else "input"
                raise WiringError(
                    f"block '{path}' ({bl.cls.type_name}) has no {word} '{port}'{extra}{hint}; "
                    f"{word}s: {', '.join(names) or 'none'}", file=c.file, line=c.line,
                    block=path)
        if (dp, dport) in dst_seen:
            first = dst_seen[(dp, dport)]
            raise WiringError(f"input '{dp}.{dport}' has two sources: '{_src_text(first)}' "
                              f"(line {first.line}) and '{_src_text(c)}'",
                              file=c.file, line=c.line, block=dp)
        dst_seen[(dp, dport)] = c

    # propagate sizes to a fixed point
    def out_size(path, port):
        return info[path].ports[("out", port)].size

    changed = True
    while changed:
        changed = False
        for bl in info.values():
            for n in bl.outputs:
                pi = bl.ports[("out", n)]
                if pi.size is not None:
                    continue
                spec = _out_size_spec(bl.cls, n)
                if isinstance(spec, str) and spec.startswith("@"):
                    pi.size = bl.ports[("in", spec[1:])].size
                elif spec is not None and hasattr(spec, "fn") and hasattr(spec, "text") \
                        and spec.fn.__code__.co_argcount == 2:
                    sizes = {m: bl.ports[("in", m)].size for m in bl.inputs}
                    if all(v is not None for v in sizes.values()):
                        pi.size = int(spec.fn(bl.params, sizes))
                changed |= pi.size is not None
        for c in flat.conns:
            sp, sport, s0, s1 = c.src
            n_src = out_size(sp, sport)
            if n_src is None:
                continue
            if s0 is not None:
                a, b = _norm_slice(s0, s1, n_src, c)
                width = b - a
            else:
                width = n_src
            dpi = info[c.dst[0]].ports[("in", c.dst[1])]
            if dpi.size is None:
                dpi.size = width
                changed = True
            elif dpi.size != width:
                raise WiringError(
                    f"size mismatch on '{c.text}': the source gives {width} element(s), "
                    f"input '{c.dst[0]}.{c.dst[1]}' expects {dpi.size}", file=c.file,
                    line=c.line, block=c.dst[0])
        if not changed:
            changed = _seed_one_size(info)
    for bl in info.values():
        for n in bl.inputs:
            pi = bl.ports[("in", n)]
            connected = (bl.path, n) in dst_seen
            if not connected:
                optional = bl.cls.input_decl(n).optional
                if callable(optional):
                    optional = optional(bl.params)
                if optional:
                    if pi.size is None:
                        pi.size = 1
                    continue
                exposed = flat.exposed.get((bl.path, n))
                if exposed is not None and exposed[0] in flat.instances:
                    inst_path, name, sub_file, sub_line = exposed
                    typ, file, line = flat.instances[inst_path]
                    raise WiringError(
                        f"input '{name}' of subsystem instance '{inst_path}' (type '{typ}') "
                        f"is not connected; it feeds {bl.path}.{n} "
                        f"({os.path.basename(sub_file)}:{sub_line}). Connect it: "
                        f"'some_block.y -> {inst_path.rpartition('.')[2]}.{name}'",
                        file=file, line=line, block=inst_path)
                inst = flat.blocks[bl.path]
                raise WiringError(_unconnected_msg(info, flat, bl, n), block=bl.path,
                                  file=inst.file, line=inst.line)
        for n in bl.outputs:
            if bl.ports[("out", n)].size is None:
                inst = flat.blocks[bl.path]
                raise WiringError(f"cannot infer the size of output '{n}': connect the "
                                  f"inputs it follows", block=bl.path, file=inst.file,
                                  line=inst.line)
        sizes = {n: bl.ports[("in", n)].size for n in bl.inputs}
        sizes.update({n: bl.ports[("out", n)].size for n in bl.outputs})
        try:
            bl.cls.check_sizes(bl.params, sizes)
        except ValueError as exc:
            inst = flat.blocks[bl.path]
            raise ParameterError(str(exc), block=bl.path, file=inst.file,
                                 line=inst.line) from None
    return info, dst_seen


def _seed_one_size(info):
    """Set one still-unknown input size from its block's ``fallback_sizes``; True if one
    was set (propagation then resumes, so a seed never overrides what wiring decides)."""
    for bl in info.values():
        fb = None
        for n in bl.inputs:
            pi = bl.ports[("in", n)]
            if pi.size is None:
                fb = bl.cls.fallback_sizes(bl.params) if fb is None else fb
                if n in fb:
                    pi.size = int(fb[n])
                    return True
    return False


def _src_text(c):
    sp, sport, s0, s1 = c.src
    return f"{sp}.{sport}" + ("" if s0 is None else f"[{s0}:{s1}]")


def _norm_slice(s0, s1, n, c):
    a = s0 + n if s0 < 0 else s0
    b = s1 + n if s1 is not None and s1 < 0 else (n if s1 is None else s1)
    if not (0 <= a < b <= n):
        raise WiringError(f"element range [{s0}:{s1}] is outside output "
                          f"'{c.src[0]}.{c.src[1]}' of size {n}", file=c.file, line=c.line,
                          block=c.src[0])
    return a, b


def _unconnected_msg(info, flat, bl, name):
    pi = bl.ports[("in", name)]
    cand = []
    for other in info.values():
        if other.path == bl.path:
            continue
        for o in other.outputs:
            po = other.ports[("out", o)]
            loose = ("1", "*")        # declared units only: inference runs later
            if (pi.size is None or po.size == pi.size) and (
                    pi.unit in loose or po.unit in loose or "@" in pi.unit + po.unit
                    or po.unit == pi.unit):
                fixed = po.unit != "*" and "@" not in po.unit
                cand.append(f"{other.path}.{o}" + (f" [{po.unit}]" if fixed else ""))
    size = "any size" if pi.size is None else f"size {pi.size}"
    hint = (f"; outputs of matching size and unit: {', '.join(cand[:8])}"
            + (" ..." if len(cand) > 8 else "")) if cand else "; no output matches it"
    decl = bl.cls.input_decl(name)
    why = f" ({decl.doc}, with these parameters)" if callable(decl.optional) else ""
    return f"input '{name}' [{pi.unit}, {size}] is not connected{why}{hint}"


def build_layout(flat: Flat) -> Layout:
    """Sizes, graph, schedule and offsets of every port, state, mode and parameter."""
    info, dst_seen = infer_sizes(flat)
    g = nx.DiGraph()
    for bl in info.values():
        prm = bl.params
        state_sizes = {}
        for s, decl in bl.cls.states.items():
            spec = decl.size
            if isinstance(spec, str) and spec.startswith("@"):
                n = bl.ports[("in", spec[1:])].size
            else:
                n = bl.cls.size_of(spec, prm)
            state_sizes[s] = n
        bl.states = state_sizes  # sizes for now, offsets later
        for o in bl.outputs:
            g.add_node(("out", bl.path, o))
            if o in state_sizes and state_sizes[o] == bl.ports[("out", o)].size:
                bl.state_outputs.add(o)
                bl.feedthrough[o] = ()
            else:
                bl.feedthrough[o] = bl.cls.feedthrough_of(o, prm)
        for i in bl.inputs:
            g.add_node(("in", bl.path, i))
        implicit = bl.cls.implicit
        for o, fts in bl.feedthrough.items():
            for i in fts:
                # an output may depend directly on an implicit output of its own block
                # (a contact force on the unknown multiplier)
                src = ("out", bl.path, i) if i in implicit else ("in", bl.path, i)
                g.add_edge(src, ("out", bl.path, o), kind="feedthrough")
        for o, (i, _guess) in implicit.items():
            # the residual is an input, or an output of the block computed from its inputs
            src = ("out", bl.path, i) if i in bl.outputs else ("in", bl.path, i)
            g.add_edge(src, ("out", bl.path, o), kind="constraint")
    for (dp, dport), c in dst_seen.items():
        g.add_edge(("out", c.src[0], c.src[1]), ("in", dp, dport), kind="wire",
                   line=c.line, file=c.file)

    for bl in info.values():
        for o, (i, _g) in bl.cls.implicit.items():
            _check_constraint_closed(g, bl, o, i, flat.blocks[bl.path])
    comps = [c for c in nx.strongly_connected_components(g) if len(c) > 1]
    loops = [_make_loop(k, g, sorted(c), info, dst_seen) for k, c in enumerate(
        sorted(comps, key=lambda c: sorted(c)[0]))]
    node_loop = {n: lp for lp in loops for n in lp.nodes}

    # schedule over the condensation
    cond = nx.condensation(g, scc=[set(lp.nodes) for lp in loops] + [
        {n} for n in g.nodes if n not in node_loop])
    valid, calls = set(), []
    for cnode in nx.topological_sort(cond):
        members = cond.nodes[cnode]["members"]
        first = next(iter(members))
        if first in node_loop:
            lp = node_loop[first]
            calls.append(("loop", lp.index))
            valid.update(n for n in lp.nodes if n[0] == "out")
            continue
        kind, path, port = first
        if kind == "in" or port in info[path].state_outputs or first in valid:
            continue
        calls.append(("call", path))
        _mark_valid(info[path], valid, dst_seen, info)
        assert first in valid, first

    # offsets: states, signals (in first-call order), modes, parameters
    n_x = 0
    for bl in info.values():
        offs = {}
        for s, n in bl.states.items():
            offs[s] = (n_x, n_x + n)
            n_x += n
        bl.states = offs
    n_sig = 0
    seen = set()
    call_paths = [c[1] for c in calls if c[0] == "call"]
    for lp in loops:
        call_paths += lp.calls
    for path in call_paths + [p for p in info if p not in call_paths]:
        if path in seen:
            continue
        seen.add(path)
        bl = info[path]
        for o in bl.outputs:
            pi = bl.ports[("out", o)]
            if o in bl.state_outputs:
                pi.loc = ("x",) + bl.states[o]
            else:
                pi.loc = ("sig", n_sig, n_sig + pi.size)
                n_sig += pi.size
    max_opt = max([bl.ports[("in", i)].size for bl in info.values() for i in bl.inputs
                   if (bl.path, i) not in dst_seen] + [0])
    zero_slot = ("sig", n_sig, n_sig + max_opt)
    n_sig += max_opt
    for bl in info.values():
        for name, spec in bl.cls.scratch.items():
            n = bl.cls.size_of(spec, bl.params)
            bl.scratch[name] = (n_sig, n_sig + n)
            n_sig += n
    from ..solver.newton import Workspace
    for lp in loops:
        for path, port, kind in lp.tears:
            pi = info[path].ports[("out", port)]
            if kind == "signal":
                lp.zslots[(path, port)] = (n_sig, n_sig + pi.size)
                n_sig += pi.size
            else:
                lp.zslots[(path, port)] = pi.loc[1:]
    n_modes = 0
    n_p = 0
    n_g = 0
    for bl in info.values():
        sizes = []
        for ev in bl.cls.events.values():
            spec = ev.size
            if ev.when is not None and not bl.params[ev.when]:
                sizes.append(0)
            elif isinstance(spec, str) and spec.startswith("@"):
                sizes.append(bl.ports[("in", spec[1:])].size)
            else:
                sizes.append(bl.cls.size_of(spec, bl.params))
        bl.event_sizes = sizes
        ne = sum(sizes)
        if ne:
            if not bl.states and not bl.cls.modes:
                inst = flat.blocks[bl.path]
                raise ParameterError(
                    f"block type {bl.cls.type_name} declares events "
                    f"({', '.join(bl.cls.events)}) but has no states or modes for them to "
                    f"change", block=bl.path, file=inst.file, line=inst.line)
            for k in ("guard", "on_event"):
                if not bl.cls.has_kernel(k):
                    raise RuntimeError(f"block type {bl.cls.type_name} declares events but "
                                       f"has no '{k}' kernel")
        bl.guard_slice = (n_g, n_g + ne)
        n_g += ne
        for m, decl in bl.cls.modes.items():
            if isinstance(decl.size, str) and decl.size.startswith("@"):
                n = bl.ports[("in", decl.size[1:])].size
            else:
                n = bl.cls.size_of(decl.size, bl.params)
            bl.modes[m] = (n_modes, n_modes + n)
            n_modes += n
        numeric = dict(bl.params)
        numeric.update(bl.cls.derive(bl.params))
        bl.params = numeric
        for name, v in numeric.items():
            decl = bl.cls.parameters.get(name)
            if decl is not None and decl.kind in ("int", "bool"):
                bl.constants[name] = v
                continue
            if isinstance(v, str):
                continue
            arr = np.asarray(v, dtype=float)
            shape = "scalar" if (decl is not None and decl.shape == ()) or (
                decl is None and arr.ndim == 0) else arr.shape
            bl.pslots[name] = (n_p, n_p + arr.size, shape)
            n_p += arr.size
        for i in bl.inputs:
            c = dst_seen.get((bl.path, i))
            n = bl.ports[("in", i)].size
            if c is None:
                bl.input_src[i] = (zero_slot[0], zero_slot[1], zero_slot[1] + n)
                continue
            src_loc = info[c.src[0]].ports[("out", c.src[1])].loc
            zs = _tear_slot(loops, c.src[0], c.src[1])
            if zs is not None:
                src_loc = ("sig",) + zs
            s0, s1 = c.src[2], c.src[3]
            if s0 is not None:
                a, b = _norm_slice(s0, s1, src_loc[2] - src_loc[1], c)
                bl.input_src[i] = (src_loc[0], src_loc[1] + a, src_loc[1] + b)
            else:
                bl.input_src[i] = src_loc
    for lp in loops:
        for path, port, kind in lp.tears:
            a, b = lp.zslots[(path, port)]
            lp.zidx += list(range(a, b))
            if kind == "signal":
                o0 = info[path].ports[("out", port)].loc[1]
                lp.residual += [("signal", a + k, o0 + k) for k in range(b - a)]
                lp.names += [f"{path}.{port}" + (f"[{k}]" if b - a > 1 else "")
                             for k in range(b - a)]
            else:
                f = info[path].cls.implicit[port][0]
                if f in info[path].input_src:
                    arr, fa, fb = info[path].input_src[f]
                else:                          # the residual is an output of the block
                    arr, fa, fb = info[path].ports[("out", f)].loc
                lp.residual += [("constraint", fa + k, None) for k in range(fb - fa)]
                lp.names += [f"{path}.{f}" + (f"[{k}]" if fb - fa > 1 else "")
                             for k in range(fb - fa)]
        lp.ws0 = n_sig
        n_sig += Workspace(len(lp.zidx)).size
    p_tol = (n_p, n_p + 1)
    n_p += 2
    return Layout(info, n_x, n_sig, n_p, n_modes, calls, loops, g, zero_slot, p_tol, n_g)


def _tear_slot(loops, path, port):
    for lp in loops:
        if (path, port) in lp.zslots and any(
                t[0] == path and t[1] == port and t[2] == "signal" for t in lp.tears):
            return lp.zslots[(path, port)]
    return None


def _mark_valid(bl, valid, dst_seen, info, known=()):
    """After a call of ``bl``: mark each output whose feedthrough inputs are all ready."""
    path = bl.path
    ready = set()
    for i in bl.inputs:
        c = dst_seen.get((path, i))
        src = None if c is None else ("out", c.src[0], c.src[1])
        if c is None or src in valid or src in known or \
                c.src[1] in info[c.src[0]].state_outputs:
            ready.add(i)
    for o in bl.cls.implicit:
        if ("out", path, o) in known or ("out", path, o) in valid:
            ready.add(o)                       # a solved (torn) unknown of the block
    for o in bl.outputs:
        if o not in bl.state_outputs and all(i in ready for i in bl.feedthrough[o]):
            valid.add(("out", path, o))


def _choose_tears(sub):
    """Greedy feedback set over output ports: tear the output with the largest
    (in-degree x out-degree) inside the remaining cycles until none is left."""
    sub = sub.copy()
    tears = []
    while True:
        cyc = [c for c in nx.strongly_connected_components(sub) if len(c) > 1]
        if not cyc:
            return tears
        cands = [n for c in cyc for n in c if n[0] == "out"]
        best = max(cands, key=lambda n: (sub.in_degree(n) * sub.out_degree(n), n))
        tears.append(best)
        sub.remove_edges_from(list(sub.out_edges(best)))


def _check_constraint_closed(g, bl, o, i, inst):
    """The residual ``i`` of the implicit output ``o`` must depend on ``o`` through the
    diagram (a path that leaves the block by a wire), not only through the block's own
    ``o -> i`` feedthrough (a residual that is an output, equal to ``o`` when the
    constraint is inactive)."""
    res = ("out", bl.path, i) if i in bl.outputs else ("in", bl.path, i)
    src = ("out", bl.path, o)
    direct = g.has_edge(src, res)
    if direct:
        data = g.edges[src, res]
        g.remove_edge(src, res)
    try:
        closed = nx.has_path(g, src, res)
    finally:
        if direct:
            g.add_edge(src, res, **data)
    if closed:
        return
    if i in bl.outputs:
        outs = [x for x, fts in bl.feedthrough.items() if o in fts and x != i]
        ins = [x for x in bl.feedthrough.get(i, ()) if x in bl.inputs]
        hint = (f"wire its outputs computed from {o} ({', '.join(outs) or 'none'}) into the "
                f"blocks that produce its inputs {', '.join(ins)}")
    else:
        hint = f"wire {o} into the blocks that compute {i}"
    raise AlgebraicLoopError(
        f"residual '{i}' does not depend on output '{o}' through the diagram: the "
        f"constraint {i}({o}) = 0 has nothing to solve ({hint})",
        block=bl.path, file=inst.file, line=inst.line)


def _make_loop(k, g, nodes, info, dst_seen):
    sub = g.subgraph(nodes).copy()
    forced = [n for n in nodes if n[0] == "out" and n[2] in getattr(
        info[n[1]].cls, "implicit", {})]
    for n in forced:
        sub.remove_edges_from(list(sub.out_edges(n)))
    tears = forced + _choose_tears(sub)
    for n in tears:
        sub.remove_edges_from(list(sub.out_edges(n)))
    valid = set()
    known = set(tears)
    calls = []
    for node in nx.topological_sort(sub):
        kind, path, port = node
        if kind == "in" or node in valid or node in forced:
            continue
        calls.append(path)
        # inputs fed from outside the loop are ready; so are torn signals
        outside = {n for n in nodes}
        _mark_valid(info[path], valid, dst_seen, info,
                    known=known | {("out", c.src[0], c.src[1]) for c in dst_seen.values()
                                   if ("out", c.src[0], c.src[1]) not in outside})
    tear_list = [(n[1], n[2], "constraint" if n in forced else "signal") for n in tears]
    return Loop(k, nodes, tear_list, calls, describe_loops(g, [nodes]))


def describe_loops(g, loops):
    """Walk each loop port by port: ``a.y -> b.u => b.y -> a.u => a.y`` (``->`` a wire,
    ``=>`` a block's direct feedthrough)."""
    lines = []
    for comp in loops:
        sub = g.subgraph(comp)
        cycle = nx.find_cycle(sub)
        text = f"{cycle[0][0][1]}.{cycle[0][0][2]}"
        for u, v in cycle:
            arrow = "->" if g.edges[u, v].get("kind") == "wire" else "=>"
            text += f" {arrow} {v[1]}.{v[2]}"
        lines.append(f"{len(comp)} ports: {text}")
    return "\n".join(lines)


def jacobian_sparsity(layout: Layout):
    """Boolean (n_x, n_x) pattern: which states can move each state's derivative."""
    info = layout.blocks
    g = layout.graph
    # states each port depends on, component by component of the condensation (a loop is
    # one component: each of its ports depends on everything the loop reads)
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
    deps = {node: comp_deps[mapping[node]] for node in g.nodes}
    pattern = np.zeros((layout.n_x, layout.n_x), dtype=bool)
    for bl in info.values():
        cols = set()
        for a, b in bl.states.values():
            cols.update(range(a, b))
        for i in bl.inputs:
            cols |= deps[("in", bl.path, i)]
        for a, b in bl.states.values():
            for c in cols:
                pattern[a:b, c] = True
    return pattern
