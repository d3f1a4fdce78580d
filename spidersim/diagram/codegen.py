"""Generate the Python source of one flat module for a whole diagram.

The module defines, over flat float arrays ``x`` (states), ``sig`` (signals), ``p``
(parameters) and ``modes`` (discrete states)::

    outputs(t, x, sig, p, modes)                  every output, in schedule order
    evaluate(task, t, x, sig, p, modes, out, k, f)
                                                  the system function of
                                                  spidersim.solver.sysfn (derivatives,
                                                  guards, time events, events...)
    SYSTEM                                        its C-callable form's address (numba),
                                                  or ``evaluate`` itself (interpreted)

Only ``outputs`` and ``SYSTEM`` (with the kernels and Newton drivers they call) are compiled
for a diagram: the integration loop and the calls from Python are spidersim's own, compiled
once for every diagram (:mod:`spidersim.solver.sysfn`, :mod:`spidersim.solver.loop_body`).
Under numba, ``SYSTEM`` is a C function (``_system``) whose body is ``evaluate``'s, written
a second time on carrays of its pointers: numba links the code of every jitted function a
function calls into the caller's module and optimises the whole module again, so a
separately jitted ``evaluate`` called by ``_system`` had all the diagram's code optimised
and turned into machine code once more (about a third of the LLVM time of ``spider.yaml``).

Kernels (``load_kernel`` and the specialised ones, ``_jit_kernel``) are compiled once and
marked for LLVM to inline into ``outputs`` and ``SYSTEM`` when small
(:mod:`spidersim.blocks.inlining`): the servo's derivatives evaluation 43 -> 11 ns.

Every kernel call binds the kernel's argument names to slices of those arrays; everything
structural (offsets, sizes, schedule, integer parameters) is a literal in the text, so the
text itself is the structure key of the compile cache.
"""
from __future__ import annotations

import re
import textwrap

import networkx as nx

from ..solver.newton import MAX_ITERATIONS, Workspace
from ..solver.sysfn import (APPLY_EVENT, DERIVATIVES, GUARDS, GUARDS_AT_SIG, INITIALIZE,
                            JACOBIAN, NEXT_TIME, TIME_EVENTS)
from . import jacobian as _jacobian
from .graph import Layout
from .grouping import Call, emit, group, table_text


def _slice(arr, a, b):
    """The view ``arr[a:b]`` passed to a kernel, borrowed (:mod:`spidersim.diagram.views`:
    no reference counting per call)."""
    return f"_v({arr}, {a}, {b})"


def _borrow(*arrays):
    """Lines that rebind a generated function's array arguments to borrowed views of
    themselves (:mod:`spidersim.diagram.views`), at its top: numba's reference count of an
    argument taken on entry is then given back in the same basic block (and pruned), and
    the functions and kernels it calls receive arrays without a memory owner, so no call
    below touches a reference count. The arrays are the caller's and outlive the call."""
    return "".join(f"    {a} = _v({a}, 0, {a}.size)\n" for a in arrays)


_XSPM = _borrow("x", "sig", "p", "modes")


def _param_expr(slot):
    a, b, shape = slot
    if shape == "scalar":
        return f"p[{a}]"
    if len(shape) == 1:
        return _slice("p", a, b)
    return f"{_slice('p', a, b)}.reshape(({shape[0]}, {shape[1]}))"


def _arg_expr(bl, kernel, name):
    return _arg(bl, kernel, name)[0]


def _arg(bl, kernel, name, partial=False):
    """``(expression, access)`` of kernel argument ``name``: ``access`` is ``"r"``,
    ``"w"``, ``"rw"`` or ``""`` (what the kernel may do with the array, by the block
    contract), used to decide which calls may be reordered (:mod:`.grouping`).
    ``partial``: the call is a partial call of the schedule (``inputs_ready`` False)."""
    if name in ("t", "direction"):
        return name, ""
    if name == "inputs_ready":
        return repr(not partial), ""
    if name == "zc":
        a, b = bl.guard_slice
        return _slice("g", a, b), "w"
    if name == "which":
        return f"k - {bl.guard_slice[0]}", ""
    if name.startswith("der_") and name[4:] in bl.states:
        a, b = bl.states[name[4:]]
        return _slice("xdot", a, b), "w"
    if name in bl.states and (bl.states[name][1] > bl.states[name][0]
                              or ("out", name) not in bl.ports):
        a, b = bl.states[name]
        return _slice("x", a, b), "rw"
    if name in bl.input_src:
        arr, a, b = bl.input_src[name]
        return _slice(arr, a, b), "r"
    if ("out", name) in bl.ports:
        arr, a, b = bl.ports[("out", name)].loc
        return _slice(arr, a, b), "w"
    if name in bl.modes:
        a, b = bl.modes[name]
        return _slice("modes", a, b), "rw"
    if name in bl.scratch:
        a, b = bl.scratch[name]
        return _slice("sig", a, b), "rw"
    if name in bl.pslots:
        return _param_expr(bl.pslots[name]), "r"
    if name in bl.constants:
        return repr(bl.constants[name]), ""
    raise RuntimeError(f"block type {bl.cls.type_name}: kernel '{kernel}' argument '{name}' "
                       f"is not a state, port, mode or parameter of the block")


def _access_sets(exprs_access):
    """``(reads, writes)``: frozensets of ``(array, index)`` of a call's arguments."""
    reads, writes = set(), set()
    for expr, acc in exprs_access:
        m = re.match(r"^_v\((\w+), (\d+), (\d+)\)", expr)
        if m:
            cells = {(m.group(1), i) for i in range(int(m.group(2)), int(m.group(3)))}
        else:
            m = re.match(r"^p\[(\d+)\]$", expr)
            cells = {("p", int(m.group(1)))} if m else set()
        if "r" in acc:
            reads |= cells
        if "w" in acc:
            writes |= cells
    return frozenset(reads), frozenset(writes)


def _call_order(L):
    """Block paths in schedule order (loop members after, then the rest)."""
    order = []
    for kind, what in L.calls:
        if kind == "call" and what not in order:
            order.append(what)
    for lp in L.loops:
        order += [p_ for p_ in lp.calls if p_ not in order]
    order += [p_ for p_ in L.blocks if p_ not in order]
    return order


def _timed_blocks(L):
    """Blocks with time events, in the order ``time_events`` visits them."""
    return [L.blocks[p_] for p_ in _call_order(L) if L.blocks[p_].cls.has_kernel("next_time")]


def influence(L, seq):
    """For each block ``k`` of ``seq`` (blocks whose kernels run one after the other, each
    able to change its own modes or states), the earlier ones ``j < k`` whose outputs reach
    an input of ``k`` in the port graph (wires and feedthrough): what ``j`` changed can
    change what ``k`` reads, so the outputs are evaluated again between them. Structural,
    decided once here."""
    g = L.graph
    outs = {}
    for n in g.nodes:
        if n.kind == "out":
            outs.setdefault(n.path, []).append(n)
    reached = []
    for bl in seq:
        paths = set()
        for n in outs.get(bl.path, ()):
            paths.update(m.path for m in nx.descendants(g, n) if m.kind == "in")
        reached.append(paths)
    return [[j for j in range(k) if bl.path in reached[j]] for k, bl in enumerate(seq)]


def sequenced_lines(gen, seq, kernel, fresh, when=None, done=None):
    """Kernel ``kernel`` of each block of ``seq`` in order, the outputs evaluated before
    the first (unless ``fresh``: the caller left those of ``(t, x)`` in ``sig``) and again
    only before a block that one run since can influence (:func:`influence`; flags
    ``d<j>``). ``when(k, bl)``: the condition of block ``k``'s call (None: always);
    ``done(k)``: a line after it."""
    reach = influence(gen.layout, seq)
    flags = sorted({j for pre in reach for j in pre})
    lines = [] if fresh else ["    outputs(t, x, sig, p, modes)"]
    lines += [f"    d{j} = False" for j in flags]
    for k, bl in enumerate(seq):
        ind = "    "
        if when is not None:
            lines.append(f"    if {when(k, bl)}:")
            ind = "        "
        if reach[k]:
            lines += [f"{ind}if {' or '.join(f'd{j}' for j in reach[k])}:",
                      f"{ind}    outputs(t, x, sig, p, modes)"]
            lines += [f"{ind}    d{j} = False" for j in flags]
        lines.append(gen.call(bl, kernel, ind))
        if done is not None:
            lines.append(f"{ind}{done(k)}")
        if k in flags:
            lines.append(f"{ind}d{k} = True")
    return lines


def _event_blocks(L):
    """Blocks with zero-crossing guards, in guard-array order."""
    return [bl for bl in L.blocks.values() if bl.guard_slice[1] > bl.guard_slice[0]]


def event_tables(layout: Layout):
    """Names of the timed blocks and of every guard, for the system (never in the text).

    Returns ``(timed, events)``: ``timed[k]`` is the block path flagged by ``fired[k]``;
    ``events[k]`` is ``(block path, event name, direction)`` of guard ``k``.
    """
    timed = [bl.path for bl in _timed_blocks(layout)]
    events = [(bl.path, name if n == 1 else f"{name}[{k}]", ev.direction)
              for bl in _event_blocks(layout)
              for (name, ev), n in zip(bl.cls.events.items(), bl.event_sizes)
              for k in range(n)]
    return timed, events


class Generator:
    """Collects kernel references and emits the module text."""

    def __init__(self, layout: Layout, jacobian: bool = False):
        self.layout = layout
        #: emit the analytic Jacobian (spidersim.diagram.jacobian) when the blocks allow
        self.jacobian = jacobian
        self.header = []
        self.kernels = {}   # (path, kernel) -> global name
        self.sources = {}   # specialised source text -> global name

    def kernel_name(self, bl, kernel):
        key = (bl.path, kernel)
        if key in self.kernels:
            return self.kernels[key]
        src = bl.cls.kernel_source(bl.params, kernel)
        if src is not None:
            name = self.sources.get(src)
            if name is None:
                name = f"_s{len(self.sources)}_{bl.cls.type_name}_{kernel}"
                self.sources[src] = name
                body = re.sub(rf"^def {kernel}\(", f"def {name}(", src, count=1, flags=re.M)
                self.header.append(f"@_jit_kernel\n{body}")
        else:
            mod = bl.cls.__module__
            name = f"_k_{bl.cls.type_name}_{kernel}"
            if name not in {v for v in self.kernels.values()}:
                self.header.append(
                    f"{name} = load_kernel({mod!r}, {bl.cls.__name__!r}, {kernel!r}, JIT)")
        self.kernels[key] = name
        return name

    def call_info(self, bl, kernel, partial=False):
        """The call of ``kernel`` of block ``bl`` as a :class:`.grouping.Call`."""
        name = self.kernel_name(bl, kernel)
        parts = [_arg(bl, kernel, a, partial) for a in bl.cls.kernel_args(kernel, bl.params)]
        reads, writes = _access_sets(parts)
        return Call(name, tuple(e for e, _ in parts), reads, writes)

    def _time_output_lines(self, timed):
        """The ``time_output`` calls of the due timed blocks that have one (contract item 4
        of :mod:`spidersim.blocks.base`), before any sample is taken; empty without
        such blocks. The outputs are evaluated again when one ran."""
        lines = []
        for bl in timed:
            if bl.cls.has_kernel("time_output"):
                lines += [f"    if {self.call(bl, 'next_time', '')} <= t + tol:",
                          self.call(bl, "time_output", "        "),
                          "        moved = True"]
        if not lines:
            return []
        return (["    moved = False"] + lines
                + ["    if moved:", "        outputs(t, x, sig, p, modes)"])

    def call(self, bl, kernel, indent="    "):
        name = self.kernel_name(bl, kernel)
        args = bl.cls.kernel_args(kernel, bl.params)
        exprs = [_arg_expr(bl, kernel, a) for a in args]
        return f"{indent}{name}({', '.join(exprs)})"

    def loop_source(self, lp):
        """Residual function and Newton driver of one algebraic loop.

        The driver owns the residual evaluations of the solve; the algorithm is the fixed,
        compiled functions of :mod:`spidersim.solver.newton` (reverse communication: they
        say when to evaluate). Only integers of the layout enter this text.
        """
        lines = ["@_jit", f"def _loop{lp.index}_res(t, x, sig, p, modes, r):",
                 f'    """Residual of algebraic loop {lp.index}."""',
                 _borrow("x", "sig", "p", "modes", "r").rstrip("\n")]
        lines += [self.call(self.layout.blocks[path], "output") for path in lp.calls
                  if self.layout.blocks[path].cls.has_kernel("output")]
        for k, (kind, a, o) in enumerate(lp.residual):
            lines.append(f"    r[{k}] = sig[{a}] - sig[{o}]" if kind == "signal"
                         else f"    r[{k}] = sig[{a}]")
        a_tol, r_tol = self.layout.p_loop_tol
        n = len(lp.zidx)
        ws = Workspace(n)
        zidx = "(" + "".join(f"{int(i)}, " for i in lp.zidx) + ")"
        return "\n".join(lines) + f"""


@_jit
def _loop{lp.index}_solve(t, x, sig, p, modes):
    \"\"\"Newton solve of algebraic loop {lp.index} ({n} unknowns), by reverse
    communication with spidersim.solver.newton: this driver evaluates the residual.\"\"\"
{_XSPM}    ws = sig[{lp.ws0}:{lp.ws0 + ws.size}]
    zi = {zidx}
    z = _newton.unknowns(ws, {n})
    r = _newton.evaluation(ws, {n})
    for i in range({n}):
        z[i] = sig[zi[i]]
    task = _newton.begin(ws, {n})
    while task == _newton.EVALUATE:
        for i in range({n}):
            sig[zi[i]] = z[i]
        _loop{lp.index}_res(t, x, sig, p, modes, r)
        task = _newton.resume(ws, {n}, t, p[{int(a_tol)}], p[{int(r_tol)}], {MAX_ITERATIONS})
"""

    def module(self, jit: bool) -> str:
        L = self.layout
        blocks = L.blocks
        # calls of identical blocks become loops over offset tables (see .grouping)
        tables = {}
        out_calls = []
        for i, (kind, what) in enumerate(L.calls):
            if kind == "loop":
                out_calls.append(Call(f"_loop{what}_solve", ("t", "x", "sig", "p", "modes"),
                                      None, None))
            elif blocks[what].cls.has_kernel("output"):
                out_calls.append(self.call_info(blocks[what], "output", i in L.partial))
        out_lines = emit(group(out_calls), tables)
        loop_text = [self.loop_source(lp) for lp in L.loops]
        der_lines = emit(group([self.call_info(bl, "derivative") for bl in blocks.values()
                                if bl.states and bl.cls.has_kernel("derivative")]), tables)
        # time events in schedule order, the outputs evaluated again before a block that
        # an upstream sampled block fired at the same instant can influence (it sees what
        # that block produced)
        order = _call_order(L)
        timed = _timed_blocks(L)
        nt_lines = emit(group([self.call_info(bl, "next_time") for bl in timed]), tables,
                        body=lambda c: [f"v = {c}", "if v < tn:", "    tn = v"])
        # the caller of TIME_EVENTS leaves the outputs of (t, x) in sig; the held outputs
        # that do not depend on the sample move first (time_output), then every sample is
        # taken from the outputs evaluated again
        te_lines = self._time_output_lines(timed)
        te_lines += sequenced_lines(
            self, timed, "time_event", True,
            when=lambda k, bl: f"{self.call(bl, 'next_time', '')} <= t + tol",
            done=lambda k: f"fired[{k}] = 1")
        init_blocks = [blocks[p_] for p_ in order if blocks[p_].cls.has_kernel("initialize")]
        init_lines = sequenced_lines(self, init_blocks, "initialize", False) \
            if init_blocks else []
        evb = _event_blocks(L)
        g_lines = emit(group([self.call_info(bl, "guard") for bl in evb]), tables)
        ev_lines = []
        for bl in evb:
            a, b = bl.guard_slice
            ev_lines += [f"    if {a} <= k < {b}:", self.call(bl, "on_event", "        ")]
        body = "\n".join
        n_g = sum(bl.guard_slice[1] - bl.guard_slice[0] for bl in evb)
        # the analytic Jacobian (spidersim.diagram.jacobian), when the blocks declare it
        jac_text, jac_lines, n_jws = _jacobian.source(
            L, lambda bl: self.kernel_name(bl, "partials"),
            lambda bl, name: _arg_expr(bl, "partials", name), L.n_sig) \
            if self.jacobian else ("", [], 0)

        def ind(lines):
            return textwrap.indent(body(lines) or "    pass", "    ")
        # INITIALIZE calls ``outputs`` between kernels: it gets its own branch only when
        # it has kernels, otherwise it shares the one call of ``outputs`` below
        te_text = (f"    if task == {TIME_EVENTS}:\n        tol = f\n        fired = out\n"
                   f"{ind(te_lines)}\n        return 0.0\n")
        init_text = (f"    if task == {INITIALIZE}:\n{ind(init_lines)}\n"
                     f"        outputs(t, x, sig, p, modes)\n        return 0.0\n"
                     ) if init_lines else ""
        ev_body = f"""\
    if task == {NEXT_TIME}:
        tn = math.inf
{ind(nt_lines)}
        return tn
{te_text}{init_text}    if task == {JACOBIAN}:
{ind(jac_lines or ["    return 0.0"])}
    if task == {GUARDS_AT_SIG}:
        g = out
{ind(g_lines)}
        return 0.0
    outputs(t, x, sig, p, modes)
    if task == {DERIVATIVES}:
        xdot = out
{ind(der_lines)}
    elif task == {GUARDS}:
        g = out
{ind(g_lines)}
    elif task == {APPLY_EVENT}:
        direction = f
{ind(ev_lines)}
    return 0.0   # OUTPUTS, and INITIALIZE without kernels
"""
        text = f'''\
"""Generated by spidersim. Do not edit: regenerated on change."""
import math
import numpy as np
from spidersim.blocks.base import load_kernel
from spidersim.solver import chain as _chain
from spidersim.solver import newton as _newton

JIT = {jit!r}
if JIT:
    from numba import njit

    from spidersim.diagram.views import matrix as _m
    from spidersim.diagram.views import view as _v

    def _jit(f):
        return njit(cache=True, nogil=True, error_model="numpy")(f)
    from spidersim.blocks.inlining import njit_inlinable as _jit_kernel
else:
    from spidersim.diagram.views import _matrix_py as _m
    from spidersim.diagram.views import _view_py as _v

    def _jit(f):
        return f
    _jit_kernel = _jit

N_X = {L.n_x}
N_SIG = {L.n_sig}
N_P = {L.n_p}
N_MODES = {L.n_modes}
N_TIMED = {len(timed)}
N_EVENTS = {n_g}
N_G = N_EVENTS
#: the analytic Jacobian: its workspace after the signals in sig (0: none, the loop uses
#: finite differences)
HAS_JACOBIAN = {bool(jac_text)!r}
N_JWS = {n_jws}

{body(self.header)}
{table_text(tables)}{jac_text}
{body(loop_text)}


@_jit
def outputs(t, x, sig, p, modes):
{_XSPM}{body(out_lines) or "    pass"}


def evaluate(task, t, x, sig, p, modes, out, k, f):
    """The system function of spidersim.solver.sysfn, on arrays: ``task`` says what to do."""
{_XSPM}{_borrow("out")}{ev_body}

if JIT:
    from numba import carray, cfunc

    from spidersim.solver.sysfn import SYSTEM_SIG

    @cfunc(SYSTEM_SIG, cache=True, nogil=True, error_model="numpy")
    def _system(task, t, x_ptr, sig_ptr, p_ptr, modes_ptr, out_ptr, k, f):
        """``evaluate`` on the data pointers of the system function: the same body,
        compiled here only (no separate ``evaluate`` to compile and link in)."""
        x = carray(x_ptr, N_X)
        sig = carray(sig_ptr, N_SIG + N_JWS)
        p = carray(p_ptr, N_P)
        modes = carray(modes_ptr, N_MODES)
        n_out = N_X * N_X if task == {JACOBIAN} else N_X
        out = carray(out_ptr, n_out if task == {DERIVATIVES} or task == {JACOBIAN}
                     else (N_G if task == {GUARDS} or task == {GUARDS_AT_SIG}
                           else N_TIMED))
{textwrap.indent(ev_body, "    ")}
    SYSTEM = _system.address
else:
    SYSTEM = evaluate
'''
        return text



def generate(layout: Layout, jit: bool, jacobian: bool = False) -> str:
    """Module text for ``layout`` (see the module docstring); ``jacobian``: with the
    analytic Jacobian when the blocks allow (only the stiff methods use it, and it costs
    compile time: a new servo diagram 1.0-1.2 -> 1.8-2.1 s CPU)."""
    return Generator(layout, jacobian).module(jit)
