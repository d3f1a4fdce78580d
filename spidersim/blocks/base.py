"""The Block base class and the declarations every block makes at class level.

Contract for block implementers
-------------------------------
1. Subclass :class:`Block`; the class name (or ``type_name``) is the YAML type name.
2. Declare ``parameters`` (:class:`Param`), ``inputs`` and ``outputs`` (:class:`Port`),
   continuous ``states`` (:class:`State`) and discrete ``modes`` (:class:`Mode`) as dicts at
   class level. The loader, ``spidersim blocks`` and the contract tests read them without
   making an instance.
3. Declare for each output the inputs it depends on *directly* (``Port.feedthrough``): a tuple
   of input names, or a callable ``f(params) -> tuple`` when it depends on a parameter (that
   parameter must then be ``structural``). A contract test probes every block numerically and
   fails when an output moves with an undeclared input.
4. Write the equations as static methods with the declared names as arguments; the compiler
   binds each name to a slice of the flat arrays:

   ``output(t, <states>, <inputs>, <params>, <modes>, <outputs>)``
       writes every output port in place. It may be called more than once per evaluation
       (once per group of outputs that the schedule needs early); it must be pure. A kernel
       that takes the reserved argument ``inputs_ready`` (a compile-time ``bool``) gets
       ``False`` in a call the schedule makes only for outputs without feedthrough, before
       the block's inputs are computed, and that is followed by a call with ``True`` in the
       same evaluation: it must then write every output without feedthrough and may skip the
       work of the others (the arm skips its forward dynamics). Every other call gets
       ``True`` and must write every output.
   ``derivative(t, <states>, <inputs>, <params>, <modes>, <outputs>, der_<state>...)``
       writes the time derivative of every state into ``der_<state>``. The block's outputs
       are those of the same evaluation (the outputs are evaluated first): a derivative may
       read them instead of computing the same terms again (``BrushlessMotor``'s back EMF).
   ``next_time(t, <params>, <modes>) -> float``
       time of the block's next *time event* (``inf`` for none): the integrator stops there.
       A function of the parameters and modes only (``t`` is the time it is asked at): the
       compiled loop asks again only after events, the only places modes change.
   ``time_event(t, <states>, <inputs>, <params>, <modes>)``
       applied at that time; may change the block's own modes and states only.
   ``time_output(t, <states>, <params>, <modes>)``
       optional, for a sampled block whose output at a sample does not depend on the
       sample it takes (a ``UnitDelay``, a strictly proper ``DiscreteTransferFunction``):
       updates the held outputs without reading any input. At a sampling instant every due
       block's ``time_output`` runs first, then the outputs are evaluated again, then the
       ``time_event`` kernels take their samples in schedule order: a block that reads such
       an output at the same instant, itself included through a loop, sees the new value
       (``y[k+1] = y[k] + 1`` counts 1, 2, 3, ...; taking the sample and moving the output
       in one kernel counted 0, 1, 1, 2, 2, ...).
   ``guard(t, <states>, <inputs>, <params>, <modes>, zc)``
       writes the zero-crossing functions of the block's ``events`` into ``zc`` (one after
       the other, each of its declared size); an event fires when its guard crosses zero in
       the declared ``direction``.
   ``on_event(t, which, direction, <states>, <inputs>, <params>, <modes>)``
       applies event ``which`` (index into ``zc``) found crossing in ``direction`` (+1/-1);
       may change the block's own states and modes only.
   ``initialize(t, <states>, <inputs>, <params>, <modes>)``
       sets the modes consistent with the inputs, at the start and after every event.

   ``partials(t, <states>, <inputs>, <params>, <modes>, <outputs>, dfdx, dfdu, dydx, dydu)``
       optional: the block's *local* partial derivatives at ``(t, states, inputs, modes)``
       (the outputs are those of the same evaluation), as small dense matrices, C order::

           dfdx[i, j] = d(der_state_i) / d(state_j)     shape (n_s, n_s)
           dfdu[i, k] = d(der_state_i) / d(input_k)     shape (n_s, n_u)
           dydx[r, j] = d(output_r) / d(state_j)        shape (n_y, n_s)
           dydu[r, k] = d(output_r) / d(input_k)        shape (n_y, n_u)

       ``state_j``: the block's states in declaration order, each element by element (a
       state of size 0 takes no column); ``input_k``: its inputs in ``input_names`` order,
       element by element (an unconnected optional input too: it reads zeros);
       ``output_r``: its outputs in ``output_names`` order *except those that are a
       state* (``DCMotor.w``: the engine knows ``dw/dw = 1``). Signs as the equations:
       each entry is the derivative of the row quantity itself, in unit(row)/unit(column)
       (``dfdx`` of ``L di/dt = v - R i`` is ``-R/L`` [1/s]). The matrices arrive zeroed:
       the kernel writes the structurally nonzero entries only, and takes only the matrices
       that can be nonzero (an argument left out is declared zero: a ``Gain`` takes
       ``dydu`` alone). Dense rather than sparse because blocks are small (a few states and
       ports: tens of entries) and a sparse format would need a second structural
       declaration per block; the engine's structure is kept at the diagram level (which
       states each signal depends on). A contract test compares every block's partials
       with finite differences of its ``output`` and ``derivative``. The engine uses them to
       assemble the Jacobian ``df/dx`` of the whole diagram by the chain rule (see
       :mod:`spidersim.diagram.jacobian`); a block without them on a path into a derivative
       makes the whole diagram fall back to finite differences.

   Reserved argument names: ``t``, ``direction``, ``zc``, ``which``, ``inputs_ready``,
   ``der_<state>`` and (``partials`` only) ``dfdx``, ``dfdu``, ``dydx``, ``dydu``; a
   declared name equal to one of them cannot be a kernel argument (it would be ambiguous).

   An output port with the same name and size as a state *is* that state: no kernel writes
   it and it has no feedthrough (``DCMotor.w``). Ports, states and modes arrive as 1-D float arrays of their declared size (a scalar port
   is ``u[0]``); real parameters as floats (scalar) or arrays (vector, matrix); ``int`` and
   ``bool`` parameters as constants; ``str`` parameters are structural and not passed. The
   functions must be numba-compilable, allocation-free (write loops, not array expressions)
   and must never clip a state or integrate by hand: discontinuities are events.
5. ``scratch`` (name -> size) gives kernels workspace arrays by name, allocated once.
6. ``implicit`` (output name -> (residual port, initial-guess parameter)): outputs the
   engine solves so that the residual is zero (an algebraic loop made on purpose, e.g. a
   constraint force).
7. The declarations are checked when the class is defined (``__init_subclass__``): every
   kernel argument must be a declared name or a reserved one (names computed by ``derive``
   are taken from a call with the default parameters, or from ``derives`` when the class
   declares them: a block whose ``derive`` reads files or compiles declares them, so that
   defining the class does neither), a name may not be declared twice in
   different roles (an output may share its state's name), a ``derivative`` needs states, a
   ``guard`` needs events, ``partials`` takes at least one of its matrices and only those
   the block can have (``dfdx`` needs states, ...); a :class:`BlockDefinitionError` names
   the class and the argument.
8. Optional class methods: ``derive(params) -> dict`` for numeric parameters computed from the
   user's (e.g. a state-space realisation of a transfer function), ``check(params)`` for
   cross-parameter validation (raise ``ValueError`` with a message), and
   ``kernel_source(params, kernel) -> str`` for kernels whose argument list depends on a
   structural parameter (e.g. a sum with N inputs), ``input_names(params)`` for such blocks.
9. Linearization (:mod:`spidersim.diagram.analysis`) differentiates the continuous-time
   equations, so two kinds of block declare what they are:

   ``sample_period = "Ts"``
       the block is *sampled* (a discrete-time law, output held between samples) when that
       parameter is > 0: its held outputs have no derivative with respect to anything
       between samples, and a linearization through it would be silently wrong (a held
       controller reads as gain 0). Linearization refuses a path through such a block,
       naming it and the parameter (``Ts = 0`` when the parameter allows it: the block's
       continuous form).
   A sampled block whose held output depends on the sample it takes
   (:meth:`Block.sample_feedthrough`: a ZeroOrderHold, a DiscretePI) may not read its own
   output back through blocks without a state: such a discrete algebraic loop is refused
   when the diagram is built, naming the path (the sample would silently read the previous
   output, a hidden delay).
   ``quantizer = {"bits": 0}``
       parameter -> value that removes the block's quantization (a staircase output of
       zero slope almost everywhere). Linearization uses the block with these values: a
       quantizer is linearized as its unquantized gain (as Simulink does), and the report
       names the blocks so treated.
"""
from __future__ import annotations

import difflib
import importlib
import inspect
import math
import re
import sys
import warnings
from dataclasses import dataclass
from typing import Any, Callable

import numpy as np

from ..errors import BlockTypeError, ParameterError, RenamedParameterWarning

REQUIRED = object()

#: name -> Block subclass; filled by ``Block.__init_subclass__``.
REGISTRY: dict[str, type["Block"]] = {}

#: the kernels a block may define, and the argument names every kernel may use
KERNELS = ("output", "derivative", "next_time", "time_output", "time_event", "guard",
           "on_event", "initialize", "partials")
RESERVED = ("t", "direction", "zc", "which", "inputs_ready")
#: the matrices of the ``partials`` kernel (contract item 4), reserved names too
PARTIALS = ("dfdx", "dfdu", "dydx", "dydu")


class BlockDefinitionError(TypeError):
    """A block class whose declarations break the contract (a programming error of the
    block's author, raised when the class is defined)."""


@dataclass(frozen=True)
class Dim:
    """A size computed from parameters: ``text`` for the docs, ``fn(params) -> int``."""

    text: str
    fn: Callable[[dict], int]


@dataclass(frozen=True)
class Param:
    """Declaration of a block parameter.

    Parameters
    ----------
    default : float, list, str or REQUIRED
    unit : str
        SI unit in Modelica notation (``"N.m"``, ``"rad/s"``, ``"1"`` for dimensionless).
    shape : () or str or int or tuple
        ``()`` scalar; ``"*"`` 1-D of any length (a scalar is accepted as length 1);
        an int, a parameter name or a :class:`Dim` for a 1-D size; a 2-tuple of those for a
        matrix.
    gt, ge, lt, le : float, optional
        Bounds applied to every element.
    kind : {"real", "int", "bool", "str"}
        ``int``, ``bool`` and ``str`` parameters are structural: their values are part of the
        compiled code, and changing them recompiles.
    choices : tuple, optional
        Allowed values of a ``str`` parameter.
    structural : bool
        A ``real`` parameter that decides structure (e.g. an inductance whose zero makes a
        port feedthrough).
    allow_inf : bool
        ``inf``/``-inf`` are meaningful values (an absent limit). Otherwise every element of a
        ``real`` parameter must be finite (``1e400`` overflows to ``inf`` and is refused).
    file : bool
        A ``str`` parameter naming a file read on the machine that runs the model (an arm
        data file). The remote service refuses requests that change it: a file path of the
        server is not the requester's to choose.
    """

    default: Any = REQUIRED
    unit: str = "1"
    doc: str = ""
    shape: Any = ()
    gt: float | None = None
    ge: float | None = None
    lt: float | None = None
    le: float | None = None
    kind: str = "real"
    choices: tuple | None = None
    structural: bool = False
    allow_inf: bool = False
    file: bool = False

    @property
    def is_structural(self):
        return self.structural or self.kind != "real"


@dataclass(frozen=True)
class Port:
    """Declaration of an input or output port.

    ``size``: an int, a parameter name, a :class:`Dim`, ``"@u"`` (same size as input ``u``;
    outputs only) or ``None`` (inputs only: take the size of whatever is connected).
    ``feedthrough`` (outputs only): the inputs this output depends on directly, or a callable
    of the parameters returning them, or ``"all"``.
    ``optional`` (inputs only): an unconnected optional input reads zeros; a function of
    the block's parameters when that depends on them (``lambda p: p["frame"] == "base"``).
    """

    unit: str = "1"
    size: Any = 1
    doc: str = ""
    feedthrough: Any = ()
    optional: object = False      # bool, or params -> bool


@dataclass(frozen=True)
class FromInputs:
    """An output size computed from the input sizes: ``fn(params, sizes) -> int``."""

    text: str
    fn: Callable[[dict, dict], int]


@dataclass(frozen=True)
class State:
    """A continuous state. ``initial``: number, parameter name or callable(params) -> array."""

    unit: str = "1"
    size: Any = 1
    initial: Any = 0.0
    doc: str = ""


@dataclass(frozen=True)
class Mode:
    """A discrete (mode) state, a float array changed only by events."""

    size: Any = 1
    initial: Any = 0.0
    doc: str = ""


@dataclass(frozen=True)
class Event:
    """A zero-crossing event: ``direction`` +1 rising, -1 falling, 0 either.

    ``size`` guards of this event (one per element, e.g. ``"@u"``); the block's guard array
    ``zc`` holds its events one after the other, and ``on_event`` receives the index into
    it as ``which``.
    """

    direction: int = 0
    doc: str = ""
    size: Any = 1
    #: name of a bool parameter: when it is false the event does not exist (no guards)
    when: str | None = None


def _fmt(v):
    if isinstance(v, float):
        return f"{v:g}"
    return str(v)


def _definition_error(cls, msg):
    """A :class:`BlockDefinitionError` naming block class ``cls``."""
    return BlockDefinitionError(f"block class {cls.__name__}: {msg}")


def _declared_roles(cls):
    """Every declared name of block class ``cls`` -> its role (parameter, input, output,
    state, mode, scratch), first role first.

    Raises
    ------
    BlockDefinitionError
        A name with the reserved prefix ``der_``, or a name declared in two roles (an
        output may share the name of a state: it is that state).
    """
    roles = {}
    for role, names in (("parameter", cls.parameters), ("input", cls.inputs),
                        ("output", cls.outputs), ("state", cls.states),
                        ("mode", cls.modes), ("scratch", cls.scratch)):
        for n in names:
            if n.startswith("der_"):
                raise _definition_error(cls, f"{role} '{n}' uses the reserved prefix der_ "
                                             f"(state derivatives)")
            if n in PARTIALS:
                raise _definition_error(cls, f"{role} '{n}' is reserved (a matrix of the "
                                             f"'partials' kernel)")
            prev = roles.get(n)
            if prev and {prev, role} != {"output", "state"}:
                raise _definition_error(cls, f"'{n}' is declared both as {prev} and as {role}")
            roles.setdefault(n, role)
    return roles


def _check_implicit(cls):
    """Each implicit output names a declared output, a residual port (input or output) and
    a guess parameter."""
    for o, (res, guess) in cls.implicit.items():
        if o not in cls.outputs or guess not in cls.parameters or not (
                res in cls.outputs or res in cls.inputs):
            raise _definition_error(cls, f"implicit output '{o}' needs output '{o}', a "
                                         f"residual port '{res}' (input or output) and a "
                                         f"guess parameter '{guess}'")


def _check_renamed(cls):
    """Each renamed parameter ``old -> new`` has ``new`` declared and ``old`` not."""
    for old, new in cls.renamed.items():
        if new not in cls.parameters or old in cls.parameters:
            raise _definition_error(cls, f"renamed parameter '{old}' -> '{new}' needs "
                                         f"'{new}' declared and '{old}' not")


def _check_linearization_decls(cls):
    """``sample_period`` and the keys of ``quantizer`` name declared parameters."""
    names = ([cls.sample_period] if cls.sample_period else []) + list(cls.quantizer)
    for n in names:
        if n not in cls.parameters:
            raise _definition_error(cls, f"'{n}' (sample_period or quantizer) is not a "
                                         f"declared parameter")


def _check_kernel_set(cls):
    """The kernels defined fit the declarations: ``derivative`` needs states, ``guard``
    needs events, events need both ``guard`` and ``on_event``."""
    if cls.has_kernel("derivative") and not cls.states:
        raise _definition_error(cls, "defines 'derivative' but declares no states")
    if cls.has_kernel("guard") and not cls.events:
        raise _definition_error(cls, "defines 'guard' but declares no events")
    if cls.events and not (cls.has_kernel("guard") and cls.has_kernel("on_event")):
        raise _definition_error(cls, "declares events but does not define both 'guard' and "
                                     "'on_event'")
    if cls.has_kernel("time_output") and not (cls.has_kernel("next_time")
                                              and cls.has_kernel("time_event")):
        raise _definition_error(cls, "defines 'time_output' but not both 'next_time' and "
                                     "'time_event'")


def _default_params(cls):
    """The default parameter values of ``cls`` (real ones as arrays), or None when a
    parameter is required (no defaults to derive from)."""
    if any(d.default is REQUIRED for d in cls.parameters.values()):
        return None
    return {n: np.asarray(d.default, dtype=float) if d.kind == "real" and
            not isinstance(d.default, str) else d.default
            for n, d in cls.parameters.items()}


def _derived_names(cls):
    """Names ``cls.derive`` computes from the default parameters: an empty set when the
    class does not define ``derive``, None when they cannot be known (a required parameter,
    or ``derive`` fails on the defaults): then any kernel argument name is accepted."""
    if cls.derives is not None:
        return set(cls.derives)
    if "derive" not in {k for c in cls.__mro__ for k in vars(c)} or \
            cls.derive.__func__ is Block.derive.__func__:
        return set()
    try:
        params = _default_params(cls)
        return None if params is None else set(cls.derive(params))
    except Exception:              # noqa: BLE001 (defaults need not be derivable)
        return None


def _has_dynamic_names(cls):
    """True when ``cls`` overrides ``kernel_source``, ``input_names`` or ``output_names``:
    its kernel arguments depend on structural parameters and cannot be checked here."""
    return any(getattr(cls, m).__func__ is not getattr(Block, m).__func__
               for m in ("kernel_source", "input_names", "output_names"))


def _check_kernel_args(cls, kernel, fn, roles, derived, extra=()):
    """Every argument of ``kernel`` (the function ``fn``) is a declared name, a state
    derivative ``der_<state>``, a reserved name or a derived name, and no declared name is
    also reserved; unknown names get the nearest known ones."""
    known = set(roles) | set(RESERVED) | set(extra) | {f"der_{n}" for n in cls.states}
    for arg in inspect.signature(fn).parameters:
        if arg in RESERVED and arg in roles:
            raise _definition_error(cls, f"kernel '{kernel}' argument '{arg}' is ambiguous: "
                                         f"a reserved name ({', '.join(RESERVED)}) and a "
                                         f"declared {roles[arg]}")
        if arg in known or (derived is None) or arg in derived:
            continue
        near = difflib.get_close_matches(arg, sorted(known | (derived or set())), n=2)
        hint = f" (did you mean {', '.join(near)}?)" if near else ""
        raise _definition_error(cls, f"kernel '{kernel}' argument '{arg}' is not a declared "
                                     f"parameter, port, state, mode, scratch or derived "
                                     f"name, nor reserved{hint}")


def _check_partials(cls, fn):
    """The ``partials`` kernel takes at least one of :data:`PARTIALS`, each only when the
    block has what it differentiates (``dfdx``: states; ``dfdu``: states and inputs;
    ``dydx``: outputs that are not states, and states; ``dydu``: such outputs and inputs),
    and none of the event or derivative arguments."""
    args = list(inspect.signature(fn).parameters)
    taken = [a for a in args if a in PARTIALS]
    if not taken:
        raise _definition_error(cls, f"kernel 'partials' takes none of "
                                     f"{', '.join(PARTIALS)}")
    has_in = bool(cls.inputs) or _has_dynamic_names(cls)
    has_y = any(o not in cls.states for o in cls.outputs) or _has_dynamic_names(cls)
    needs = {"dfdx": (cls.states, "states"), "dfdu": (cls.states and has_in,
                                                       "states and inputs"),
             "dydx": (has_y and cls.states, "outputs that are not states, and states"),
             "dydu": (has_y and has_in, "outputs that are not states, and inputs")}
    for a in taken:
        ok, what = needs[a]
        if not ok:
            raise _definition_error(cls, f"kernel 'partials' takes '{a}' but the block "
                                         f"declares no {what}")
    bad = [a for a in args if a in ("direction", "zc", "which", "inputs_ready")
           or a.startswith("der_")]
    if bad:
        raise _definition_error(cls, f"kernel 'partials' argument '{bad[0]}' is not "
                                     f"available to it")


def _check_time_output(cls, fn):
    """``time_output`` reads no input (it runs before the samples are taken)."""
    bad = [a for a in inspect.signature(fn).parameters if a in cls.inputs]
    if bad:
        raise _definition_error(cls, f"kernel 'time_output' argument '{bad[0]}' is an "
                                     f"input: the output update at a sample reads none")


def _check_kernels(cls, roles, derived):
    """The kernels ``cls`` itself defines are static methods with known arguments (see
    :func:`_check_kernel_args`; skipped for blocks with dynamic names)."""
    for kernel in KERNELS:
        fn = cls.__dict__.get(kernel)
        if fn is None:
            continue
        if not isinstance(fn, staticmethod):
            raise _definition_error(cls, f"kernel '{kernel}' must be a @staticmethod")
        if kernel == "partials":
            _check_partials(cls, fn.__func__)
        if kernel == "time_output":
            _check_time_output(cls, fn.__func__)
        if _has_dynamic_names(cls):
            continue
        _check_kernel_args(cls, kernel, fn.__func__, roles, derived,
                           PARTIALS if kernel == "partials" else ())


def _positive_period(Ts) -> bool:
    """Whether a sample period parameter's value makes the block sampled (> 0)."""
    try:
        return float(Ts) > 0.0
    except (TypeError, ValueError):
        return False


class Block:
    """Base class of every block; see the module docstring for the contract."""

    type_name: str = ""
    category: str = "misc"
    parameters: dict[str, Param] = {}
    inputs: dict[str, Port] = {}
    outputs: dict[str, Port] = {}
    states: dict[str, State] = {}
    modes: dict[str, Mode] = {}
    events: dict[str, Event] = {}
    #: name -> size of scratch memory a kernel may use freely (allocated once in the signal
    #: array, never logged): workspaces of compiled algorithms, so nothing is allocated
    scratch: dict = {}
    #: output -> (residual port, initial-guess parameter): outputs the engine solves for
    implicit: dict = {}
    #: old parameter name -> current name: a renamed parameter is still accepted under its
    #: old name for one release, with a :class:`RenamedParameterWarning` saying where
    renamed: dict = {}
    #: name of the parameter that makes the block sampled when > 0 (contract item 9)
    sample_period: str | None = None
    #: parameter -> value that removes the block's quantization (contract item 9)
    quantizer: dict = {}
    #: the names ``derive`` returns, declared by a block whose ``derive`` is costly on the
    #: defaults (the arm blocks read their model file and build the kinematic chain): the
    #: definition check (contract item 7) takes them instead of calling ``derive``, and
    #: :meth:`derived` refuses a ``derive`` that returns other names
    derives: tuple | None = None

    def __init_subclass__(cls, abstract=False, **kw):
        super().__init_subclass__(**kw)
        if abstract:
            return
        name = cls.__dict__.get("type_name") or cls.__name__
        cls.type_name = name
        if name in REGISTRY and REGISTRY[name] is not cls:
            raise RuntimeError(f"block type {name!r} registered twice")
        cls._check_contract()
        REGISTRY[name] = cls

    @classmethod
    def _check_contract(cls):
        """Check the declarations against the kernels (see contract item 7); raise
        :class:`BlockDefinitionError` naming the class at the first problem."""
        roles = _declared_roles(cls)
        _check_implicit(cls)
        _check_renamed(cls)
        _check_linearization_decls(cls)
        _check_kernel_set(cls)
        _check_kernels(cls, roles, _derived_names(cls))

    # ---------------------------------------------------------------- interface
    @classmethod
    def input_names(cls, params):
        """Input port names for these parameters (override for variable-arity blocks)."""
        return list(cls.inputs)

    @classmethod
    def input_decl(cls, name):
        """Port declaration of input ``name`` (variable-arity blocks share one)."""
        return cls.inputs[name]

    @classmethod
    def output_names(cls, params):
        """Output port names for these parameters (override for variable-arity blocks)."""
        return list(cls.outputs)

    @classmethod
    def output_decl(cls, name):
        return cls.outputs[name]

    @classmethod
    def unit_of(cls, decl, params=None) -> str:
        """The unit text of a parameter, port or state declaration: a unit (``"N.m"``),
        ``"*"`` (inherited) or a rule (``"@k*@u"``); a unit that depends on parameters
        (a Product's output) is evaluated with ``params`` (default: the defaults)."""
        u = decl.unit
        if callable(u):
            if params is None:
                params = {n: p.default for n, p in cls.parameters.items()}
            try:
                u = u(params)
            except Exception:   # defaults that cannot decide it (a required parameter)
                u = "*"
        return u if isinstance(u, str) else "*"

    @classmethod
    def unit_relations(cls, params) -> list:
        """Directed unit relations beyond the declared unit rules, for blocks whose ports
        may carry vectors of mixed units: ``("common", out, [inputs])`` (``out`` takes the
        inputs' unit when they all agree: a Mux) or ``("copy", out, [input])`` (``out``
        takes ``input``'s unit when it has one: a Demux). See :mod:`spidersim.diagram.units`.
        """
        return []

    @classmethod
    def fallback_sizes(cls, params) -> dict:
        """Input sizes to assume when wiring alone cannot decide them (a loop of blocks
        that all inherit their size): input name -> size. Used only after propagation
        along the wires has stalled, one port at a time."""
        return {}

    @classmethod
    def check_sizes(cls, params, sizes):
        """Validation once port sizes are known (``sizes``: port name -> int); raise
        ``ValueError`` with a message."""

    @classmethod
    def derive(cls, params) -> dict:
        """Numeric parameters computed from the user's; passed to kernels by name."""
        return {}

    @classmethod
    def derived(cls, params) -> dict:
        """``derive(params)``, its names checked against ``derives`` when declared."""
        out = cls.derive(params)
        if cls.derives is not None and set(out) != set(cls.derives):
            raise _definition_error(cls, f"derive returned {sorted(out)}, the class declares "
                                         f"derives = {sorted(cls.derives)}")
        return out

    @classmethod
    def check(cls, params):
        """Cross-parameter validation; raise ``ValueError`` with a message."""

    @classmethod
    def sample_feedthrough(cls, params) -> bool:
        """Whether the output the block holds from a sample depends on that sample (a
        direct feedthrough in discrete time, contract item 9): a sampled block (its
        ``sample_period`` parameter > 0) without ``time_output``; a block whose answer
        depends on a parameter overrides it (a ``DiscreteTransferFunction`` with
        ``b_0 != 0``). Such a block may not read its own output back through blocks
        without a state (:func:`spidersim.diagram.portgraph.check_sampled_loops`)."""
        if not cls.sample_period or cls.has_kernel("time_output"):
            return False
        return _positive_period(params.get(cls.sample_period, 0.0))

    @classmethod
    def has_kernel(cls, kernel):
        return callable(cls.__dict__.get(kernel)) or any(
            callable(getattr(b, "__dict__", {}).get(kernel)) for b in cls.__mro__[1:-1]
            if b is not Block)

    @classmethod
    def kernel_source(cls, params, kernel) -> str | None:
        """Source text of a kernel specialised to structural parameters, or None."""
        return None

    @classmethod
    def kernel_args(cls, kernel, params):
        """Argument names of ``kernel`` (from its signature or specialised source)."""
        src = cls.kernel_source(params, kernel)
        if src is not None:
            ns = {}
            exec(compile(src, f"<{cls.type_name}.{kernel}>", "exec"), {"math": math}, ns)
            fn = ns[kernel]
        else:
            fn = getattr(cls, kernel)
        return list(inspect.signature(fn).parameters)

    # ---------------------------------------------------------------- parameters
    @classmethod
    def validate_params(cls, given: dict, lines: dict | None = None, where=None):
        """Check names, types, shapes and bounds; return a dict of normalised values.

        ``given`` maps names to evaluated values; ``where(name) -> (file, line)`` locates
        them for error messages. Raises :class:`ParameterError`.
        """
        where = where or (lambda name: (None, None))
        old_of = {cls.renamed[k]: k for k in given if k in cls.renamed}
        given = cls.current_names(given, where)
        if old_of:                       # locate a renamed value at its old name's line
            where_given = where
            where = lambda name: where_given(old_of.get(name, name))  # noqa: E731
        for name in given:
            if name not in cls.parameters:
                near = difflib.get_close_matches(name, list(cls.parameters), n=3)
                hint = f"; did you mean {', '.join(repr(n) for n in near)}?" if near else ""
                known = ", ".join(cls.parameters) or "none"
                f, l = where(name)
                raise ParameterError(
                    f"unknown parameter '{name}' for type {cls.type_name}{hint} "
                    f"(parameters: {known})", file=f, line=l)
        out = {}
        for name, decl in cls.parameters.items():
            if name in given:
                value = given[name]
            elif decl.default is REQUIRED:
                f, l = where(None)
                raise ParameterError(
                    f"missing parameter '{name}' of type {cls.type_name} "
                    f"[{cls.unit_of(decl)}]: {decl.doc}", file=f, line=l)
            else:
                value = decl.default
            out[name] = cls._normalise(name, decl, value, out, where)
        try:
            cls.check(out)
        except ValueError as exc:
            f, l = where(None)
            raise ParameterError(str(exc), file=f, line=l) from None
        return out

    @classmethod
    def current_names(cls, given: dict, where=None) -> dict:
        """``given`` with renamed parameters under their current names (see ``renamed``),
        warning once per use; both names at once is a :class:`ParameterError`."""
        if not cls.renamed or not any(k in cls.renamed for k in given):
            return given
        where = where or (lambda name: (None, None))
        out = dict(given)
        for old, new in cls.renamed.items():
            if old not in out:
                continue
            f, l = where(old)
            if new in out:
                raise ParameterError(f"parameter '{old}' is the old name of '{new}'; give "
                                     f"only '{new}'", file=f, line=l)
            out[new] = out.pop(old)
            at = f"{f}:{l}: " if f and l else (f"{f}: " if f else "")
            warnings.warn(f"{at}{cls.type_name}: parameter '{old}' is now called '{new}' "
                          f"(the names table in the README); '{old}' is accepted until "
                          f"spidersim 0.2", RenamedParameterWarning, stacklevel=2)
        return out

    @classmethod
    def _normalise(cls, name, decl, value, known, where):
        """Check one parameter value against its declaration and normalise it.

        Parameters
        ----------
        name : str
            The parameter.
        decl : Param
            Its declaration (kind, shape, bounds, choices).
        value : object
            The evaluated value from the diagram (or the default).
        known : dict
            Parameters normalised so far (sizes given by another parameter's name).
        where : callable
            ``where(name) -> (file, line)`` for the message.

        Returns
        -------
        str, bool, int, float or numpy.ndarray
            ``str``/``bool``/``int`` for those kinds; a real scalar as a float; a vector
            or matrix as a C-contiguous float array of the declared shape.

        Raises
        ------
        ParameterError
            ``parameter '<name>' must ...`` located by ``where(name)``.
        """
        f, l = where(name)

        def fail(msg):
            raise ParameterError(f"parameter '{name}' {msg}", file=f, line=l)

        if decl.kind == "str":
            return cls._normalise_str(decl, value, fail)
        if decl.kind == "bool":
            return cls._normalise_bool(value, fail)
        arr = cls._as_float_array(value, fail)
        if decl.kind == "int":
            return cls._normalise_int(decl, arr, value, fail)
        cls._check_finite(decl, arr, value, fail)
        shape = decl.shape
        if shape == ():
            return cls._normalise_scalar(decl, arr, fail)
        if shape == "*" or not isinstance(shape, tuple):
            arr = cls._normalise_vector(shape, arr, known, fail)
        else:
            arr = cls._normalise_matrix(shape, arr, known, fail)
        cls._bounds(decl, arr, fail)
        return np.ascontiguousarray(arr, dtype=float)

    @staticmethod
    def _normalise_str(decl, value, fail):
        """A ``str`` parameter: a string, one of ``decl.choices`` when given (the nearest
        choice is suggested)."""
        if not isinstance(value, str):
            fail(f"must be a string, got {value!r}")
        if decl.choices and value not in decl.choices:
            near = difflib.get_close_matches(value, decl.choices, n=1)
            hint = f" (did you mean '{near[0]}'?)" if near else ""
            fail(f"must be one of {', '.join(decl.choices)}, got '{value}'{hint}")
        return value

    @staticmethod
    def _normalise_bool(value, fail):
        """A ``bool`` parameter: true/false, or the numbers 0 and 1."""
        if isinstance(value, bool):
            return value
        if isinstance(value, (int, float)) and value in (0, 1):
            return bool(value)
        fail(f"must be true or false, got {value!r}")

    @staticmethod
    def _as_float_array(value, fail):
        """``value`` of a numeric parameter as a float array; strings, booleans (alone or
        in a list) and what numpy cannot read as floats are refused."""
        if value is None:                 # numpy would read it as NaN
            fail("must be a number, got None")
        if isinstance(value, str):
            fail(f"must be a number, got the string '{value}'")
        if isinstance(value, bool) or (isinstance(value, (list, tuple)) and any(
                isinstance(v, bool) for v in np.ravel(np.array(value, dtype=object)))):
            fail(f"must be a number, got a boolean ({value!r}; write 1 or 0 if you mean "
                 f"a number)")
        try:
            return np.asarray(value, dtype=float)
        except (TypeError, ValueError, OverflowError):
            fail(f"must be numeric (and representable as a float), got {str(value)[:40]}")

    @classmethod
    def _normalise_int(cls, decl, arr, value, fail):
        """An ``int`` parameter: a scalar with an integer value, within the bounds."""
        if arr.ndim != 0 or not float(arr).is_integer():
            fail(f"must be an integer, got {value!r}")
        cls._bounds(decl, arr, fail)
        return int(arr)

    @staticmethod
    def _check_finite(decl, arr, value, fail):
        """No NaN; no infinity unless ``decl.allow_inf`` (``1e400`` overflows to inf)."""
        if np.any(np.isnan(arr)):
            fail(f"must not be NaN, got {value!r}")
        if not decl.allow_inf and np.any(np.isinf(arr)):
            fail(f"must be finite, got {str(value)[:40]} (a number beyond 1.8e308, such as "
                 f"1e400, is infinite)")

    @classmethod
    def _normalise_scalar(cls, decl, arr, fail):
        """A real scalar (a one-element flat list is accepted; a nested one, ``[[[1]]]``,
        is not a scalar), within the bounds, as a float."""
        if arr.ndim != 0:
            if arr.size == 1 and arr.ndim == 1:
                arr = arr.reshape(())
            else:
                fail(f"must be a scalar, got an array of shape {arr.shape}")
        cls._bounds(decl, arr, fail)
        return float(arr)

    @classmethod
    def _normalise_vector(cls, shape, arr, known, fail):
        """A non-empty 1-D array; of the declared size unless ``shape`` is ``"*"`` (a
        scalar given for a vector of size n is repeated n times)."""
        arr = np.atleast_1d(arr)
        if arr.ndim != 1:
            fail(f"must be a 1-D list, got shape {arr.shape}")
        if shape != "*":
            n = cls._dim(shape, known)
            if arr.size == 1 and n != 1:
                arr = np.full(n, arr[0])
            if arr.size != n:
                fail(f"must have {n} elements ({_size_text(shape)}), got {arr.size}")
        if arr.size == 0:
            fail("must not be empty")
        return arr

    @classmethod
    def _normalise_matrix(cls, shape, arr, known, fail):
        """A 2-D array with the declared rows and columns (``"*"``: any); a scalar is a
        1x1 matrix, a flat list a row (when one row is declared) or else a column."""
        if arr.ndim == 0:
            arr = arr.reshape(1, 1)
        if arr.ndim == 1:
            arr = arr.reshape(1, -1) if shape[0] == 1 else arr.reshape(-1, 1)
        if arr.ndim != 2:
            fail(f"must be a matrix (list of rows), got shape {arr.shape}")
        for k, d in enumerate(shape):
            if d != "*":
                n = cls._dim(d, known)
                if arr.shape[k] != n:
                    fail(f"must have {n} {'rows' if k == 0 else 'columns'} "
                         f"({_size_text(d)}), got shape {arr.shape}")
        return arr

    @staticmethod
    def _bounds(decl, arr, fail):
        a = np.asarray(arr)
        for attr, op, word in (("gt", np.greater, ">"), ("ge", np.greater_equal, ">="),
                               ("lt", np.less, "<"), ("le", np.less_equal, "<=")):
            lim = getattr(decl, attr)
            if lim is not None and not np.all(op(a, lim)):
                bad = a if a.ndim == 0 else a[~op(a, lim)][0]
                fail(f"must be {word} {_fmt(lim)}, got {_fmt(float(bad))}")

    @staticmethod
    def _dim(spec, params):
        if isinstance(spec, int):
            return spec
        if isinstance(spec, Dim):
            return int(spec.fn(params))
        if isinstance(spec, str) and spec in params:
            v = params[spec]
            return int(v) if np.ndim(v) == 0 else int(np.size(v))
        raise RuntimeError(f"size {spec!r} cannot be resolved")

    @classmethod
    def size_of(cls, spec, params):
        """Resolve a size declaration to an int; ``None`` for inherited sizes."""
        if spec is None or isinstance(spec, FromInputs) or (
                isinstance(spec, str) and spec.startswith("@")):
            return None
        return cls._dim(spec, params)

    @classmethod
    def feedthrough_of(cls, out_name, params):
        ft = cls.output_decl(out_name).feedthrough
        if callable(ft):
            ft = ft(params)
        names = cls.input_names(params)
        if ft == "all":
            return tuple(names)
        return tuple(ft)

    @classmethod
    def initial_value(cls, decl, size, params):
        """Initial value of a state or mode as an array of ``size``."""
        init = decl.initial
        if callable(init):
            v = init(params)
        elif isinstance(init, str):
            v = params[init]
        else:
            v = init
        v = np.asarray(v, dtype=float).ravel()
        if v.size == 1 and size != 1:
            v = np.full(size, v[0])
        if v.size != size:
            raise ParameterError(f"initial value of size {v.size} for a state of size {size}")
        return v

    # ---------------------------------------------------------------- docs
    @classmethod
    def describe(cls) -> str:
        """Documentation generated from the declarations (``spidersim blocks TYPE``): the
        docstring in plain text, then parameters, inputs, outputs, states, modes and events,
        one line each."""
        lines = [f"{cls.type_name}  ({cls.category})", ""]
        lines += _describe_doc(cls) + [""]
        lines += _describe_section("Parameters", cls.parameters,
                                   lambda n, p: _describe_param(cls, n, p))
        lines += _describe_section("Inputs", cls.inputs,
                                   lambda n, p: _describe_port(cls, n, p, output=False))
        lines += _describe_section("Outputs", cls.outputs,
                                   lambda n, p: _describe_port(cls, n, p, output=True))
        lines += _describe_section("States", cls.states,
                                   lambda n, s: _describe_state(cls, n, s))
        lines += _describe_section("Modes", cls.modes, _describe_mode)
        lines += _describe_section("Events", cls.events, _describe_event)
        return "\n".join(lines)


# ------------------------------------------------------------------ docs (Block.describe)
def _describe_doc(cls):
    """The class docstring as indented plain-text lines; a docstring that refers to the
    module docstring gets the module docstring (the shared equations) appended."""
    from ..text.plain import plain
    doc = inspect.cleandoc(cls.__doc__ or "")
    if "module docstring" in doc:
        # the equations are shared by the module's blocks: print them here
        mod_doc = inspect.cleandoc(sys.modules[cls.__module__].__doc__ or "")
        doc = re.sub(r"\s*\(?see the module docstring[^.)]*\)?", "", doc)
        doc += "\n\nEquations and conventions (shared by the blocks of this module):\n\n" \
            + mod_doc
    return ["  " + ln for ln in plain(doc).splitlines()]


def _size_text(s):
    """A size declaration in words: ``7``, a :class:`Dim`'s text, ``inherited`` or
    ``size of u``."""
    if isinstance(s, (Dim, FromInputs)):
        return s.text
    if s is None:
        return "inherited"
    if isinstance(s, str) and s.startswith("@"):
        return f"size of {s[1:]}"
    return str(s)


def _describe_section(title, decls, line_of):
    """``  Title:`` and one line per declaration (``line_of(name, decl)``); nothing for
    an empty section."""
    if not decls:
        return []
    return [f"  {title}:"] + [line_of(n, d) for n, d in decls.items()]


def _bounds_text(p):
    """``, > 0 and <= 1`` for the bounds a parameter declares, or ''."""
    bnds = [f"{w} {_fmt(getattr(p, a))}" for a, w in
            (("gt", ">"), ("ge", ">="), ("lt", "<"), ("le", "<="))
            if getattr(p, a) is not None]
    return f", {' and '.join(bnds)}" if bnds else ""


def _describe_param(cls, n, p):
    """``    R [Ohm] (default 1.0, > 0): winding resistance`` for parameter ``n``."""
    from ..text.plain import plain
    dflt = "required" if p.default is REQUIRED else f"default {p.default!r}"
    shape = "" if p.shape == () else f", shape {_size_text(p.shape)}"
    ch = f", one of {'|'.join(p.choices)}" if p.choices else ""
    kind = "" if p.kind == "real" else f" {p.kind}"
    return (f"    {n} [{cls.unit_of(p)}]{kind} ({dflt}{shape}{_bounds_text(p)}{ch}): "
            f"{plain(p.doc)}")


def _feedthrough_text(f):
    """How an output's declared feedthrough reads in the docs ('' for none)."""
    return ("; feedthrough depends on parameters" if callable(f) else
            "; direct feedthrough (all inputs)" if f == "all" else
            f"; direct feedthrough from {', '.join(f)}" if f else "")


def _describe_port(cls, n, p, output):
    """One line for input or output port ``n``: unit, size, optional, feedthrough, doc."""
    from ..text.plain import plain
    ft = _feedthrough_text(p.feedthrough) if output else ""
    opt = (", optional: zero when unconnected" if p.optional is True else
           ", optional for some parameters" if p.optional else "")
    return (f"    {n} [{cls.unit_of(p)}] (size {_size_text(p.size)}{opt}{ft}): "
            f"{plain(p.doc)}")


def _describe_state(cls, n, s):
    """One line for state ``n``: unit, size, initial value (or 'computed'), doc."""
    return (f"    {n} [{cls.unit_of(s)}] (size {_size_text(s.size)}, initial "
            f"{s.initial if not callable(s.initial) else 'computed'}): {s.doc}")


def _describe_mode(n, m):
    """One line for mode ``n``: size and doc."""
    return f"    {n} (size {_size_text(m.size)}): {m.doc}"


def _describe_event(n, e):
    """One line for event ``n``: crossing direction in words and doc."""
    d = {1: "rising", -1: "falling", 0: "either"}[e.direction]
    return f"    {n} ({d}): {e.doc}"


def unit_vector(v, what):
    """``v / |v|`` for a direction parameter; ValueError (a parameter error of the block)
    for the zero vector or a non-finite component (the values printed as plain numbers).

    A vector whose squares would under- or overflow (``[0, 0, 1e-300]`` had the norm 0,
    ``[1e300, 1e300, 0, 0]`` infinity) is first divided by its largest ``|component|``;
    others are divided by their norm directly (usual directions unchanged to the bit).
    """
    v = np.asarray(v, dtype=float)
    big = float(np.max(np.abs(v), initial=0.0))
    if not np.isfinite(big):
        raise ValueError(f"{what} must be finite, got {[float(x) for x in v.ravel()]}")
    if big == 0.0:
        raise ValueError(f"{what} must not be the zero vector")
    if not 1e-150 < big < 1e150:
        v = v / big
    return v / float(np.linalg.norm(v))


def lookup(type_name, file=None, line=None, extra=()):
    """The Block class registered as ``type_name``; suggests near names when unknown."""
    if not isinstance(type_name, str):
        raise BlockTypeError(f"block type must be a name, got {type_name!r}", file=file,
                             line=line)
    cls = REGISTRY.get(type_name)
    if cls is None:
        names = list(REGISTRY) + list(extra)
        near = difflib.get_close_matches(type_name, names, n=3, cutoff=0.5)
        if not near:
            near = [n for n in names if n.lower().startswith(str(type_name).lower()[:3])][:3]
        hint = f"; did you mean {', '.join(near)}?" if near else ""
        raise BlockTypeError(f"unknown block type '{type_name}'{hint} "
                             f"(`spidersim blocks` lists them)", file=file, line=line)
    return cls


_JIT_CACHE: dict = {}


def load_kernel(module: str, cls_name: str, kernel: str, jit: bool):
    """The kernel ``kernel`` of block class ``module:cls_name``, numba-compiled if ``jit``.

    Used by generated diagram modules; one dispatcher per kernel per process, cached on disk.
    Compiled kernels are inlined by LLVM into the generated system function when small
    (:mod:`spidersim.blocks.inlining`).
    """
    key = (module, cls_name, kernel, jit)
    fn = _JIT_CACHE.get(key)
    if fn is None:
        cls = getattr(importlib.import_module(module), cls_name)
        fn = getattr(cls, kernel)
        if jit:
            from .inlining import njit_inlinable
            fn = njit_inlinable(fn)
        _JIT_CACHE[key] = fn
    return fn
