"""The parts of the diagram-file parser (spidersim.diagram.spec), each on a tiny YAML text.

Every part is a function of the loaded YAML mapping and the file name only, so these tests need
no block library, no flattening and no compilation; whole files are covered by test_errors.py
and the hostile corpus.
"""
import os

import pytest

from spidersim.diagram import spec as S
from spidersim.errors import DiagramError, WiringError
from spidersim.text.yamlio import load_text


def data(text):
    """The loaded YAML mapping of ``text`` (with line numbers), file name ``t.yaml``."""
    return load_text(text, "t.yaml")


def test_check_sections_suggests_the_nearest_section():
    """A misspelt section is refused at its line with the nearest section name; a file
    without ``blocks`` is refused at line 1."""
    with pytest.raises(DiagramError) as ei:
        S._check_sections(data("blocks: {}\nconections: []\n"), "t.yaml")
    assert ei.value.line == 2
    assert "unknown section 'conections' (did you mean 'connections'?)" in str(ei.value)
    with pytest.raises(DiagramError, match="no 'blocks' section") as ei:
        S._check_sections(data("parameters: {a: 1}\n"), "t.yaml")
    assert ei.value.line == 1


@pytest.mark.parametrize("text,words", [("", "empty"), ("- 1\n- 2\n", "got a list"),
                                        ("just text\n", "got a text")])
def test_check_sections_refuses_what_is_not_a_mapping(text, words):
    """An empty document, a list or a bare string is not a diagram: the message says
    what was found."""
    with pytest.raises(DiagramError, match=words):
        S._check_sections(data(text), "t.yaml")


def test_subsystem_paths_are_relative_to_the_file(tmp_path):
    """Both entry forms (``T: f.yaml`` and ``T: {file: f.yaml}``) resolve against the
    folder given, normalised; the raw section keeps the lines."""
    d = data("blocks: {}\nsubsystems:\n  A: sub/a.yaml\n  B: {file: ../b.yaml}\n")
    subs, raw = S._parse_subsystems(d, "t.yaml", str(tmp_path))
    assert subs == {"A": os.path.join(str(tmp_path), "sub", "a.yaml"),
                    "B": os.path.join(os.path.dirname(str(tmp_path)), "b.yaml")}
    assert (raw.line_of("A"), raw.line_of("B")) == (3, 4)
    with pytest.raises(DiagramError, match="subsystem 'C' must name a YAML file, got 3"):
        S._parse_subsystems(data("blocks: {}\nsubsystems: {C: 3}\n"), "t.yaml", "/")


def test_block_arrays_expand_in_place_and_keep_the_array_line():
    """``g[1..3]`` becomes g1, g2, g3 at the array's position and line, with per-instance
    ``each`` values; the array's index range is returned for ``{i}`` connections."""
    d = data("blocks:\n  a: {type: Gain}\n  g[1..3]: {type: Gain, k: {each: [1, 2, 3]}}\n"
             "  z: {type: Gain}\n")
    entries, arrays = S._expand_block_arrays(d["blocks"], "t.yaml")
    assert [e.name for e in entries] == ["a", "g1", "g2", "g3", "z"]
    assert [e.line for e in entries] == [2, 3, 3, 3, 4]
    assert [e.entry["k"] for e in entries[1:4]] == [1, 2, 3]
    assert list(arrays) == ["g"]


def test_block_array_clashing_with_a_plain_block():
    """An array instance with the name of a block declared on its own is refused at the
    array's line."""
    d = data("blocks:\n  g2: {type: Gain}\n  g[1..3]: {type: Gain}\n")
    with pytest.raises(DiagramError, match="makes 'g2', which is also declared") as ei:
        S._expand_block_arrays(d["blocks"], "t.yaml")
    assert ei.value.line == 3


def test_parse_block_keeps_parameter_lines():
    """A block entry becomes a BlockSpec without the ``type`` key among its parameters, each
    parameter with its own line."""
    d = data("blocks:\n  m:\n    type: DCMotor\n    R: 1.5\n    L: 0.002\n")
    b = S._parse_block(S.BlockEntry("m", d["blocks"]["m"], 2), "t.yaml")
    assert (b.name, b.type, b.line) == ("m", "DCMotor", 2)
    assert dict(b.params) == {"R": 1.5, "L": 0.002}
    assert b.param_lines == {"R": 4, "L": 5}


@pytest.mark.parametrize("entry,words,line", [
    ("{type: [Gain]}", "'type' must be a block or subsystem type name (letters, digits, _), "
                       "got a list", 2),
    ("{type: {a: 1}}", "got a mapping", 2),
    ("{k: 2}", "must be a mapping with a 'type' key, e.g. 'm: {type: Gain, k: 2}'", 2),
])
def test_parse_block_errors(entry, words, line):
    """A block without a usable ``type`` is refused with the block's name and what was
    found, at the line of the entry."""
    d = data(f"blocks:\n  m: {entry}\n")
    with pytest.raises(DiagramError) as ei:
        S._parse_block(S.BlockEntry("m", d["blocks"]["m"], 2), "t.yaml")
    assert words in str(ei.value) and ei.value.line == line


def test_block_declared_twice_by_an_array():
    """Two entries making the same instance name (two arrays overlapping) are refused."""
    d = data("blocks:\n  g[1..2]: {type: Gain}\n  g[2..3]: {type: Gain}\n")
    with pytest.raises(DiagramError, match="block 'g2' is declared twice") as ei:
        S._parse_blocks(d, "t.yaml")
    assert ei.value.line == 3


def test_connection_fans_out_to_each_destination():
    """``src -> d1, d2`` is one ConnSpec per destination, all with the same source slice;
    a two-element list is a connection too."""
    conns = S._parse_connection("a.y[1:3] -> b.u, c.u", "t.yaml", 7)
    assert [(str(c.src), str(c.dst), c.line) for c in conns] == [
        ("a.y[1:3]", "b.u", 7), ("a.y[1:3]", "c.u", 7)]
    (c,) = S._parse_connection(["a.y[0]", "b.u"], "t.yaml", 8)
    assert (c.src.start, c.src.stop, c.src.single) == (0, 1, True)


@pytest.mark.parametrize("text,start,stop", [("a.y[-1]", -1, None), ("a.y[-2]", -2, -1),
                                             ("a.y[2]", 2, 3), ("a.y[0:-1]", 0, -1)])
def test_negative_index_is_counted_from_the_end(text, start, stop):
    """A single index [-1] is the last element ([-1:None]), not the empty [-1:0]."""
    a = S.parse_address(text, "t.yaml", 3)
    assert (a.start, a.stop, str(a)) == (start, stop, text)


@pytest.mark.parametrize("text,start,stop", [("a.y[1:]", 1, None), ("a.y[:2]", 0, 2),
                                             ("a.y[:]", 0, None), ("a.y[-2:]", -2, None),
                                             ("a.y[:-1]", 0, -1), ("a.y[ 1 : ]", 1, None)])
def test_a_range_may_leave_out_either_bound(text, start, stop):
    """``[a:]`` runs to the end and ``[:b]`` from the start, as in Python (they were not
    read at all); the text is quoted as written, without its spaces."""
    a = S.parse_address(text, "t.yaml", 3)
    assert (a.start, a.stop, a.single, str(a)) == (start, stop, False, text.replace(" ", ""))


@pytest.mark.parametrize("text", ["a.y[::2]", "a.y[1:3:1]", "a.y[::]"])
def test_a_range_with_a_step_is_refused_by_name(text):
    """A step is no contiguous range: refused, saying so, at the line."""
    with pytest.raises(WiringError) as ei:
        S.parse_address(text, "t.yaml", 3, "connection source")
    assert (f"connection source '{text}': a step ('[a:b:step]') is not supported"
            in str(ei.value)) and ei.value.line == 3


@pytest.mark.parametrize("item,words", [
    ("a.y -> b.u[0]", "a destination takes a whole input port, got 'b.u[0]'"),
    ("a.y b.u", "must read 'src.port -> dst.port'"),
    (["a.y"], "must read 'src.port -> dst.port'"),
    ("a -> b.u", "cannot read connection source 'a':"),  # quoted without the space
    ("a.y[] -> b.u", "cannot read connection source 'a.y[]': expected 'block.port', "
                     "'block.port[i]' or 'block.port[i:j]' (i or j may be left out)"),
    ("a.y -> b.u[1:]", "a destination takes a whole input port, got 'b.u[1:]'"),
])
def test_connection_errors(item, words):
    """Malformed connections are wiring errors at the connection's line."""
    with pytest.raises(WiringError) as ei:
        S._parse_connection(item, "t.yaml", 4)
    assert words in str(ei.value) and ei.value.line == 4


def test_connections_expand_over_block_arrays():
    """A ``{i}`` line is repeated over the array and every copy keeps the line."""
    d = data("blocks: {}\nconnections:\n  - s.y{i} -> g{i}.u\n")
    conns = S._parse_connections(d, {"g": range(1, 3), "s": range(1, 3)}, "t.yaml")
    assert [(str(c.src), str(c.dst), c.line) for c in conns] == [
        ("s.y1", "g1.u", 3), ("s.y2", "g2.u", 3)]


def test_exposed_ports_and_their_lines():
    """An exposed input may map to a list of ports; each exposed port has its line under
    ("in"|"out", name)."""
    d = data("blocks: {}\ninputs:\n  u: [a.u, b.u]\noutputs:\n  y: c.y[2]\n")
    inputs, outputs, lines = S._parse_exposed_ports(d, "t.yaml")
    assert [str(a) for a in inputs["u"]] == ["a.u", "b.u"]
    assert str(outputs["y"]) == "c.y[2]"
    assert lines == {("in", "u"): 3, ("out", "y"): 5}


def test_simulation_and_log_sections():
    """An unknown simulation setting names the nearest one; ``log`` is 'all' by default and
    otherwise must be a list."""
    with pytest.raises(DiagramError, match=r"'rtoll' \(did you mean 'rtol'\?\)") as ei:
        S._parse_simulation(data("blocks: {}\nsimulation: {t_end: 1, rtoll: 1e-6}\n"),
                            "t.yaml")
    assert ei.value.line == 2
    assert S._parse_log(data("blocks: {}\n"), "t.yaml") == "all"
    with pytest.raises(DiagramError, match="'all' or a list"):
        S._parse_log(data("blocks: {}\nlog: a.y\n"), "t.yaml")


@pytest.mark.parametrize("text,char,code,pos", [
    ("c.y[١] -> g.u", "١", "U+0661 ARABIC-INDIC DIGIT ONE", 5),
    ("c.y[𝟏] -> g.u", "𝟏", "U+1D7CF MATHEMATICAL BOLD DIGIT ONE", 5),
    ("c.y[١:] -> g.u", "١", "U+0661", 5),
    ("c.y[:٢] -> g.u", "٢", "U+0662 ARABIC-INDIC DIGIT TWO", 6),
    ("c.y[１] -> g.u", "１", "U+FF11 FULLWIDTH DIGIT ONE", 5),
    ("c.y[{i+١}] -> g{i}.u", "١", "U+0661", 8),
])
def test_a_non_ascii_digit_is_no_index(text, char, code, pos):
    """``\\d`` and ``int`` read other scripts' digits: ``c.y[𝟏]`` and ``c.y[١]`` were
    element 1. Refused at the line, naming the character, its code point and position (a
    ``{i+١}`` before the line is repeated over the array)."""
    d = data(f"blocks: {{}}\nconnections:\n  - {text}\n")
    with pytest.raises(WiringError) as ei:
        S._parse_connections(d, {"g": range(1, 3)}, "t.yaml")
    msg = str(ei.value)
    assert ei.value.line == 3
    assert (f"connection '{text}': non-ASCII character '{char}' ({code}" in msg and
            f") at character {pos}: names and indices are ASCII" in msg)


def test_a_non_ascii_digit_in_an_exposed_output_or_an_array_key():
    """The same in a subsystem's exposed output, and in a block array's bounds
    (``g[١..٣]`` made g1..g3)."""
    with pytest.raises(WiringError, match="exposed output 'y' 'c.y\\[١\\]': non-ASCII "
                                          "character '١' \\(U\\+0661"):
        S._parse_exposed_ports(data("blocks: {}\noutputs:\n  y: c.y[١]\n"), "t.yaml")
    with pytest.raises(DiagramError) as ei:
        S._parse_blocks(data("blocks:\n  g[١..٣]: {type: Gain}\n"), "t.yaml")
    assert ("block name 'g[١..٣]' is not an identifier (letters, digits, _; no dots): "
            "non-ASCII character '١' (U+0661 ARABIC-INDIC DIGIT ONE) at character 3"
            in str(ei.value)) and ei.value.line == 2


@pytest.mark.parametrize("entry", ["i.y[-1]", "i.y[1]", "i.y[0:2]", "j3.motor.w [0]"])
def test_a_log_entry_with_elements_is_refused_saying_so(entry):
    """The log records whole signals; an element (any index, -1 too) was 'no signal
    'i.y[-1]'; did you mean i.y?'. The message points to plots and metrics, which pick
    elements; each entry at its own line."""
    d = data(f"blocks: {{}}\nlog:\n  - i.y\n  - \"{entry}\"\n")
    with pytest.raises(DiagramError) as ei:
        S._parse_log(d, "t.yaml")
    base = entry.partition("[")[0].strip()
    assert ei.value.line == 4
    assert (f"log: '{entry}' names elements: the log records whole signals ('{base}'); "
            f"plots and metrics pick one element of it ('{base}[0]', '{base}[-1]' the "
            f"last)") in str(ei.value)


def test_log_entries_of_whole_signals_and_non_ascii_ones():
    """Whole signals pass (an unknown one is the diagram's to name); a non-ASCII entry is
    named by its character."""
    assert S._parse_log(data("blocks: {}\nlog: [i.y, nothere.y, 5]\n"), "t.yaml") == [
        "i.y", "nothere.y", 5]
    with pytest.raises(DiagramError, match="log: 'i.y\\[١\\]': non-ASCII character '١'"):
        S._parse_log(data("blocks: {}\nlog: ['i.y[١]']\n"), "t.yaml")
