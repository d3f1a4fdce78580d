"""Command-line smoke tests: every shipped diagram runs, writes its files and checks.

Parametrised over every ``*.yaml`` directly in ``diagrams/`` (``diagrams/lib/`` holds
subsystems, not runnable diagrams) and ``spider.yaml`` at the top when it exists. Runs are
short (``--t-end``) and interpreted (``--no-jit``) to keep the file fast.
"""
from __future__ import annotations

import csv
import glob
import os

import numpy as np
import pytest
import yaml

import spidersim
from spidersim.cli import main

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


def _is_subsystem(path):
    """A file with exposed inputs is a subsystem (diagrams/joint.yaml): it runs inside the
    diagrams that use it, not alone."""
    with open(path) as fh:
        return bool((yaml.safe_load(fh) or {}).get("inputs"))


ALL = sorted(glob.glob(os.path.join(ROOT, "diagrams", "*.yaml")))
FILES = [f for f in ALL if not _is_subsystem(f)]
SUBSYSTEMS = [f for f in ALL if _is_subsystem(f)]
if os.path.isfile(os.path.join(ROOT, "spider.yaml")):
    FILES.append(os.path.join(ROOT, "spider.yaml"))
IDS = [os.path.relpath(f, ROOT) for f in FILES]
T_SMOKE = 0.02   # s


def _yaml(path):
    with open(path) as fh:
        return yaml.safe_load(fh) or {}


def _t_end(path):
    sim = _yaml(path).get("simulation") or {}
    t = sim.get("t_end", 1.0)
    return min(T_SMOKE, float(t)) if isinstance(t, (int, float)) else T_SMOKE


def test_there_are_diagrams():
    assert any(f.endswith(os.path.join("diagrams", "servo.yaml")) for f in FILES)


@pytest.mark.parametrize("path", FILES, ids=IDS)
def test_run_writes_data_report_and_plots(path, tmp_path, capsys):
    out = tmp_path / "out"
    t_end = _t_end(path)
    rc = main(["run", path, "--t-end", repr(t_end), "--out", str(out), "--no-jit"])
    captured = capsys.readouterr()
    assert rc == 0, captured.err
    assert "done" in captured.out

    with np.load(out / "result.npz") as z:
        assert "t" in z.files
        t = z["t"]
        assert len(t) >= 2 and t[0] == 0.0 and t[-1] == pytest.approx(t_end)
        assert len(z.files) > 1
        for name in z.files:
            if name == "__meta__":            # units, sizes, statistics, provenance
                continue
            assert len(z[name]) == len(t), name
            assert np.all(np.isfinite(z[name])), name

    with open(out / "result.csv", newline="") as fh:
        rows = list(csv.reader(fh))
    assert rows[0][0] == "t [s]" and len(rows[0]) > 1
    assert all(h.endswith("]") for h in rows[0])   # every header carries its unit
    assert len(rows) == len(t) + 1
    assert all(len(r) == len(rows[0]) for r in rows)
    float(rows[1][0])                       # data rows are numbers

    report = (out / "report.txt").read_text()
    assert "status: ok" in report.splitlines()

    plots = _yaml(path).get("plots") or []
    images = sorted(p.name for p in [*out.glob("*.png"), *out.glob("*.gif")])
    assert len(images) == len(plots), images        # one PNG, or GIF (animation), per entry
    for p in out.glob("*.png"):
        assert p.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    for p in out.glob("*.gif"):
        assert p.read_bytes()[:6] in (b"GIF87a", b"GIF89a")


@pytest.mark.parametrize("path", FILES, ids=IDS)
def test_check_prints_the_schedule(path, capsys):
    assert main(["check", path]) == 0
    out = capsys.readouterr().out
    assert "schedule" in out
    assert out.rstrip().endswith("OK")
    d = spidersim.load(path)
    for block in d.blocks:                   # every block is listed
        assert f"    {block}: " in out


def test_blocks_lists_the_library(capsys):
    assert main(["blocks"]) == 0
    out = capsys.readouterr().out
    for name in ("Gain", "Integrator", "PI", "DCMotor", "Step"):
        assert name in out


def test_blocks_documents_one_type(capsys):
    assert main(["blocks", "Gain"]) == 0
    out = capsys.readouterr().out
    assert out.startswith("Gain")
    assert "Parameters:" in out and "k [" in out and "Inputs:" in out and "Outputs:" in out


def test_blocks_unknown_type_is_a_user_error(capsys):
    assert main(["blocks", "Gian"]) == 2
    assert "Gain" in capsys.readouterr().err      # did you mean Gain?


def _run(tmp_path, name, *extra):
    out = tmp_path / name
    rc = main(["run", os.path.join(ROOT, "diagrams", "servo.yaml"), "--t-end", "0.05",
               "--out", str(out), "--no-jit", "--no-plots", *extra])
    assert rc == 0
    with np.load(out / "result.npz") as z:
        return {k: z[k] for k in z.files}


def test_set_from_the_command_line(tmp_path, capsys):
    base = _run(tmp_path, "base")
    # a block parameter
    r2 = _run(tmp_path, "r2", "--set", "motor.R=2")
    assert np.max(np.abs(r2["motor.i"] - np.interp(r2["t"], base["t"], base["motor.i"]))) > 1e-2
    api = spidersim.load(os.path.join(ROOT, "diagrams", "servo.yaml"),
                         set={"motor.R": 2.0}).simulate(t_end=0.05, jit=False)
    np.testing.assert_allclose(r2["t"], api.t, rtol=1e-12)
    np.testing.assert_allclose(r2["motor.i"], api["motor.i"], rtol=1e-12, atol=1e-15)
    # a top-level parameter, used in an expression (sat limits -V_max..V_max); the first
    # command is 5 V, so a 2 V supply saturates
    r3 = _run(tmp_path, "r3", "--set", "V_max=2")
    assert r3["sat.y"].max() == 2.0 and base["sat.y"].max() > 2.0
    # a bad path is a user error, exit status 2
    rc = main(["run", os.path.join(ROOT, "diagrams", "servo.yaml"), "--t-end", "0.01",
               "--out", str(tmp_path / "bad"), "--no-jit", "--set", "motor.Q=1"])
    assert rc == 2
    assert "motor.Q" in capsys.readouterr().err


@pytest.mark.parametrize("value, words", [
    ("010", "--set c.value: '010' has a leading zero, which YAML 1.1 reads as an octal"),
    ("-010", "--set c.value: '-010' has a leading zero"),
    ("1:30", "--set c.value: '1:30' is a base-60 number in YAML 1.1"),
    ("[1, 010]", "--set c.value: '010' has a leading zero"),
    ("2020-13-01", "--set c.value: '2020-13-01' is written as a YAML date but is none"),
])
def test_set_refuses_the_yaml11_numbers_a_file_refuses(tmp_path, capsys, value, words):
    """``--set c.value=010`` ran with 8 and ``=1:30`` with 90 (plain yaml.safe_load), where
    the same value in the file is refused; an impossible date was an internal error. Now
    the loader's rules, exit status 2; what a file takes still passes (quoted 010 reaches
    the expression reader, 0x10 is 16, a text that is not YAML stays a text)."""
    f = tmp_path / "c.yaml"
    f.write_text("blocks:\n  c: {type: Constant, value: 1}\n  i: {type: Integrator}\n"
                 "connections: [c.y -> i.u]\n")
    assert main(["check", str(f), "--set", f"c.value={value}"]) == 2
    err = capsys.readouterr().err
    assert words in err and "Traceback" not in err and "internal error" not in err, err
    from spidersim.cli import _parse_sets
    assert _parse_sets(["a=0x10", "b='010'", "c=1e3", "d=a: b: c", "e=[1, 2.5]"]) == {
        "a": 16, "b": "010", "c": "1e3", "d": "a: b: c", "e": [1, 2.5]}


@pytest.mark.parametrize("edit, message, at", [
    ("      ref.aftr: {doc: position after the step, unit: rad, default: 1}",
     "argument 'ref.aftr' names no parameter: block 'ref' (Step) has no parameter 'aftr'; "
     "did you mean after?", "      ref.aftr"),
    ("      ref.after: {doc: position after the step, unit: rad, default: [1, 2]}",
     "block 'ref': command 'position_step': parameter 'after' must be a scalar",
     "commands:"),
    ("      ref.after: {doc: position after the step, unit: m}",
     "argument 'ref.after' is declared in m, but the parameter is in rad: m does not "
     "convert to rad", "      ref.after"),
    ("      ref.after: {unit: rad}\n      motor.R: {doc: resistance, unit: degC}",
     "argument 'motor.R' is declared in degC, but the parameter is in Ohm: degC does not "
     "convert to Ohm", "      motor.R"),
    ("      ref.after: {unit: rad}\n      e_pos.signs: {unit: K}",
     "argument 'e_pos.signs' is declared in K: a str parameter takes no unit",
     "      e_pos.signs"),
])
def test_check_reads_the_named_commands(tmp_path, capsys, edit, message, at):
    """``spidersim check`` reads the ``commands`` section the service serves: a command
    whose argument names a parameter the model does not have or is declared in a unit of
    another kind than the parameter's (a K on a time passed; at the argument's line) or
    whose default the model refuses (at the section's line) fails at the check, with the
    file and the command's name, not at the first request to the service. The intact file
    lists its commands."""
    src = os.path.join(ROOT, "diagrams", "servo.yaml")
    assert main(["check", src]) == 0
    assert "named commands (spidersim serve): position_step" in capsys.readouterr().out
    text = open(src).read()
    good = "      ref.after: {doc: position after the step, unit: rad}"
    assert good in text
    bad = tmp_path / "servo.yaml"
    bad.write_text(text.replace(good, edit))
    assert main(["check", str(bad)]) == 2
    err = capsys.readouterr().err
    line = next(k for k, t in enumerate(bad.read_text().splitlines(), 1) if t.startswith(at))
    assert f"servo.yaml:{line}: " in err and "command 'position_step'" in err
    assert message in err
    assert "Traceback" not in err


CHECKED = """\
parameters: {a: 1.0}
subsystems:
  SUB: sub.yaml
blocks:
  c: {type: Constant, value: 1}
  g: {type: Gain, k: a}
  j: {type: SUB, gain: 3}
connections:
  - c.y -> g.u
  - g.y -> j.u
commands:
  go:
    doc: a command
    arguments:
      ARG: {doc: an argument}
"""
SUB = """\
parameters: {gain: 1.0}
blocks:
  h: {type: Gain, k: gain}
inputs: {u: h.u}
"""


@pytest.mark.parametrize("arg, problem", [
    ("a", None), ("g.k", None), ("j.gain", None), ("j.h.k", None),
    ("nosuch.k", "there is no block or subsystem 'nosuch'"),
    ("b", "the diagram has no parameter 'b'"),
    ("g.kk", "block 'g' (Gain) has no parameter 'kk'; did you mean k?"),
    ("j.gian", "subsystem 'j' (type 'SUB') has no parameter 'gian'; did you mean gain?"),
    ("j.h.x", "block 'j.h' (Gain) has no parameter 'x'"),
    ("j.nosuch.k", "there is no block or subsystem 'j.nosuch'"),
])
def test_check_refuses_an_argument_that_names_no_parameter(tmp_path, capsys, arg, problem):
    """An argument a request could never give (no such parameter) is refused by ``check``
    at its line; every path ``--set`` takes (a diagram parameter, a block's, a subsystem
    instance's, a block's inside one) passes."""
    (tmp_path / "sub.yaml").write_text(SUB)
    f = tmp_path / "m.yaml"
    f.write_text(CHECKED.replace("ARG", arg))
    rc = main(["check", str(f)])
    out, err = capsys.readouterr()
    if problem is None:
        assert rc == 0 and "named commands (spidersim serve): go" in out, err
        return
    assert rc == 2 and "Traceback" not in err
    assert f"m.yaml:15: command 'go': argument '{arg}' names no parameter: {problem}" in err


@pytest.mark.parametrize("path", SUBSYSTEMS,
                         ids=[os.path.relpath(f, ROOT) for f in SUBSYSTEMS])
def test_subsystem_files_are_used_and_checked(path, capsys):
    """Each top-level subsystem file is used by at least one runnable diagram, and running
    it alone says it is a subsystem to use from a parent (not a traceback)."""
    name = os.path.basename(path)
    users = [f for f in FILES if name in open(f).read()]
    assert users, f"{name} is used by no diagram"
    rc = main(["check", path])
    err = capsys.readouterr().err
    assert rc == 2 and "is a subsystem" in err and "parent" in err and "Traceback" not in err
    assert f"{name}:" in err


def test_compile_progress_says_what_happens(tmp_path):
    """A new structure says it compiles (and how long it took); the next run says it loaded
    the compiled code from the cache (issue #16 item 4)."""
    import subprocess
    import sys
    env = dict(os.environ, SPIDERSIM_CACHE=str(tmp_path / "cache"))
    cmd = [sys.executable, "-m", "spidersim.cli", "run", os.path.join(ROOT, "diagrams",
           "three_lags.yaml"), "--t-end", "0.01", "--no-plots", "--out", str(tmp_path / "o")]
    first = subprocess.run(cmd, capture_output=True, text=True, env=env, timeout=600)
    second = subprocess.run(cmd, capture_output=True, text=True, env=env, timeout=600)
    assert first.returncode == 0 and second.returncode == 0, first.stderr + second.stderr
    assert "new structure: compiling with numba" in first.stderr
    assert "compiled in" in first.stderr and "from the cache" not in first.stderr
    assert "loading compiled code from the cache" in second.stderr
    assert "loaded from the cache in" in second.stderr


def test_a_long_explicit_run_suggests_a_stiff_method(tmp_path, capsys, monkeypatch):
    """An explicit method that needs very many steps says the diagram may be stiff and
    names the stiff methods (a DC motor with L = 1e-8 H took 60 million DP54 steps without
    a word; a hostile review, session 12); a short run says nothing. The threshold is
    lowered here so that a small stiff lag (time constant 1e-5 s) reaches it quickly."""
    from spidersim import cli
    monkeypatch.setattr(cli, "STIFF_HINT_STEPS", 2_000)
    path = tmp_path / "stiff.yaml"
    path.write_text("blocks:\n  u: {type: Step}\n  f: {type: TransferFunction, num: [1], "
                    "den: [1e-5, 1]}\n  s: {type: TransferFunction, num: [1], den: [1, 1]}\n"
                    "connections:\n  - u.y -> f.u\n  - f.y -> s.u\n"
                    "simulation: {t_end: 1, method: DP54}\nlog: [s.y]\n")
    for method, noted in (("DP54", True), ("NDF", False)):
        assert cli.main(["run", str(path), "--method", method, "--no-plots", "--out",
                         str(tmp_path / method)]) == 0
        err = capsys.readouterr().err
        assert ("if the diagram is stiff" in err) == noted, err
        if noted:
            assert "--method NDF" in err
