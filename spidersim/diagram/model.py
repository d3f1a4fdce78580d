"""A loaded, validated and laid-out diagram: ``spidersim.load`` returns one.

Compilation happens once per structure and mode (compiled or interpreted), on the first
``simulate``; parameter values live in an array, so ``set`` and ``simulate`` with new values
never recompile.
"""
from __future__ import annotations

import collections.abc
import functools
import math
import numbers
import os
import time

import numpy as np

from ..errors import DiagramError, ParameterError, SpidersimError, described
from ..solver import CompiledSystem, integrate
from ..solver import loop_warm
from ..solver.compiled import is_cached, load_module, loop_cached
from ..solver.events import MIN_SPAN, STALL_COUNT, STALL_STEP
from ..solver.integrate import COMPILED, STIFF
from ..solver.system import loop_compiled
from .codegen import event_tables, generate
from .flatten import flatten
from .graph import build_layout, jacobian_sparsity
from .jacobian import plan as jacobian_plan
from .units import UNKNOWN, infer_units
from .spec import SIM_KEYS, DiagramSpec, parse_file, parse_text
from ..text.yamlio import found

#: loop residual tolerances are this fraction of the integrator's atol and rtol
LOOP_TOL_FACTOR = 1e-3

#: max_step when none is given: (t_end - t0) / AUTO_STEPS, as Simulink's "auto"
AUTO_STEPS = 50

#: the most sample instants one sampled block may take in a run (a 1 us sampler for 100 s):
#: each is a time event of the integration, so 1e9 were about a day of computing with
#: nothing saying so (a ``Ts: 1e-9`` typo for 1e-3)
MAX_SAMPLES = 1e8

DEFAULTS = {"t_end": 1.0, "method": "LSODA", "rtol": 1e-6, "atol": 1e-8, "max_step": None,
            "output_interval": None, "first_step": None}


#: keys of the ``microgravity`` section
MICROGRAVITY_KEYS = {"signal", "mass", "window", "f_min", "f_max"}


def _check_microgravity_keys(sec, err):
    """Only known keys, and ``signal`` and ``mass`` given (``err(msg, key)`` makes the
    located error)."""
    for k in sec:
        if k not in MICROGRAVITY_KEYS:
            raise err(f"unknown key '{k}'; keys are {', '.join(sorted(MICROGRAVITY_KEYS))}",
                      k)
    for k in ("signal", "mass"):
        if k not in sec:
            raise err(f"'{k}' is required (signal: the base force, e.g. arm.base_force; "
                      f"mass: the station mass in kg)")


#: the relative tolerances the integrators can honour: below 1e-14 the error estimate is
#: round-off (DP54 took 130,000 steps of a 0.1 s servo run at 1e-20 and met nothing), above
#: 1 a step may be all error
RTOL_RANGE = (1e-14, 1.0)


def check_rtol(rtol, what="simulation.rtol", file=None, line=None):
    """A :class:`DiagramError` unless ``RTOL_RANGE[0] <= rtol <= RTOL_RANGE[1]``."""
    lo, hi = RTOL_RANGE
    if not (isinstance(rtol, (int, float)) and lo <= rtol <= hi):
        raise DiagramError(f"{what} must be in [{lo:g}, {hi:g}], got {rtol!r} (below "
                           f"{lo:g} the error estimate is round-off: the steps shrink "
                           f"without meeting it; above {hi:g} a step may be all error)",
                           file=file, line=line)


#: the shortest ``t_end`` and ``first_step`` [s] of the solvers' rules: a run shorter than
#: MIN_SPAN is refused by ``integrate``, and STALL_COUNT consecutive steps shorter than
#: STALL_STEP are a stall (a first step of 1e-300 s grew too slowly: NDF and LSODA stalled)
SHORTEST = {"t_end": (MIN_SPAN, f"the shortest run: the solvers take steps shorter than "
                                f"{STALL_STEP:g} s as a stall"),
            "first_step": (STALL_STEP, f"the solvers take {STALL_COUNT} consecutive steps "
                                       f"shorter than {STALL_STEP:g} s as a stall")}


def _check_shortest(key, val, what, file, line):
    """A :class:`DiagramError` when ``val`` is below the shortest ``t_end`` or
    ``first_step`` of :data:`SHORTEST`."""
    lo, why = SHORTEST[key]
    if val < lo:
        raise DiagramError(f"{what} must be at least {lo:g} s ({why}), got {val:g}",
                           file=file, line=line)


def sim_setting(key, v, what, file=None, line=None, text=True, shortest=True):
    """A setting of the ``simulation`` section (``what`` names it in messages:
    ``simulation.t_end`` for the file, ``t_end`` for an argument of ``simulate``) checked
    and returned: ``method`` a name; the others (:data:`SIM_KEYS`) a finite number > 0 as a
    float, ``rtol`` within :data:`RTOL_RANGE`, ``t_end`` and ``first_step`` at least their
    :data:`SHORTEST` (1e-7 s, 1e-10 s) unless ``shortest`` is false (the file's ``t_end``,
    a default that ``--t-end`` may replace: the run checks the one it uses). Booleans are
    refused (a YAML ``true`` is
    not a time). With ``text`` (the file) a text is an expression (``2*0.5``); without it
    (Python arguments) a text, a list or an array is refused, so that nothing is read
    silently as something else, and ``max_step`` may be ``inf`` (no limit). Raises a
    :class:`DiagramError` saying what was expected and what was found."""
    if key == "method":
        if not isinstance(v, str):
            raise DiagramError(f"{what} must be a name, got {v!r}", file=file, line=line)
        return v
    if type(v) is float or type(v) is int:      # the common case, checked in a few ns
        val = float(v)
        if _setting_fits(key, val, text, shortest):
            return val                           # else the checks below say what is wrong
    val = _setting_number(key, v, what, file, line, text)
    if not val > 0:
        raise DiagramError(f"{what} must be > 0, got {val:g}", file=file, line=line)
    if not math.isfinite(val) and not (key == "max_step" and not text):
        raise DiagramError(f"{what} ({SIM_KEYS[key]}) must be finite, got "
                           f"{_shown(v, text)}"
                           + (" (.inf is infinite)" if text else ""), file=file,
                           line=line)
    if key == "rtol":
        check_rtol(val, what=what, file=file, line=line)
    if shortest and key in SHORTEST:
        _check_shortest(key, val, what, file, line)
    return val


def _setting_fits(key, val, text, shortest):
    """Whether the number ``val`` passes every rule of setting ``key`` (see
    :func:`sim_setting`): the fast path of a plain float or int."""
    return val > 0 and (math.isfinite(val) or (key == "max_step" and not text)) and (
        key != "rtol" or RTOL_RANGE[0] <= val <= RTOL_RANGE[1]) and (
        not shortest or key not in SHORTEST or val >= SHORTEST[key][0])


def _shown(v, text):
    """``v`` as a message shows it: as written in a file, described from Python (only on
    the way to an error: simulate() checks every call)."""
    return repr(v) if text else described(v)


def _setting_number(key, v, what, file, line, text):
    """The value of setting ``key`` as a float: a number, or with ``text`` (the file) an
    expression; a boolean, a text from Python, a list or an array is a
    :class:`DiagramError` naming ``what``."""
    from ..text.expr import ExprError, evaluate
    if isinstance(v, (bool, np.bool_)):  # YAML true/false is not a time or a tolerance
        raise DiagramError(f"{what} ({SIM_KEYS[key]}) must be a number, got the boolean "
                           f"{bool(v)!r}", file=file, line=line)
    try:
        if not text and not (isinstance(v, numbers.Real) or (
                isinstance(v, np.ndarray) and v.ndim == 0 and v.dtype.kind in "iuf")):
            raise TypeError("not a real number")
        val = evaluate(v, {}) if isinstance(v, str) else v
        if isinstance(val, bool):
            raise TypeError("boolean")
        return float(val)
    except ExprError as exc:        # say why (an overflowing 1e400, a NaN, ...)
        raise DiagramError(f"{what} ({SIM_KEYS[key]}) must be a number, got "
                           f"{_shown(v, text)}: {exc}", file=file,
                           line=line) from None
    except (TypeError, ValueError, OverflowError):
        raise DiagramError(f"{what} ({SIM_KEYS[key]}) must be a number, got "
                           f"{_shown(v, text)}", file=file, line=line) from None


def _python_bools(value):
    """``value`` with its NumPy booleans and complex numbers (``np.True_``,
    ``np.complex128``, an array of dtype bool or complex, one inside a list, a tuple or an
    object array) as Python ones, so that the parameter checks refuse them as they refuse
    ``True`` and ``1+2j`` (NumPy's were read as 1 and 0, a complex as its real part with a
    ComplexWarning); anything else unchanged."""
    if isinstance(value, np.bool_):
        return bool(value)
    if isinstance(value, np.complexfloating):
        return complex(value)
    if isinstance(value, np.ndarray) and value.dtype.kind in "bcO":
        return _python_bools(value.tolist())
    if isinstance(value, (list, tuple)):
        return [_python_bools(v) for v in value]
    return value


def _positive_setting(sec, k, default, scope, err):
    """Setting ``k`` of a section (``default`` when absent): a number or an expression of
    the parameters in ``scope``, finite and > 0, as a float. Booleans are refused."""
    from ..text.expr import ExprError, evaluate
    v = sec.get(k, default)
    try:
        v = float(evaluate(v, scope) if isinstance(v, str) else v)
    except (ExprError, TypeError, ValueError):
        raise err(f"'{k}' must be a number or an expression of parameters, got {v!r}",
                  k) from None
    if isinstance(sec.get(k), bool) or not (np.isfinite(v) and v > 0):
        raise err(f"'{k}' must be a finite number > 0, got {sec.get(k)!r}", k)
    return v


def _time_window(w, err):
    """A time window ``[t0, t1]`` with ``0 <= t0 < t1`` [s] as a pair of floats, or None
    when not given."""
    if w is None:
        return None
    if not (isinstance(w, list) and len(w) == 2 and all(
            isinstance(v, (int, float)) and not isinstance(v, bool) for v in w)
            and 0 <= w[0] < w[1]):
        raise err(f"'window' must be [t0, t1] with 0 <= t0 < t1 (seconds), got {w!r}",
                  "window")
    return (float(w[0]), float(w[1]))


class Diagram:
    """A flat diagram ready to simulate.

    Attributes
    ----------
    spec : DiagramSpec
        The parsed top-level file.
    blocks : dict
        Dotted path -> instance (type, parameters).
    layout : Layout
        Sizes, schedule, offsets.
    simulation : dict
        Settings from the file's ``simulation`` section merged with the defaults.
    """

    def __init__(self, spec: DiagramSpec, overrides=None):
        self.spec = spec
        self.file = spec.file
        if spec.inputs:
            first = next(iter(spec.inputs))
            raise DiagramError(
                f"this file is a subsystem (it has 'inputs:', e.g. '{first}'): it runs inside "
                f"a parent diagram, not alone. Use it from a parent: 'subsystems: {{my_type: "
                f"{os.path.basename(spec.file)}}}' and a block '{{type: my_type}}' whose inputs "
                f"are connected", file=spec.file, line=spec.data.line_of("inputs")
                if hasattr(spec.data, "line_of") else None)
        self.flat = flatten(spec, overrides)
        if not self.flat.blocks:
            raise DiagramError("the diagram has no blocks", file=spec.file)
        try:
            self.layout = build_layout(self.flat)
            self.units = infer_units(self.flat)
        except SpidersimError as exc:
            self.flat.note_subsystem(exc)
            raise
        for bl in self.layout.blocks.values():
            for (kind, name), pinfo in bl.ports.items():
                pinfo.unit = self.units.get((bl.path, kind, name), pinfo.unit)
        self.blocks = self.flat.blocks
        self.simulation = dict(DEFAULTS)
        for k, v in spec.simulation.items():
            self.simulation[k] = self._sim_value(k, v)
        self.p = self._param_array()
        self._modules = {}
        #: bumped by :meth:`set`: the start values kept with an idle system are stale
        self._param_gen = 0
        #: per ``jit``, the system the last run used and its start values (see
        #: :meth:`_run_system`)
        self._idle = {}
        self._log = self._log_spec(spec.log)
        self.microgravity = self._microgravity_spec(spec.microgravity)
        self._check_spectrum_windows(spec)

    # ------------------------------------------------------------------ set-up
    def _sim_value(self, key, v):
        return sim_setting(key, v, f"simulation.{key}", file=self.file,
                           line=self.spec.simulation_lines.get(key), shortest=key != "t_end")

    def _param_array(self):
        p = np.zeros(self.layout.n_p)
        for bl in self.layout.blocks.values():
            for name, (a, b, _shape) in bl.pslots.items():
                p[a:b] = np.ravel(bl.params[name])
        return p

    def _signal_table(self):
        """(name, array, start, stop, unit) of every output and of states not output."""
        rows = []
        for bl in self.layout.blocks.values():
            for o in bl.outputs:
                pi = bl.ports[("out", o)]
                rows.append((f"{bl.path}.{o}", pi.loc[0], pi.loc[1], pi.loc[2], pi.unit))
            for s, (a, b) in bl.states.items():
                if s not in bl.state_outputs and b > a and s not in bl.outputs:
                    rows.append((f"{bl.path}.{s}", "x", a, b,
                                 self.units.get((bl.path, "state", s), UNKNOWN)))
        by_port = {(r[0]): r for r in rows}
        for alias, (path, port, s0, s1) in self.flat.aliases.items():
            name, arr, a, b, unit = by_port[f"{path}.{port}"]
            if s0 is not None:
                a, b = a + s0, a + s1
            rows.append((alias, arr, a, b, unit))
        return rows

    def signals(self):
        """Names of every signal that can be logged."""
        return [r[0] for r in self._signal_table()]

    def _check_spectrum_windows(self, spec):
        """A spectrum plot's window holds enough samples of the run's output grid (see
        :func:`spidersim.plots.spectrum_window_problem`); a :class:`DiagramError` at the
        entry's line naming the window and the count. Entries whose window or grid is not
        a number are left to the plot checks."""
        from ..plots import spectrum_window_problem
        dt, t_end = self.simulation.get("output_interval"), self.simulation.get("t_end")
        if not _is_number(dt) or not _is_number(t_end) or not dt > 0:
            return
        lines = getattr(spec.data.get("plots") if hasattr(spec.data, "get") else None,
                        "lines", None) or []
        for k, p in enumerate(spec.plots):
            if not isinstance(p, dict) or p.get("kind") != "spectrum" or not all(
                    p.get(w) is None or _is_number(p.get(w)) for w in ("t_min", "t_max")):
                continue
            if p.get("t_min") is not None and p["t_min"] >= t_end:
                continue        # a window after the run: run's window check names that
            if p.get("t_max") is not None and p["t_max"] > t_end:
                continue        # past the file's t_end: a longer run (--t-end, simulate)
                #               may fill it; a short run's plot says "no spectrum"
            problem = spectrum_window_problem(p.get("t_min"), p.get("t_max"), t_end, dt)
            if problem:
                raise DiagramError(f"plots[{k}]: {problem}", file=self.file,
                                   line=lines[k] if k < len(lines) else None)

    def _microgravity_spec(self, sec):
        """The ``microgravity`` section checked: ``{signal, mass, window, f_min, f_max}``
        with the mass evaluated (a number or an expression of the diagram's parameters),
        or None without the section."""
        if not sec:
            return None

        def err(msg, key=None):
            return DiagramError(f"microgravity: {msg}", file=self.file,
                                line=sec.line_of(key) if key else sec.line)
        _check_microgravity_keys(sec, err)
        self._check_microgravity_signal(sec["signal"], err)
        out = {"signal": sec["signal"]}
        for k, default in (("mass", None), ("f_min", 0.01), ("f_max", 300.0)):
            out[k] = _positive_setting(sec, k, default, self.flat.scope, err)
        if not out["f_min"] < out["f_max"]:
            raise err(f"f_min ({out['f_min']:g}) must be below f_max ({out['f_max']:g})")
        from ..microgravity import band_range_problem
        problem = band_range_problem(out["f_min"], out["f_max"])
        if problem:
            msg, key = problem
            raise err(msg, key if key in sec else None)
        out["window"] = _time_window(sec.get("window"), err)
        return out

    def _check_microgravity_signal(self, signal, err):
        """The microgravity ``signal`` is logged; a signal of the diagram that is not
        logged is told to be added to ``log``, an unknown one gets near names; anything
        but a text (a list, a mapping, a number) is refused before it is looked up."""
        if not isinstance(signal, str):
            raise err(f"'signal' must be a signal name 'block.port', got {found(signal)}",
                      "signal")
        if signal in self.logged_sizes():
            self._check_microgravity_unit(signal, err)
            return
        known = {r[0] for r in self._signal_table()}
        if signal in known:
            raise err(f"signal '{signal}' is not logged (add it to 'log')", "signal")
        import difflib
        near = difflib.get_close_matches(str(signal), sorted(known), n=3)
        hint = f"; did you mean {', '.join(near)}?" if near else ""
        raise err(f"no signal '{signal}'{hint}", "signal")

    def _check_microgravity_unit(self, signal, err):
        """The microgravity ``signal`` is a force (any force unit, converted to N by the
        assessment; a signal with no stated unit is taken to be in N)."""
        from ..microgravity import newtons_per_unit
        unit = next((r[4] for r in self._signal_table() if r[0] == signal), None)
        try:
            newtons_per_unit(unit)
        except ValueError as exc:
            raise err(f"signal '{signal}': {exc}", "signal") from None

    def logged_sizes(self):
        """Logged signals (what a run's result holds) -> number of values of each."""
        return {r[0]: r[3] - r[2] for r in self._log}

    def _log_spec(self, log):
        table = {r[0]: r for r in self._signal_table()}
        if log == "all" or log is None:
            return list(table.values())
        out = []
        lines = getattr(log, "lines", [self.spec.log_line] * len(log))
        for k, name in enumerate(log):
            if not isinstance(name, str):
                found = ("a mapping" if isinstance(name, dict) else
                         "a list" if isinstance(name, list) else repr(name))
                raise DiagramError(f"log: entry {k} must be a signal name 'block.port', got "
                                   f"{found}", file=self.file,
                                   line=lines[k] if k < len(lines) else self.spec.log_line)
            if name not in table:
                import difflib
                near = difflib.get_close_matches(str(name), list(table), n=3)
                hint = f"; did you mean {', '.join(near)}?" if near else ""
                raise DiagramError(f"log: no signal '{name}'{hint}", file=self.file,
                                   line=lines[k] if k < len(lines) else self.spec.log_line)
            out.append(table[name])
        return out

    # ------------------------------------------------------------------ parameters
    def set(self, path, value):
        """Change a numeric parameter ``block.param`` without recompiling.

        Structural parameters (integers, strings, sizes) need ``spidersim.load(...,
        set={path: value})`` instead.
        """
        if not isinstance(path, str):
            raise ParameterError(f"set: path must be a text 'block.param', got "
                                 f"{described(path)}")
        block, _, name = path.rpartition(".")
        bl = self.layout.blocks.get(block)
        if bl is None:
            raise ParameterError(self._set_target_problem(path, block, name))
        (name, value), = bl.cls.current_names({name: value}).items()
        decl = bl.cls.parameters.get(name)
        if decl is None:
            raise ParameterError(f"set {path}: type {bl.cls.type_name} has no parameter "
                                 f"'{name}'", block=block)
        if decl.is_structural:
            raise ParameterError(f"set {path}: '{name}' is structural; reload with "
                                 f"spidersim.load(file, set={{'{path}': ...}})", block=block)
        user = {k: v for k, v in self.blocks[block].params.items()}
        user[name] = _python_bools(value)
        try:
            new = bl.cls.validate_params(user)
        except ParameterError as exc:       # the value, or its check against the others
            exc.message, exc.block = f"set {path}: {exc.message}", block
            raise
        old_shape = np.shape(self.blocks[block].params[name])
        if np.shape(new[name]) != old_shape:
            raise ParameterError(f"set {path}: shape {np.shape(new[name])} differs from "
                                 f"{old_shape}; reload to change sizes", block=block)
        try:
            self.blocks[block].params = new
            merged = dict(new)
            merged.update(bl.cls.derived(new))
            bl.params = merged
            for pname, (a, b, _s) in bl.pslots.items():
                if np.size(merged[pname]) != b - a:
                    raise ParameterError(f"set {path}: changes the size of '{pname}'; "
                                         f"reload", block=block)
                self.p[a:b] = np.ravel(merged[pname])
        finally:                        # after every update: a run kept until now is stale
            self._param_gen += 1

    def _set_target_problem(self, path, block, name):
        """What is wrong with the target of ``set(path, ...)`` that names no block
        parameter: a parameter of the diagram or of a subsystem instance (evaluated into
        the blocks' values at load: load again with ``set=``), a block or subsystem
        instance without a parameter, or no such name (near names suggested)."""
        again = f"reload with spidersim.load(file, set={{{path!r}: ...}})"
        if not block and name in self.spec.parameters:
            return (f"set {path}: '{name}' is a parameter of the diagram, not of a block: "
                    f"its value went into the blocks' values (and later parameters) when the "
                    f"diagram was loaded; to change it, {again}")
        if block in self.flat.subsystem_instances:
            return (f"set {path}: '{block}' is a subsystem instance: its parameters went "
                    f"into its blocks' values when the diagram was loaded; to change "
                    f"'{name}', {again} (or set a block parameter inside it: "
                    f"{block}.<block>.<param>)")
        whole = path if not block else block
        if whole in self.layout.blocks or whole in self.flat.subsystem_instances:
            return (f"set {path}: '{whole}' is a block; write {whole}.<param> (e.g. "
                    f"{whole}.{next(iter(self.blocks[whole].params), 'k')})"
                    if whole in self.blocks else
                    f"set {path}: '{whole}' is a subsystem instance; write "
                    f"{whole}.<block>.<param>")
        import difflib
        known = list(self.layout.blocks) + list(self.spec.parameters)
        near = difflib.get_close_matches(whole, known, n=3)
        hint = f"; did you mean {', '.join(near)}?" if near else ""
        return (f"set {path}: the diagram has no block{' or parameter' if not block else ''} "
                f"'{whole}'{hint} (write block.param, e.g. motor.R)")

    def initial_state(self):
        x0 = np.zeros(self.layout.n_x)
        for bl in self.layout.blocks.values():
            for s, (a, b) in bl.states.items():
                try:
                    x0[a:b] = bl.cls.initial_value(bl.cls.states[s], b - a, bl.params)
                except ParameterError as exc:
                    inst = self.blocks[bl.path]
                    raise ParameterError(f"state '{s}': {exc.message}", file=inst.file,
                                         line=inst.line, block=bl.path) from None
        return x0

    def initial_modes(self):
        m0 = np.zeros(self.layout.n_modes)
        for bl in self.layout.blocks.values():
            for m, (a, b) in bl.modes.items():
                m0[a:b] = bl.cls.initial_value(bl.cls.modes[m], b - a, bl.params)
        return m0

    def initial_signals(self):
        """Signal array at start: zeros, with the initial guesses of constraint unknowns."""
        sig = np.zeros(self.layout.n_sig)
        for lp in self.layout.loops:
            for path, port, kind in lp.tears:
                if kind == "constraint":
                    bl = self.layout.blocks[path]
                    a, b = lp.zslots[(path, port)]
                    guess = bl.cls.implicit[port][1]
                    sig[a:b] = np.broadcast_to(np.ravel(bl.params[guess]), (b - a,))
        return sig

    def loop_info(self):
        """What the solver needs to report a loop failure, per loop."""
        out = []
        for lp in self.layout.loops:
            n = len(lp.zidx)
            first = self.blocks[lp.tears[0][0]]
            out.append({"index": lp.index, "walk": lp.walk, "names": lp.names,
                        "tears": [f"{p}.{q}" for p, q, _ in lp.tears], "ws0": lp.ws0,
                        "n": n, "file": first.file, "line": first.line,
                        "block": first.path})
        return out

    # ------------------------------------------------------------------ compile & run
    def source(self, jit=True, jacobian=False):
        """The generated module text (``jacobian``: with the analytic Jacobian when the
        blocks declare their partials, see :mod:`spidersim.diagram.jacobian`)."""
        return generate(self.layout, jit, jacobian)

    def compile(self, jit=True, loop=False, jacobian=False):
        """Generate, import and warm up the compiled functions; return the system.

        With ``loop``, the compiled integration loop's entry of the diagram's method (or of the
        method ``loop`` names: ``DP54``, ``ROS34PW2``, ``NDF``) is compiled too (or loaded
        from the cache); otherwise it is compiled on its first use.
        With ``jacobian``, the system can assemble the analytic Jacobian when the blocks
        allow (``system.analytic_jacobian``; what the stiff methods use): a module made
        without it is made again with it (a superset, kept for later calls).
        """
        jit = check_jit(jit, self.file)
        self._ensure_compiled(jit, loop, jacobian)
        # the next run reports this compile as its own (the CLI compiles, then runs: its
        # report said compile_time 0 after "compiled in 68.9 s")
        self._compile_carried = self._compile_time
        return self._system(jit)

    def _ensure_compiled(self, jit, loop, jacobian):
        """The module of :meth:`compile` made or loaded (and the loop with ``loop``);
        ``_compile_time`` is what this call spent."""
        if jit in self._modules and jacobian and not self._jacobian_reason() and not \
                getattr(self._modules[jit][0], "HAS_JACOBIAN", False):
            del self._modules[jit]          # made again with the Jacobian
        if jit not in self._modules:
            t0 = time.perf_counter()
            def warm_up(mod):
                # numba compiles, or loads from its cache, on the first calls: inside
                # load_module so that a corrupt numba cache is cleared and retried
                self._modules[jit] = (mod, None)
                self._system(jit).warm_up()

            text = self.source(jit, jacobian)
            second = self._loop_in_second_process(jit, loop, text)
            ok = False
            try:
                mod, key, _ = load_module(text, jit, check=warm_up)
                ok = True
            finally:        # wait for the loop's compile (stop it after an error)
                loop_warm.finish(second, ok)
            self._modules[jit] = (mod, key)
            self._compile_time = time.perf_counter() - t0
        else:
            self._compile_time = getattr(self, "_compile_carried", 0.0)
        self._compile_carried = 0.0
        method = loop if isinstance(loop, str) else self.simulation["method"]
        if loop and jit and not loop_compiled(method):
            t0 = time.perf_counter()
            self._system(jit).warm_up_loop(method)
            self._compile_time += time.perf_counter() - t0

    def _loop_in_second_process(self, jit, loop, text):
        """Start compiling the integration loop's entry of the run's method in a second
        process (:mod:`spidersim.solver.loop_warm`) when both it and the module ``text``
        are to be compiled; the process, or None."""
        if not (jit and loop):
            return None
        method = loop if isinstance(loop, str) else self.simulation["method"]
        if loop_compiled(method) or loop_cached(method) or is_cached(text):
            return None
        return loop_warm.start(method)

    def _system(self, jit):
        mod, key = self._modules[jit]
        L = self.layout
        sig_names, x_names, sparsity, tables = self._system_tables()
        system = CompiledSystem(mod, self.initial_state(), self.p.copy(), self.initial_modes(),
                                L.n_sig, self._log, sig_names, x_names, sparsity,
                                sig0=self.initial_signals(), loops=self.loop_info(),
                                tables=tables, shared=self._shared(mod))
        system.jacobian_reason = self._jacobian_reason()
        #: block path -> its modes' span in ``modes`` (the SciPy loop keeps the modes an
        #: event chose: :meth:`~spidersim.solver.scipy_loop.SciPyLoop._keep_event_modes`)
        system.mode_slices = {bl.path: (min(a for a, _ in bl.modes.values()),
                                        max(b for _, b in bl.modes.values()))
                              for bl in L.blocks.values() if bl.modes}
        a, r = L.p_loop_tol
        system.p[a] = LOOP_TOL_FACTOR * self.simulation["atol"]
        system.p[r] = LOOP_TOL_FACTOR * self.simulation["rtol"]
        system.structure_key = key
        # every system, not only the warm-up one, calls the machine code directly
        # (no-op before the first warm-up compiled the functions)
        system._bind_entry_points()
        return system

    def _run_system(self, jit):
        """The system a run uses: the previous run's, reset to the start values (its
        parameters from :attr:`p`, modes, signals and the loops' workspaces), or a new one
        after :meth:`set` or a new module. Taken out of :attr:`_idle` for the run and put
        back by :meth:`_release` after it, so runs in parallel threads each get their own;
        saves a third of ``simulate``'s Python time on short runs (the ball's 100 impacts:
        about 10 of 30 us)."""
        mod = self._modules[jit][0]
        idle = self._idle.pop(jit, None)
        if idle is not None and idle[0] is mod and idle[1] == self._param_gen:
            _, _, system, modes0, sig0 = idle
            np.copyto(system.p, self.p)
            np.copyto(system.modes, modes0)
            system.sig[:sig0.size] = sig0
            system.sig[sig0.size:] = 0.0
            return system
        return self._system(jit)

    def _release(self, jit, system, modes0, sig0, gen):
        """Keep ``system`` (just run) for the next run, with its start values, made at
        parameter generation ``gen`` (a :meth:`set` since then makes it stale)."""
        if system.jit == bool(jit) and self._modules.get(jit, (None,))[0] is system.module:
            self._idle[jit] = (system.module, gen, system, modes0, sig0)

    def _shared(self, mod):
        """The dict every system of this layout and module shares (what does not change
        between runs: record layout, event tables; see :class:`CompiledSystem`)."""
        cached = getattr(self, "_shared_cache", None)
        if cached is None or cached[0] is not self.layout or cached[1] is not mod:
            cached = self._shared_cache = (self.layout, mod, {})
        return cached[2]

    def _jacobian_reason(self):
        """Why the diagram has no analytic Jacobian ('' when it has one; see
        :func:`spidersim.diagram.jacobian.plan`), computed once per layout."""
        cached = getattr(self, "_jac_reason_cache", None)
        if cached is None or cached[0] is not self.layout:
            cached = self._jac_reason_cache = (self.layout, jacobian_plan(self.layout).reason)
        return cached[1]

    def _system_tables(self):
        """The structural tables of a system (signal and state names, Jacobian sparsity,
        event tables): computed once per diagram, shared by every system it compiles."""
        cached = getattr(self, "_tables_cache", None)
        if cached is not None and cached[0] is self.layout:
            return cached[1]
        L = self.layout
        sig_names, x_names = [], []
        for r in self._signal_table():
            (sig_names if r[1] == "sig" else x_names).append((r[0], r[2], r[3]))
        seen = {n for n, _, _ in x_names}
        for bl in L.blocks.values():
            for s_, (a, b) in bl.states.items():
                nm = f"{bl.path}.{s_}"
                if nm not in seen:
                    x_names.append((nm, a, b))
                    seen.add(nm)
        sig_names.sort(key=lambda r: r[1])
        # the pattern is made when an implicit method first asks (n_x^2 booleans)
        pattern = functools.cache(functools.partial(jacobian_sparsity, L)) if L.n_x else None
        tables = (sig_names, x_names, pattern, event_tables(L))
        self._tables_cache = (L, tables)
        return tables

    def simulate(self, t_end=None, method=None, rtol=None, atol=None, max_step=None,
                 output_interval=None, jit=True, progress=None, should_stop=None,
                 jacobian="auto"):
        """Run the diagram; arguments left ``None`` come from the file's ``simulation``.

        ``jacobian`` (the compiled ``ROS34PW2`` and ``NDF``): ``"auto"`` the analytic
        Jacobian when the diagram has one (its blocks declare their partials, see
        :mod:`spidersim.diagram.jacobian`), else finite differences; ``"fd"`` always finite
        differences; ``"analytic"`` the analytic one or a :class:`SpidersimError` saying
        why there is none.

        Returns a :class:`~spidersim.solver.result.Result`; raises
        :class:`~spidersim.errors.IntegrationError` (with ``partial``) on failure.
        """
        cfg = self._run_settings(dict(t_end=t_end, method=method, rtol=rtol, atol=atol,
                                      max_step=max_step, output_interval=output_interval),
                                 jit, progress, should_stop)
        if cfg["max_step"] is None:
            cfg["max_step"] = cfg["t_end"] / AUTO_STEPS
        self.check_samples(cfg["t_end"])
        self._ensure_compiled(jit, cfg["method"] in COMPILED and cfg["method"],
                              cfg["method"] in STIFF and jacobian != "fd")
        gen = self._param_gen
        system = self._run_system(jit)
        modes0, sig0 = system.modes.copy(), system.sig[:self.layout.n_sig].copy()
        a, r = self.layout.p_loop_tol
        system.p[a] = LOOP_TOL_FACTOR * cfg["atol"]
        system.p[r] = LOOP_TOL_FACTOR * cfg["rtol"]
        stats = {"diagram": self.spec.name, "jit": jit, "compile_time": self._compile_time,
                 "structure_key": system.structure_key}
        try:
            result = integrate(system, cfg["t_end"], method=cfg["method"], rtol=cfg["rtol"],
                               atol=cfg["atol"], max_step=cfg["max_step"],
                               first_step=cfg["first_step"],
                               output_interval=cfg["output_interval"], progress=progress,
                               should_stop=should_stop,
                               stats=stats, jacobian=jacobian)
        except SpidersimError as exc:
            if exc.file is None:
                exc.file = self.file
            raise
        self._release(jit, system, modes0, sig0, gen)
        return result

    def check_samples(self, t_end):
        """Raise a :class:`DiagramError` at the block's line when a sampled block (its
        ``sample_period`` parameter > 0) would take more than :data:`MAX_SAMPLES` samples
        in a run of ``t_end`` seconds."""
        for path, inst in self.flat.blocks.items():
            name = inst.cls.sample_period
            Ts = float(inst.params.get(name, 0.0)) if name else 0.0
            if Ts > 0.0 and t_end / Ts > MAX_SAMPLES * (1.0 + 1e-9):
                raise DiagramError(
                    f"{inst.cls.type_name} samples every {name} = {Ts:g} "
                    f"s: {t_end / Ts:.3g} samples in the run (t_end = {t_end:g} s), more "
                    f"than the {MAX_SAMPLES:.0e} a run may take (each sample is a time "
                    f"event of the integration: hours of computing); make {name} larger "
                    f"or the run shorter", file=inst.file,
                    line=inst.param_lines.get(name, inst.line), block=path)

    def _run_settings(self, given, jit, progress, should_stop):
        """The file's ``simulation`` settings with the arguments of :meth:`simulate` that
        are not None in their place, each checked by :func:`sim_setting` (the rules and
        messages of the file's section, a text refused); ``jit`` a boolean, ``progress``
        and ``should_stop`` functions or None. A :class:`DiagramError` names the
        argument."""
        cfg = dict(self.simulation)
        for k, v in given.items():
            if v is not None:
                cfg[k] = sim_setting(k, v, k, file=self.file, text=False)
        check_jit(jit, self.file)
        for name, f, sig in (("progress", progress, "progress(t)"),
                             ("should_stop", should_stop, "should_stop() -> bool")):
            if f is not None and not callable(f):
                raise DiagramError(f"{name} must be a function {sig} or None, got "
                                   f"{described(f)}", file=self.file)
        return cfg

    # ------------------------------------------------------------------ analysis
    def linearize(self, inputs, outputs, at=None, open=(), jit=True):
        """Named ``control.StateSpace`` from ``inputs`` to ``outputs`` (signal names) at the
        operating point ``at``, loops cut at the signals in ``open``; see
        :mod:`spidersim.diagram.analysis`."""
        from .analysis import linearize
        return linearize(self, inputs, outputs, at=at, open=open, jit=jit)

    def loop_transfer(self, signal, at=None, jit=True):
        """Loop transfer ``L`` with the loop opened at ``signal`` (closed loop L/(1+L))."""
        from .analysis import loop_transfer
        return loop_transfer(self, signal, at=at, jit=jit)

    def trim(self, targets=None, derivatives="all", free_inputs=(), x0=None, t=0.0,
             jit=True, tol=1e-10):
        """Operating point with chosen derivatives zero and target signal values; see
        :func:`spidersim.diagram.analysis.trim` (the same arguments, so that an unknown
        keyword is refused at the call)."""
        from .analysis import trim
        return trim(self, targets=targets, derivatives=derivatives, free_inputs=free_inputs,
                    x0=x0, t=t, jit=jit, tol=tol)

    # ------------------------------------------------------------------ summary
    def inferred_parameter_units(self):
        """``{"block.param": unit}`` of the real parameters declared with an inherited unit
        (a Gain's ``k``, a PI's ``kp``) whose unit the wiring fixed."""
        out = {}
        for path, inst in self.flat.blocks.items():
            for name, decl in inst.cls.parameters.items():
                rule = inst.cls.unit_of(decl, inst.params)
                unit = self.units.get((path, "param", name))
                if decl.kind == "real" and (rule == "*" or "@" in rule) and unit not in (
                        None, UNKNOWN):
                    out[f"{path}.{name}"] = unit
        return out

    def summary(self):
        """Text for ``spidersim check``: blocks, states, signals, schedule."""
        L = self.layout
        lines = [f"diagram '{self.spec.name}' ({self.file})",
                 f"  {len(L.blocks)} blocks, {L.n_x} states, {L.n_sig} signal values, "
                 f"{L.n_p} parameter values, {L.n_modes} mode values, "
                 f"{len(self.flat.subsystem_instances)} subsystem instances",
                 "  blocks:"]
        for bl in L.blocks.values():
            st = ", ".join(f"{s}[{b - a}]" for s, (a, b) in bl.states.items())
            lines.append(f"    {bl.path}: {bl.cls.type_name}" + (f"  states {st}" if st else ""))
        lines.append("  signals:")
        for name, arr, a, b, unit in self._signal_table():
            lines.append(f"    {name} [{unit}] size {b - a}" + ("  (state)" if arr == "x"
                                                                  else ""))
        inferred = self.inferred_parameter_units()
        if inferred:
            lines.append("  parameter units inferred from the wiring:")
            lines += [f"    {name} [{unit}]" for name, unit in inferred.items()]
        lines.append(f"  schedule ({len(L.calls)} items):")
        lines.append("    " + " -> ".join(p if k == "call" else f"[loop {p + 1}]"
                                          for k, p in L.calls) if L.calls else "    (none)")
        if not L.loops:
            lines.append("  algebraic loops: none")
        for lp in L.loops:
            lines.append(f"  algebraic loop {lp.index + 1}: {lp.walk}")
            lines.append("    tear variables: " + ", ".join(
                f"{p}.{q}" + (" (constraint)" if k == "constraint" else "")
                for p, q, k in lp.tears) + f"; inner calls: {' -> '.join(lp.calls)}")
        return "\n".join(lines)


def _file_name(path, what):
    """``path`` (a text, bytes or an ``os.PathLike``) as a text; anything else (None, a
    number: an integer would be taken as an open file descriptor) is a
    :class:`DiagramError` naming the argument ``what``."""
    if not isinstance(path, (str, bytes, os.PathLike)):
        raise DiagramError(f"{what} must be a file path (a str or a pathlib.Path), got "
                           f"{described(path)}")
    return os.fsdecode(os.fspath(path))


def check_jit(jit, file=None) -> bool:
    """``jit`` as a bool (a numpy boolean too); a :class:`DiagramError` for anything else
    (a text ``"no"`` would be true)."""
    if not isinstance(jit, (bool, np.bool_)):
        raise DiagramError(f"jit must be True (compiled) or False (plain Python), got "
                           f"{described(jit)}", file=file)
    return bool(jit)


def _overrides(set_, fn):
    """The ``set`` argument of :func:`load` and :func:`loads` (``fn``): None or a mapping of
    texts ``block.param`` (or a top-level parameter) to values; a
    :class:`ParameterError` otherwise (a text ``"motor.R=1"`` is the command line's form)."""
    if set_ is None:
        return None
    if not isinstance(set_, collections.abc.Mapping):
        raise ParameterError(f"{fn}: set must be a mapping {{'block.param': value}}, got "
                             f"{described(set_)}")
    for k in set_:
        if not isinstance(k, str):
            raise ParameterError(f"{fn}: the keys of set are parameter paths "
                                 f"'block.param', got {described(k)}")
    return {k: _python_numbers(v) for k, v in set_.items()}


def _python_numbers(value):
    """A value of ``load(set=)`` with its NumPy numbers as Python ones, as
    :meth:`Diagram.set` takes them: a real scalar (``np.int64``, ``np.float32``) or a 0-d
    array of one as an int or a float, an array of real numbers as a (nested) list;
    NumPy booleans and complex numbers become Python ones (refused as those are); anything
    else unchanged."""
    value = _python_bools(value)
    if isinstance(value, np.generic) and value.dtype.kind in "iuf":
        return value.item()
    if isinstance(value, np.ndarray) and value.dtype.kind in "iuf":
        return value.tolist()
    if isinstance(value, list):
        return [_python_numbers(v) for v in value]
    return value


def load(path, set=None) -> Diagram:
    """Load a diagram file. ``set`` maps dotted parameter paths to values (or expressions).

    ``path``: a str, bytes or pathlib.Path; ``set``: a mapping ``{"block.param": value}``.
    Anything else is a :class:`~spidersim.errors.SpidersimError` naming the argument.
    """
    path, overrides = _file_name(path, "load: path"), _overrides(set, "load")
    return Diagram(parse_file(path), overrides)


def loads(text, set=None, file="<string>") -> Diagram:
    """Load a diagram from YAML text (subsystem paths relative to the current directory).

    ``text``: a str (bytes are refused: decode them); ``set`` as for :func:`load`;
    ``file``: the name errors give the text.
    """
    if not isinstance(text, str):
        hint = " (decode bytes first: text.decode('utf-8'))" if isinstance(
            text, (bytes, bytearray)) else ""
        raise DiagramError(f"loads: text must be the YAML text of a diagram (a str), got "
                           f"{described(text)}{hint}")
    file, overrides = _file_name(file, "loads: file"), _overrides(set, "loads")
    return Diagram(parse_text(text, file), overrides)


def _is_number(v):
    """A real number that is not a bool."""
    return isinstance(v, (int, float)) and not isinstance(v, bool)
