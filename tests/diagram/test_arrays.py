"""Arrays of instances in YAML (issue #16 item 9): ``name[a..b]`` entries with ``{each:}``
values and ``{i}`` connection patterns make exactly the diagram written out by hand."""
import os
import re

import pytest
import yaml

import spidersim
from spidersim.errors import SpidersimError

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))

BY_HAND = """\
blocks:
  src: {type: Constant, value: [1, 2, 3]}
  split: {type: Demux, sizes: [1, 1, 1]}
  g1: {type: Gain, k: 2}
  g2: {type: Gain, k: 3}
  g3: {type: Gain, k: 4}
  out: {type: Mux, n: 3}
connections:
  - src.y -> split.u
  - split.y1 -> g1.u
  - split.y2 -> g2.u
  - split.y3 -> g3.u
  - g1.y -> out.u1
  - g2.y -> out.u2
  - g3.y -> out.u3
"""

ARRAY = """\
blocks:
  src: {type: Constant, value: [1, 2, 3]}
  split: {type: Demux, sizes: [1, 1, 1]}
  g[1..3]: {type: Gain, k: {each: [2, 3, 4]}}
  out: {type: Mux, n: 3}
connections:
  - src.y -> split.u
  - split.y{i} -> g{i}.u
  - g{i}.y -> out.u{i}
"""


def test_array_equals_the_diagram_by_hand():
    a, b = spidersim.loads(BY_HAND), spidersim.loads(ARRAY)
    assert a.source(jit=False) == b.source(jit=False)
    ra, rb = a.simulate(t_end=0.1, jit=False), b.simulate(t_end=0.1, jit=False)
    assert list(rb["out.y"][-1]) == [2.0, 6.0, 12.0] == list(ra["out.y"][-1])


def test_element_index_arithmetic():
    text = ARRAY.replace("  - split.y{i} -> g{i}.u", "  - src.y[{i-1}] -> g{i}.u")
    r = spidersim.loads(text).simulate(t_end=0.1, jit=False)
    assert list(r["out.y"][-1]) == [2.0, 6.0, 12.0]


def test_negative_element_indexes_count_from_the_end():
    """src.y[-3], [-2], [-1] written out are its elements 0, 1, 2 as in Python ([-1] was
    refused: 'element range [-1:0] is outside', while an exposed output's [-1] was the
    last)."""
    text = ARRAY.replace("  - split.y{i} -> g{i}.u", "  - src.y[-3] -> g1.u\n"
                         "  - src.y[-2] -> g2.u\n  - src.y[-1] -> g3.u")
    r = spidersim.loads(text).simulate(t_end=0.1, jit=False)
    assert list(r["out.y"][-1]) == [2.0, 6.0, 12.0]


@pytest.mark.parametrize("place,inst,value", [("{i-2}", "g1", -1), ("{i-4}", "g1", -3),
                                              ("{i - 3}", "g1", -2)])
def test_a_computed_negative_index_is_refused(place, inst, value):
    """An index that {i-N} makes negative is an off-by-one, not 'count from the end': it
    silently read the last element (g1 of src.y[{i-2}] read src.y[-1] = 3)."""
    text = ARRAY.replace("  - split.y{i} -> g{i}.u", f"  - src.y[{place}] -> g{{i}}.u")
    with pytest.raises(SpidersimError) as exc:
        spidersim.loads(text, file="arr.yaml")
    assert exc.value.line == 8
    assert (f"for instance {inst} (i = {int(inst[1:])}), {place} is {value}: an index "
            f"computed from {{i}} may not be negative") in exc.value.message


def test_a_computed_negative_index_in_a_range_is_refused():
    text = ARRAY.replace("  - split.y{i} -> g{i}.u", "  - src.y[{i-2}:{i}] -> g{i}.u")
    with pytest.raises(SpidersimError, match=r"instance g1 \(i = 1\), \{i-2\} is -1"):
        spidersim.loads(text, file="arr.yaml")


@pytest.mark.parametrize("conn, words", [
    ("g{i-1}.y -> g{i}.u", "the block name g{i-1} gives g-1, which names no block"),
    ("g{i}.y -> out.u{i-1}", "the port name u{i-1} gives u-1, which names no port"),
])
def test_a_name_computed_negative_is_named_as_a_name(conn, words):
    """``g{i-1}`` over ``g[0..2]`` is a block name (g-1 for g0), not an index: it was
    reported as 'an index computed from {i} may not be negative'."""
    text = ("blocks:\n  out: {type: Mux, n: 3}\n  g[0..2]: {type: Gain}\n"
            f"connections:\n  - {conn}\n")
    with pytest.raises(SpidersimError) as exc:
        spidersim.loads(text, file="arr.yaml")
    assert exc.value.line == 5
    assert f"for instance g0 (i = 0), {words}" in exc.value.message
    assert "index" not in exc.value.message


def test_port_pattern_is_not_read_as_an_array():
    """In 'g{i}.y -> out.u{i}' only g{i} names an array: an unrelated array u[0..1] made it
    fail 'arrays 'g' and 'u' have different index ranges'."""
    text = ARRAY.replace("  out: {type: Mux, n: 3}\n",
                         "  out: {type: Mux, n: 3}\n  u[0..1]: {type: Constant, value: 0}\n")
    assert "u[0..1]" in text
    r = spidersim.loads(text).simulate(t_end=0.1, jit=False)
    assert list(r["out.y"][-1]) == [2.0, 6.0, 12.0]


def test_spider_yaml_uses_an_array_of_seven_joints():
    """spider.yaml declares the joints once (j[1..7]) and wires each joint port once with
    {i}: no connection names a joint by its number."""
    d = spidersim.load(os.path.join(ROOT, "spider.yaml"))
    for k, n in enumerate([160, 160, 160, 160, 100, 100, 100], start=1):
        assert f"j{k}.motor" in d.blocks
    with open(os.path.join(ROOT, "spider.yaml")) as fh:
        text = fh.read()
    assert "j[1..7]" in text and text.count("j{i}") >= 5
    conns = [c for c in yaml.safe_load(text)["connections"] if isinstance(c, str)]
    assert not [c for c in conns if re.search(r"\bj[1-7]\.", c)]


@pytest.mark.parametrize("change,words", [
    (("k: {each: [2, 3, 4]}", "k: {each: [2, 3]}"), "needs a list of 3 values"),
    (("  - g{i}.y -> out.u{i}", "  - h{i}.y -> out.u{i}"), "names no block array"),
    (("g[1..3]", "g[1..5000]"), "1 to 1000 instances"),
    (("g[1..3]", "g[3..1]"), "1 to 1000 instances"),
    # a range too large for len() was an internal OverflowError before the bound was checked
    (("g[1..3]", "g[1..99999999999999999999]"), r"1 to 1000 instances .* got 1e\+20"),
    (("g[1..3]", "g[1..1" + "0" * 999 + "]"), "got a number of 1000 digits"),
    (("  out: {type: Mux, n: 3}", "  out: {type: Mux, n: 3}\n  g2: {type: Gain}"),
     "also declared on its own"),
    (("  - g{i}.y -> out.u{i}", "  - g{i}.y -> out.u{j}"), "braces"),
    # messages that named the wrong thing: 'got LineDict', 'a value with a unit is
    # written {value: 2.5, unit: N.m}', 'not another value with a unit'
    (("k: {each: [2, 3, 4]}", "k: {each: {a: 1}}"),
     "needs a list of 3 values .*got a mapping"),
    (("k: {each: [2, 3, 4]}", "k: {value: {each: [2, 3, 4]}, unit: '1'}"),
     r"'each' goes outside the unit, one value with its unit per instance: \{each: "),
    (("  out: {type: Mux, n: 3}", "  out: {type: Mux, n: 3}\n  h: {type: Gain, k: {each: "
      "[1, 2]}}"),
     "block 'h': parameter 'k': 'each' gives one value per instance of a block array"),
])
def test_array_errors(change, words):
    with pytest.raises(SpidersimError, match=words) as exc:
        spidersim.loads(ARRAY.replace(*change), file="arr.yaml")
    assert exc.value.line is not None
