"""YAML diagram file -> :class:`DiagramSpec` (still unflattened, values unevaluated).

A diagram file has these top-level sections (all optional but ``blocks``)::

    name, description      free text
    parameters             name: value or expression (in order; later ones may use earlier)
    subsystems             type_name: path/to/file.yaml  (relative to this file)
    blocks                 name: {type: TypeName, param: value, ...}; ``name[1..7]`` makes
                           name1..name7 (``{each: [...]}`` per-instance values; see
                           spidersim.diagram.arrays)
    connections            - "src.port -> dst.port"   (``src.port[i]``, ``src.port[i:j]``,
                             ``[i:]``, ``[:j]``; several destinations separated by
                             commas; ``{i}`` repeats the line over a block array:
                             ``q.y{i} -> j{i}.u``)
    inputs                 (subsystem files) exposed input: internal "block.port" or a list
    outputs                (subsystem files) exposed output: internal "block.port[...]"
    simulation             t_end, method, rtol, atol, max_step, output_interval
    log                    list of "block.port" to record, or "all" (the default)
    plots                  list of {title, signals, kind, file, ...}
    analysis               linearizations (see spidersim.linreport)
    metrics                name: {signal, reduce, unit}: scalars per run for sweeps
                           (see spidersim.sweep)
    commands               named high-level commands for the remote service: name ->
                           {doc, set, arguments, t_end} (see spidersim.service.commands);
                           ignored by local runs
    microgravity           {signal, mass, window, f_min, f_max}: station acceleration bands
                           against the ISS limit after a run (see spidersim.microgravity)
"""
from __future__ import annotations

import os
import re
from dataclasses import dataclass, field
from typing import NamedTuple

from ..errors import ASCII_RULE, DiagramError, WiringError, non_ascii
from ..text.yamlio import LineDict, file_problem, load_text, read_file
from .arrays import array_key, expand_block, expand_connection

SECTIONS = ("name", "description", "parameters", "subsystems", "blocks", "connections",
            "inputs", "outputs", "simulation", "log", "plots", "analysis", "metrics",
            "commands", "microgravity")
SIM_KEYS = {"t_end": "simulated time [s]", "method": "LSODA, RK45, DOP853, Radau or BDF",
            "rtol": "relative tolerance", "atol": "absolute tolerance",
            "max_step": "largest step [s]", "output_interval": "spacing of output samples [s]",
            "first_step": "first step [s]"}
_NAME = re.compile(r"^[A-Za-z_][A-Za-z0-9_]*\Z")
_ADDR = re.compile(r"^\s*([A-Za-z_][A-Za-z0-9_]*)\.([A-Za-z_][A-Za-z0-9_]*)"
                   r"(?:\[([^\[\]]*)\])?\s*\Z")
#: inside the brackets: ``i``, or ``a:b`` with either bound left out (``1:``, ``:2``, ``:``)
#: (ASCII digits: ``\d`` matches other scripts' digits, which ``int`` reads: ``[١]`` was 1)
_INDEX = re.compile(r"^\s*(-?[0-9]+)\s*\Z")
_SLICE = re.compile(r"^\s*(-?[0-9]+)?\s*:\s*(-?[0-9]+)?\s*\Z")
#: a log entry naming elements of a signal (``i.y[1]``, ``i.y[-1]``, ``j3.motor.w[0:2]``)
_LOG_ELEMENTS = re.compile(r"^\s*([A-Za-z_][A-Za-z0-9_.]*)\s*\[[^\[\]]*\]\s*\Z")
_FORMS = "'block.port', 'block.port[i]' or 'block.port[i:j]' (i or j may be left out)"


@dataclass
class Address:
    """``block.port[start:stop]`` inside one diagram file (``start`` None: whole port;
    ``stop`` None: to the end). Negative bounds count from the end, as in Python."""

    block: str
    port: str
    start: int | None = None
    stop: int | None = None
    single: bool = False
    #: the range as written, without spaces (``[1:]``, ``[:2]``); '' for ``[i]`` or none
    written: str = ""

    def __str__(self):
        if self.start is None:
            return f"{self.block}.{self.port}"
        if self.single:
            return f"{self.block}.{self.port}[{self.start}]"
        return f"{self.block}.{self.port}{self.written or f'[{self.start}:{self.stop}]'}"


@dataclass
class BlockSpec:
    name: str
    type: str
    params: dict
    line: int
    param_lines: dict


@dataclass
class ConnSpec:
    src: Address
    dst: Address
    line: int


@dataclass
class DiagramSpec:
    file: str
    name: str
    description: str
    parameters: dict
    param_lines: dict
    subsystems: dict          # type name -> absolute path
    subsystem_lines: dict
    blocks: dict              # name -> BlockSpec
    connections: list
    inputs: dict              # exposed name -> [Address]
    outputs: dict             # exposed name -> Address
    port_lines: dict
    simulation: dict
    simulation_lines: dict
    log: object
    log_line: int | None
    plots: list
    analysis: dict
    metrics: dict = field(default_factory=dict)
    microgravity: dict = field(default_factory=dict)
    data: dict = field(repr=False, default=None)


def parse_address(text, file, line, what="address"):
    """The :class:`Address` written ``text``: ``block.port``, ``block.port[i]`` or
    ``block.port[a:b]`` with ``a`` or ``b`` (or both) left out as in Python (``[1:]``,
    ``[:2]``, ``[:]``); a WiringError at ``file:line`` naming ``what`` otherwise (a step,
    ``[::2]``, is refused by name)."""
    if not isinstance(text, str):
        raise WiringError(f"{what} must be a string 'block.port', got {text!r}", file=file,
                          line=line)
    _check_ascii(text, f"{what} '{text.strip()}'", file, line)
    m = _ADDR.match(text)
    if not m:
        raise WiringError(f"cannot read {what} '{text.strip()}': expected {_FORMS}",
                          file=file, line=line)
    block, port, inside = m.groups()
    if inside is None:
        return Address(block, port)
    single, rng = _INDEX.match(inside), _SLICE.match(inside)
    if not (single or rng):
        raise WiringError(_index_problem(text, inside, what), file=file, line=line)
    a, b = single.groups() + (None,) if single else rng.groups()
    if max(len(a or ""), len(b or "")) > 100:   # int() of more than 4300 digits would fail
        raise WiringError(f"an index of more than 100 digits in {what} '{text[:60]}...' is "
                          f"outside any port", file=file, line=line)
    if single:        # [-1] is the last element, [-2] the one before: [-1:None], [-2:-1]
        a = int(a)
        return Address(block, port, a, a + 1 if a != -1 else None, single=True)
    return Address(block, port, 0 if a is None else int(a), None if b is None else int(b),
                   written=f"[{a or ''}:{b or ''}]")


def _check_ascii(text, what, file, line):
    """``text`` (of ``what``: ``connection 'c.y[𝟏] -> g.u'``) is ASCII, else a WiringError
    naming the first other character (a bold or Arabic-Indic digit read as its value made
    ``c.y[𝟏]`` element 1)."""
    problem = non_ascii(text)
    if problem:
        raise WiringError(f"{what}: {problem}: {ASCII_RULE}", file=file, line=line)


def _index_problem(text, inside, what):
    """The message for brackets ``inside`` of ``text`` that are neither ``[i]`` nor
    ``[a:b]`` (a step named as such)."""
    if inside.count(":") >= 2:
        return (f"{what} '{text.strip()}': a step ('[a:b:step]') is not supported: take a "
                f"contiguous range '[a:b]' (or pick the elements with a Selector)")
    return f"cannot read {what} '{text.strip()}': expected {_FORMS}"


def _section(data, key, kind, file):
    v = data.get(key)
    if v is None:
        return kind()
    if not isinstance(v, kind):
        want = "a mapping (name: value)" if kind is LineDict or kind is dict else "a list"
        raise DiagramError(f"section '{key}' must be {want}, got {type(v).__name__}",
                           file=file, line=data.line_of(key))
    return v


def parse_file(path: str) -> DiagramSpec:
    """Read and check one diagram file (no subsystems opened yet)."""
    problem = file_problem(path)
    if problem:
        raise DiagramError(f"diagram file {problem}: {path}")
    return _parse_data(read_file(path), path)


def parse_text(text: str, file: str = "<string>") -> DiagramSpec:
    """Check one diagram given as text (``file`` names it in errors)."""
    return _parse_data(load_text(text, file), file)


def _did_you_mean(key, choices):
    """`` (did you mean 'x'?)`` for the closest of ``choices`` to ``key``, or ''."""
    import difflib
    near = difflib.get_close_matches(str(key), list(choices), n=1)
    return f" (did you mean '{near[0]}'?)" if near else ""


def _check_sections(data, file):
    """Check that ``data`` is a mapping of known sections with a ``blocks`` section.

    Parameters
    ----------
    data : LineDict or None or other
        The loaded YAML document.
    file : str
        Name of the file, for the messages.

    Raises
    ------
    DiagramError
        For an empty document, a document that is not a mapping, an unknown section
        (with the nearest section name) or a missing ``blocks`` section.
    """
    if data is None:
        raise DiagramError("the diagram is empty: it needs at least a 'blocks' section",
                           file=file)
    if not isinstance(data, dict):
        kind = {"LineList": "a list", "str": "a text"}.get(type(data).__name__,
                                                             type(data).__name__)
        raise DiagramError(f"a diagram must be a mapping of sections (blocks:, connections:, "
                           f"...), got {kind}", file=file, line=getattr(data, "line", None))
    for key in data:
        if key not in SECTIONS:
            raise DiagramError(f"unknown section '{key}'{_did_you_mean(key, SECTIONS)}; "
                               f"sections are {', '.join(SECTIONS)}", file=file,
                               line=data.line_of(key))
    if "blocks" not in data:
        raise DiagramError("the diagram has no 'blocks' section", file=file, line=1)


def _text(data, key, default, file):
    """Free-text section ``key`` (``name``, ``description``): a text, or a number taken as
    its text; ``default`` when absent or empty (the name may not be empty). A boolean,
    a list or a mapping is a DiagramError at its line."""
    v = data.get(key)
    if v is None and not (key == "name" and key in data):
        return default
    if isinstance(v, bool) or not isinstance(v, (str, int, float)):
        found = ("empty" if v is None else f"the boolean {v!r}" if isinstance(v, bool)
                 else "a list" if isinstance(v, list) else "a mapping")
        raise DiagramError(f"section '{key}' must be a text, got {found}", file=file,
                           line=data.line_of(key))
    return str(v)


def _base_dir(file):
    """Folder that relative subsystem paths of ``file`` start from (the current folder for
    a diagram given as text, ``file == "<string>"``)."""
    return os.path.dirname(os.path.abspath(file)) if file != "<string>" else os.getcwd()


def _animation_models_beside(plots, file):
    """An animation's relative ``model:`` path (an arm data file) names a file beside the
    diagram file, as ``Arm.model`` does: rewritten in place to that path. ``spider``,
    absolute paths and diagrams read from text keep their value (the latter relative to the
    current folder)."""
    if not os.path.isfile(file or ""):
        return
    for p in plots:
        model = p.get("model") if isinstance(p, dict) else None
        if (p.get("kind") if isinstance(p, dict) else None) != "animation" or not isinstance(
                model, str) or not model or model == "spider" or os.path.isabs(model):
            continue
        p["model"] = os.path.join(_base_dir(file), model)


def _parse_parameters(data, file):
    """The ``parameters`` section (name -> unevaluated value, in order); every name must be
    an identifier (DiagramError at its line otherwise)."""
    params = _section(data, "parameters", LineDict, file)
    for k in params:
        if not isinstance(k, str) or not _NAME.match(k):
            raise DiagramError(f"parameter name '{k}' is not an identifier", file=file,
                               line=params.line_of(k))
    return params


def _parse_subsystems(data, file, base):
    """The ``subsystems`` section: ``(type name -> absolute normalised path, raw section)``.

    An entry is ``Type: path.yaml`` or ``Type: {file: path.yaml}``; the path is relative to
    ``base``. A type name that is not an identifier or an entry without a file name is a
    DiagramError at its line.
    """
    subs_raw = _section(data, "subsystems", LineDict, file)
    subsystems = {}
    for k, v in subs_raw.items():
        if not isinstance(k, str) or not _NAME.match(k):
            raise DiagramError(f"subsystem type name '{k}' is not an identifier (letters, "
                               f"digits, _)", file=file, line=subs_raw.line_of(k))
        if isinstance(v, dict):
            v = v.get("file")
        if not isinstance(v, str):
            raise DiagramError(f"subsystem '{k}' must name a YAML file, got {v!r}",
                               file=file, line=subs_raw.line_of(k))
        subsystems[k] = os.path.normpath(os.path.join(base, v))
    return subsystems, subs_raw


class BlockEntry(NamedTuple):
    """One block entry of the ``blocks`` section after block arrays are expanded."""

    name: str
    entry: object     #: the YAML value (a LineDict with a ``type`` key when well formed)
    line: int | None  #: line of the entry (of the array entry for array instances)


def _expand_block_arrays(blocks_raw, file):
    """The entries of the ``blocks`` section with ``name[a..b]`` arrays expanded.

    Returns
    -------
    entries : list of BlockEntry
        In file order; an array contributes its instances at its own position.
    arrays : dict
        Array base name -> its index range (for ``{i}`` in connections).

    Raises
    ------
    DiagramError
        When an array instance has the name of a block declared on its own.
    """
    arrays = {}
    entries = []
    for name, entry in blocks_raw.items():
        line = blocks_raw.line_of(name)
        arr = array_key(name)
        if arr is None:
            entries.append(BlockEntry(name, entry, line))
            continue
        arrays[arr[0]] = arr[1]
        for inst, e in expand_block(name, entry, file, line):
            if inst in blocks_raw:
                raise DiagramError(f"block array '{name}' makes '{inst}', which is also "
                                   f"declared on its own", file=file, line=line)
            entries.append(BlockEntry(inst, e, line))
    return entries, arrays


def _kind_name(value):
    """What ``value`` is, in words, for a message (``a list``, ``a mapping`` or its type)."""
    return {"LineList": "a list", "LineDict": "a mapping"}.get(type(value).__name__,
                                                               type(value).__name__)


def _check_block_type(name, entry, file):
    """The ``type`` of block ``name`` must be an identifier (DiagramError at its line)."""
    btype = entry["type"]
    if not isinstance(btype, str) or not _NAME.match(btype):
        shown = btype if isinstance(btype, str) else _kind_name(btype)
        raise DiagramError(f"block '{name}': 'type' must be a block or subsystem type "
                           f"name (letters, digits, _), got {shown}", file=file,
                           line=entry.line_of("type"))


def _parse_block(item: BlockEntry, file) -> BlockSpec:
    """One block entry -> :class:`BlockSpec` (parameters unevaluated, with their lines).

    Raises
    ------
    DiagramError
        When the name is not an identifier, the entry is not a mapping with a ``type`` key,
        or the type is not an identifier.
    """
    name, entry, line = item
    if not isinstance(name, str) or not _NAME.match(name):
        problem = non_ascii(name)
        raise DiagramError(f"block name '{name}' is not an identifier (letters, digits, "
                           f"_; no dots)" + (f": {problem}; {ASCII_RULE}" if problem else ""),
                           file=file, line=line)
    if not isinstance(entry, dict) or "type" not in entry:
        raise DiagramError(f"block '{name}' must be a mapping with a 'type' key, e.g. "
                           f"'{name}: {{type: Gain, k: 2}}'", file=file, line=line)
    _check_block_type(name, entry, file)
    p = LineDict((k, v) for k, v in entry.items() if k != "type")
    plines = {k: entry.line_of(k) for k in p}
    return BlockSpec(name, entry["type"], p, line, plines)


def _parse_blocks(data, file):
    """The ``blocks`` section: ``(name -> BlockSpec, arrays)`` (see
    :func:`_expand_block_arrays`); a name made twice is a DiagramError."""
    entries, arrays = _expand_block_arrays(_section(data, "blocks", LineDict, file), file)
    blocks = {}
    for item in entries:
        if item.name in blocks:
            raise DiagramError(f"block '{item.name}' is declared twice (an array entry and "
                               f"another entry make the same name)", file=file, line=item.line)
        blocks[item.name] = _parse_block(item, file)
    return blocks, arrays


def _split_connection(item, file, line):
    """``(source text, [destination texts])`` of one connection: ``"src -> d1, d2"`` or a
    pair ``[src, dst]``; anything else is a WiringError."""
    if isinstance(item, (list, tuple)) and len(item) == 2:
        return item[0], [item[1]]
    if isinstance(item, str) and "->" in item:
        src_t, rest = item.split("->", 1)
        return src_t, rest.split(",")
    raise WiringError(f"connection {item!r} must read 'src.port -> dst.port'",
                      file=file, line=line)


def _parse_connection(item, file, line):
    """One connection (after ``{i}`` expansion) -> a list of :class:`ConnSpec`, one per
    destination. A destination must be a whole input port (no ``[i]``)."""
    src_t, dsts = _split_connection(item, file, line)
    src = parse_address(src_t, file, line, "connection source")
    conns = []
    for d in dsts:
        dst = parse_address(d, file, line, "connection destination")
        if dst.start is not None:
            raise WiringError(f"a destination takes a whole input port, got '{d.strip()}' "
                              f"(select elements on the source side or with a Selector)",
                              file=file, line=line)
        conns.append(ConnSpec(src, dst, line))
    return conns


def _check_connection_ascii(item, file, line):
    """The texts of connection ``item`` (a string or a pair) are ASCII, checked before
    ``{i}`` is worked out (a ``{i+١}`` is named by its digit, not as a bad brace)."""
    for t in (item if isinstance(item, list) else [item]):
        if isinstance(t, str):
            _check_ascii(t, f"connection '{t.strip()}'", file, line)


def _parse_connections(data, arrays, file):
    """The ``connections`` section -> list of :class:`ConnSpec`, lines over block
    ``arrays`` expanded first (every line is expanded before any is parsed)."""
    conns_raw = _section(data, "connections", list, file)
    items = []
    for k, item in enumerate(conns_raw):
        line = conns_raw.lines[k] if hasattr(conns_raw, "lines") else None
        _check_connection_ascii(item, file, line)
        items += [(x, line) for x in expand_connection(item, arrays, file, line)]
    conns = []
    for item, line in items:
        conns += _parse_connection(item, file, line)
    return conns


def _parse_exposed_ports(data, file):
    """The ``inputs`` and ``outputs`` sections of a subsystem file.

    Returns
    -------
    inputs : dict
        Exposed input -> list of :class:`Address` (one exposed input may feed several).
    outputs : dict
        Exposed output -> :class:`Address`.
    port_lines : dict
        ``("in", name)`` / ``("out", name)`` -> line.
    """
    port_lines = {}
    inputs = {}
    for k, v in _section(data, "inputs", LineDict, file).items():
        line = data["inputs"].line_of(k)
        _check_port_name(k, "input", file, line)
        vs = v if isinstance(v, list) else [v]
        inputs[k] = [parse_address(a, file, line, f"exposed input '{k}'") for a in vs]
        port_lines[("in", k)] = line
    outputs = {}
    for k, v in _section(data, "outputs", LineDict, file).items():
        line = data["outputs"].line_of(k)
        _check_port_name(k, "output", file, line)
        if k in inputs:                  # 'inst.u' would name both, told apart by its side
            raise DiagramError(f"exposed output '{k}' has the name of an exposed input "
                               f"(line {port_lines[('in', k)]}): give the two ports different "
                               f"names (a log or plot entry 'instance.{k}' names an output, a "
                               f"connection's side decides which port it means)",
                               file=file, line=line)
        outputs[k] = parse_address(v, file, line, f"exposed output '{k}'")
        port_lines[("out", k)] = line
    return inputs, outputs, port_lines


def _check_port_name(name, kind, file, line):
    """An exposed port's name is an identifier: the parent connects it as ``inst.name``
    (a name such as ``a.b`` or ``1x`` could never be connected or logged)."""
    if not isinstance(name, str) or not _NAME.match(name):
        raise DiagramError(f"exposed {kind} name {name!r} is not an identifier (letters, "
                           f"digits, _; no dots): the parent connects it as "
                           f"'instance.<name>'", file=file, line=line)


def _parse_simulation(data, file):
    """The ``simulation`` section; a key not in :data:`SIM_KEYS` is a DiagramError naming
    the nearest setting."""
    sim = _section(data, "simulation", LineDict, file)
    for k in sim:
        if k not in SIM_KEYS:
            raise DiagramError(f"unknown simulation setting '{k}'{_did_you_mean(k, SIM_KEYS)}; "
                               f"settings are {', '.join(SIM_KEYS)}", file=file,
                               line=sim.line_of(k))
    return sim


def _parse_log(data, file):
    """The ``log`` section: ``"all"`` (the default) or a list of signal names (checked
    against the diagram's signals once it is built; see :func:`_check_log_entry`)."""
    log = data.get("log", "all")
    if not (log == "all" or isinstance(log, list)):
        raise DiagramError("section 'log' must be 'all' or a list of 'block.port'",
                           file=file, line=data.line_of("log"))
    if isinstance(log, list):
        lines = getattr(log, "lines", [])
        for k, name in enumerate(log):
            _check_log_entry(name, file, lines[k] if k < len(lines) else
                             data.line_of("log"))
    return log


def _check_log_entry(name, file, line):
    """A log entry names a whole signal: one with brackets (``i.y[-1]``, ``i.y[1]``) is
    refused saying so (it was 'no signal'), and a non-ASCII one by its character; other
    entries are left to the diagram's signal table."""
    if not isinstance(name, str):
        return
    problem = non_ascii(name)
    if problem:
        raise DiagramError(f"log: '{name.strip()}': {problem}: {ASCII_RULE}", file=file,
                           line=line)
    m = _LOG_ELEMENTS.match(name)
    if m:
        base = m.group(1)
        raise DiagramError(f"log: '{name.strip()}' names elements: the log records whole "
                           f"signals ('{base}'); plots and metrics pick one element of it "
                           f"('{base}[0]', '{base}[-1]' the last)", file=file, line=line)


def _parse_data(data, file: str) -> DiagramSpec:
    """Check the loaded YAML ``data`` of diagram ``file`` section by section and collect it
    in a :class:`DiagramSpec` (values unevaluated, subsystems not opened).

    The sections are checked in a fixed order (top level, parameters, subsystems, blocks,
    connections, exposed ports, simulation, log, the rest), so the first error of a file
    is always the same one.
    """
    _check_sections(data, file)
    params = _parse_parameters(data, file)
    subsystems, subs_raw = _parse_subsystems(data, file, _base_dir(file))
    blocks, arrays = _parse_blocks(data, file)
    conns = _parse_connections(data, arrays, file)
    inputs, outputs, port_lines = _parse_exposed_ports(data, file)
    sim = _parse_simulation(data, file)
    log = _parse_log(data, file)
    plots = _section(data, "plots", list, file)
    _animation_models_beside(plots, file)
    analysis = _section(data, "analysis", LineDict, file)
    metrics = _section(data, "metrics", LineDict, file)
    microgravity = _section(data, "microgravity", LineDict, file)
    return DiagramSpec(
        file=file, name=_text(data, "name", os.path.splitext(os.path.basename(file))[0], file),
        description=_text(data, "description", "", file), parameters=dict(params),
        param_lines={k: params.line_of(k) for k in params}, subsystems=subsystems,
        subsystem_lines={k: subs_raw.line_of(k) for k in subs_raw}, blocks=blocks,
        connections=conns, inputs=inputs, outputs=outputs, port_lines=port_lines,
        simulation=dict(sim), simulation_lines={k: sim.line_of(k) for k in sim}, log=log,
        log_line=data.line_of("log") if "log" in data else None, plots=list(plots),
        analysis=dict(analysis), metrics=metrics, microgravity=microgravity, data=data)
