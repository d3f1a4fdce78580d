"""Errors inside subsystems name the subsystem file:line and the parent instance's line."""
import os
import subprocess
import sys

import pytest

import spidersim
from spidersim.errors import SpidersimError

SUB = """\
blocks:
  g: {type: Gain, k: 2}
  i: {type: Integrator}
connections:
  - g.y -> i.u
inputs:
  u: g.u
outputs:
  y: i.y
"""
PARENT = """\
subsystems:
  my: sub.yaml
blocks:
  c: {type: Constant, value: 1}
  s: {type: my}
connections:
  - c.y -> s.u
"""


def _error(tmp_path, sub, parent):
    (tmp_path / "sub.yaml").write_text(sub)
    (tmp_path / "parent.yaml").write_text(parent)
    with pytest.raises(SpidersimError) as e:
        spidersim.load(str(tmp_path / "parent.yaml"))
    return e.value, str(e.value)


def test_typo_in_exposed_input_is_reported_in_the_subsystem_file(tmp_path):
    exc, msg = _error(tmp_path, SUB.replace("u: g.u", "u: g.uu"), PARENT)
    assert os.path.basename(exc.file) == "sub.yaml" and exc.line == 7
    assert "'uu'" in msg and "did you mean u" in msg
    assert "parent.yaml:5" in msg and "'s'" in msg          # the instance's line


@pytest.mark.parametrize("old, new, line", [("  u: g.u", "  a.b: g.u", 7),
                                             ("  u: g.u", "  '1x': g.u", 7),
                                             ("  y: i.y", "  y.z: i.y", 9)])
def test_exposed_port_name_must_be_an_identifier(tmp_path, old, new, line):
    """An exposed port named 'a.b' could never be connected ('inst.a.b' is not an address):
    the parent was told to connect it anyway. Refused in the subsystem file, at its line."""
    err, msg = _error(tmp_path, SUB.replace(old, new), PARENT)
    assert "is not an identifier" in msg and err.line == line
    assert err.file.endswith("sub.yaml")


def test_unconnected_exposed_input_is_reported_at_the_instance(tmp_path):
    exc, msg = _error(tmp_path, SUB, PARENT.replace("connections:\n  - c.y -> s.u\n", ""))
    assert os.path.basename(exc.file) == "parent.yaml" and exc.line == 5
    assert "input 'u' of subsystem instance 's'" in msg
    assert "s.g.u" in msg and "sub.yaml:7" in msg


def test_unit_mismatch_inside_a_subsystem_names_both_lines(tmp_path):
    sub = ("blocks:\n  m: {type: DCMotor}\n  g: {type: Gain, k: 2}\nconnections:\n"
           "  - m.i -> m.tau_load\n  - g.y -> m.v\ninputs:\n  u: g.u\noutputs:\n  y: m.w\n")
    exc, msg = _error(tmp_path, sub, PARENT)
    assert os.path.basename(exc.file) == "sub.yaml" and exc.line == 5
    assert "[A]" in msg and "[N.m]" in msg and "parent.yaml:5" in msg


def test_nested_instances_are_all_named(tmp_path):
    (tmp_path / "inner.yaml").write_text(SUB.replace("k: 2", "k: [1, 2, 3]").replace(
        "i: {type: Integrator}", "i: {type: Integrator, x0: [0, 0]}"))
    mid = ("subsystems:\n  inner: inner.yaml\nblocks:\n  x: {type: inner}\n"
           "inputs:\n  u: x.u\noutputs:\n  y: x.y\n")
    exc, msg = _error(tmp_path, mid, PARENT)
    assert "'s.x'" in msg and "'s'" in msg and "parent.yaml:5" in msg


def test_running_a_subsystem_file_says_what_it_is(tmp_path):
    (tmp_path / "sub.yaml").write_text(SUB)
    r = subprocess.run([sys.executable, "-c", "import sys; from spidersim.cli import main; sys.exit(main())", "run",
                        str(tmp_path / "sub.yaml")],
                       capture_output=True, text=True, cwd=tmp_path)
    assert r.returncode == 2 and "Traceback" not in r.stderr
    assert "subsystem" in r.stderr and "sub.yaml:6" in r.stderr


def test_subsystem_fan_out_bomb_stops_at_the_block_limit(tmp_path, monkeypatch):
    """Ten instances of ten instances of ten subsystems of ten blocks (10^4 blocks; one more
    level would be 10^5, and the compile time and memory grow with the blocks) stop at
    ``MAX_BLOCKS`` with the block reached and the instance chain, before anything is
    compiled. Lowered to 500 here to keep the test fast; the count is exact."""
    from spidersim.text import limits
    monkeypatch.setattr(limits, "MAX_BLOCKS", 500)
    (tmp_path / "l1.yaml").write_text(
        "blocks:\n" + "".join(f"  c{i}: {{type: Constant, value: 1}}\n" for i in range(10)))
    for k in (2, 3):
        (tmp_path / f"l{k}.yaml").write_text(
            f"subsystems:\n  L: l{k - 1}.yaml\nblocks:\n"
            + "".join(f"  s{i}: {{type: L}}\n" for i in range(10)))
    (tmp_path / "top.yaml").write_text(
        "subsystems:\n  L: l3.yaml\nblocks:\n"
        + "".join(f"  s{i}: {{type: L}}\n" for i in range(10)))
    with pytest.raises(SpidersimError) as e:
        spidersim.load(str(tmp_path / "top.yaml"))
    msg = str(e.value)
    # blocks 0..499 fit: the 501st, s0.s5.s0.c0, is refused
    assert e.value.block == "s0.s5.s0.c0" and "more than 500 blocks" in msg
    assert "MAX_BLOCKS" in msg and msg.startswith(f"{tmp_path / 'l1.yaml'}:2: ")
    monkeypatch.setattr(limits, "MAX_BLOCKS", 1000)       # exactly at the limit: loads
    assert len(spidersim.load(str(tmp_path / "l3.yaml")).flat.blocks) == 1000


def test_subsystem_type_named_like_a_library_block_is_refused(tmp_path):
    """``subsystems: {Gain: lag.yaml}`` made every ``type: Gain`` of the file a lag without
    a word (the README documents no shadowing): refused at the entry's line, naming the
    library block it would hide."""
    exc, msg = _error(tmp_path, SUB, PARENT.replace("  my: sub.yaml", "  Gain: sub.yaml")
                      .replace("{type: my}", "{type: Gain, k: 2}"))
    assert os.path.basename(exc.file) == "parent.yaml" and exc.line == 2
    assert "subsystem type 'Gain' has the name of the library block Gain" in msg
    assert "sub.yaml" in msg
    # the same subsystem under its own name loads
    (tmp_path / "parent.yaml").write_text(PARENT)
    assert "s.g" in spidersim.load(str(tmp_path / "parent.yaml")).blocks


def test_self_inclusion_through_a_link_says_so(tmp_path):
    """``me: d/x.yaml`` with ``d -> .`` is x.yaml itself: the cycle check compares real
    paths (it used to nest 40 levels of d/d/d/... and say 'not found')."""
    os.symlink(".", tmp_path / "d")
    (tmp_path / "x.yaml").write_text(
        "subsystems:\n  me: d/x.yaml\nblocks:\n  g: {type: Gain}\n  inner: {type: me}\n"
        "connections:\n  - g.y -> inner.u\ninputs: {u: g.u}\noutputs: {y: g.y}\n")
    (tmp_path / "top.yaml").write_text(
        "subsystems:\n  me: x.yaml\nblocks:\n  c: {type: Constant, value: 1}\n"
        "  inner: {type: me}\nconnections:\n  - c.y -> inner.u\n")
    with pytest.raises(SpidersimError) as e:
        spidersim.load(str(tmp_path / "top.yaml"))
    msg = str(e.value)
    assert "subsystem type 'me' includes itself (top.yaml -> x.yaml -> x.yaml" in msg
    assert "through a link" in msg and os.path.basename(e.value.file) == "x.yaml"
    assert e.value.line == 5 and "d/d" not in msg


def _chain(tmp_path, n):
    """top.yaml -> s0.yaml -> ... -> s<n-1>.yaml, each a subsystem holding the next; the
    last holds a Gain: n levels of subsystem instances."""
    for k in range(n):
        inner = ("blocks:\n  g: {type: Gain}\ninputs: {u: g.u}\noutputs: {y: g.y}\n"
                 if k == n - 1 else
                 f"subsystems: {{nxt: s{k + 1}.yaml}}\nblocks:\n  n: {{type: nxt}}\n"
                 f"inputs: {{u: n.u}}\noutputs: {{y: n.y}}\n")
        (tmp_path / f"s{k}.yaml").write_text(inner)
    (tmp_path / "top.yaml").write_text(
        "subsystems: {s: s0.yaml}\nblocks:\n  c: {type: Constant, value: 1}\n"
        "  a: {type: s}\nconnections:\n  - c.y -> a.u\n")
    return str(tmp_path / "top.yaml")


@pytest.mark.parametrize("limit, chain", [
    (4, "top.yaml -> s0.yaml -> s1.yaml -> s2.yaml -> s3.yaml -> s4.yaml"),
    (6, "top.yaml -> s0.yaml -> s1.yaml -> ... -> s5.yaml -> s6.yaml"),   # long: its ends
])
def test_subsystem_nesting_depth_is_bounded(tmp_path, monkeypatch, limit, chain):
    """A chain of distinct files deeper than MAX_SUBSYSTEM_DEPTH is refused at the top
    instance that starts it, naming the chain's ends and the level (a chain of 3,000 files
    failed in the YAML reader of the 483rd, blaming that small file). Lowered here;
    exactly at the limit loads."""
    from spidersim.text import limits
    assert limits.MAX_SUBSYSTEM_DEPTH == 32
    monkeypatch.setattr(limits, "MAX_SUBSYSTEM_DEPTH", limit)
    with pytest.raises(SpidersimError) as e:
        spidersim.load(_chain(tmp_path, limit + 1))
    msg = str(e.value)
    assert msg.startswith(f"{tmp_path / 'top.yaml'}:4: block 'a': ")
    assert f"subsystems nested more than {limit} levels deep (limit MAX_SUBSYSTEM_DEPTH)" in msg
    assert f"chain of files {chain} that reaches level {limit + 1} at 'a{'.n' * limit}'" in msg
    for f in tmp_path.glob("*.yaml"):
        f.unlink()
    assert f"a{'.n' * (limit - 1)}.g" in spidersim.load(_chain(tmp_path, limit)).blocks


VEC_SUB = """\
blocks:
  i: {type: Integrator, x0: [0, 0, 0]}
inputs:
  u: i.u
outputs:
  y: RANGE
"""
VEC_PARENT = """\
subsystems:
  my: sub.yaml
blocks:
  c: {type: Constant, value: [1, 2, 3]}
  s: {type: my}
connections:
  - c.y -> s.u
"""


@pytest.mark.parametrize("rng, words", [
    ("i.y[2:1]", "'i.y[2:1]': element range [2:1] is empty"),
    ("i.y[1:1]", "'i.y[1:1]': element range [1:1] is empty"),
    ("i.y[1:9]", "'i.y[1:9]': element range [1:9] is outside"),
    ("i.y[3]", "'i.y[3]': element [3] is outside"),
    ("i.y[-4]", "'i.y[-4]': element [-4] is outside"),
    ("i.y[3:]", "'i.y[3:]': element range [3:] is empty"),
    ("i.y[:-3]", "'i.y[:-3]': element range [:-3] is empty"),
    ("i.y[:4]", "'i.y[:4]': element range [:4] is outside"),
])
def test_exposed_output_range_outside_is_refused_at_its_line(tmp_path, rng, words):
    """An exposed output's element range was never checked: [2:1] had size -1 and the run
    aborted in free() (heap corruption), [1:9] read memory past the output. Now it is
    checked as a connection's range, at the exposed output's line, naming the instance."""
    exc, msg = _error(tmp_path, VEC_SUB.replace("RANGE", rng), VEC_PARENT)
    assert os.path.basename(exc.file) == "sub.yaml" and exc.line == 6
    assert f"exposed output 'y' {words}" in msg and "'i.y' has size 3" in msg
    assert "subsystem instance 's'" in msg and "parent.yaml:5" in msg


def test_range_of_an_exposed_range_is_checked_inside_it(tmp_path):
    """A parent's range of an exposed range is taken of the exposed elements: s.y = i.y[1:3]
    has 2, so s.y[1:3] is outside it (it was read as i.y[2:4], past the output)."""
    parent = VEC_PARENT.replace("  s: {type: my}\n", "  s: {type: my}\n  g: {type: Gain}\n") \
        + "  - s.y[1:3] -> g.u\n"
    exc, msg = _error(tmp_path, VEC_SUB.replace("RANGE", "i.y[1:3]"), parent)
    assert os.path.basename(exc.file) == "parent.yaml" and exc.line == 9
    assert ("connection source 's.y[1:3]': element range [1:3] is outside: "
            "'s.y' has size 2") in msg


@pytest.mark.parametrize("src, words", [
    ("s.y[5]", "'s.y[5]': element [5] is outside: 's.y' has size 2 (indices 0..1"),
    ("s.y[2:]", "'s.y[2:]': element range [2:] is empty: 's.y' has size 2"),
    ("s.y[:3]", "'s.y[:3]': element range [:3] is outside: 's.y' has size 2"),
])
def test_element_of_an_exposed_range_is_named_as_written(tmp_path, src, words):
    """An element outside an exposed output's range names the port and the range the user
    wrote (s.y, its 2 exposed elements), not the flat output inside (hostile review 14b:
    'v.ytail[5]' was told as 'element range [6:7]' of 'v.i.y')."""
    parent = VEC_PARENT.replace("  s: {type: my}\n", "  s: {type: my}\n  g: {type: Gain}\n") \
        + f"  - {src} -> g.u\n"
    exc, msg = _error(tmp_path, VEC_SUB.replace("RANGE", "i.y[1:3]"), parent)
    assert os.path.basename(exc.file) == "parent.yaml" and exc.line == 9
    assert f"connection source {words}" in msg
    assert "i.y" not in msg and "s.i" not in msg


def test_range_of_an_exposed_output_in_a_middle_file_names_the_instance(tmp_path):
    """A range written in a subsystem file that reads an inner instance's exposed output
    (mid.yaml: 'tail: v.y[5]') is refused at its line and names the instance of the file
    in the parent, as a range of a primitive output does (it named none)."""
    (tmp_path / "mid.yaml").write_text("subsystems: {my: sub.yaml}\nblocks:\n"
                                       "  v: {type: my}\ninputs: {u: v.u}\n"
                                       "outputs: {tail: 'v.y[5]'}\n")
    parent = VEC_PARENT.replace("my: sub.yaml", "my: mid.yaml")
    exc, msg = _error(tmp_path, VEC_SUB.replace("RANGE", "i.y[1:]"), parent)
    assert os.path.basename(exc.file) == "mid.yaml" and exc.line == 5
    assert "exposed output 'tail' 'v.y[5]': element [5] is outside: 'v.y' has size 2" in msg
    assert "subsystem instance 's' of type 'my', parent.yaml:5" in msg


@pytest.mark.parametrize("rng, parent_src, want", [

    ("i.y[0:-1]", "s.y", [1.0, 2.0]),          # negative stop counts from the end
    ("i.y[-1]", "s.y", 3.0),                   # the last element
    ("i.y[-2]", "s.y", 2.0),
    ("i.y[1:3]", "s.y[-1]", 3.0),              # a negative index of an exposed range
    ("i.y", "s.y[-2:-1]", 2.0),
    ("i.y[1:]", "s.y", [2.0, 3.0]),            # open-ended ranges, exposed and taken
    ("i.y[:2]", "s.y[1:]", 2.0),
    ("i.y[:]", "s.y[:-1]", [1.0, 2.0]),
    ("i.y[-2:]", "s.y[:1]", 2.0),
])
def test_negative_bounds_count_from_the_end_in_exposed_outputs(tmp_path, rng, parent_src,
                                                               want):
    """Exposed outputs and connections follow one rule (sizes.norm_slice): negative bounds
    count from the end; the values are those elements (the Integrator of [1, 2, 3] over
    1 s)."""
    (tmp_path / "sub.yaml").write_text(VEC_SUB.replace("RANGE", rng))
    parent = VEC_PARENT.replace("  s: {type: my}\n", "  s: {type: my}\n  g: {type: Gain}\n") \
        + f"  - {parent_src} -> g.u\nsimulation: {{t_end: 1}}\n"
    (tmp_path / "parent.yaml").write_text(parent)
    r = spidersim.load(str(tmp_path / "parent.yaml")).simulate(jit=False)
    assert r["g.y"][-1] == pytest.approx(want)


UNUSED = """\
subsystems:
  my: sub.yaml
  spare: {spare}
blocks:
  c: {{type: Constant, value: 1}}
  s: {{type: my}}
connections:
  - c.y -> s.u
"""


@pytest.mark.parametrize("spare,words", [
    ("nothere.yaml", "subsystem file for type 'spare' not found: "),
    ("/dev/zero", "subsystem file for type 'spare' is not a regular file (a character "
                  "device): /dev/zero"),
    (".", "subsystem file for type 'spare' is a folder, not a file"),
])
def test_an_unused_subsystem_entry_must_name_a_file(tmp_path, spare, words):
    """A type no block uses was never opened: a missing file, a device or a folder
    passed check with exit 0. Refused at the entry's line, saying no block uses it."""
    err, msg = _error(tmp_path, SUB, UNUSED.format(spare=spare))
    assert err.file.endswith("parent.yaml") and err.line == 3
    assert words in msg and "(no block uses the type: fix the path or remove the entry)" in msg


@pytest.mark.parametrize("text, words", [
    ("blocks: [\n", "YAML syntax error"),
    # a WiringError, not a DiagramError: the note naming the entry was missing
    ("blocks:\n  c: {type: Constant}\nconnections:\n  - 'c.y[1:2:3] -> d.u'\n", "step"),
])
def test_an_unused_subsystem_file_must_parse(tmp_path, text, words):
    """An unused entry's file with a syntax error or a bad connection is reported in that
    file, naming the entry's line and that no block uses it."""
    (tmp_path / "broken.yaml").write_text(text)
    err, msg = _error(tmp_path, SUB, UNUSED.format(spare="broken.yaml"))
    assert err.file.endswith("broken.yaml")
    assert words in msg
    assert "(subsystem type 'spare', parent.yaml:3, used by no block)" in msg


def test_a_valid_unused_subsystem_entry_is_allowed(tmp_path):
    """An unused entry naming a good file (here the used one again) is no error, and its
    own subsystems are not opened."""
    (tmp_path / "nested.yaml").write_text("subsystems:\n  x: nothere.yaml\nblocks:\n"
                                          "  g: {type: Gain, k: 1}\n")
    for spare in ("sub.yaml", "nested.yaml"):
        (tmp_path / "sub.yaml").write_text(SUB)
        (tmp_path / "parent.yaml").write_text(UNUSED.format(spare=spare))
        d = spidersim.load(str(tmp_path / "parent.yaml"))
        assert "s.g" in d.blocks
