"""Layout pass 4: slots of every state, signal, parameter, mode, guard and loop workspace.

Contract
--------
1. :func:`allocate` ``(flat, ps, pg, sched) -> Slots`` is the pass; it does not modify its
   inputs. Each step below takes the next free index of its array and returns its slots
   and the new next free index.
2. ``x`` (states): block by block, states in declaration order.
3. ``sig`` (signals), in this order: the outputs that are not states, block by block in
   first-call order (scheduled calls, then loop calls, then blocks never called); one zero
   slot as long as the longest unconnected input; each block's scratch arrays; one slot per
   signal tear; finally, after the per-block step 4, each loop's Newton workspace.
4. Per block, in block order: guards (``g``, one per zero-crossing event element), modes,
   and parameters (``p``: every real parameter, derived ones included; integers and
   booleans become literal constants). Then two ``p`` entries for the loops' atol and rtol.
5. Input sources: each input reads its source's slot (the tear's slot for a signal tear),
   narrowed to the connection's element range, or the zero slot if unconnected.
6. Loop unknowns: each loop's unknown indices, residual terms and element names.
"""
from __future__ import annotations

from dataclasses import dataclass
from types import MappingProxyType
from typing import Mapping, NamedTuple

import numpy as np

from ..errors import ParameterError
from ..solver.newton import Workspace
from .portgraph import PortGraph
from .schedule import Schedule
from .sizes import BlockPorts, PortSizes, norm_slice


class Span(NamedTuple):
    """Indices ``start:stop`` of one array."""

    start: int
    stop: int


class Loc(NamedTuple):
    """Indices ``start:stop`` of array ``array`` (``"x"`` or ``"sig"``)."""

    array: str
    start: int
    stop: int


class ParamSlot(NamedTuple):
    """``p[start:stop]`` holds a parameter of ``shape`` (``"scalar"`` or a tuple)."""

    start: int
    stop: int
    shape: object


class Residual(NamedTuple):
    """One element of a loop residual: ``sig[index] - sig[other]`` for kind ``"signal"``
    (a tear against the output recomputed from it), ``sig[index]`` for ``"constraint"``
    (``other`` is None)."""

    kind: str
    index: int
    other: object


@dataclass(frozen=True)
class BlockSlots:
    """Where one block's values live.

    Attributes
    ----------
    states, modes, scratch : Mapping
        ``name -> Span`` in ``x``, ``modes`` and ``sig``.
    outputs : Mapping
        ``output -> Loc`` (in ``x`` for a state output).
    input_src : Mapping
        ``input -> Loc`` it reads.
    guards : Span
        The block's zero-crossing guards in ``g``.
    event_sizes : tuple of int
        Guards per declared event.
    params : dict
        Validated parameters merged with the derived ones (what the kernels see).
    pslots : Mapping
        ``parameter -> ParamSlot`` in ``p``.
    constants : Mapping
        Integer and boolean parameters (literals in the generated code).
    """

    states: Mapping
    modes: Mapping
    scratch: Mapping
    outputs: Mapping
    input_src: Mapping
    guards: Span
    event_sizes: tuple
    params: dict
    pslots: Mapping
    constants: Mapping


@dataclass(frozen=True)
class LoopSlots:
    """Unknowns and workspace of one loop.

    Attributes
    ----------
    zslots : Mapping
        ``(path, port) -> Span`` in ``sig`` of each tear (a constraint tear is solved in
        place, in its output's slot).
    zidx : tuple of int
        ``sig`` indices of all unknowns.
    residual : tuple of Residual
        One term per unknown element.
    names : tuple of str
        A name per unknown element.
    ws0 : int
        Start of the Newton workspace in ``sig``.
    """

    zslots: Mapping
    zidx: tuple
    residual: tuple
    names: tuple
    ws0: int


@dataclass(frozen=True)
class Slots:
    """Result of pass 4: per-block and per-loop slots and the array lengths."""

    blocks: Mapping
    loops: tuple
    n_x: int
    n_sig: int
    n_p: int
    n_modes: int
    n_g: int
    zero_slot: Loc
    p_loop_tol: Span


@dataclass(frozen=True)
class _Numbers:
    """Step 4 of the contract for one block."""

    guards: Span
    event_sizes: tuple
    modes: Mapping
    params: dict
    pslots: Mapping
    constants: Mapping


def allocate(flat, ps: PortSizes, pg: PortGraph, sched: Schedule) -> Slots:
    """Pass 4: allocate every slot (see the module contract).

    Parameters
    ----------
    flat : Flat
        The flat diagram (file and line of each block, for errors).
    ps, pg, sched : PortSizes, PortGraph, Schedule
        Results of passes 1 to 3.

    Returns
    -------
    Slots

    Raises
    ------
    ParameterError
        A block declares events but has neither states nor modes.
    """
    states, n_x = state_slots(ps, pg, 0)
    outputs, n_sig = output_slots(ps, pg, sched, states, 0)
    zero_slot, n_sig = zero_slot_of(ps, n_sig)
    scratch, n_sig = scratch_slots(ps, n_sig)
    tears, n_sig = tear_slots(ps, sched, outputs, n_sig)
    numbers, n_g, n_modes, n_p = {}, 0, 0, 0
    for bp in ps.blocks.values():
        numbers[bp.path], n_g, n_modes, n_p = block_numbers(
            bp, ps, pg, flat.blocks[bp.path], n_g, n_modes, n_p)
    p_loop_tol = Span(n_p, n_p + 1)
    n_p += 2
    signal_tears = {}
    for lp, zs in zip(sched.loops, tears):
        for t in lp.tears:
            if t.kind == "signal":
                signal_tears.setdefault((t.path, t.port), zs[(t.path, t.port)])
    inputs = {path: input_sources(bp, ps, outputs, signal_tears, zero_slot)
              for path, bp in ps.blocks.items()}
    loops = []
    for lp, zs in zip(sched.loops, tears):
        slots, n_sig = loop_unknowns(lp, zs, ps, outputs, inputs, n_sig)
        loops.append(slots)
    blocks = {path: BlockSlots(states[path], numbers[path].modes, scratch[path], outputs[path],
                               inputs[path], numbers[path].guards, numbers[path].event_sizes,
                               numbers[path].params, numbers[path].pslots,
                               numbers[path].constants)
              for path in ps.blocks}
    return Slots(MappingProxyType(blocks), tuple(loops), n_x, n_sig, n_p, n_modes, n_g,
                 zero_slot, p_loop_tol)


def state_slots(ps: PortSizes, pg: PortGraph, n_x):
    """``(path -> {state: Span}, next free x index)``: states block by block."""
    out = {}
    for path in ps.blocks:
        spans = {}
        for s, n in pg.flow[path].state_sizes.items():
            spans[s] = Span(n_x, n_x + n)
            n_x += n
        out[path] = MappingProxyType(spans)
    return out, n_x


def signal_order(ps: PortSizes, sched: Schedule):
    """Block paths in first-call order: scheduled calls, loop calls, blocks never called."""
    paths = [s.what for s in sched.steps if s.kind == "call"]
    for lp in sched.loops:
        paths += lp.calls
    paths += [p for p in ps.blocks if p not in paths]
    return list(dict.fromkeys(paths))


def output_slots(ps: PortSizes, pg: PortGraph, sched: Schedule, states, n_sig):
    """``(path -> {output: Loc}, next free sig index)``: state outputs point at their
    state; other outputs get ``sig`` slots in first-call order."""
    out = {}
    for path in signal_order(ps, sched):
        locs = {}
        for o in ps.blocks[path].outputs:
            if o in pg.flow[path].state_outputs:
                locs[o] = Loc("x", *states[path][o])
            else:
                n = ps.size(path, "out", o)
                locs[o] = Loc("sig", n_sig, n_sig + n)
                n_sig += n
        out[path] = MappingProxyType(locs)
    return {path: out[path] for path in ps.blocks}, n_sig


def zero_slot_of(ps: PortSizes, n_sig):
    """``(Loc of the zero slot, next free sig index)``: as long as the longest unconnected
    input (zero elements if none)."""
    n = max([ps.size(path, "in", i) for path, bp in ps.blocks.items() for i in bp.inputs
             if ps.source(path, i) is None] + [0])
    return Loc("sig", n_sig, n_sig + n), n_sig + n


def scratch_slots(ps: PortSizes, n_sig):
    """``(path -> {scratch array: Span}, next free sig index)``."""
    out = {}
    for path, bp in ps.blocks.items():
        spans = {}
        for name, spec in bp.cls.scratch.items():
            n = bp.cls.size_of(spec, bp.params)
            spans[name] = Span(n_sig, n_sig + n)
            n_sig += n
        out[path] = MappingProxyType(spans)
    return out, n_sig


def tear_slots(ps: PortSizes, sched: Schedule, outputs, n_sig):
    """``(per loop {(path, port): Span}, next free sig index)``: a new slot per signal
    tear; a constraint tear is its output's slot."""
    out = []
    for lp in sched.loops:
        zs = {}
        for t in lp.tears:
            if t.kind == "signal":
                n = ps.size(t.path, "out", t.port)
                zs[(t.path, t.port)] = Span(n_sig, n_sig + n)
                n_sig += n
            else:
                loc = outputs[t.path][t.port]
                zs[(t.path, t.port)] = Span(loc.start, loc.stop)
        out.append(MappingProxyType(zs))
    return out, n_sig


def _port_or_size(bp: BlockPorts, ps: PortSizes, spec, params):
    """A declared size: ``@input`` follows that input, anything else ``size_of``."""
    if isinstance(spec, str) and spec.startswith("@"):
        return ps.size(bp.path, "in", spec[1:])
    return bp.cls.size_of(spec, params)


def event_sizes(bp: BlockPorts, ps: PortSizes, pg: PortGraph, inst):
    """Guards per declared event of ``bp`` (0 for an event switched off by its ``when``).

    Raises
    ------
    ParameterError
        The block has guards but neither states nor modes.
    RuntimeError
        The block type has guards but no ``guard`` or ``on_event`` kernel.
    """
    sizes = tuple(0 if ev.when is not None and not bp.params[ev.when]
                  else _port_or_size(bp, ps, ev.size, bp.params)
                  for ev in bp.cls.events.values())
    if sum(sizes):
        if not pg.flow[bp.path].state_sizes and not bp.cls.modes:
            raise ParameterError(
                f"block type {bp.cls.type_name} declares events "
                f"({', '.join(bp.cls.events)}) but has no states or modes for them to "
                f"change", block=bp.path, file=inst.file, line=inst.line)
        for k in ("guard", "on_event"):
            if not bp.cls.has_kernel(k):
                raise RuntimeError(f"block type {bp.cls.type_name} declares events but "
                                   f"has no '{k}' kernel")
    return sizes


def param_slots(cls, params, n_p):
    """``(pslots, constants, next free p index)`` of the merged parameters ``params``.

    Integer and boolean parameters are constants; strings are skipped; every other value
    takes ``size`` entries of ``p`` with its shape (``"scalar"`` for a declared scalar or an
    undeclared 0-d value).
    """
    pslots, constants = {}, {}
    for name, v in params.items():
        decl = cls.parameters.get(name)
        if decl is not None and decl.kind in ("int", "bool"):
            constants[name] = v
            continue
        if isinstance(v, str):
            continue
        arr = np.asarray(v, dtype=float)
        shape = "scalar" if (decl is not None and decl.shape == ()) or (
            decl is None and arr.ndim == 0) else arr.shape
        pslots[name] = ParamSlot(n_p, n_p + arr.size, shape)
        n_p += arr.size
    return MappingProxyType(pslots), MappingProxyType(constants), n_p


def block_numbers(bp: BlockPorts, ps: PortSizes, pg: PortGraph, inst, n_g, n_modes, n_p):
    """Guards, modes and parameters of one block (contract step 4).

    Returns
    -------
    tuple
        ``(_Numbers, next free g index, next free modes index, next free p index)``.
    """
    sizes = event_sizes(bp, ps, pg, inst)
    guards = Span(n_g, n_g + sum(sizes))
    modes = {}
    for m, decl in bp.cls.modes.items():
        n = _port_or_size(bp, ps, decl.size, bp.params)
        modes[m] = Span(n_modes, n_modes + n)
        n_modes += n
    params = dict(bp.params)
    params.update(bp.cls.derived(bp.params))
    pslots, constants, n_p = param_slots(bp.cls, params, n_p)
    return (_Numbers(guards, sizes, MappingProxyType(modes), params, pslots, constants),
            guards.stop, n_modes, n_p)


def input_sources(bp: BlockPorts, ps: PortSizes, outputs, signal_tears, zero_slot):
    """``input -> Loc`` of block ``bp`` (contract step 5)."""
    out = {}
    for i in bp.inputs:
        c = ps.source(bp.path, i)
        if c is None:
            n = ps.size(bp.path, "in", i)
            out[i] = Loc(zero_slot.array, zero_slot.start, zero_slot.start + n)
            continue
        src = outputs[c.src[0]][c.src[1]]
        zs = signal_tears.get((c.src[0], c.src[1]))
        if zs is not None:
            src = Loc("sig", *zs)
        s0, s1 = c.src[2], c.src[3]
        if s0 is not None:
            a, b = norm_slice(s0, s1, src.stop - src.start, c)
            src = Loc(src.array, src.start + a, src.start + b)
        out[i] = src
    return MappingProxyType(out)


def _element_names(name, n):
    return [f"{name}" + (f"[{k}]" if n > 1 else "") for k in range(n)]


def loop_unknowns(lp, zslots, ps: PortSizes, outputs, inputs, n_sig):
    """``(LoopSlots, next free sig index)`` of one loop (contract step 6); the Newton
    workspace starts at ``n_sig``."""
    zidx, residual, names = [], [], []
    for t in lp.tears:
        a, b = zslots[(t.path, t.port)]
        zidx += range(a, b)
        if t.kind == "signal":
            o0 = outputs[t.path][t.port].start
            residual += [Residual("signal", a + k, o0 + k) for k in range(b - a)]
            names += _element_names(f"{t.path}.{t.port}", b - a)
        else:
            f = ps.blocks[t.path].cls.implicit[t.port][0]
            # the residual is an input of the block, or else one of its outputs
            loc = inputs[t.path][f] if f in inputs[t.path] else outputs[t.path][f]
            residual += [Residual("constraint", k, None) for k in range(loc.start, loc.stop)]
            names += _element_names(f"{t.path}.{f}", loc.stop - loc.start)
    slots = LoopSlots(zslots, tuple(zidx), tuple(residual), tuple(names), n_sig)
    return slots, n_sig + Workspace(len(zidx)).size
