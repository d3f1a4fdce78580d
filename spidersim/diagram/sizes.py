"""Layout pass 1: the ports of every block, the wiring checks and the size of every port.

Contract
--------
1. :func:`port_sizes` ``(flat) -> PortSizes`` is the pass; it runs the steps below in order
   and modifies ``flat`` only in step 6.
2. Declared ports (:func:`declare_ports`): each block's input and output names, declared
   units and declared sizes (``None`` where a size follows the wiring).
3. Wiring checks (:func:`check_wiring`): each connection names known blocks and ports; each
   input has at most one source.
4. Size propagation (:func:`propagate_sizes`), to a fixed point: an output sized ``@input``
   or by a function of the input sizes follows its inputs; an input follows the output (or
   the element range of it) that feeds it; when nothing moves, one input is seeded from its
   block's ``fallback_sizes`` and propagation resumes. An element range is taken as written
   (:func:`range_bounds`: negative bounds count from the end; a range of an exposed
   subsystem output is taken of the elements it exposes) and must be inside, not empty.
5. Final checks, block by block: an unconnected input is optional (size 1 unless known) or an
   error; every output has a size; the block accepts its sizes (``check_sizes``).
6. Element ranges resolved (:func:`resolve_ranges`): every range of a connection or of an
   exposed output is checked and written into ``flat`` as ``(path, port, start, stop)``
   from the start of the output, so later passes read plain non-negative bounds.

The first error met in this order is raised (:class:`~spidersim.errors.WiringError` or
:class:`~spidersim.errors.ParameterError`, at the connection's or the block's line).
"""
from __future__ import annotations

import difflib
import os
from dataclasses import dataclass
from types import MappingProxyType
from typing import Mapping

from ..errors import ParameterError, WiringError
from .flatten import Flat, FlatConn


@dataclass(frozen=True)
class BlockPorts:
    """One block's ports as its type declares them for its parameters.

    Attributes
    ----------
    path : str
        Dotted path of the block.
    cls : type
        Block class.
    params : dict
        The instance's validated parameters (before ``derive``); not modified.
    inputs, outputs : tuple of str
        Port names in declaration order.
    declared : Mapping
        ``(kind, name) -> size`` with ``kind`` ``"in"`` or ``"out"``; ``None`` where the
        size follows the wiring.
    units : Mapping
        ``(kind, name) -> declared unit`` (before unit inference).
    """

    path: str
    cls: type
    params: dict
    inputs: tuple
    outputs: tuple
    declared: Mapping
    units: Mapping


@dataclass(frozen=True)
class PortSizes:
    """Result of pass 1: ports, sources and sizes of every block.

    Attributes
    ----------
    blocks : Mapping
        ``path -> BlockPorts``, in the flat diagram's block order.
    sources : Mapping
        ``(path, input) -> FlatConn`` feeding that input, in connection order.
    sizes : Mapping
        ``(path, kind, name) -> int`` for every port.
    """

    blocks: Mapping
    sources: Mapping
    sizes: Mapping

    def size(self, path, kind, name):
        """Size of port ``name`` (``kind`` ``"in"`` or ``"out"``) of block ``path``."""
        return self.sizes[(path, kind, name)]

    def source(self, path, name):
        """The connection feeding input ``name`` of ``path``, or None if unconnected."""
        return self.sources.get((path, name))


def port_sizes(flat: Flat) -> PortSizes:
    """Pass 1: declared ports, wiring checks, size propagation and final checks.

    Parameters
    ----------
    flat : Flat
        The flat diagram.

    Returns
    -------
    PortSizes
    """
    blocks = declare_ports(flat)
    sources = check_wiring(flat, blocks)
    sizes = propagate_sizes(flat, blocks, sources)
    return PortSizes(blocks, sources, sizes)


def declare_ports(flat: Flat):
    """``path -> BlockPorts`` of every block of ``flat``, in block order."""
    out = {}
    for path, inst in flat.blocks.items():
        cls, prm = inst.cls, inst.params
        ins, outs = tuple(cls.input_names(prm)), tuple(cls.output_names(prm))
        declared, units = {}, {}
        for kind, names, decl_of in (("in", ins, cls.input_decl), ("out", outs,
                                                                   cls.output_decl)):
            for n in names:
                d = decl_of(n)
                declared[(kind, n)] = cls.size_of(d.size, prm)
                units[(kind, n)] = cls.unit_of(d, prm)
        out[path] = BlockPorts(path, cls, prm, ins, outs, MappingProxyType(declared),
                               MappingProxyType(units))
    return MappingProxyType(out)


def check_wiring(flat: Flat, blocks):
    """Check each connection's blocks and ports; ``(path, input) -> FlatConn``.

    Raises
    ------
    WiringError
        An unknown block or port, or an input with two sources.
    """
    sources = {}
    for c in flat.conns:
        sp, sport = c.src[0], c.src[1]
        dp, dport = c.dst
        for path in (sp, dp):
            if path not in blocks:
                raise WiringError(f"unknown block '{path}'", file=c.file, line=c.line)
        _check_port(blocks[sp], sport, "out", c)
        _check_port(blocks[dp], dport, "in", c)
        if (dp, dport) in sources:
            first = sources[(dp, dport)]
            raise WiringError(f"input '{dp}.{dport}' has two sources: '{_src_text(first)}' "
                              f"(line {first.line}) and '{_src_text(c)}'",
                              file=c.file, line=c.line, block=dp)
        sources[(dp, dport)] = c
    return MappingProxyType(sources)


def _check_port(bp: BlockPorts, port, kind, c: FlatConn):
    """Raise a WiringError naming the ports of ``bp`` if it has no ``kind`` port ``port``."""
    if (kind, port) in bp.declared:
        return
    names = bp.outputs if kind == "out" else bp.inputs
    other = bp.inputs if kind == "out" else bp.outputs
    near = difflib.get_close_matches(port, names, n=2)
    hint = f"; did you mean {', '.join(near)}?" if near else ""
    extra = (f" ('{port}' is an {'input' if kind == 'out' else 'output'})"
             if port in other else "")
    word = "output" if kind == "out" else "input"
    raise WiringError(
        f"block '{bp.path}' ({bp.cls.type_name}) has no {word} '{port}'{extra}{hint}; "
        f"{word}s: {', '.join(names) or 'none'}", file=c.file, line=c.line, block=bp.path)


def propagate_sizes(flat: Flat, blocks, sources):
    """Sizes of every port: propagated to a fixed point, then checked block by block.

    Returns
    -------
    Mapping
        ``(path, kind, name) -> int``.
    """
    size = {(p, kind, n): s for p, bp in blocks.items()
            for (kind, n), s in bp.declared.items()}
    changed = True
    while changed:
        changed = _outputs_from_inputs(blocks, size)
        changed |= _inputs_from_wires(flat.conns, size)
        if not changed:
            changed = _seed_one_size(blocks, size)
    for bp in blocks.values():
        _check_block(flat, blocks, sources, size, bp)
    resolve_ranges(flat, size)
    return MappingProxyType(size)


def resolve_ranges(flat: Flat, size):
    """Check every element range as written against the sizes and write it resolved
    (non-negative, from the start of the output) into ``flat``: each connection's
    ``src`` (its ``ranges`` emptied) and each subsystem output alias. An exposed output
    of the top level is only checked.

    Raises
    ------
    WiringError
        A range empty or outside its output, at the line that writes it.
    """
    for c in flat.conns:
        if c.ranges:
            sp, sport = c.src[0], c.src[1]
            a, b = range_bounds(c.ranges, size[(sp, "out", sport)], sp)
            c.src, c.ranges = (sp, sport, a, b), ()
    for name, (path, port, ranges) in list(flat.out_ranges.items()):
        a, b = range_bounds(ranges, size[(path, "out", port)], path)
        if name in flat.aliases:
            flat.aliases[name] = (path, port, a, b)
        del flat.out_ranges[name]


def range_bounds(ranges, n, path):
    """``(start, stop)`` in an output of size ``n`` (of block ``path``) of the element
    ranges ``ranges`` (:class:`~.flatten.Range`, innermost first: each is taken of the
    elements the one before selects). Negative bounds count from the end, as for
    :func:`norm_slice`.

    Raises
    ------
    WiringError
        A range empty or outside what it selects from, at its own file and line, naming
        the block or subsystem instance it reads (:attr:`~.flatten.Range.at`; else block
        ``path`` for the innermost range only), so the instances around it are named.
    """
    off = 0
    for k, r in enumerate(ranges):
        a, b = _bounds(r.start, r.stop, n)
        if not 0 <= a < b <= n:
            elem = "element range" if ":" in r.text else "element"
            why = "is empty" if 0 <= a <= n and 0 <= b <= n else "is outside"
            raise WiringError(f"{r.what} '{r.of}{r.text}': {elem} {r.text} {why}: "
                              f"'{r.of}' has size {n} (indices 0..{n - 1}, or "
                              f"-{n}..-1 from the end)", file=r.file, line=r.line,
                              block=r.at or (path if k == 0 else None))
        off, n = off + a, b - a
    return off, off + n


def _bounds(s0, s1, n):
    """``(a, b)`` of ``[s0:s1]`` in a size ``n`` (negative bounds from the end, ``s1``
    None: the end), not checked."""
    a = s0 + n if s0 < 0 else s0
    b = n if s1 is None else (s1 + n if s1 < 0 else s1)
    return a, b


def _outputs_from_inputs(blocks, size):
    """Size outputs declared ``@input`` or by a function of the input sizes (in place);
    True if one was sized."""
    changed = False
    for bp in blocks.values():
        for n in bp.outputs:
            if size[(bp.path, "out", n)] is None:
                size[(bp.path, "out", n)] = _output_size(bp, n, size)
                changed |= size[(bp.path, "out", n)] is not None
    return changed


def _output_size(bp, name, size):
    """Size of output ``name`` of ``bp`` from its input sizes so far, or None."""
    spec = bp.cls.output_decl(name).size
    if isinstance(spec, str) and spec.startswith("@"):
        return size[(bp.path, "in", spec[1:])]
    if spec is not None and hasattr(spec, "fn") and hasattr(spec, "text") \
            and spec.fn.__code__.co_argcount == 2:
        ins = {m: size[(bp.path, "in", m)] for m in bp.inputs}
        if all(v is not None for v in ins.values()):
            return int(spec.fn(bp.params, ins))
    return None


def _inputs_from_wires(conns, size):
    """Size each input from the output (range) that feeds it (in place); True if one was
    sized.

    Raises
    ------
    WiringError
        An element range outside its output, or a size mismatch.
    """
    changed = False
    for c in conns:
        sp, sport, s0, s1 = c.src
        n_src = size[(sp, "out", sport)]
        if n_src is None:
            continue
        if c.ranges:
            a, b = range_bounds(c.ranges, n_src, sp)
            width = b - a
        elif s0 is not None:
            a, b = norm_slice(s0, s1, n_src, c)
            width = b - a
        else:
            width = n_src
        key = (c.dst[0], "in", c.dst[1])
        if size[key] is None:
            size[key] = width
            changed = True
        elif size[key] != width:
            raise WiringError(
                f"size mismatch on '{c.text}': the source gives {width} element(s), "
                f"input '{c.dst[0]}.{c.dst[1]}' expects {size[key]}", file=c.file,
                line=c.line, block=c.dst[0])
    return changed


def _seed_one_size(blocks, size):
    """Set one still-unknown input size from its block's ``fallback_sizes``; True if one
    was set (propagation then resumes, so a seed never overrides what wiring decides)."""
    for bp in blocks.values():
        fb = None
        for n in bp.inputs:
            if size[(bp.path, "in", n)] is None:
                fb = bp.cls.fallback_sizes(bp.params) if fb is None else fb
                if n in fb:
                    size[(bp.path, "in", n)] = int(fb[n])
                    return True
    return False


def _check_block(flat, blocks, sources, size, bp):
    """Final checks of one block: unconnected inputs (optional ones sized 1 if unknown, in
    place), sized outputs, ``check_sizes``."""
    inst = flat.blocks[bp.path]
    for n in bp.inputs:
        if (bp.path, n) in sources:
            continue
        if _is_optional(bp, n):
            if size[(bp.path, "in", n)] is None:
                size[(bp.path, "in", n)] = 1
            continue
        _raise_exposed(flat, bp, n)
        raise WiringError(_unconnected_msg(blocks, size, bp, n), block=bp.path,
                          file=inst.file, line=inst.line)
    for n in bp.outputs:
        if size[(bp.path, "out", n)] is None:
            raise WiringError(f"cannot infer the size of output '{n}': connect the "
                              f"inputs it follows", block=bp.path, file=inst.file,
                              line=inst.line)
    sizes = {n: size[(bp.path, "in", n)] for n in bp.inputs}
    sizes.update({n: size[(bp.path, "out", n)] for n in bp.outputs})
    try:
        bp.cls.check_sizes(bp.params, sizes)
    except ValueError as exc:
        raise ParameterError(str(exc), block=bp.path, file=inst.file,
                             line=inst.line) from None


def _is_optional(bp, name):
    """True if input ``name`` of ``bp`` may stay unconnected with these parameters."""
    optional = bp.cls.input_decl(name).optional
    return optional(bp.params) if callable(optional) else optional


def _raise_exposed(flat, bp, name):
    """Raise at the subsystem instance if the unconnected input ``name`` is fed by an
    exposed input of a subsystem instance; return otherwise."""
    exposed = flat.exposed.get((bp.path, name))
    if exposed is None or exposed[0] not in flat.instances:
        return
    inst_path, ext, sub_file, sub_line = exposed
    typ, file, line = flat.instances[inst_path]
    raise WiringError(
        f"input '{ext}' of subsystem instance '{inst_path}' (type '{typ}') "
        f"is not connected; it feeds {bp.path}.{name} "
        f"({os.path.basename(sub_file)}:{sub_line}). Connect it: "
        f"'some_block.y -> {inst_path.rpartition('.')[2]}.{ext}'",
        file=file, line=line, block=inst_path)


def _src_text(c):
    sp, sport, s0, s1 = c.src
    return f"{sp}.{sport}" + ("".join(r.text for r in c.ranges) if c.ranges else
                              "" if s0 is None else f"[{s0}:{s1}]")


def norm_slice(s0, s1, n, c):
    """``(start, stop)`` of the element range ``[s0:s1]`` of an output of size ``n``
    (negative bounds count from the end).

    Raises
    ------
    WiringError
        The range is empty or outside the output (at connection ``c``).
    """
    a, b = _bounds(s0, s1, n)
    if not (0 <= a < b <= n):
        raise WiringError(f"element range [{s0}:{s1}] is outside output "
                          f"'{c.src[0]}.{c.src[1]}' of size {n}", file=c.file, line=c.line,
                          block=c.src[0])
    return a, b


def _unconnected_msg(blocks, size, bp, name):
    """Message for the unconnected input ``name`` of ``bp``, listing outputs of matching
    size and declared unit."""
    n_in = size[(bp.path, "in", name)]
    u_in = bp.units[("in", name)]
    cand = []
    for other in blocks.values():
        if other.path == bp.path:
            continue
        for o in other.outputs:
            n_out, u_out = size[(other.path, "out", o)], other.units[("out", o)]
            if (n_in is None or n_out == n_in) and _units_may_match(u_in, u_out):
                fixed = u_out != "*" and "@" not in u_out
                cand.append(f"{other.path}.{o}" + (f" [{u_out}]" if fixed else ""))
    n_text = "any size" if n_in is None else f"size {n_in}"
    hint = (f"; outputs of matching size and unit: {', '.join(cand[:8])}"
            + (" ..." if len(cand) > 8 else "")) if cand else "; no output matches it"
    decl = bp.cls.input_decl(name)
    why = f" ({decl.doc}, with these parameters)" if callable(decl.optional) else ""
    return f"input '{name}' [{u_in}, {n_text}] is not connected{why}{hint}"


def _units_may_match(u_in, u_out):
    """True if declared units ``u_in`` and ``u_out`` may agree (inference runs later)."""
    loose = ("1", "*")
    return u_in in loose or u_out in loose or "@" in u_in + u_out or u_out == u_in
