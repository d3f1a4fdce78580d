"""Arrays of block instances in YAML: one entry that makes N blocks, connections that fan out
by index.

A block key ``name[a..b]`` makes the blocks ``name<a>`` ... ``name<b>`` (inclusive, e.g.
``j[1..7]`` makes ``j1`` ... ``j7``); a parameter written ``{each: [v_a, ..., v_b]}`` gives
each instance its own value, any other value is shared. A connection holding ``{i}`` (or
``{i+1}``, ``{i-1}``) is repeated for every index of the array it names as ``name{i}``::

    blocks:
      j[1..7]: {type: joint, q0: {each: [0, 0.6, 0, -1.3, 0, 0.8, 0]}, N: 160}
    connections:
      - q_ref.y{i} -> j{i}.q_ref          # q_ref.y1 -> j1.q_ref ... q_ref.y7 -> j7.q_ref
      - arm.q[{i-1}] -> j{i}.phi_l        # element i-1 of the arm's joint angles

An index worked out from ``{i-N}`` may not be negative (``c.y[{i-2}]`` for ``g[1..3]``
is refused at ``g1``): a negative index written out (``c.y[-1]``) counts from the end, a
computed one is an off-by-one that would read another element. A name worked out negative
(``g{i-1}.y`` for ``g[0..2]`` gives ``g-1`` at ``g0``) is refused as naming nothing.

Errors name the array entry and the instance (``block 'j[1..7]', instance j3``).
"""
from __future__ import annotations

import re

from ..errors import DiagramError, described

#: most instances one array entry may make (a bounded input)
MAX_INSTANCES = 1000

#: ASCII digits only (``\d`` matches other scripts' digits, which ``int`` reads as numbers)
ARRAY_KEY = re.compile(r"^([A-Za-z_][A-Za-z0-9_]*)\[\s*([0-9]+)\s*\.\.\s*([0-9]+)\s*\]\Z")
_PLACE = re.compile(r"\{\s*i\s*(?:([+-])\s*([0-9]+)\s*)?\}")
#: ``name{i}`` as the block of an endpoint: not after a dot, so the port of ``m.u{i}``
#: (inputs u1, u2, ... of one block) is not read as an array ``u``
_USES = re.compile(r"(?<![.\w])([A-Za-z_][A-Za-z0-9_]*)\{\s*i\s*\}")


def array_key(key):
    """``(base, indices)`` of an array key ``name[a..b]``, or None for a plain name."""
    m = ARRAY_KEY.match(key) if isinstance(key, str) else None
    if not m:
        return None
    a, b = int(m.group(2)), int(m.group(3))
    return m.group(1), range(a, b + 1)


def expand_block(key, entry, file, line):
    """The ``(name, entry)`` pairs an array entry makes (checked), in index order."""
    base, idx = array_key(key)
    # the count from the bounds, not len(range): a range of 10^20 indices has no len
    n = idx.stop - idx.start
    if n < 1 or n > MAX_INSTANCES:
        got = n if abs(n) < 10**9 else (f"{n:.3g}" if abs(n) < 10**300 else
                                         f"a number of {len(str(n))} digits")
        raise DiagramError(f"block '{key}': an array needs 1 to {MAX_INSTANCES} instances "
                           f"(a..b with a <= b), got {got}", file=file, line=line)
    if not isinstance(entry, dict):
        return [(f"{base}{i}", entry) for i in idx]
    out = []
    for k, i in enumerate(idx):
        inst = type(entry)()
        for p, v in entry.items():
            if isinstance(v, dict) and set(v) == {"each"}:
                vals = v["each"]
                if not isinstance(vals, list) or len(vals) != n:
                    got = len(vals) if isinstance(vals, list) else described(vals)
                    raise DiagramError(
                        f"block '{key}': parameter '{p}': 'each' needs a list of {n} values "
                        f"(one per instance {base}{idx[0]}..{base}{idx[-1]}), got {got}",
                        file=file, line=entry.line_of(p) if hasattr(entry, "line_of")
                        else line)
                v = vals[k]
            inst[p] = v
        if hasattr(entry, "lines"):
            inst.line = entry.line
            inst.lines = dict(entry.lines)
        out.append((f"{base}{i}", inst))
    return out


def expand_connection(text, arrays, file, line):
    """The connection strings a pattern with ``{i}`` stands for (the text itself when it has
    none); ``arrays`` maps array names to their index ranges."""
    if not isinstance(text, str) or "{" not in text:
        return [text]
    used = sorted(set(_USES.findall(text)))
    known = [u for u in used if u in arrays]
    if not known:
        raise DiagramError(f"connection '{text}' uses {{i}} but names no block array "
                           f"(write name{{i}} for an array 'name[a..b]'; arrays: "
                           f"{', '.join(arrays) or 'none'})", file=file, line=line)
    idx = arrays[known[0]]
    for u in known[1:]:
        if arrays[u] != idx:
            raise DiagramError(f"connection '{text}': arrays '{known[0]}' and '{u}' have "
                               f"different index ranges", file=file, line=line)
    out = []
    for i in idx:
        def sub(m, i=i):
            v = i + (int(m.group(2)) * (1 if m.group(1) == "+" else -1) if m.group(1) else 0)
            if v < 0:
                raise _negative(text, m, f"{known[0]}{i}", i, v, file, line)
            return str(v)
        out.append(_PLACE.sub(sub, text))
    if any("{" in o for o in out):
        raise DiagramError(f"connection '{text}': only {{i}}, {{i+N}} and {{i-N}} may stand "
                           f"in braces", file=file, line=line)
    return out


def _negative(text, m, inst, i, v, file, line):
    """The error for the place ``m`` (a match of ``{i-2}``) of connection ``text`` working
    out to the negative number ``v`` for instance ``inst`` (index ``i``).

    Inside brackets it is an index: a written ``[-1]`` counts from the end, as in Python; a
    computed one is an off-by-one (``{i-1}`` of an array starting at 0), which would
    silently read the last element. Elsewhere it is part of a name (``g{i-1}.y`` of
    ``g[0..2]`` gives ``g-1`` for ``g0``), which names nothing.
    """
    place = m.group(0)
    before = text[:m.start()]
    where = f"connection '{text}': for instance {inst} (i = {i})"
    if before.count("[") > before.count("]"):
        return DiagramError(f"{where}, {place} is {v}: an index computed from {{i}} may not "
                            f"be negative (it would count from the end, reading another "
                            f"element); start the array higher or change the offset",
                            file=file, line=line)
    stem = re.search(r"[A-Za-z0-9_]*$", before).group()
    kind = "port" if before[:len(before) - len(stem)].endswith(".") else "block"
    return DiagramError(f"{where}, the {kind} name {stem}{place} gives {stem}{v}, which "
                        f"names no {kind}: the pattern runs over every instance of the "
                        f"array; write the connections it cannot make one by one (a chain's "
                        f"first link)", file=file, line=line)
