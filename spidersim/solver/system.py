"""The ``System`` the solver integrates: flat arrays and compiled functions, no blocks.

Contract (what :func:`spidersim.solver.integrate.integrate` needs)
-----------------------------------------------------------------
1. ``n_x``, ``x0`` (float array), ``sig``, ``p``, ``modes`` (float arrays owned by the system;
   ``modes`` changes only at events).
2. ``rhs(t, x) -> xdot`` (a new array) and ``outputs(t, x)`` (fills ``sig``).
3. ``next_time(t) -> float`` (earliest pending time event, ``inf`` for none) and
   ``time_events(t, x, tol) -> list of names`` (apply every event due by ``t + tol``).
4. ``record_row(t, x, buf, row) -> bool``: outputs at (t, x), logged values written into
   ``buf[row]``; False when the state or a logged value is not finite. ``record_size``,
   ``record_names``, ``record_slices`` (name -> (start, stop)) and ``units`` describe a row.
   ``record_row_guards(t, x, buf, row, g)`` does the same and writes the guards into ``g``
   (one evaluation of the outputs for both).
5. ``n_g``, ``event_table`` (list of (block, event name, direction)), ``guards(t, x) -> g``
   (a new array of the zero-crossing functions) and ``apply_event(t, x, k, direction)``
   (applies event ``k`` in place on ``x`` and ``modes``); ``initialize(t, x)`` lets blocks
   set modes consistent with their inputs, at the start and after every event.
6. ``diagnose(t, x) -> str``: which signal or state derivative is not finite, in schedule
   order, for error messages.
7. ``jac_sparsity``: ``None`` or an (n_x, n_x) boolean pattern for the implicit methods.
8. ``newton_iterations() -> int`` and ``loop_failure() -> (report, loop)`` for systems with
   algebraic loops (``0`` and ``("", None)`` without).

:class:`PlainSystem` gives every item a default, so that a hand-written system for a test
is a few lines; :class:`CompiledSystem` is the one a diagram compiles into.
"""
from __future__ import annotations

import numpy as np

from . import newton, sysfn
from .sysfn import entry_point

#: the Python-side calls of a compiled system, compiled once for every diagram
_OPS = {name: getattr(sysfn, name) for name in (
    "rhs", "outputs", "record", "record_guards", "guards", "next_time", "time_events",
    "initialize", "apply_event", "jacobian")}


def _record_layout(log):
    """The record layout of ``log`` (see :class:`CompiledSystem`): ``(s_idx, x_idx,
    names, slices, size, units)``; a row holds all logged signal values first, then the
    logged states."""
    x_idx, s_idx, names, slices, units = [], [], [], {}, {}
    for name, arr, a, b, unit in log:
        (x_idx if arr == "x" else s_idx).append(np.arange(a, b))
        names.append(name)
        units[name] = unit
    k = 0
    for name, arr, a, b, unit in log:
        if arr == "sig":
            slices[name] = (k, k + b - a)
            k += b - a
    for name, arr, a, b, unit in log:
        if arr == "x":
            slices[name] = (k, k + b - a)
            k += b - a
    s_idx = (np.concatenate(s_idx) if s_idx else np.zeros(0)).astype(np.int64)
    x_idx = (np.concatenate(x_idx) if x_idx else np.zeros(0)).astype(np.int64)
    return s_idx, x_idx, names, slices, k, units


def loop_compiled(method="DP54") -> bool:
    """Whether the compiled integration loop's entry of ``method`` (:func:`loop_entry`) has
    machine code in this process."""
    return len(loop_entry(method).overloads) > 0


def loop_entry(method):
    """The compiled loop's entry of ``method`` (``DP54``, ``ROS34PW2``, ``NDF``; a SciPy
    method gives DP54's): each is compiled or loaded on its own, with only its method's code
    (:mod:`.loop_body`)."""
    global _ENTRY_OF
    if _ENTRY_OF is None:           # imported on first use (numba), then kept
        from .loop_body import entry
        _ENTRY_OF = entry
    return _ENTRY_OF(method)


_ENTRY_OF = None


class CompiledSystem:
    """A diagram compiled into a generated module (see :mod:`spidersim.diagram.codegen`).

    Parameters
    ----------
    module : module
        Generated module with the sizes ``N_X``, ``N_SIG``, ``N_P``, ``N_MODES``,
        ``N_TIMED``, ``N_EVENTS`` and the system function ``SYSTEM`` (its address under
        numba, else the Python function; see :mod:`spidersim.solver.sysfn`).
    x0, p, modes0 : ndarray
        Initial state, parameters, initial modes.
    n_sig : int
        Length of the signal array.
    log : list of (name, array, start, stop, unit)
        Logged signals: ``array`` is ``"x"`` or ``"sig"``.
    sig_names, x_names : list of (name, start, stop)
        Every signal and state, in schedule / layout order, for diagnostics.
    shared : dict, optional
        Kept by the caller for every system of the same module and ``log`` (a diagram
        keeps one per layout): the record index arrays, slices and units, and the compiled
        loop's event tables, its event names and Jacobian colouring, computed by the first
        system and reused (never written by a run), and the row count of the last
        successful run (``rows_hint``: only the size of the next run's first buffers).
    tables : (timed, events)
        Block paths flagged by ``time_events`` and ``(block, event, direction)`` per guard,
        from :func:`spidersim.diagram.codegen.event_tables`; the generated module holds only
        their lengths, never names.
    jac_sparsity : ndarray or callable, optional
        The pattern of contract item 7, or a function returning it, called on first use
        (only the implicit methods read it: an explicit run of many states never builds
        its n_x x n_x pattern).
    """

    @property
    def jac_sparsity(self):
        """Contract item 7, made on first use when a function was given."""
        if callable(self._jac_sparsity):
            self._jac_sparsity = self._jac_sparsity()
        return self._jac_sparsity

    def __init__(self, module, x0, p, modes0, n_sig, log, sig_names, x_names,
                 jac_sparsity=None, sig0=None, loops=(), tables=((), ()), shared=None):
        self.module = module
        #: what does not change between the systems of one compiled structure (record
        #: layout, the compiled loop's event tables), kept by the caller across runs
        self.shared = shared
        self.n_x = len(x0)
        self.x0 = np.ascontiguousarray(x0, dtype=float)
        self.p = np.ascontiguousarray(p, dtype=float)
        self.modes = np.array(modes0, dtype=float)
        # the analytic Jacobian's workspace follows the signals (N_JWS floats, zero)
        n_jws = int(getattr(module, "N_JWS", 0))
        self.sig = np.zeros(n_sig + n_jws)
        if sig0 is not None:
            self.sig[:n_sig] = sig0
        #: the generated module assembles df/dx from the blocks' partials (the loop's
        #: ROS34PW2 and NDF then call it instead of finite differences)
        self.analytic_jacobian = bool(getattr(module, "HAS_JACOBIAN", False))
        self.loops = list(loops)
        self.sig_names = sig_names
        self.x_names = x_names
        self._jac_sparsity = jac_sparsity
        # names come from the layout, never from the generated text (security rule)
        self.timed = list(tables[0])
        self.event_table = list(tables[1])
        if len(self.timed) != module.N_TIMED or len(self.event_table) != module.N_EVENTS:
            raise RuntimeError("generated module does not match its diagram's event tables")
        self.n_g = len(self.event_table)
        rec = shared.get("record") if shared is not None else None
        if rec is None or rec[0] is not log:
            rec = (log,) + _record_layout(log)
            if shared is not None:
                shared["record"] = rec
        _, self._s_idx, self._x_idx, names, slices, k, units = rec
        self.record_names = names
        self.record_slices = slices
        self.record_size = k
        self.units = dict(units)      # the system's own: the shared one stays as built
        m = module
        for name, arr, extra in (("N_X", self.x0, 0), ("N_SIG", self.sig, n_jws),
                                 ("N_P", self.p, 0), ("N_MODES", self.modes, 0)):
            if getattr(m, name) + extra != arr.size:   # the system function trusts these
                raise RuntimeError(f"generated module's {name} = {getattr(m, name)} does "
                                   f"not match its array of size {arr.size}")
        self._fired = np.zeros(max(1, len(self.timed)))
        self._g = np.zeros(max(1, self.n_g))
        #: the system function (:mod:`.sysfn`): its address, or the Python function
        self.fn = m.SYSTEM
        self.jit = bool(getattr(m, "JIT", False))
        self._ops = {name: (f if self.jit else f.py_func) for name, f in _OPS.items()}
        fn, sig, p_, modes = self.fn, self.sig, self.p, self.modes
        rhs = self._ops["rhs"]
        self.rhs = lambda t, x: rhs(fn, t, x, sig, p_, modes)
        #: the compiled integration loop's system function (numba-compiled modules only)
        self.compiled_entry = self.fn if self.jit else None

    def _call(self, name, *args):
        return self._ops[name](self.fn, *args)

    def jacobian(self, t, x):
        """The analytic ``J = df/dx`` at ``(t, x)`` from the blocks' declared partials (a
        new ``(n_x, n_x)`` array; zero outside the structural pattern), or None when the
        diagram has none (see :mod:`spidersim.diagram.jacobian`). Leaves the outputs of
        ``(t, x)`` in ``sig``."""
        J = np.zeros((self.n_x, self.n_x))
        x = np.ascontiguousarray(x, dtype=float)
        ok = self._call("jacobian", t, x, self.sig, self.p, self.modes, J)
        return J if ok else None

    def outputs(self, t, x):
        self._call("outputs", t, x, self.sig, self.p, self.modes)

    def record_row(self, t, x, buf, row):
        return self._call("record", t, x, self.sig, self.p, self.modes, self._s_idx,
                          self._x_idx, buf, row)

    def next_time(self, t):
        return self._call("next_time", t, self.p, self.modes)

    def time_events(self, t, x, tol):
        self._fired[:] = 0.0
        self._call("outputs", t, x, self.sig, self.p, self.modes)
        self._call("time_events", t, x, self.sig, self.p, self.modes, tol, self._fired)
        return [self.timed[k] for k in np.flatnonzero(self._fired[:len(self.timed)])]

    def guards(self, t, x):
        self._call("guards", t, x, self.sig, self.p, self.modes, self._g)
        return self._g[:self.n_g].copy()

    def record_row_guards(self, t, x, buf, row, g):
        """``record_row`` and the guards into ``g`` from one evaluation of the outputs."""
        ok = self._call("record_guards", t, x, self.sig, self.p, self.modes, self._s_idx,
                        self._x_idx, buf, row, self._g)
        g[:] = self._g[:self.n_g]
        return ok

    def initialize(self, t, x):
        """Let blocks make their modes consistent with their inputs (start, after events)."""
        self._call("initialize", t, x, self.sig, self.p, self.modes)

    def apply_event(self, t, x, k, direction):
        self._call("apply_event", t, x, self.sig, self.p, self.modes, k, float(direction))

    def warm_up(self):
        """Call the system function for every task once (numba compiles or loads the
        diagram's function when its module is imported; this loads spidersim's callers)."""
        x = self.x0.copy()
        modes = self.modes.copy()
        self.rhs(0.0, x)
        self.outputs(0.0, x)
        self.next_time(0.0)
        self.record_row(0.0, x, np.zeros((1, self.record_size)), 0)
        self.record_row_guards(0.0, x, np.zeros((1, self.record_size)), 0,
                               np.zeros(self.n_g))
        fired = np.zeros_like(self._fired)
        self._call("time_events", -np.inf, x, self.sig, self.p, self.modes, 0.0, fired)
        self.guards(0.0, x)
        self.initialize(0.0, x)
        self._call("apply_event", 0.0, x, self.sig, self.p, self.modes, -1, 1.0)
        self.modes[:] = modes
        self._bind_entry_points()

    def loop_ready(self, method="DP54") -> bool:
        """Whether the compiled integration loop of ``method`` has machine code (compiled or
        loaded)."""
        return self.compiled_entry is not None and loop_compiled(method)

    def warm_up_loop(self, method="DP54"):
        """Compile the integration loop's entry of ``method`` (once for every diagram; the
        other methods' entries are not compiled) or load it from numba's cache, without
        running it."""
        entry = loop_entry(method)
        if self.compiled_entry is None or entry.overloads:
            return
        from .loop_state import METHODS
        from .loop_warm import loop_types
        entry.compile(loop_types(method if method in METHODS else "DP54", self, self.fn))

    def _bind_entry_points(self):
        """Call the machine code of the hot Python-side calls directly: numba's dispatcher
        re-checks every argument type on each call (about 0.4 us of 1 us here). The
        argument types are the same for every diagram, so the entry points are looked up
        once per process (:func:`entry_point`) and kept in ``shared`` for the next system
        of this structure (no arrays made to look them up again)."""
        if not self.jit:
            return
        fn, sig, p_, modes = self.fn, self.sig, self.p, self.modes
        bound = self.shared.get("entry_points") if self.shared is not None else None
        if bound is not None:         # looked up by an earlier system of this structure
            self._ops.update(bound)
            rhs = self._ops["rhs"]
            self.rhs = lambda t, x: rhs(fn, t, x, sig, p_, modes)
            return
        x = self.x0.copy()
        rows = np.zeros((1, self.record_size))
        found = {}
        for name, args in (("rhs", (fn, 0.0, x, sig, p_, modes)),
                           ("record", (fn, 0.0, x, sig, p_, modes, self._s_idx, self._x_idx,
                                       rows, 0)),
                           ("guards", (fn, 0.0, x, sig, p_, modes, self._g)),
                           ("record_guards", (fn, 0.0, x, sig, p_, modes, self._s_idx,
                                              self._x_idx, rows, 0, self._g))):
            e = entry_point(_OPS[name], args)
            if e is not None:
                self._ops[name] = e
                found[name] = e
        if self.shared is not None and len(found) == 4:
            self.shared["entry_points"] = found
        rhs = self._ops["rhs"]
        self.rhs = lambda t, x: rhs(fn, t, x, sig, p_, modes)

    def newton_iterations(self):
        """Newton iterations over all loops since the start (0 without loops): the
        ``TOTAL`` slot of each loop's workspace."""
        total = 0
        for lp in self.loops:
            total += int(self.sig[lp["ws0"] + newton.TOTAL])
        return total

    def _workspace(self, lp):
        """The Newton workspace of loop ``lp`` (a view of ``sig``)."""
        from .newton import Workspace
        return self.sig[lp["ws0"]:lp["ws0"] + Workspace(lp["n"]).size]

    def loop_failure(self):
        """``(report, loop)`` of the most recent failed Newton solve of any loop, or
        ``("", None)``.

        Failures during rejected trial steps are normal; this is read only once the
        integration itself has failed.
        """
        from .newton import Workspace
        worst = None
        for lp in self.loops:
            fail = Workspace(lp["n"]).failure(self._workspace(lp))
            if fail is not None and (worst is None or fail["t"] >= worst[1]["t"]):
                worst = (lp, fail)
        if worst is None:
            return "", None
        lp, fail = worst
        status, t = fail["status"], fail["t"]
        why = {1: "did not converge", 2: "produced a non-finite residual",
               3: "has a singular Jacobian"}.get(status, "failed")
        res = "; ".join(f"{nm} = {v:.3g}" for nm, v in zip(lp["names"], fail["residuals"]))
        advice = {1: "check that the loop has a solution near the last one (a jump of an "
                     "input may need a smaller max_step), or break the loop with a small lag",
                  2: "a block in the loop divides by zero or overflows for these values",
                  3: "the unknowns do not influence the residual (a saturated or constant "
                     "path): the loop has no unique solution here"}.get(status, "")
        return (f"algebraic loop {lp['index'] + 1} {why} at t = {t:.9g} s after "
                f"{fail['iterations']} Newton iterations.\n"
                f"  loop: {lp['walk']}\n  unknowns (tear variables): "
                f"{', '.join(lp['tears'])}\n  residuals: {res}\n  advice: {advice}"), lp

    def diagnose(self, t, x):
        """Name the first non-finite signal (schedule order) or state derivative."""
        with np.errstate(all="ignore"):
            bad_x = [n for n, a, b in self.x_names if not np.all(np.isfinite(x[a:b]))]
            self.outputs(t, x)
            for name, a, b in self.sig_names:
                if not np.all(np.isfinite(self.sig[a:b])):
                    return (f"signal '{name}' is {self.sig[a:b].tolist()} at t = {t:.9g} s"
                            + (f" (non-finite state: {bad_x[0]})" if bad_x else ""))
            if bad_x:
                return f"state '{bad_x[0]}' is not finite at t = {t:.9g} s"
            xdot = np.array(self.rhs(t, x), dtype=float)
            for name, a, b in self.x_names:
                if not np.all(np.isfinite(xdot[a:b])):
                    return (f"the derivative of state '{name}' is {xdot[a:b].tolist()} "
                            f"at t = {t:.9g} s")
            # all finite: name the largest signal and derivative (a singularity ahead)
            parts = []
            if self.sig_names:
                name, a, b = max(self.sig_names, key=lambda r: np.max(np.abs(
                    self.sig[r[1]:r[2]]), initial=0.0))
                parts.append(f"largest signal '{name}' = {np.max(np.abs(self.sig[a:b])):.3g}")
            if self.x_names:
                name, a, b = max(self.x_names, key=lambda r: np.max(np.abs(xdot[r[1]:r[2]]),
                                                                   initial=0.0))
                parts.append(f"fastest state '{name}' (|derivative| "
                             f"{np.max(np.abs(xdot[a:b])):.3g})")
                stiff = self._stiffest(t, x, xdot)
                if stiff:
                    parts.append(stiff)
            if parts:
                return "at t = " + f"{t:.9g} s: " + ", ".join(parts)
        return ""


    def _stiffest(self, t, x, xdot):
        """``stiffest mode |lambda| rad/s (time constant T s), mostly state 'name'``: the
        eigenvalue of largest magnitude of the Jacobian ``d xdot / d x`` (forward
        differences, one evaluation per state) and the state with the largest component
        of its eigenvector: what makes a stiff method's steps collapse (a stiffness of
        1e300, an inductance of 1e-300), which the largest derivative does not name."""
        n = len(x)
        if n == 0 or n > 400:           # (a dense eigenproblem of a huge model: skip)
            return ""
        J = np.empty((n, n))
        for i in range(n):
            h = 1e-7 * max(1.0, abs(x[i]))
            xp = x.copy()
            xp[i] += h
            J[:, i] = (np.array(self.rhs(t, xp), dtype=float) - xdot) / h
        if not np.all(np.isfinite(J)):
            bad = int(np.argwhere(~np.isfinite(J))[0][1])
            return f"the derivatives are not finite near state '{self._state_name(bad)}'"
        lam, vec = np.linalg.eig(J)
        k = int(np.argmax(np.abs(lam)))
        if abs(lam[k]) == 0.0:
            return "no stiff mode (the Jacobian is zero)"
        i = int(np.argmax(np.abs(vec[:, k])))
        return (f"stiffest mode {abs(lam[k]):.3g} rad/s (time constant "
                f"{1.0 / abs(lam[k]):.3g} s), mostly state '{self._state_name(i)}'")

    def _state_name(self, i):
        """The name of state ``i`` (``name[k]`` for an element of a vector state)."""
        for name, a, b in self.x_names:
            if a <= i < b:
                return name if b - a == 1 else f"{name}[{i - a}]"
        return f"x[{i}]"


class PlainSystem:
    """A ``System`` written by hand in Python: the contract with its defaults.

    A subclass gives ``x0`` and overrides ``rhs`` and, where it has them, ``guards`` with
    ``event_table``/``n_g``, ``apply_event``, ``next_time`` and ``time_events``. The whole
    state is recorded under the name ``"x"``. Used to test the integration loop without a
    diagram, a code generator or numba::

        class Fall(PlainSystem):                    # a ball falling onto the floor
            n_g, event_table = 1, [("ball", "impact", -1)]
            def rhs(self, t, x): return np.array([x[1], -9.81])
            def guards(self, t, x): return np.array([x[0]])
            def apply_event(self, t, x, k, direction): x[1] = -0.8 * x[1]

        integrate(Fall([1.0, 0.0]), 2.0)
    """

    n_g = 0
    event_table: list = []
    jac_sparsity = None

    def __init__(self, x0, modes=()):
        self.x0 = np.array(x0, dtype=float)
        self.n_x = len(self.x0)
        self.modes = np.array(modes, dtype=float)
        self.record_names = ["x"]
        self.record_slices = {"x": (0, self.n_x)}
        self.record_size = self.n_x
        self.units = {"x": ""}

    def rhs(self, t, x):
        """``xdot`` at (t, x): every hand-written system defines it."""
        raise TypeError(f"{type(self).__name__} does not define rhs(t, x), the state "
                        f"derivative (item 2 of the System contract)")

    def outputs(self, t, x):
        """No signals besides the state."""

    def guards(self, t, x):
        return np.zeros(0)

    def apply_event(self, t, x, k, direction):
        """No state events."""

    def initialize(self, t, x):
        """No modes to make consistent."""

    def next_time(self, t):
        return np.inf

    def time_events(self, t, x, tol):
        return []

    def record_row(self, t, x, buf, row):
        buf[row, :self.n_x] = x
        return bool(np.all(np.isfinite(x)))

    def record_row_guards(self, t, x, buf, row, g):
        g[:] = self.guards(t, x)
        return self.record_row(t, x, buf, row)

    def diagnose(self, t, x):
        return ""

    def newton_iterations(self):
        return 0

    def loop_failure(self):
        return "", None
