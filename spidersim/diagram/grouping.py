"""Kernel calls of identical blocks emitted once, as a loop over their offsets.

A diagram made of several instances of one subsystem (the seven joints of ``spider.yaml``)
calls the same kernel with the same kinds of arguments once per instance; only the offsets
into the flat arrays differ. numba types, lowers and optimizes every call site, so the
compile time grew with the number of instances. This pass finds such calls and emits each
set once, as a loop over tables of offsets::

    for _i in range(7):
        _k_BrushlessMotor_output(t, _v(x, _g3_1[_i], _g3_1[_i] + 1), p[_g3_4[_i]], ...)

Rules
-----
1. A call is a kernel name and its argument expressions (:class:`Call`); its *key* is the
   name with every offset taken out of ``_v(arr, a, b)`` (kept: the array and the width
   ``b - a``) and ``p[a]``; any other expression (a constant, ``t``) must match exactly.
2. Calls are grouped in order: a later call with the same key joins the first one's group
   if it can move up to it, i.e. it has no read-after-write, write-after-read or
   write-after-write conflict with any call it moves over (:func:`conflict`; reads and
   writes are sets of ``(array, index)``). A call that reads or writes everything (a Newton
   solve of an algebraic loop) is a barrier: nothing moves over it.
3. Inside a group the calls keep their order, so the group computes exactly what the calls
   computed one by one (the same operations on the same values: bit-identical results).
4. The offsets become module constants (tuples of integers, literals of the layout), so the
   generated text still holds every structural decision and stays the cache key.
"""
from __future__ import annotations

import re
from dataclasses import dataclass

_VIEW = re.compile(r"^_v\((\w+), (\d+), (\d+)\)(.*)$")
_PARAM = re.compile(r"^p\[(\d+)\]$")


@dataclass(frozen=True)
class Call:
    """One kernel call: ``name(*args)``.

    ``reads`` and ``writes`` are frozensets of ``(array name, index)``; ``None`` for both
    marks a barrier (the call may touch anything).
    """

    name: str
    args: tuple
    reads: frozenset | None = frozenset()
    writes: frozenset | None = frozenset()

    @property
    def barrier(self) -> bool:
        return self.reads is None

    def key(self):
        """The call with its offsets taken out (rule 1), or None for a barrier."""
        if self.barrier:
            return None
        return (self.name,) + tuple(_template(a)[0] for a in self.args)


def _template(expr):
    """``(template, offset)``: the expression with its offset taken out, or
    ``(expr, None)`` when it has none."""
    m = _VIEW.match(expr)
    if m:
        arr, a, b, tail = m.group(1), int(m.group(2)), int(m.group(3)), m.group(4)
        return ("v", arr, b - a, tail), a
    m = _PARAM.match(expr)
    if m:
        return ("p",), int(m.group(1))
    return ("=", expr), None


def conflict(a: Call, b: Call) -> bool:
    """Whether ``a`` and ``b`` may not swap places (rule 2)."""
    if a.barrier or b.barrier:
        return True
    return bool(a.writes & (b.reads | b.writes) or b.writes & a.reads)


def group(calls):
    """The calls in groups (lists) of equal key, in an order equivalent to the given one."""
    remaining = list(calls)
    out = []
    while remaining:
        first = remaining.pop(0)
        grp = [first]
        key = first.key()
        if key is not None:
            passed = []
            i = 0
            while i < len(remaining):
                c = remaining[i]
                if c.barrier:
                    break
                if c.key() == key and not any(conflict(c, d) for d in passed):
                    grp.append(remaining.pop(i))
                else:
                    passed.append(c)
                    i += 1
        out.append(grp)
    return out


def emit(groups, tables, indent="    ", body=None):
    """Lines for ``groups``; offset tables are added to ``tables`` (name -> tuple).

    ``body(call_text)`` makes the statement lines of one call (default: the call alone), so
    that ``v = call`` / ``if v < tn`` patterns can be grouped too.
    """
    body = body or (lambda text: [text])
    lines = []
    for grp in groups:
        if len(grp) == 1:
            c = grp[0]
            lines += [indent + s for s in body(f"{c.name}({', '.join(c.args)})")]
            continue
        args = []
        for k, expr in enumerate(grp[0].args):
            tpl, _ = _template(expr)
            offsets = tuple(_template(c.args[k])[1] for c in grp)
            if tpl[0] == "=" or len(set(offsets)) == 1:
                args.append(expr)
                continue
            name = f"_g{len(tables)}"
            tables[name] = offsets
            if tpl[0] == "p":
                args.append(f"p[{name}[_i]]")
            else:
                _, arr, width, tail = tpl
                args.append(f"_v({arr}, {name}[_i], {name}[_i] + {width}){tail}")
        lines.append(f"{indent}for _i in range({len(grp)}):")
        lines += [indent + "    " + s for s in body(f"{grp[0].name}({', '.join(args)})")]
    return lines


def table_text(tables) -> str:
    """Module-level definitions of the offset tables."""
    return "".join(f"{name} = {values!r}\n" for name, values in tables.items())
