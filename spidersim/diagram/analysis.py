"""Linearization of diagrams between named signals, loop openings, operating points, trim.

Analysis points are inserted into the *flat* diagram as extra stateless blocks, so the state
and mode layouts are those of the diagram itself and the same compiled code (with its loop
solves) is differentiated:

- an input ``S`` (a perturbation added to signal ``S``): every consumer of ``S`` reads
  ``S + d`` from a new Sum fed by ``S`` and a Constant ``d``;
- an opening at ``S``: every consumer of ``S`` reads ``S_op + d`` instead, where ``S_op``
  is the value of ``S`` at the operating point of the closed diagram; ``S`` itself is then
  the loop's return. The transfer from the opening's input to its output is ``-L`` for a
  negative-feedback loop, so :func:`loop_transfer` returns ``L = -T``;
- outputs are read at their source ports.

Sampled blocks and quantizers (contract item 9 of :mod:`spidersim.blocks.base`): a block
that is sampled (``sample_period`` > 0) on a path from an input (or opening) to an output
is refused with an :class:`AnalysisError` naming it and its parameter: its held output has
no derivative between samples, so the linear model would be silently wrong (a sampled
controller reads as gain 0). A quantizer (``quantizer``) is linearized as its unquantized
gain: the copy that is differentiated has the block's quantization parameters set to the
values that remove it (the staircase has zero slope almost everywhere; its describing gain
for small signals many steps wide is 1). :attr:`Linearizer.quantizers` lists the blocks on
the path so treated.

Kinks: where the one-sided differences of a column disagree (the operating point on a
Saturation's limit without zero crossing: slopes 0 and 1, central difference 0.5),
:func:`linearize` keeps the central value and warns, naming both slopes (:func:`_kinks`).

python-control does not allow '.' in signal names, so the state space names its states,
inputs and outputs with '/' in place of '.' (``j3.motor.w`` -> ``j3/motor/w``).

The operating point (``at``) is the initial state (``None`` or ``"initial"``), the state at
time ``T`` of a simulation (a number), an :class:`OperatingPoint` from :func:`trim`, or a
``{"trim": {...}}`` mapping of :func:`trim`'s arguments.
"""
from __future__ import annotations

import collections.abc
import difflib
from dataclasses import dataclass, field
from typing import NamedTuple

import math
import numbers
import re

import numpy as np

from ..blocks.base import REGISTRY
from ..errors import ASCII_RULE, SpidersimError, described, non_ascii
from ..solver import dense_size
from ..solver.linearize import jacobians
from .flatten import FlatConn, Instance


class AnalysisError(SpidersimError):
    """Bad analysis request: unknown signal, opening on an unconnected signal, failed trim."""


@dataclass
class OperatingPoint:
    """States ``x`` and modes at time ``t`` (and trimmed inputs by name, if any)."""

    t: float
    x: np.ndarray
    modes: np.ndarray
    inputs: dict = field(default_factory=dict)
    residuals: dict = field(default_factory=dict)


def _check_diagram(d, fn):
    """``d`` is a loaded diagram (what :func:`spidersim.load` returns), else an
    :class:`AnalysisError` naming ``fn``."""
    from .graph import Layout
    if not isinstance(getattr(d, "layout", None), Layout):
        raise AnalysisError(f"{fn}: the first argument must be a diagram "
                            f"(spidersim.load(file)), got {described(d)}")


def _signal_names(v, what, d, kind="signal name 'block.port'"):
    """The signal names of argument ``what``: a list or tuple of texts, or one text (a list
    of one); None is none. Anything else (a number, a mapping, a list holding a number) is
    an :class:`AnalysisError` naming the argument."""
    if v is None:
        return []
    if isinstance(v, str):
        return [v]
    if not isinstance(v, (list, tuple)) or not all(isinstance(n, str) for n in v):
        raise AnalysisError(f"{what} must be a {kind} or a list of them, got "
                            f"{described(v)}", file=d.file)
    twice = next((n for k, n in enumerate(v) if n in v[:k]), None)
    if twice is not None:                # (an opening given twice read as "not read")
        raise AnalysisError(f"{what}: '{twice}' is given twice", file=d.file)
    return list(v)


#: ``block.port[i]``: ``i`` in ASCII digits (``int`` read ``[١]`` as 1 and ``[1_0]`` as 10),
#: negative from the end
_ELEMENT = re.compile(r"^([^\[\]]*)\[\s*(-?[0-9]{1,100})\s*\]\Z")


def _split_name(d, name):
    """``(base, index or None)`` of signal name ``name`` (``g.y[-1]`` -> ``("g.y", -1)``);
    an AnalysisError for non-ASCII text or brackets that hold no index."""
    problem = non_ascii(name)
    if problem:
        raise AnalysisError(f"signal '{name}': {problem}: {ASCII_RULE}", file=d.file)
    if not ("[" in name or "]" in name):
        return name, None
    m = _ELEMENT.match(name)
    if not m:
        raise AnalysisError(f"cannot read signal '{name}' (use block.port or "
                            f"block.port[i], i negative from the end: [-1] is the last)",
                            file=d.file)
    return m.group(1), int(m.group(2))


def _signal_ref(d, name):
    """``(path, port, s0, s1, size, unit)`` of a signal name of diagram ``d`` (``name[i]``
    one element, ``i`` negative from the end as in connections)."""
    base, idx = _split_name(d, name)
    path, _, port = base.rpartition(".")
    if base in d.flat.aliases:
        path, port, s0, s1 = d.flat.aliases[base]
    else:
        s0 = s1 = None
    bl = d.layout.blocks.get(path)
    if bl is None or ("out", port) not in bl.ports:
        near = difflib.get_close_matches(name, d.signals(), n=3)
        hint = f"; did you mean {', '.join(near)}?" if near else ""
        raise AnalysisError(f"unknown signal '{name}'{hint} (signals are block.port)",
                            file=d.file)
    full = bl.ports[("out", port)].size
    if s0 is None:
        s0, s1 = 0, full
    if idx is not None:
        n = s1 - s0
        if not -n <= idx < n:
            raise AnalysisError(f"signal '{name}': index {idx} out of range (size {n}: "
                                f"0..{n - 1}, or -{n}..-1 from the end)", file=d.file)
        s0, s1 = s0 + idx % n, s0 + idx % n + 1
    return path, port, s0, s1, s1 - s0, bl.ports[("out", port)].unit


def _refs(d, inputs, outputs, open):
    """``name -> _signal_ref`` of every input, output and opening; an AnalysisError when
    two inputs (or two outputs, or two openings) share an element (``c.y`` and
    ``c.y[2]``): the model had a column (row) more than it had names, and a perturbation
    of the shared element was added twice."""
    refs = {n: _signal_ref(d, n) for n in inputs + outputs + open}
    for what, names in (("inputs", inputs), ("outputs", outputs), ("open", open)):
        for k, a in enumerate(names):
            for b in names[:k]:
                (pa, qa, a0, a1), (pb, qb, b0, b1) = refs[a][:4], refs[b][:4]
                if (pa, qa) == (pb, qb) and a0 < b1 and b0 < a1:
                    raise AnalysisError(
                        f"{what}: '{b}' and '{a}' share element(s) of one signal: give "
                        f"each element once", file=d.file)
    return refs


def _alias_owner(d, name):
    """The subsystem instance whose exposed output ``name`` (or ``name[i]``) is (``p`` for
    ``p.y``), else None. An analysis point there is the output as the parent reads it: the
    instance's own blocks reading the signal inside (a lag's inner feedback) keep it
    (opening ``p.y`` of a lag in a loop cut the lag's own loop too: L = 10/s for
    8/(s + 2))."""
    base = name.partition("[")[0] if name.endswith("]") else name
    if base not in d.flat.aliases:
        return None
    return base.rpartition(".")[0]


def _channel_names(name, n):
    return [name] if n == 1 else [f"{name}[{i}]" for i in range(n)]


def control_name(name):
    """python-control forbids '.' in signal names: ``j3.motor.w`` becomes ``j3/motor/w``."""
    return name.replace(".", "/")


class AnalysisPoint(NamedTuple):
    """The blocks inserted for one analysis point (see the module docstring)."""

    name: str            #: the signal
    kind: str            #: ``"input"`` (a perturbation added) or ``"open"`` (loop cut)
    delta: str           #: path of the Constant holding the perturbation ``d``
    op_const: str | None  #: path of the Constant holding ``S_op`` (openings), else None
    offset: int = 0      #: index in ``delta`` of the signal's first element


def _port_size(d, path, port):
    return d.layout.blocks[path].ports[("out", port)].size


def _consumers(conns, ref, d):
    """The connections that read any element of the signal ``ref`` (path, port, s0, s1,
    ...): a consumer of a slice that overlaps ``[s0, s1)`` of the same output port."""
    path, port, s0, s1 = ref[:4]
    return [c for c in conns if c.src[0] == path and c.src[1] == port and
            _overlaps(c.src, s0, s1, d)]


def _overlaps(src, s0, s1, d):
    """True when the output slice ``src`` (path, port, start, stop) shares an element with
    ``[s0, s1)`` of that port."""
    a = 0 if src[2] is None else src[2]
    b = _port_size(d, src[0], src[1]) if src[3] is None else src[3]
    return a < s1 and s0 < b


def _conn(src, dst, d):
    return FlatConn(src, dst, d.file, 0, "")


def _input_point(blocks, k, ref, d):
    """Blocks and connections of an input at ``ref``: ``__lin_s{k} = S + __lin_d{k}`` over
    the whole output port (the perturbation is zero outside the signal's elements);
    ``(point signal path, new connections, delta, offset)``."""
    path, port, s0 = ref[:3]
    full = _port_size(d, path, port)
    delta, add = f"__lin_d{k}", f"__lin_s{k}"
    blocks[delta] = _instance(delta, "Constant", {"value": np.zeros(full)}, d.file)
    blocks[add] = _instance(add, "Sum", {"signs": "++"}, d.file)
    new = [_conn((path, port, None, None), (add, "u1"), d),
           _conn((delta, "y", None, None), (add, "u2"), d)]
    return add, new, delta, s0


def _opening_point(blocks, k, ref, d):
    """Blocks and connections of an opening at ``ref``: ``__lin_s{k} = __lin_op{k} +
    __lin_d{k}`` (the signal's operating value plus the perturbation) for its elements; when
    the signal is part of its output port, a Mux ``__lin_m{k}`` rebuilds the whole port
    with the other elements read live. ``(point signal path, new connections, delta,
    op_const)``."""
    path, port, s0, s1, n = ref[:5]
    full = _port_size(d, path, port)
    delta, add, opc = f"__lin_d{k}", f"__lin_s{k}", f"__lin_op{k}"
    for c in (delta, opc):
        blocks[c] = _instance(c, "Constant", {"value": np.zeros(n)}, d.file)
    blocks[add] = _instance(add, "Sum", {"signs": "++"}, d.file)
    new = [_conn((opc, "y", None, None), (add, "u1"), d),
           _conn((delta, "y", None, None), (add, "u2"), d)]
    if n == full:
        return add, new, delta, opc
    mux = f"__lin_m{k}"
    pieces = [(path, port, 0, s0), (add, "y", None, None), (path, port, s1, full)]
    pieces = [p for p in pieces if p[0] == add or p[3] > p[2]]
    blocks[mux] = _instance(mux, "Mux", {"n": len(pieces)}, d.file)
    new += [_conn(p, (mux, f"u{i + 1}"), d) for i, p in enumerate(pieces)]
    return mux, new, delta, opc


def _insert_point(blocks, conns, k, name, kind, ref, d):
    """Insert analysis point number ``k`` at signal ``name`` (``ref`` from
    :func:`_signal_ref`) into ``blocks`` (in place) and return ``(conns, point)``.

    The point's blocks (:func:`_input_point`, :func:`_opening_point`) produce a signal of
    the size of the whole output port; every consumer of a slice of that port overlapping
    the signal then reads the same slice of it (consumers of other elements are unchanged).
    Opening a signal nobody reads is an :class:`AnalysisError`.
    """
    consumers = _consumers(conns, ref, d)
    owner = _alias_owner(d, name)
    if owner is not None:       # a subsystem's output: as its parent sees it
        consumers = [c for c in consumers if not c.dst[0].startswith(owner + ".")]
    if not consumers and kind == "open":
        raise AnalysisError(f"cannot open '{name}': it is not a connection (no block "
                            f"reads it)", file=d.file)
    if kind == "open":
        sig, new, delta, opc = _opening_point(blocks, k, ref, d)
        point = AnalysisPoint(name, kind, delta, opc)
    else:
        sig, new, delta, offset = _input_point(blocks, k, ref, d)
        point = AnalysisPoint(name, kind, delta, None, offset)
    conns = [FlatConn((sig, "y", c.src[2], c.src[3]), c.dst, c.file, c.line, c.text)
             if c in consumers else c for c in conns]
    return conns + new, point


def _with_analysis_points(d, inputs, open, refs):
    """The flat diagram of ``d`` with an analysis point at every opening, then at every
    input that is not also opened; ``(blocks, conns, points)``."""
    blocks, conns = dict(d.flat.blocks), list(d.flat.conns)
    todo = [(n, "open") for n in open] + [(n, "input") for n in inputs if n not in open]
    points = []
    for k, (name, kind) in enumerate(todo):
        conns, point = _insert_point(blocks, conns, k, name, kind, refs[name], d)
        points.append(point)
    return blocks, conns, points


def _diagram_copy(d, flat, blocks):
    """A copy of diagram ``d`` over another flat diagram (its own layout, parameter array,
    log of every signal and compiled modules), made without importing the model module."""
    from .graph import build_layout
    dlin = type(d).__new__(type(d))
    dlin.__dict__.update({k: v for k, v in d.__dict__.items()
                          if k not in ("_modules", "_idle")})
    dlin._modules, dlin._idle = {}, {}
    dlin.flat = flat
    dlin.blocks = blocks
    dlin.layout = build_layout(flat)
    dlin.p = dlin._param_array()
    dlin._log = dlin._log_spec("all")
    if dlin.layout.n_x != d.layout.n_x:
        raise RuntimeError("analysis points changed the state layout")
    return dlin


def _path_blocks(blocks, conns, points, refs, outputs):
    """Paths of the blocks on a path (through any block, states included) from an analysis
    point's perturbation to the source of an output, in the flat diagram with the points
    inserted (an opened connection no longer carries the signal)."""
    succ, pred = {}, {}
    for c in conns:
        succ.setdefault(c.src[0], set()).add(c.dst[0])
        pred.setdefault(c.dst[0], set()).add(c.src[0])

    def reach(start, nxt):
        seen, todo = set(start), list(start)
        while todo:
            for b in nxt.get(todo.pop(), ()):
                if b not in seen:
                    seen.add(b)
                    todo.append(b)
        return seen

    down = reach([p.delta for p in points], succ)
    up = reach([refs[n][0] for n in outputs], pred)
    return [b for b in blocks if b in down and b in up and not b.startswith("__lin_")]


def sampled_on_path(blocks, path):
    """``(block path, type, parameter, value, continuous_allowed)`` of each block of ``path``
    that is sampled (its ``sample_period`` parameter > 0)."""
    found = []
    for b in path:
        inst = blocks[b]
        name = inst.cls.sample_period
        if name and float(inst.params.get(name, 0.0)) > 0.0:
            decl = inst.cls.parameters[name]
            zero_ok = not (decl.gt is not None and decl.gt >= 0.0)
            found.append((b, inst.cls.type_name, name, float(inst.params[name]), zero_ok))
    return found


def _sampled_error(d, found):
    """The :class:`AnalysisError` for sampled blocks on the linearization path."""
    items = []
    for b, type_name, name, v, zero_ok in found:
        fix = (f"{name} = 0 makes it continuous (--set {b}.{name}=0)" if zero_ok else
               "a discrete-time block with no continuous form: replace it by its "
               "continuous counterpart")
        items.append(f"'{b}' ({type_name}, {name} = {v:g} s: {fix})")
    return AnalysisError("cannot linearize through sampled block(s) on the path from the "
                         "inputs to the outputs: " + "; ".join(items) + ". Their outputs "
                         "are held between samples (zero derivative), so the linear model "
                         "would be wrong (a held controller reads as gain 0); spidersim "
                         "linearizes continuous-time models only", file=d.file)


def check_continuous_path(d, inputs, outputs, open=()):
    """Raise :class:`AnalysisError` when a sampled block lies on a path from ``inputs`` or
    ``open`` to ``outputs`` of diagram ``d`` (``check`` calls it for analysis entries);
    return the quantizers on the path (``(block path, {parameter: value})``)."""
    inputs, outputs, open = list(inputs), list(outputs), list(open or ())
    refs = _refs(d, inputs, outputs, open)
    blocks, conns, points = _with_analysis_points(d, inputs, open, refs)
    path = _path_blocks(blocks, conns, points, refs, outputs)
    found = sampled_on_path(blocks, path)
    if found:
        raise _sampled_error(d, found)
    return [(b, {k: blocks[b].params[k] for k in blocks[b].cls.quantizer})
            for b in path if _quantized(blocks[b])]


def _quantized(inst):
    """True when block instance ``inst`` quantizes (a ``quantizer`` parameter differs from
    the value that removes the quantization)."""
    return any(inst.params.get(k) != v for k, v in inst.cls.quantizer.items())


def _unquantized(blocks):
    """``blocks`` with every quantizer's quantization removed (contract item 9)."""
    import dataclasses
    return {b: (dataclasses.replace(inst, params={**inst.params, **inst.cls.quantizer})
                if _quantized(inst) else inst) for b, inst in blocks.items()}


class Linearizer:
    """A diagram transformed with analysis points, ready to be differentiated.

    ``linear=True`` (linearization): a sampled block on a path from an input or opening to
    an output is an :class:`AnalysisError`, and quantizers are replaced by their
    unquantized form (:attr:`quantizers` names those on the path); ``False`` (trim's free
    inputs) keeps the diagram as it is."""

    def __init__(self, d, inputs, outputs, open=(), jit=True, linear=True):
        self.d = d
        inputs, outputs, open = list(inputs), list(outputs), list(open or ())
        refs = _refs(d, inputs, outputs, open)
        blocks, conns, points = _with_analysis_points(d, inputs, open, refs)
        self.quantizers = []
        self.kinks = []      #: see :meth:`state_space`
        if linear:
            path = _path_blocks(blocks, conns, points, refs, outputs)
            found = sampled_on_path(blocks, path)
            if found:
                raise _sampled_error(d, found)
            self.quantizers = [b for b in path if _quantized(blocks[b])]
            blocks = _unquantized(blocks)
        #: (name, const path, offset, size) of each input; (const path, (path, port, s0,
        #: s1)) of
        #: each opening
        self.in_slots = [(p.name, p.delta, p.offset, refs[p.name][4]) for p in points
                         if p.name in inputs]
        self.op_consts = [(p.op_const, refs[p.name][:4]) for p in points if p.kind == "open"]
        flat2 = type(d.flat)(blocks, conns, d.flat.subsystem_instances, d.flat.aliases)
        self.dlin = _diagram_copy(d, flat2, blocks)
        self.system = self.dlin.compile(jit)
        a, r = self.dlin.layout.p_loop_tol
        self.system.p[a] = 1e-14        # loops to round-off: central differences need it
        self.system.p[r] = 1e-13
        self.inputs, self.outputs, self.open = inputs, outputs, open
        self.out_slices = self._output_slices(outputs, refs)
        self.in_p = self._input_slots()
        self.op_p = self._opening_slots()

    def _output_slices(self, outputs, refs):
        """``(name, array, start, stop)`` of each output in the signal or state array."""
        slices = []
        for name in outputs:
            path, port, s0, s1, n, unit = refs[name]
            arr, a0, _b0 = self.dlin.layout.blocks[path].ports[("out", port)].loc
            slices.append((name, arr, a0 + s0, a0 + s1))
        return slices

    def _input_slots(self):
        """``(name, start, stop)`` of each input's perturbation in the parameter array."""
        slots = []
        for name, delta, offset, n in self.in_slots:
            a0 = self.dlin.layout.blocks[delta].pslots["value"][0] + offset
            slots.append((name, a0, a0 + n))
        return slots

    def _opening_slots(self):
        """``(start, stop, (path, port, s0, s1))``: where each opening's operating value
        goes in the parameter array, and the signal it is taken from."""
        slots = []
        for opc, src in self.op_consts:
            a0, b0, _ = self.dlin.layout.blocks[opc].pslots["value"]
            slots.append((a0, b0, src))
        return slots

    def state_names(self):
        names = [""] * self.d.layout.n_x
        for bl in self.d.layout.blocks.values():
            for s, (a, b) in bl.states.items():
                for i, nm in enumerate(_channel_names(f"{bl.path}.{s}", b - a)):
                    names[a + i] = nm
        return names

    def at(self, t, x, modes):
        """Set the operating point; openings hold the closed-loop values of their signals."""
        sys_ = self.system
        self.t = float(t)
        self.x = np.array(x, dtype=float)
        sys_.modes[:] = modes
        sys_.p[[i for _, a, b in self.in_p for i in range(a, b)]] = 0.0
        if self.op_p:
            # the closed diagram's value of each opened signal at this point
            sys0 = self.d.compile(self.system_jit)
            sys0.modes[:] = modes
            sys0.outputs(self.t, self.x)
            for a0, b0, (path, port, s0, s1) in self.op_p:
                arr, l0, _ = self.d.layout.blocks[path].ports[("out", port)].loc
                src = sys0.sig if arr == "sig" else self.x
                sys_.p[a0:b0] = src[l0 + s0:l0 + s1]

    def evaluate(self, x, u):
        sys_ = self.system
        k = 0
        for name, a, b in self.in_p:
            sys_.p[a:b] = u[k:k + b - a]
            k += b - a
        xdot = sys_.rhs(self.t, x)
        y = [(sys_.sig if arr == "sig" else x)[a:b] for name, arr, a, b in self.out_slices]
        return xdot, (np.concatenate(y) if y else np.zeros(0))

    def state_space(self):
        """The named ``control.StateSpace`` at the operating point (central differences);
        :attr:`kinks` lists the one-sided slopes that differ there (:func:`_kinks`)."""
        import control
        nu = sum(b - a for _, a, b in self.in_p)
        calls = []
        A, B, C, D = jacobians(_recording(self.evaluate, calls), self.x, np.zeros(nu))
        if not all(np.all(np.isfinite(m)) for m in (A, B, C, D)):
            self._non_finite()
        in_names = [nm for name, a, b in self.in_p for nm in _channel_names(name, b - a)]
        out_names = [nm for name, arr, a, b in self.out_slices
                     for nm in _channel_names(name, b - a)]
        self.kinks = _kinks(calls, self.state_names(), in_names, out_names)
        return control.ss(A, B, C, D, states=[control_name(n) for n in self.state_names()],
                          inputs=[control_name(n) for n in in_names],
                          outputs=[control_name(n) for n in out_names],
                          name=control_name(self.d.spec.name))


    def _non_finite(self):
        """Raise the error behind non-finite Jacobian entries: a failed algebraic-loop
        solve (an :class:`AlgebraicLoopError` walking the loop, as ``run`` reports it) or
        the first non-finite signal or derivative (:class:`AnalysisError`)."""
        from ..errors import AlgebraicLoopError
        report, lp = self.system.loop_failure()
        if report:
            raise AlgebraicLoopError("cannot linearize at t = " + f"{self.t:g} s: " + report,
                                     file=lp.get("file") or self.d.file, line=lp.get("line"),
                                     block=lp.get("block"))
        diagnose = getattr(self.system, "diagnose", None)
        why = diagnose(self.t, self.x) if diagnose is not None else ""
        raise AnalysisError("cannot linearize: the perturbed model has non-finite values"
                            + (f" ({why})" if why else ""), file=self.d.file)


def _recording(evaluate, calls):
    """``evaluate(x, u) -> (xdot, y)`` that also appends ``(z, F)`` (``(x, u)`` and
    ``(xdot, y)`` joined, copies) of every call to ``calls``."""
    def recorded(x, u):
        xdot, y = evaluate(x, u)
        calls.append((np.concatenate((x, u)), np.concatenate((xdot, y))))
        return xdot, y
    return recorded


#: one-sided slopes that differ by more than this fraction of the larger mark a kink
KINK_SLOPE_JUMP = 0.1


def _kinks(calls, states, in_names, out_names):
    """``(variable, row, forward slope, backward slope)`` wherever the one-sided differences
    of a central-difference Jacobian disagree: the operating point sits on a kink (a
    Saturation's limit or a DeadZone's edge without zero crossing), and the central
    difference is the mean of two slopes, neither of which the model has on either side.

    ``calls``: ``(z, F)`` of every evaluation of ``(x, u) -> (xdot, y)``, the operating point
    first; each other one perturbs one variable. A difference counts when it exceeds
    :data:`KINK_SLOPE_JUMP` of the larger slope and the round-off of the evaluations (the
    loops are solved to 1e-13, so ``1e-9 |F| / h``); a smooth function's slopes differ by
    ``h f''`` only (``h`` = 6e-6 of the variable). Variables are named by ``states`` and
    ``in_names``, rows by ``d/dt`` of the states and ``out_names``."""
    var_names = states + in_names
    row_names = [f"d/dt {n}" for n in states] + out_names
    z0, F0 = calls[0]
    sides = {}
    for z, F in calls[1:]:
        j = np.flatnonzero(z != z0)
        if j.size == 1:
            sides.setdefault(int(j[0]), {})[bool(z[j[0]] > z0[j[0]])] = (z[j[0]] - z0[j[0]], F)
    found = []
    for j, side in sorted(sides.items()):
        if len(side) < 2:
            continue
        (hp, Fp), (hm, Fm) = side[True], side[False]
        fwd, bwd = (Fp - F0) / hp, (Fm - F0) / hm
        size = np.maximum(np.maximum(abs(F0), abs(Fp)), abs(Fm))
        floor = (1e-9 * size + 1e-12) / hp
        with np.errstate(invalid="ignore"):
            jump = abs(fwd - bwd) > np.maximum(KINK_SLOPE_JUMP * np.maximum(abs(fwd), abs(bwd)),
                                               floor)
        found += [(var_names[j], row_names[i], float(fwd[i]) + 0.0, float(bwd[i]) + 0.0)
                  for i in np.flatnonzero(jump)]
    return found


def kink_note(kinks):
    """The :class:`~spidersim.errors.LinearizationWarning` text for :func:`_kinks`."""
    items = [f"{row} by {var}: {fwd:.6g} above, {bwd:.6g} below" for var, row, fwd, bwd in
             kinks[:6]]
    more = f" and {len(kinks) - 6} more" if len(kinks) > 6 else ""
    return ("the operating point sits on a kink within the difference step (a Saturation "
            "limit or DeadZone edge without zero crossing, |v| of a friction model near "
            "rest): the one-sided slopes differ, and the linear model holds their mean: "
            + "; ".join(items) + more + ". Move the operating point off the corner, or give "
            "a Saturation or DeadZone zero_crossing: true (its mode then picks the side)")


def _instance(path, type_name, params, file):
    cls = REGISTRY[type_name]
    return Instance(path, cls, cls.validate_params(params), file, 0, {})


#: the keys of a ``{trim: {...}}`` operating point (the arguments of :func:`trim`)
TRIM_KEYS = ("targets", "derivatives", "free_inputs", "x0", "t", "tol")


def _number(v, what):
    """A finite float from a YAML value (a number, or a text such as ``1e9``, which YAML
    1.1 reads as text, evaluated as an expression as everywhere in a diagram)."""
    from ..text.expr import ExprError, evaluate
    if isinstance(v, str):
        try:
            v = evaluate(v, {})
        except ExprError as exc:
            raise AnalysisError(f"{what}: {exc}") from None
    if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
        raise AnalysisError(f"{what} must be a finite number, got {v!r}")
    return float(v)


def _names(v, what):
    if not isinstance(v, list) or not all(isinstance(n, str) for n in v):
        raise AnalysisError(f"{what} must be a list of signal or state names, got {v!r}")
    return list(v)


def trim_request(at):
    """The keyword arguments of :func:`trim` from an operating point ``{trim: {...}}``,
    checked: known keys, ``targets`` a mapping of signal names to finite numbers (or lists
    of them), ``derivatives`` ``"all"`` or a list of state names, ``free_inputs`` a list of
    signal names, ``x0`` a list of numbers, ``t`` a time, ``tol`` > 0. An
    :class:`AnalysisError` names what is wrong."""
    spec = _trim_mapping(at)
    kw = {"targets": _trim_target_values(spec.get("targets") or {})}
    der = spec.get("derivatives", "all")
    kw["derivatives"] = der if der == "all" else _names(der, "trim: 'derivatives' ('all' or "
                                                             "a list)")
    kw["free_inputs"] = _names(spec.get("free_inputs") or [], "trim: 'free_inputs'")
    if spec.get("x0") is not None:
        x0 = spec["x0"]
        if not isinstance(x0, list):
            raise AnalysisError(f"trim: 'x0' must be a list of numbers, got {x0!r}")
        kw["x0"] = [_number(v, "trim: an entry of 'x0'") for v in x0]
    if "t" in spec:
        kw["t"] = _number(spec["t"], "trim: 't'")
    if "tol" in spec:
        kw["tol"] = _number(spec["tol"], "trim: 'tol'")
        if kw["tol"] <= 0:
            raise AnalysisError(f"trim: 'tol' must be > 0, got {kw['tol']:g}")
    return kw


def _trim_mapping(at):
    """The inner mapping of ``{trim: {...}}`` (``{trim: null}`` is ``{}``), its keys known."""
    if not isinstance(at, dict) or set(at) != {"trim"}:
        raise AnalysisError(f"an operating point mapping is {{trim: {{targets: ..., "
                            f"free_inputs: [...], derivatives: [...]}}}}, got {at!r}")
    spec = at["trim"] if at["trim"] is not None else {}
    if not isinstance(spec, dict):
        raise AnalysisError(f"'trim' must be a mapping of {', '.join(TRIM_KEYS)}, got "
                            f"{spec!r}")
    unknown = [k for k in spec if k not in TRIM_KEYS]
    if unknown:
        raise AnalysisError(f"trim: unknown key '{unknown[0]}' (keys: {', '.join(TRIM_KEYS)})")
    return spec


def _trim_target_values(targets):
    """``targets`` of a trim mapping: signal name -> a finite number or a list of them."""
    if not isinstance(targets, dict):
        raise AnalysisError(f"trim: 'targets' must be a mapping of signals to values, got "
                            f"{targets!r}")
    return {str(k): ([_number(x, f"trim: target '{k}'") for x in v]
                     if isinstance(v, list) else _number(v, f"trim: target '{k}'"))
            for k, v in targets.items()}


def operating_point(d, at, jit=True):
    """Resolve ``at`` into an :class:`OperatingPoint` of diagram ``d``."""
    if isinstance(at, OperatingPoint):
        return at
    if isinstance(at, dict):
        return trim(d, jit=jit, **trim_request(at))
    if isinstance(at, np.ndarray) and at.ndim == 0 and at.dtype.kind in "iuf":
        at = at.item()                      # a 0-d array of a real number: that number
    if at is None or (isinstance(at, str) and at == "initial"):
        system = d.compile(jit)
        x = system.x0.copy()
        modes = d.initial_modes()
        system.modes[:] = modes
        system.initialize(0.0, x)
        tol = 1e-12
        while system.next_time(0.0) <= tol:
            system.time_events(0.0, x, tol)
            system.initialize(0.0, x)
        return OperatingPoint(0.0, x, system.modes.copy())
    if isinstance(at, numbers.Real) and not isinstance(at, (bool, np.bool_)):
        if not (math.isfinite(at) and at >= 0):
            raise AnalysisError(f"the operating point at = {at!r} must be a time >= 0 s "
                                f"(the state of a simulation to that time), None or "
                                f"'initial'", file=d.file)
        if at == 0:
            return operating_point(d, None, jit)
        r = d.simulate(t_end=float(at), jit=jit)
        t, x, modes = r.final
        return OperatingPoint(t, x, modes)
    raise AnalysisError(f"cannot use {at!r} as an operating point: give None, 'initial', a "
                        f"time, an OperatingPoint or {{'trim': {{...}}}}", file=d.file)


def linearize(d, inputs, outputs, at=None, open=(), jit=True):
    """Linear model of diagram ``d`` from ``inputs`` to ``outputs`` (signal names) at ``at``,
    with the connections named in ``open`` cut; a named ``control.StateSpace``."""
    _check_diagram(d, "linearize")
    inputs = _signal_names(inputs, "linearize: inputs", d)
    outputs = _signal_names(outputs, "linearize: outputs", d)
    open = _signal_names(open, "linearize: open", d)
    if not inputs or not outputs:
        raise AnalysisError("linearize needs at least one input and one output signal",
                            file=d.file)
    lin = Linearizer(d, inputs, outputs, open, jit)
    if lin.quantizers:
        import warnings

        from ..errors import LinearizationWarning
        warnings.warn(f"quantizer(s) linearized as their unquantized gain: "
                      f"{', '.join(lin.quantizers)} (staircase outputs have zero slope "
                      f"between steps)", LinearizationWarning, stacklevel=3)
    lin.system_jit = jit
    op = operating_point(d, at, jit)
    lin.at(op.t, op.x, op.modes)
    sys = lin.state_space()
    if lin.kinks:
        import warnings

        from ..errors import LinearizationWarning
        warnings.warn(kink_note(lin.kinks), LinearizationWarning, stacklevel=3)
    return sys


def loop_transfer(d, signal, at=None, jit=True):
    """Loop transfer ``L`` at ``signal``: the loop opened there, ``L = -T`` where ``T`` is
    the transfer from the opening's input to its return (negative feedback: the closed loop
    is ``L / (1 + L)``)."""
    _check_diagram(d, "loop_transfer")
    if not isinstance(signal, str):
        raise AnalysisError(f"loop_transfer: signal must be one signal name 'block.port', "
                            f"got {described(signal)}", file=d.file)
    sys = linearize(d, [signal], [signal], at=at, open=[signal], jit=jit)
    import control
    D = np.asarray(sys.D, dtype=float)
    closing = np.eye(D.shape[0]) - D          # I + L(j inf), with L = -T and D = T(j inf)
    if np.linalg.cond(closing) > 1e12:
        raise AnalysisError(f"the loop at '{signal}' is singular when closed: its gain at "
                            f"high frequency L(j inf) = {-float(D.ravel()[0]):.6g} makes "
                            f"1 + L(j inf) = 0 (an algebraic loop of gain -1 through "
                            f"'{signal}': the closed diagram has no unique solution, and "
                            f"run fails there too)", file=d.file)
    return control.ss(sys.A, sys.B, -sys.C, -sys.D, states=sys.state_labels,
                      inputs=sys.input_labels, outputs=sys.output_labels,
                      name=f"L({control_name(signal)})")


def _derivative_rows(d, derivatives, names):
    """Indices of the state derivatives ``trim`` drives to zero: all, or those of the
    states named (``block.state`` covers every element, ``block.state[i]`` one)."""
    if derivatives == "all":
        return list(range(d.layout.n_x))
    rows = []
    for nm in derivatives:
        idx = [i for i, n in enumerate(names) if n == nm or n.startswith(nm + "[")]
        if not idx:
            near = difflib.get_close_matches(nm, names, n=3)
            raise AnalysisError(f"trim: unknown state '{nm}'"
                                + (f"; did you mean {', '.join(near)}?" if near else ""),
                                file=d.file)
        rows += idx
    return rows


def _check_trim_residuals(d, res, resid, sol, tol, changes=()):
    """Every residual ``res`` finite and at most ``tol``; otherwise an
    :class:`AnalysisError` with the solver's message, the mode changes that led to the
    modes solved in (``changes``, texts of :func:`_mode_changes`) and the six largest
    residuals by name (``resid``: label -> residual)."""
    if not np.all(np.isfinite(res)) or np.max(np.abs(res), initial=0.0) > tol:
        where = ""
        if changes:
            where = (": the point solved for in the blocks' earlier modes puts them in "
                     "others (" + "; then ".join(changes) + "), and in those the targets "
                     "and derivatives are not met")
        raise AnalysisError("trim did not converge" + where + " (" + sol.message + "); "
                            "largest residuals: " + _worst(list(resid), list(resid.values())),
                            file=d.file)


def _check_trim_start(d, res, labels, given):
    """The residuals ``res`` (named by ``labels``) at trim's starting point are finite, else
    an :class:`AnalysisError` naming the first non-finite ones: the solver cannot start
    from there (``given``: the start is the caller's ``x0``, else the initial state)."""
    bad = [f"{k} = {v:g}" for k, v in zip(labels, res) if not math.isfinite(v)]
    if bad:
        start = "the given x0" if given else "the initial state"
        raise AnalysisError(f"trim cannot start from {start}: the residuals there are not "
                            f"finite ({', '.join(bad[:6])}); give an x0 of moderate values",
                            file=d.file)


def _named_inputs(lin, u):
    """The free inputs' values ``u`` by name: a float for a scalar, an array otherwise."""
    inputs = {}
    k = 0
    for name, a, b in getattr(lin, "in_p", []):
        inputs[name] = u[k:k + b - a].copy() if b - a > 1 else float(u[k])
        k += b - a
    return inputs


def trim(d, targets=None, derivatives="all", free_inputs=(), x0=None, t=0.0, jit=True,
         tol=1e-10):
    """Find states (and the values of ``free_inputs``, signals opened as unknown inputs) such
    that the chosen state derivatives are zero and ``targets`` (signal -> value) hold.

    ``derivatives``: ``"all"`` or a list of state names (``block.state`` or
    ``block.state[i]``). Solved by ``scipy.optimize.least_squares`` from ``x0`` (default:
    the initial state). Raises :class:`AnalysisError` naming the residuals when the solution
    does not reach ``tol``. The point returned carries the modes its blocks take there
    (a Saturation at its limit, a clamped PI): the solve starts in the start point's modes
    and is repeated from the point found in the modes taken there (:func:`_trim_rounds`).
    """
    _check_diagram(d, "trim")
    if d.layout.n_x > dense_size.MAX_DENSE_STATES:     # least_squares' dense Jacobian
        raise AnalysisError(f"trim solves with a dense {d.layout.n_x}-column Jacobian: at "
                            f"most {dense_size.MAX_DENSE_STATES} states", file=d.file)
    targets = trim_targets(d, targets)
    if not (isinstance(derivatives, str) and derivatives == "all"):
        derivatives = _signal_names(derivatives, "trim: derivatives ('all' or states)", d,
                                    kind="state name 'block.state'")
    free_inputs = _signal_names(free_inputs, "trim: free_inputs", d)
    x0 = _trim_x0(d, x0)
    t, tol = (_argument_number(d, v, f"trim: {k}", lo) for k, v, lo in
              (("t", t, None), ("tol", tol, 0.0)))
    outs = list(targets)
    lin = Linearizer(d, free_inputs, outs, (), jit, linear=False) if free_inputs else None
    names = _state_names(d)
    rows = _derivative_rows(d, derivatives, names)
    base = operating_point(d, None, jit)
    x_start = base.x.copy() if x0 is None else np.asarray(x0, dtype=float)
    if lin is None:
        lin = _TrimEval(d, outs, jit)
    lin.system_jit = jit
    lin.at(t, x_start, base.modes)
    nu = sum(b - a for _, a, b in getattr(lin, "in_p", []))
    want = np.concatenate([np.ravel(targets[n]) for n in outs]) if outs else np.zeros(0)

    def residual(z):
        x, u = z[:len(x_start)], z[len(x_start):]
        xdot, y = lin.evaluate(x, u)
        return np.concatenate((xdot[rows], y - want))

    labels = [f"d/dt {names[i]}" for i in rows] + [
        nm for n in outs for nm in _channel_names(n, np.size(targets[n]))]
    z0 = np.concatenate((x_start, np.zeros(nu)))
    _check_trim_start(d, residual(z0), labels, x0 is not None)
    sol, modes = _trim_rounds(d, lin, residual, z0, t, base.modes, labels, tol)
    x = sol.x[:len(x_start)]
    u = sol.x[len(x_start):]
    return OperatingPoint(float(t), x, modes, _named_inputs(lin, u),
                          dict(zip(labels, residual(sol.x))))


#: trim's solves at most: each after the first in the modes the blocks took at the point
#: the one before found
TRIM_MODE_ROUNDS = 4


def _trim_solve(residual, z0):
    """``least_squares`` of ``residual`` from ``z0``. With fewer residuals than unknowns
    (free inputs or states no residual depends on) 'dogbox': 'trf' with its exact
    trust-region solver stops at the start there (``[z1 - 0.5]`` from ``(0, 0)``), and
    dogbox moves only the unknowns the residuals need (``(0, 0.5)``)."""
    from scipy.optimize import least_squares
    method = "dogbox" if np.size(residual(z0)) < np.size(z0) else "trf"
    return least_squares(residual, z0, method=method, xtol=1e-15, ftol=1e-15, gtol=1e-15,
                         max_nfev=2000)


def _trim_rounds(d, lin, residual, z0, t, modes, labels, tol):
    """Solve in ``modes`` (the start point's), then again from the point found in the modes
    the blocks take there (:func:`_settled_modes`) until they no longer change: ``(sol,
    modes)`` of a point whose residuals meet ``tol`` in the modes it has. Raises
    :class:`AnalysisError` when they do not (naming the mode changes met on the way) or the
    modes keep changing."""
    n_x = d.layout.n_x
    modes = modes.copy()
    seen, changes = [modes.copy()], []
    for _ in range(TRIM_MODE_ROUNDS):
        lin.at(t, z0[:n_x], modes)
        sol = _trim_solve(residual, z0)
        res = residual(sol.x)
        new = _settled_modes(d, lin, t, sol.x[:n_x], sol.x[n_x:], modes)
        if np.array_equal(new, modes):
            _check_trim_residuals(d, res, dict(zip(labels, res)), sol, tol, changes)
            return sol, modes
        changes.append(_mode_changes(d, modes, new))
        if any(np.array_equal(new, m) for m in seen):
            break
        seen.append(new.copy())
        modes, z0 = new, sol.x
    raise AnalysisError("trim found no point consistent with its blocks' modes: they "
                        "change at every point found (" + "; then ".join(changes) + "); "
                        "largest residuals in the last modes: " + _worst(labels, res),
                        file=d.file)


def _settled_modes(d, lin, t, x, u, modes):
    """The modes the blocks take at states ``x`` and free inputs ``u``, as at the start of a
    simulation: every block that sets its modes from its inputs (an ``initialize`` kernel,
    no time events) from its declared initial modes, the others (sampled blocks, timed
    sources) keep theirs from ``modes``."""
    m = modes.copy()
    for bl in d.layout.blocks.values():
        if bl.cls.has_kernel("initialize") and not bl.cls.has_kernel("next_time"):
            for name, (a, b) in bl.modes.items():
                m[a:b] = bl.cls.initial_value(bl.cls.modes[name], b - a, bl.params)
    system = lin.system
    lin.evaluate(x, u)                          # the free inputs into the parameters
    saved = system.modes.copy()
    system.modes[:] = m
    system.initialize(t, np.array(x, dtype=float))    # (a copy: only the modes are kept)
    m = system.modes.copy()
    system.modes[:] = saved
    return m


def _mode_changes(d, old, new):
    """The modes that differ between ``old`` and ``new``, by block: ``'sat' (Saturation)
    mode m 0 -> 1 (-1 at lower, 0 linear, +1 at upper)``."""
    items = []
    for bl in d.layout.blocks.values():
        for name, (a, b) in bl.modes.items():
            for i in range(a, b):
                if old[i] != new[i]:
                    nm = name if b - a == 1 else f"{name}[{i - a}]"
                    doc = bl.cls.modes[name].doc
                    items.append(f"'{bl.path}' ({bl.cls.type_name}) mode {nm} "
                                 f"{old[i]:g} -> {new[i]:g}" + (f" ({doc})" if doc else ""))
    return ", ".join(items)


def _worst(labels, res):
    """The six largest residuals by name: ``sat.y = -0.2, ...``."""
    worst = sorted(zip(labels, res), key=lambda kv: -abs(kv[1]))[:6]
    return ", ".join(f"{k} = {v:.3g}" for k, v in worst)


def _trim_x0(d, x0):
    """``x0`` of :func:`trim`: None or one finite number per state, as a float array."""
    if x0 is None:
        return None
    try:
        if isinstance(x0, (str, bytes, dict)):
            raise TypeError
        arr = np.ravel(np.asarray(x0, dtype=float))
        if not np.all(np.isfinite(arr)):
            raise ValueError
    except (TypeError, ValueError):
        raise AnalysisError(f"trim: x0 must be a list of finite numbers (one per state), got "
                            f"{described(x0)}", file=d.file) from None
    if arr.size != d.layout.n_x:
        raise AnalysisError(f"trim: 'x0' has {arr.size} value(s), the diagram has "
                            f"{d.layout.n_x} state(s)", file=d.file)
    return arr


def _argument_number(d, v, what, above=None):
    """A Python argument that must be a finite real number (> ``above`` when given), as a
    float; an :class:`AnalysisError` naming ``what`` otherwise."""
    if isinstance(v, (bool, np.bool_)) or not isinstance(v, numbers.Real) or not \
            math.isfinite(v) or (above is not None and not v > above):
        bound = f" > {above:g}" if above is not None else ""
        raise AnalysisError(f"{what} must be a finite number{bound}, got {described(v)}",
                            file=d.file)
    return float(v)


def trim_targets(d, targets):
    """``targets`` (signal name -> a number or a list) as arrays of the signals' sizes: a
    number for a signal of several elements holds for each; a list must have the signal's
    size (it was broadcast against it, or misaligned with the next target). Raises
    :class:`AnalysisError` naming the target."""
    if targets is not None and not isinstance(targets, collections.abc.Mapping):
        raise AnalysisError(f"trim: targets must be a mapping {{'block.port': value}}, got "
                            f"{described(targets)}", file=d.file)
    out = {}
    for name, v in dict(targets or {}).items():
        if not isinstance(name, str):
            raise AnalysisError(f"trim: a target must be a signal name 'block.port', got "
                                f"{described(name)}", file=d.file)
        size = _signal_ref(d, name)[4]
        try:
            if isinstance(v, (str, bytes, dict)):
                raise TypeError
            v = np.ravel(np.asarray(v, dtype=float))
        except (TypeError, ValueError):
            raise AnalysisError(f"trim: target '{name}' must be a number or a list of "
                                f"numbers, got {described(v)}", file=d.file) from None
        if v.size == 1:
            v = np.full(size, v[0])
        elif v.size != size:
            raise AnalysisError(f"trim: target '{name}' has {v.size} values, the signal has "
                                f"{size}", file=d.file)
        out[name] = v
    return out


def _state_names(d):
    names = [""] * d.layout.n_x
    for bl in d.layout.blocks.values():
        for s, (a, b) in bl.states.items():
            for i, nm in enumerate(_channel_names(f"{bl.path}.{s}", b - a)):
                names[a + i] = nm
    return names


class _TrimEval:
    """Evaluate derivatives and target signals of the diagram itself (no free inputs)."""

    def __init__(self, d, outs, jit):
        self.d = d
        self.system = d.compile(jit)
        self.refs = [_signal_ref(d, n) for n in outs]

    def at(self, t, x, modes):
        self.t = t
        self.system.modes[:] = modes

    def evaluate(self, x, u):
        xdot = self.system.rhs(self.t, x)
        ys = []
        for path, port, s0, s1, n, unit in self.refs:
            arr, a0, _ = self.d.layout.blocks[path].ports[("out", port)].loc
            ys.append((self.system.sig if arr == "sig" else x)[a0 + s0:a0 + s1])
        return xdot, (np.concatenate(ys) if ys else np.zeros(0))
