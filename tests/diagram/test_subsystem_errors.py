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
