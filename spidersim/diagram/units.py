"""Unit inference: every port, state and real parameter of the flat diagram gets a unit.

One pass over the flat diagram, run when the diagram is compiled:

1. *Variables*: one per port, state and real parameter of every block. A declared unit
   (``"A"``, ``"N.m"``, ``"1"``) binds its variable; ``"*"`` leaves it free; a rule such as
   ``"@u"`` (the same unit as ``u``) joins two variables, and a product rule such as
   ``"@k*@u"`` or ``"@u*s"`` becomes a relation. A parameter given in the file as
   ``{value: 2, unit: V/A}`` binds its variable too.
2. *Connections* join the source output and the destination input: same unit, or an error
   at the connection's file:line naming both units.
3. *Relations* are solved to a fixed point: a relation whose terms are all known but one
   gives that one (``y = k u``: y from k and u, or k from y and u). Directed relations carry a
   unit forward only: a Mux output takes its inputs' unit when they all agree, a Demux or
   Selector output takes its input's.

What stays free is shown as ``?`` (nothing in the diagram fixes it: e.g. a Sine feeding only
a plot). The result maps ``(path, kind, name)`` to Modelica unit text.
"""
from __future__ import annotations

import math

import numpy as np

from ..errors import DiagramError
from ..text import units as U

UNKNOWN = "?"


class UnitMismatchError(DiagramError):
    """Two units that must be the same are not."""


class _Classes:
    """Union-find over variables; each class holds a unit, its text and where it came from.

    A class also keeps every distinct unit bound to it (``bound``): "the same unit" (factor
    1) is not transitive (``Hz`` is ``1/s`` and ``rad/s`` is ``1/s``, but ``rad/s`` is not
    ``Hz``), so a new unit is compared with each of them, not with the first alone (else a
    class would accept ``Hz`` and ``rad/s`` or not depending on the order of binding)."""

    def __init__(self):
        self.parent = {}
        self.unit = {}       # root -> (pint unit, text, origin)
        self.bound = {}      # root -> [(pint unit, text, origin)], distinct units

    def add(self, v):
        self.parent.setdefault(v, v)

    def find(self, v):
        root = v
        while self.parent[root] != root:
            root = self.parent[root]
        while self.parent[v] != root:
            self.parent[v], v = root, self.parent[v]
        return root

    def get(self, v):
        return self.unit.get(self.find(v))

    def bind(self, v, unit, text, origin):
        """Bind ``v``'s class; return the conflicting binding or None."""
        r = self.find(v)
        have = self.bound.setdefault(r, [])
        for h in have:
            if not U.same(h[0], unit):
                return h
        if r not in self.unit:
            self.unit[r] = (unit, text, origin)
        if not any(h[0] == unit for h in have):
            have.append((unit, text, origin))
        return None

    def union(self, a, b):
        """Join the classes; return (binding of a, binding of b) when they conflict."""
        ra, rb = self.find(a), self.find(b)
        if ra == rb:
            return None
        ba, bb = self.bound.get(ra, []), self.bound.get(rb, [])
        for x in ba:
            for y in bb:
                if not U.same(x[0], y[0]):
                    return x, y
        ua, ub = self.unit.get(ra), self.unit.get(rb)
        self.parent[rb] = ra
        if ua is None and ub is not None:
            self.unit[ra] = ub
        self.unit.pop(rb, None)
        merged = self.bound.setdefault(ra, [])
        for y in self.bound.pop(rb, []):
            if not any(x[0] == y[0] for x in merged):
                merged.append(y)
        return None


def _names(cls, params):
    """name -> (kind, declaration) in lookup order for ``@name``: inputs, outputs, params,
    states."""
    out = {}
    for n in cls.input_names(params):
        out.setdefault(n, ("in", cls.input_decl(n)))
    for n in cls.output_names(params):
        out.setdefault(n, ("out", cls.output_decl(n)))
    for n, p in cls.parameters.items():
        if p.kind == "real":
            out.setdefault(n, ("param", p))
    for n, s in cls.states.items():
        out.setdefault(n, ("state", s))
    return out


def _declared(decl, params):
    u = decl.unit
    return u(params) if callable(u) else u


def related_names(cls, params) -> set:
    """The names of block type ``cls`` (ports, states, real parameters) that a unit rule or
    a unit relation of the block uses: ``k`` of a Gain (``y`` is ``@k*@u``). A unit given
    with a parameter declared ``*`` takes part in unit inference only when its name is one
    of them."""
    names = _names(cls, params)
    out = set()
    for _kind, decl in names.values():
        rule = _declared(decl, params)
        if rule != U.ANY:
            out.update(n for n, _p in U.rule_terms(rule)[0])
    for _mode, target, sources in cls.unit_relations(params):
        out.add(target)
        out.update(sources)
    return out


def _refuse_offset(inst, v, rule, fixed):
    """A port or state (``v``) may not be declared in a temperature scale with an offset
    (``degC``, ``degF``): the unit rules multiply, integrate and add signals by factors,
    which such a scale does not obey (a Gain of 2 on 20 degC gave 40 degC, and 20 degC
    summed with 300 K gave 320 K where 293.15 + 300 was meant). A UnitMismatchError at
    the block names the unit and what to write instead. A parameter may be declared in
    one (its value is converted to it)."""
    if v[1] == "param":
        return
    try:
        U.check_no_offset(fixed, "a signal (multiplied, integrated and added by factors)")
    except U.UnitError as exc:
        raise UnitMismatchError(f"{inst.cls.type_name}: '{v[2]}' is declared [{rule}]: "
                                f"{exc}", file=inst.file, line=inst.line,
                                block=inst.path) from None


def _describe(v):
    path, kind, name = v
    return f"{path}.{name}"


class _Problem:
    def __init__(self, flat):
        self.flat = flat
        self.c = _Classes()
        self.relations = []     # (target, [(var, power)], fixed unit, block instance, rule)
        self.directed = []      # ("common"|"copy", target, [vars], instance)
        self.equal = []         # (var, var, instance, rule): "@x" rules inside a block

    def var(self, path, name, names):
        kind = names[name][0]
        return (path, "in" if kind == "in" else kind, name)

    def declare(self, inst):
        cls, params = inst.cls, inst.params
        names = _names(cls, params)
        given = getattr(inst, "param_units", {}) or {}
        for name, (kind, decl) in names.items():
            v = (inst.path, kind, name)
            self.c.add(v)
        for name, (kind, decl) in names.items():
            v = (inst.path, kind, name)
            if kind == "param" and name in given:
                unit = U.parse(given[name])
                self.c.bind(v, unit, given[name], f"{_describe(v)} is given as [{given[name]}]")
            self._rule(inst, names, v, _declared(decl, params), decl)
        for rel in cls.unit_relations(params):
            mode, target, sources = rel
            if mode not in ("common", "copy"):
                raise ValueError(f"{cls.type_name}.unit_relations: unknown mode {mode!r}")
            self.directed.append((mode, self.var(inst.path, target, names),
                                  [self.var(inst.path, s, names) for s in sources], inst))

    def _rule(self, inst, names, v, rule, decl):
        if rule == U.ANY:
            return
        refs, fixed = U.rule_terms(rule)
        _refuse_offset(inst, v, rule, fixed)
        for name, _p in refs:
            if name not in names:
                raise ValueError(f"{inst.cls.type_name}: unit rule '{rule}' of "
                                 f"'{v[2]}' names '{name}', which the block does not have")
        if not refs:
            bad = self.c.bind(v, fixed, rule, f"{_describe(v)} is [{rule}]")
            if bad is not None:
                self._conflict_in_block(inst, v, bad, (fixed, rule, f"declared [{rule}]"))
            return
        ref_vars = [(self.var(inst.path, n, names), p) for n, p in refs]
        if len(ref_vars) == 1 and ref_vars[0][1] == 1 and U.same(fixed, U.DIMENSIONLESS):
            # joined after the connections, so that a clash is reported at the block
            self.equal.append((v, ref_vars[0][0], inst, rule))
            return
        self.relations.append((v, ref_vars, fixed, inst, rule))

    def join_inside_blocks(self):
        for v, w, inst, rule in self.equal:
            bad = self.c.union(v, w)
            if bad is not None:
                self._conflict_in_block(inst, v, bad[0], bad[1], rule)

    def _conflict_in_block(self, inst, v, a, b, rule=None):
        how = f" ('{v[2]}' must have the unit of '{rule[1:]}')" if rule else ""
        raise UnitMismatchError(
            f"{inst.cls.type_name}: unit mismatch{how}: {a[2]}, but "
            f"{b[2]}", file=inst.file, line=inst.line, block=inst.path)

    def connect(self, conn):
        src = (conn.src[0], "out", conn.src[1])
        dst = (conn.dst[0], "in", conn.dst[1])
        bad = self.c.union(src, dst)
        if bad is not None:
            (ua, ta, _), (ub, tb, _) = bad
            raise UnitMismatchError(
                f"connection '{conn.text}': {_describe(src)} is [{ta}] but "
                f"{_describe(dst)} is [{tb}]; connect a signal in [{tb}], or insert a "
                f"UnitCast block (unit: {tb}) if reading [{ta}] as [{tb}] is deliberate"
                + self._inside(conn.dst[0], conn.file), file=conn.file, line=conn.line)

    def _inside(self, path, file):
        """The enclosing instances of a connection written in a subsystem's file."""
        enclosing = path.rpartition(".")[0]
        if enclosing and self.flat.subsystem_instances.get(enclosing) == file:
            return self.flat.used_at(path)
        return ""

    def _solve_relation(self, target, refs, fixed, inst, rule):
        """One step on ``target = fixed * prod(ref ** p)``; True when something was bound."""
        terms = [(target, -1)] + refs          # fixed * prod(term ** p) == 1
        unknown = [(v, p) for v, p in terms if self.c.get(v) is None]
        # the same class may appear twice (y = u * u); collect powers per class
        if len({self.c.find(v) for v, _ in unknown}) > 1:
            return False
        product = fixed
        for v, p in terms:
            b = self.c.get(v)
            if b is not None:
                product = product * b[0] ** p
        if not unknown:
            if not U.same(product, U.DIMENSIONLESS):
                t = self.c.get(target)
                got = fixed
                for v, p in refs:
                    got = got * self.c.get(v)[0] ** p
                raise UnitMismatchError(
                    f"{inst.cls.type_name}: unit mismatch: '{target[2]} = {rule}' "
                    f"gives [{U.text(got)}] but {t[2]}", file=inst.file, line=inst.line,
                    block=inst.path)
            return False
        p_total = sum(p for _, p in unknown)
        if p_total == 0:
            return False
        unit = (product ** -1) ** (1.0 / p_total) if p_total != 1 else product ** -1
        v = unknown[0][0]
        _refuse_scaled_number(v, unit, target, rule, inst)
        self.c.bind(v, unit, U.text(unit), f"{_describe(v)} inferred [{U.text(unit)}] "
                    f"from '{target[2]} = {rule}' of block '{inst.path}'")
        return True

    def _solve_directed(self, mode, target, sources, inst):
        if self.c.get(target) is not None:
            return False
        got = [self.c.get(s) for s in sources]
        if any(g is None for g in got):
            return False
        if mode == "common" and not all(U.same(g[0], got[0][0]) for g in got[1:]):
            return False        # a vector of mixed units: no single unit
        g = got[0]
        self.c.bind(target, g[0], g[1], f"{_describe(target)} from {_describe(sources[0])} "
                    f"[{g[1]}]")
        return True

    def solve(self):
        changed = True
        while changed:
            changed = False
            for rel in self.relations:
                changed |= self._solve_relation(*rel)
            for rel in self.directed:
                changed |= self._solve_directed(*rel)
        for rel in self.relations:       # fully known relations are checked once more
            self._solve_relation(*rel)
        self._check_free_relations()

    def _free_rows(self):
        """The relations that still have a free term, as rows of a linear system in the
        logarithms of the free classes' units: ``(coefficients by class, rhs, relation)``
        with ``rhs`` the dimension exponents and log scale of the known part. A relation
        with a unit of a scale with an offset (``degC``) has no such form and is left out."""
        rows = []
        for rel in self.relations:
            target, refs, fixed, _inst, _rule = rel
            coef, product = {}, fixed
            for v, p in [(target, -1)] + refs:
                b = self.c.get(v)
                if b is None:
                    r = self.c.find(v)
                    coef[r] = coef.get(r, 0) + p
                else:
                    product = product * b[0] ** p
            if not coef:
                continue
            try:
                scale = U.factor(product, U.base(product))
            except U.UnitError:
                continue
            rhs = dict(product.dimensionality)
            rhs["scale"] = math.log(scale)
            rows.append((coef, {k: -x for k, x in rhs.items()}, rel))
        return rows

    def _check_free_relations(self):
        """Relations left with free terms must have a common solution: ``g1.y = 90 deg *
        c.y`` and ``g2.y = 1 rad * c.y`` with ``g1.y`` and ``g2.y`` summed (one class) hold
        together for no unit of ``c.y`` (the sum would add 90 c and 1 c raw). Solved by
        least squares in the logarithms of the units; a residual is a UnitMismatchError at
        the first relation that makes the system inconsistent."""
        for rows in _components(self._free_rows()):
            if not _consistent(rows):
                self._refuse_free(rows)
            self._check_free_inputs(rows)

    def _refuse_free(self, rows):
        """The UnitMismatchError for inconsistent ``rows`` (see :meth:`_check_free_relations`),
        at the first row that makes them so."""
        n = next(n for n in range(1, len(rows) + 1) if not _consistent(rows[:n]))
        # rows[:n - 1] hold together and the row n - 1 is fixed by them: its residual
        # is the same for every solution of theirs
        bad = _fit(rows[:n - 1])[1](rows[n - 1]) if n > 1 else _fit(rows[:1])[1](rows[0])
        coef, _rhs, (target, _refs, _fixed, inst, rule) = rows[n - 1]
        others = sorted({r[2][3].path for r in rows[:n - 1]
                         if set(r[0]) & set(coef)} - {inst.path})
        free = sorted(_describe(v) for v in self.c.parent
                      if v[1] == "out" and self.c.find(v) in coef)
        what = (f"a pure number scaled by {math.exp(bad['scale']):.6g} (in deg on one path "
                f"and rad on another, % and 1, mN.m and N.m)" if set(bad) == {"scale"}
                else "units of different dimensions")
        with_ = (f" with the relations of block{'s' if len(others) > 1 else ''} "
                 f"{', '.join(repr(o) for o in others)}" if others else "")
        raise UnitMismatchError(
            f"{inst.cls.type_name}: unit mismatch: '{target[2]} = {rule}' of block "
            f"'{inst.path}' does not hold{with_} for any unit of the free signals "
            f"{', '.join(free[:6])}{' ...' if len(free) > 6 else ''}: their paths differ "
            f"by {what}; "
            f"give the gains matching units, or the signals a unit ({{value: ..., unit: "
            f"...}})", file=inst.file, line=inst.line, block=inst.path)

    def _check_free_inputs(self, rows):
        """Two free classes that only feed relations (a plain Constant before a Gain in deg,
        another before a Gain in rad) may not be forced to differ by a scaled pure number:
        ``g1.y = 90 deg * c1.y`` and ``g2.y = 1 rad * c2.y`` summed hold only with
        ``c2.y`` in [deg/rad] of ``c1.y`` (the sum adds 90 c1 and 1 c2 raw, 91 where
        pi/2 + 1 was meant), as one Constant before both Gains is refused by
        :meth:`_check_free_relations`. A ratio of a dimension (one input in m, one in s)
        stays free: it may be meant."""
        targets = {self.c.find(rel[0]) for _c, _r, rel in rows}
        inputs = sorted({k for c, _r, _rel in rows for k in c} - targets, key=repr)
        found = _pure_number_ratio(rows, inputs)
        if found:
            self._refuse_inputs(rows, *found)

    def _refuse_inputs(self, rows, i, j, factor):
        """The UnitMismatchError for free input classes ``i`` and ``j`` forced to a ratio
        of a pure number ``factor`` (see :meth:`_check_free_inputs`), at the last relation
        that reads ``j``, naming the blocks of the relations that read either."""
        names = {k: sorted(_describe(v) for v in self.c.parent
                           if v[1] == "out" and self.c.find(v) == k) for k in (i, j)}
        readers = [rel for c, _r, rel in rows if i in c or j in c]
        target, _refs, _fixed, inst, rule = next(rel for c, _r, rel in reversed(rows)
                                                 if j in c)
        others = sorted({rel[3].path for rel in readers} - {inst.path})
        with_ = (f" with the relations of block{'s' if len(others) > 1 else ''} "
                 f"{', '.join(repr(o) for o in others)}" if others else "")
        sig = [", ".join(names[k]) or "?" for k in (i, j)]
        raise UnitMismatchError(
            f"{inst.cls.type_name}: unit mismatch: '{target[2]} = {rule}' of block "
            f"'{inst.path}' holds{with_} only if the free signals {sig[0]} and {sig[1]} "
            f"differ by a pure number scaled by {factor:.6g} (in deg on one path and rad on "
            f"another, % and 1, mN.m and N.m): their plain values would be summed raw; "
            f"give the gains matching units, or the signals a unit ({{value: ..., unit: "
            f"...}})", file=inst.file, line=inst.line, block=inst.path)

    def result(self):
        out = {}
        for v in self.c.parent:
            b = self.c.get(v)
            out[v] = b[1] if b is not None else UNKNOWN
        return out


def _fit(rows):
    """The least-squares solution of the rows ``(coefficients by class, rhs, relation)``:
    ``(x, residual)``, functions of a class (its solved logarithm, by component of ``rhs``)
    and of a row (its residual by component, only those that do not vanish: ``"scale"``,
    ``"[length]"``)."""
    cols = sorted({k for c, _r, _rel in rows for k in c}, key=repr)
    keys = sorted({k for _c, r, _rel in rows for k in r})
    a = np.array([[c.get(k, 0.0) for k in cols] for c, _r, _rel in rows], dtype=float)
    b = np.array([[r.get(k, 0.0) for k in keys] for _c, r, _rel in rows], dtype=float)
    x = np.linalg.lstsq(a, b, rcond=None)[0]
    sol = {c: dict(zip(keys, x[i])) for i, c in enumerate(cols)}

    def residual(row):
        coef, rhs, _rel = row
        out = {k: sum(p * sol.get(c, {}).get(k, 0.0) for c, p in coef.items())
               - rhs.get(k, 0.0) for k in set(keys) | set(rhs)}
        return {k: v for k, v in out.items() if abs(v) > 1e-9}
    return sol, residual


def _pure_number_ratio(rows, classes):
    """``(i, j, factor)`` for a pair of ``classes`` whose ratio of units the consistent
    ``rows`` fix (the same for every solution) to a pure number ``factor`` that is not 1,
    else None. Classes whose difference of logarithms is fixed share their row of the
    null space; among them, those with the same dimension part differ by a scale only
    (one pass, not a pass per pair: a component may hold hundreds of classes)."""
    cols = sorted({k for c, _r, _rel in rows for k in c}, key=repr)
    a = np.array([[c.get(k, 0.0) for k in cols] for c, _r, _rel in rows], dtype=float)
    _u, sv, vt = np.linalg.svd(a)
    rank = int(np.sum(sv > 1e-9 * max(1.0, sv.max(initial=0.0))))
    null = vt[rank:].T                  # rows: the directions no relation fixes
    sol = _fit(rows)[0]
    at = {k: n for n, k in enumerate(cols)}
    first = {}
    for c in classes:
        dims = tuple(round(v, 6) + 0.0 for k, v in sorted(sol[c].items()) if k != "scale")
        key = (tuple(np.round(null[at[c]], 6) + 0.0), dims)
        f = first.setdefault(key, c)
        diff = sol[c].get("scale", 0.0) - sol[f].get("scale", 0.0)
        if abs(diff) > 1e-9:
            return f, c, math.exp(diff)
    return None


def _components(rows):
    """``rows`` grouped into sets that share no free class (each solved on its own: one
    system for a whole array of free gains took 0.9 s of a 2 s load)."""
    parent = {}

    def find(k):
        while parent.setdefault(k, k) != k:
            parent[k] = parent[parent[k]]
            k = parent[k]
        return k
    for coef, _rhs, _rel in rows:
        first, *rest = coef
        for k in rest:
            parent[find(k)] = find(first)
    groups = {}
    for row in rows:
        groups.setdefault(find(next(iter(row[0]))), []).append(row)
    return list(groups.values())


def _consistent(rows):
    """True when the rows have a common solution (see :func:`_fit`)."""
    _sol, residual = _fit(rows)
    return not any(residual(r) for r in rows)


def _pure_factor(unit):
    """The factor of ``unit`` to a pure number when it is one and the factor is not 1
    (``rad/deg``: 57.3), else None."""
    try:
        f = U.factor(unit, U.DIMENSIONLESS)
    except U.UnitError:
        return None
    return None if abs(f - 1.0) <= 1e-12 else f


def _pure_part(unit):
    """The part of ``unit`` that is a pure number: its pure-number factors (``rad``,
    ``deg``, ``%``) and each group of factors of one dimension whose powers cancel
    (``mN/N``); ``rad/(s.deg)`` -> ``rad/deg``, ``N/%`` -> ``1/%``, ``mm/s`` -> ``1``."""
    part, groups = U.DIMENSIONLESS, {}
    for u, p in U.terms(unit):
        if u.dimensionality == U.DIMENSIONLESS.dimensionality:
            part = part * u ** p
        else:
            groups.setdefault(u.dimensionality, []).append((u, p))
    for members in groups.values():
        if len(members) > 1 and sum(p for _, p in members) == 0:
            for u, p in members:
                part = part * u ** p
    return part


def _scale_of_number(unit):
    """``(part, factor)``: the scale by a pure number that ``unit`` carries without a user
    having written it, else None.

    Two shapes: a compound unit that is a pure number (``rad/deg``: 57.3, ``mN.m/(N.m)``:
    0.001; the part is the whole unit), and a unit *per* a scaled pure number, whose
    pure-number part (:func:`_pure_part`) has a factor in the denominator and is not 1
    (``rad/(s.deg)``: ``rad/deg`` = 57.3, ``N/%``: ``1/%`` = 100). Not: a unit of a
    dimension (``mm/s``), a single unit such as ``deg`` or ``%``, a pure number of factor 1
    (``rad/rad``, ``rad/s``), or a scaled pure number that only multiplies (``deg/s``, the
    rate of an angle in degrees; ``%.s/rad``, a duty-cycle gain on a speed error, refused
    at first because the factor of the whole pure part, 0.01, was tested)."""
    part = _pure_part(unit)
    if not any(p < 0 for _, p in U.terms(part)):
        return None
    num, den = U.DIMENSIONLESS, U.DIMENSIONLESS     # the single pure-number units
    for u, p in U.terms(part):
        if u.dimensionality == U.DIMENSIONLESS.dimensionality:
            if p < 0:
                den = den * u ** p
            else:
                num = num * u ** p
    f_den = _pure_factor(den)
    if f_den is not None:          # per a scaled pure number: [rad/(s.deg)], [N/%]
        whole = unit.dimensionality == U.DIMENSIONLESS.dimensionality
        return (unit if whole else part), (_pure_factor(part) or f_den)
    f_all = _pure_factor(part) or 1.0
    f_groups = f_all / (_pure_factor(num) or 1.0)
    if abs(f_groups - 1.0) > 1e-12:       # a group that cancels to a scale: mN.m/(N.m)
        return part, f_all
    return None                    # a scale only in the numerator: [%.s/rad] is fine


def _refuse_scaled_number(v, unit, target, rule, inst):
    """A free variable may not be inferred in a unit scaled by a pure number: a Constant 1
    before a Gain of 90 deg into a port in rad was given [rad/deg] and the port got 90 rad
    (the user's 1 read as 1 rad/deg = 57.3) where pi/2 was meant; into a port in rad/s it
    was given [rad/(s.deg)] and a Gain of 50 % into a force gave the Constant [N/%] (its 1
    read as 100 N, the force 50 N where 0.5 N was meant)."""
    found = _scale_of_number(unit)
    if found is None:
        return
    part, f = found
    what = (f"a pure number scaled by {f:.6g}" if part is unit else
            f"a unit per a scaled pure number ([{U.text(part)}] = {f:.6g})")
    raise UnitMismatchError(
        f"{_describe(v)} would have to be [{U.text(unit)}], {what}, for "
        f"'{target[2]} = {rule}' of block '{inst.path}' to hold: give its unit explicitly "
        f"({{value: ..., unit: ...}}), or the other terms in matching units (an angle gain "
        f"in rad, a ratio as a plain number: 0.5, not 50 %)", file=inst.file,
        line=inst.line, block=inst.path)


def infer_units(flat) -> dict:
    """``(path, kind, name) -> unit text`` for every port (kind "in"/"out"), state and real
    parameter of the flat diagram; raises :class:`UnitMismatchError` at the file:line of the
    connection or block where two units disagree."""
    prob = _Problem(flat)
    for inst in flat.blocks.values():
        prob.declare(inst)
    for conn in flat.conns:
        prob.connect(conn)
    prob.join_inside_blocks()
    prob.solve()
    return prob.result()
