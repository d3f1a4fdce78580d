"""The analytic Jacobian of a diagram, assembled from its blocks' declared partials.

When every block on a path into a state derivative declares its local partial derivatives
(the ``partials`` kernel of :mod:`spidersim.blocks.base`, contract item 4), the generated
module's system function gets a branch for the task ``JACOBIAN``
(:mod:`spidersim.solver.sysfn`; ``out`` is ``J``, ``n_x * n_x``) that forms ``J = df/dx`` by
the chain rule, in schedule order:

1. the outputs at ``(t, x)`` (one evaluation of the diagram's outputs, no derivatives);
2. each such block's partials ``dfdx, dfdu, dydx, dydu`` into its matrices (zeroed first);
3. the sensitivities ``S[v] = d v / d x`` of every signal element ``v`` on a path into a
   derivative, output after output in dependency order (a topological order of the port
   graph; not the call order, since a block called twice makes its outputs at two places)
   (``S[y] = dydx S[x_b] + dydu S[u_b]``; a state's row is ``e_k``; a signal that depends
   on no state, a source's, reads a zero row);
4. the derivative rows ``J[x'_b] = dfdx S[x_b] + dfdu S[u_b]``,

each row only over the columns of the structural pattern (:func:`.graph.port_state_deps`),
by :func:`spidersim.solver.chain.chain`. The sensitivities and the blocks' matrices live in a
workspace of ``N_JWS`` floats after the signals in ``sig`` (allocated once with it); the
index lists are one constant int64 table ``_JT``. Everything here is decided at code
generation; only integers the generator makes enter the text (never a name).

When is there none (the loop then uses the coloured finite differences, as before)?

* a block on a path into a derivative (a block with states, or one whose output reaches
  one and depends on a state) declares no ``partials``: the whole Jacobian falls back
  (mixing analytic and difference columns is left for later);
* such a path goes through an algebraic loop (solving the linearised loop is left for
  later): the whole Jacobian falls back;
* the diagram has no states, or the workspace would exceed :data:`MAX_WORKSPACE` floats.

:func:`plan` says which, with the block's name (for messages and tests, never the text).
"""
from __future__ import annotations

import re
from dataclasses import dataclass, field

from ..blocks.base import PARTIALS
from ..solver.chain import RECORD
from .graph import Layout, block_columns, port_state_deps

#: largest workspace (floats) of an analytic Jacobian; beyond it, finite differences
MAX_WORKSPACE = 4_000_000


@dataclass
class _BlockPlan:
    """One block of the chain: its kernel's matrices and its index lists in the table."""

    bl: object
    mats: dict = field(default_factory=dict)    # matrix name -> (offset, rows, cols)
    x_rows: list = field(default_factory=list)  # S rows of its state elements (x indices)
    u_rows: list = field(default_factory=list)  # S rows of its input elements
    outs: list = field(default_factory=list)    # (port, row offset in dydx/dydu, S rows,
    #                                             columns)
    der_cols: list = field(default_factory=list)


@dataclass
class Plan:
    """What the generator emits: blocks in order, sizes; ``reason`` when there is none."""

    reason: str = ""
    blocks: list = field(default_factory=list)
    n_rows: int = 0             # rows of S: states, chained signal elements, one zero row
    n_ws: int = 0               # floats of workspace after the signals
    #: ``(block plan, output entry)`` in an order where every output's sensitivity rows come
    #: after those of the outputs it is computed from (a topological order of the port graph)
    emit: list = field(default_factory=list)


def _ancestors(g, targets):
    """Every node with a path to one of ``targets`` (the targets included)."""
    seen, todo = set(targets), list(targets)
    while todo:
        for m in g.predecessors(todo.pop()):
            if m not in seen:
                seen.add(m)
                todo.append(m)
    return seen


def _last_call_order(L: Layout):
    """Block paths by their last output call in the schedule (a block called twice, once
    for its outputs without feedthrough, has every output by the second), then the rest."""
    last = {}
    for k, (kind, what) in enumerate(L.calls):
        if kind == "call":
            last[what] = k
    order = sorted(last, key=last.get)
    return order + [p_ for p_ in L.blocks if p_ not in last]


def plan(L: Layout) -> Plan:
    """The analytic Jacobian's structure for layout ``L``, or a :class:`Plan` whose
    ``reason`` says why there is none (see the module docstring)."""
    if L.n_x == 0:
        return Plan("the diagram has no states")
    deps = port_state_deps(L)
    stateful, targets, relevant = _paths_into_derivatives(L, deps)
    active = {bl.path for bl in stateful} | {n[1] for n in relevant}
    reason = _why_none(L, deps, targets, relevant, active)
    if reason:
        return Plan(reason)
    row_of, n_rows = _signal_rows(L, relevant)
    zero_row = n_rows
    n_rows += 1
    ws = n_rows * L.n_x
    blocks = []
    for path_ in _last_call_order(L):
        if path_ in active:
            bp, ws = _block_plan(L, deps, relevant, row_of, zero_row, L.blocks[path_], ws)
            blocks.append(bp)
    if ws > MAX_WORKSPACE:
        return Plan(f"the analytic Jacobian would need {ws} floats of workspace "
                    f"(more than {MAX_WORKSPACE})")
    return Plan("", blocks, n_rows, ws, _emission_order(L, blocks, relevant))


def _emission_order(L, blocks, relevant):
    """Every relevant output's ``(block plan, output entry)``, its sensitivity rows after
    those of the outputs it is computed from: a topological order of the port graph over
    the relevant outputs and the inputs of the blocks in the chain (acyclic: a cycle there
    would be an algebraic loop, which has no plan). Not the blocks' call order: a block
    called twice (its outputs without feedthrough needed before its inputs) has its
    outputs' rows at different places."""
    import networkx as nx
    entry = {("out", bp.bl.path, e[0]): (bp, e) for bp in blocks for e in bp.outs}
    nodes = set(relevant) | {("in", bp.bl.path, i) for bp in blocks for i in bp.bl.inputs}
    sub = L.graph.subgraph(n for n in L.graph.nodes if tuple(n) in nodes)
    order = nx.lexicographical_topological_sort(sub, key=str)
    return [entry[tuple(n)] for n in order if tuple(n) in entry]


def _paths_into_derivatives(L, deps):
    """``(stateful, targets, relevant)``: the blocks with states, their input ports, and
    the output ports on a path into one of those inputs that depend on a state (outputs
    that are states excluded: their rows are the states')."""
    stateful = [bl for bl in L.blocks.values() if any(b > a for a, b in bl.states.values())]
    targets = [("in", bl.path, i) for bl in stateful for i in bl.inputs]
    reach = _ancestors(L.graph, targets)
    relevant = {n for n in reach if n[0] == "out" and deps[n]
                and n[2] not in L.blocks[n[1]].state_outputs}
    return stateful, targets, relevant


def _why_none(L, deps, targets, relevant, active):
    """Why there is no analytic Jacobian (``""``: there is one): an algebraic loop on a
    path into a derivative or a block on such a path without partials (see the module
    docstring)."""
    in_loops = {n for lp in L.loops for n in lp.nodes}
    looped = sorted((n for n in relevant | set(targets) if n in in_loops and deps[n]),
                    key=str)
    if looped:
        return (f"a path into a derivative goes through an algebraic loop "
                f"(at {looped[0][1]}.{looped[0][2]})")
    for path_ in sorted(active):
        bl = L.blocks[path_]
        if not bl.cls.has_kernel("partials"):
            return f"block '{path_}' ({bl.cls.type_name}) declares no partial derivatives"
    return ""


def _signal_rows(L, relevant):
    """Rows of ``S`` for the relevant signal elements, after the ``n_x`` state rows, in
    the blocks' last-call order: ``(row_of, n_rows)`` (``row_of``: signal index -> row)."""
    row_of = {}
    n_rows = L.n_x
    for path_ in _last_call_order(L):
        bl = L.blocks[path_]
        for o in bl.outputs:
            if ("out", path_, o) in relevant:
                _arr, a, b = bl.ports[("out", o)].loc
                for k in range(a, b):
                    row_of[k] = n_rows
                    n_rows += 1
    return row_of, n_rows


def _block_plan(L, deps, relevant, row_of, zero_row, bl, ws):
    """Block ``bl``'s part of the chain (:class:`_BlockPlan`: its state and input rows,
    its relevant outputs' rows and columns, its derivative columns, its matrices placed
    from workspace offset ``ws``); returns it and the next free offset."""
    bp = _BlockPlan(bl)
    for s in bl.cls.states:
        if s in bl.states:
            bp.x_rows += list(range(*bl.states[s]))
    for i in bl.inputs:
        arr, a, b = bl.input_src[i]
        bp.u_rows += [k if arr == "x" else row_of.get(k, zero_row) for k in range(a, b)]
    r0 = 0
    for o in bl.outputs:
        if o in bl.state_outputs:
            continue
        node = ("out", bl.path, o)
        if node in relevant:
            _arr, a, b = bl.ports[("out", o)].loc
            bp.outs.append((o, r0, [row_of[k] for k in range(a, b)], sorted(deps[node])))
        r0 += bl.ports[("out", o)].size
    n_s, n_u, n_y = len(bp.x_rows), len(bp.u_rows), r0
    if bl.states:
        bp.der_cols = sorted(block_columns(L, deps, bl))
    shapes = {"dfdx": (n_s, n_s), "dfdu": (n_s, n_u), "dydx": (n_y, n_s),
              "dydu": (n_y, n_u)}
    for name in bl.cls.kernel_args("partials", bl.params):
        if name in PARTIALS:
            r, c = shapes[name]
            bp.mats[name] = (ws, r, c)
            ws += r * c
    return bp, ws


def _chain_line(target, mat, d0, dst, src, cols, acc, table):
    """One :func:`spidersim.solver.chain.chain` call; appends its record (``d0``, the
    offset and length of each index list, ``acc``: :data:`spidersim.solver.chain.RECORD`
    numbers) and its index lists to ``table``."""
    h = len(table)
    table.extend([0] * RECORD)
    record = [int(d0)]
    for lst in (dst, src, cols):
        record += [len(table), len(lst)]
        table.extend(int(v) for v in lst)
    table[h:h + RECORD] = record + [int(bool(acc))]
    return f"    _chain.chain({target}, {mat}, S, _JT, np.int64({h}))"


def source(L: Layout, kernel_name, arg_expr, sig_size):
    """``(defs, branch, n_ws)``: the module-level definitions of the analytic Jacobian
    (the table ``_JT``), the lines of the system function's ``JACOBIAN`` branch (indented
    by four spaces; ``out`` is ``J``) and its workspace size, or ``("", [], 0)`` when
    :func:`plan` finds none. The branch is written into the system function's body itself,
    as every other task (see :mod:`.codegen`: a separately jitted function is linked in and
    optimised again; measured here within the noise of the machine: a new servo diagram
    1.8-2.1 s CPU either way, against 1.0-1.2 s without the Jacobian).

    ``kernel_name(bl)``: the global name of block ``bl``'s ``partials`` kernel;
    ``arg_expr(bl, name)``: the expression of one of its other arguments (the generator's
    binding, :func:`spidersim.diagram.codegen._arg`); ``sig_size``: where the workspace
    starts in ``sig``.
    """
    pl = plan(L)
    if pl.reason:
        return "", [], 0
    n_x = L.n_x
    base = sig_size
    table = []
    lines = [f"    S = _m(sig, {base}, {pl.n_rows}, {n_x})",
             f"    _chain.seed(S, np.int64({n_x}))"]
    mat_expr = {}
    for bp in pl.blocks:
        args = []
        for name in bp.bl.cls.kernel_args("partials", bp.bl.params):
            if name in PARTIALS:
                off, r, c = bp.mats[name]
                a, b = base + off, base + off + r * c
                lines.append(f"    _chain.zero(_v(sig, {a}, {b}))")
                e = f"_m(sig, {a}, {r}, {c})"
                mat_expr[(bp.bl.path, name)] = e
                args.append(e)
            else:
                args.append(_as_matrix(arg_expr(bp.bl, name)))
        lines.append(f"    {kernel_name(bp.bl)}({', '.join(args)})")
    # the outputs' sensitivities in dependency order, then the derivative rows
    for bp, (_port, r0, dst, cols) in pl.emit:
        lines += _pair(bp, "dydx", "dydu", "S", r0, dst, cols, mat_expr, table)
    for bp in pl.blocks:
        if bp.x_rows:
            lines += _pair(bp, "dfdx", "dfdu", "J", 0, bp.x_rows, bp.der_cols, mat_expr,
                           table)
    tab = ", ".join(str(v) for v in table)
    defs = f"_JT = np.array([{tab}], dtype=np.int64)\n"
    branch = ["    outputs(t, x, sig, p, modes)", f"    J = _m(out, 0, {n_x}, {n_x})"] \
        + lines + ["    return 1.0"]
    return defs, branch, pl.n_ws


def _as_matrix(expr):
    """A matrix parameter's ``_v(p, a, b).reshape((r, c))`` as the borrowed matrix
    ``_m(p, a, r, c)`` (the same values, without ``reshape``'s run-time work)."""
    m = re.fullmatch(r"_v\(p, (\d+), (\d+)\)\.reshape\(\((\d+), (\d+)\)\)", expr)
    return f"_m(p, {m.group(1)}, {m.group(3)}, {m.group(4)})" if m else expr


def _pair(bp, mx, mu, target, r0, dst, cols, mat_expr, table):
    """The chain calls of rows ``dst`` of ``target``: ``mx`` times the state rows, plus
    ``mu`` times the input rows (a matrix the kernel does not take is zero: no call); a
    row with neither is zeroed over its columns (a chain call with no source)."""
    out = []
    acc = False
    for m, src in ((mx, bp.x_rows), (mu, bp.u_rows)):
        e = mat_expr.get((bp.bl.path, m))
        if e is None or not src:
            continue
        out.append(_chain_line(target, e, r0, dst, src, cols, acc, table))
        acc = True
    if not out:
        # nothing declared: the rows are zero (chain with no source writes zeros)
        e = "S"
        out.append(_chain_line(target, e, 0, dst, [], cols, False, table))
    return out
