"""A run repeated from its report gives bit-identical results (issue #16 item 3); the
report and the NPZ say how the run was made."""
import json
import os

import numpy as np
import pytest

from spidersim.cli import main
from spidersim.solver.result import Result

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


def test_rerun_is_bit_identical(tmp_path, capsys):
    first = tmp_path / "first"
    assert main(["run", os.path.join(ROOT, "diagrams", "servo.yaml"), "--set", "motor.R=1.3",
                 "--set", "V_max=2*12", "--t-end", "0.05", "--no-plots", "--no-jit",
                 "--out", str(first)]) == 0
    prov = json.loads((first / "report.json").read_text())["provenance"]
    assert prov["rerun"]["set"] == {"motor.R": "1.3", "V_max": "2*12"}
    assert set(prov["versions"]) >= {"spidersim", "numpy", "scipy", "numba", "python"}
    assert len(prov["file_sha256"]) == 1 and prov["date_utc"].endswith("+00:00")
    report = (first / "report.txt").read_text()
    assert "spidersim:" in report and "file_sha256:" in report and "date_utc:" in report
    second = tmp_path / "second"
    assert main(["run", "--rerun", str(first / "report.json"), "--out", str(second)]) == 0
    a, b = Result.load(first), Result.load(second)
    assert a.names == b.names and np.array_equal(a.t, b.t)
    for n in a.names:
        assert np.array_equal(a[n], b[n]), n
    assert b.units == a.units and b.provenance["rerun"] == a.provenance["rerun"]
    # a changed parameter would show: the rerun used the --set values, not the defaults
    plain = tmp_path / "plain"
    assert main(["run", os.path.join(ROOT, "diagrams", "servo.yaml"), "--t-end", "0.05",
                 "--no-plots", "--no-jit", "--out", str(plain)]) == 0
    assert not np.array_equal(Result.load(plain)["motor.i"], a["motor.i"])


def test_rerun_warns_when_the_file_changed(tmp_path, capsys):
    src = tmp_path / "servo.yaml"
    src.write_text(open(os.path.join(ROOT, "diagrams", "servo.yaml")).read())
    out = tmp_path / "a"
    assert main(["run", str(src), "--t-end", "0.02", "--no-plots", "--no-jit",
                 "--out", str(out)]) == 0
    src.write_text(src.read_text() + "\n# edited\n")
    capsys.readouterr()
    assert main(["run", "--rerun", str(out), "--out", str(tmp_path / "b")]) == 0
    assert "has changed since the reported run" in capsys.readouterr().err


def test_rerun_repeats_no_plots(tmp_path, capsys):
    """The rerun of a --no-plots run draws no plots either (it drew them); the rerun of a
    run with plots draws them, and --no-plots given with --rerun skips them."""
    src = os.path.join(ROOT, "diagrams", "servo.yaml")
    quiet, drawn = tmp_path / "quiet", tmp_path / "drawn"
    assert main(["run", src, "--t-end", "0.02", "--no-plots", "--no-jit",
                 "--out", str(quiet)]) == 0
    assert main(["run", src, "--t-end", "0.02", "--no-jit", "--out", str(drawn)]) == 0
    assert json.loads((quiet / "report.json").read_text())["provenance"]["rerun"][
        "plots"] is False
    pngs = lambda f: sorted(p.name for p in f.glob("*.png"))
    assert pngs(quiet) == [] and pngs(drawn) != []
    for first, extra, plotted in ((quiet, [], False), (drawn, [], True),
                                  (drawn, ["--no-plots"], False)):
        again = tmp_path / f"again-{first.name}-{len(extra)}"
        assert main(["run", "--rerun", str(first), "--out", str(again), *extra]) == 0
        assert (pngs(again) == pngs(drawn)) if plotted else pngs(again) == []


def test_rerun_of_something_else_is_a_clear_error(tmp_path, capsys):
    (tmp_path / "report.json").write_text("{}")
    assert main(["run", "--rerun", str(tmp_path)]) == 2
    assert "not a spidersim run report" in capsys.readouterr().err


GOOD_RERUN = {"file": "servo.yaml", "set": {}, "t_end": None, "method": None, "jit": True}


@pytest.mark.parametrize("field, value, words", [
    ("set", [1, 2], "'rerun.set' must be a mapping of names to values"),
    ("set", {"V_max": {"a": 1}}, "'rerun.set' must be a mapping"),
    ("method", ["DP54"], "'rerun.method' must be a method name or null"),
    ("jit", "no", "'rerun.jit' must be true or false"),
    ("t_end", True, "'rerun.t_end' must be a number or null"),
    ("file", 3, "'rerun.file' must be a path"),
    ("plots", "no", "'rerun.plots' must be true or false"),
])
def test_rerun_of_an_edited_report_names_the_field(tmp_path, capsys, field, value, words):
    """A hand-edited report whose fields have the wrong types is refused, naming the field
    (a list under 'method' was an internal error; "jit": "no" ran with the JIT on)."""
    spec = dict(GOOD_RERUN, **{field: value})
    (tmp_path / "report.json").write_text(json.dumps({"provenance": {"rerun": spec}}))
    assert main(["run", "--rerun", str(tmp_path)]) == 2
    err = capsys.readouterr().err
    assert "not a spidersim run report" in err and words in err, err


def test_version(capsys):
    import pytest
    with pytest.raises(SystemExit) as exc:
        main(["--version"])
    assert exc.value.code == 0 and capsys.readouterr().out.startswith("spidersim ")


BASE = ("blocks:\n  c: {type: Constant, value: 1}\n  i: {type: Integrator}\n"
        "connections: [c.y -> i.u]\nsimulation: {t_end: 1}\n")


def test_rerun_from_another_folder_checks_the_same_file(tmp_path, capsys, monkeypatch):
    """The hashes are keyed by absolute path: a run started in d3/ and repeated from d/
    warned about nothing after d3/base.yaml was edited (it hashed d/base.yaml, absent:
    'changed' only by chance) and the rerun integrated 5 instead of 1 silently; from the
    parent folder an unchanged file was reported changed."""
    (tmp_path / "d3").mkdir()
    (tmp_path / "d").mkdir()
    src = tmp_path / "d3" / "base.yaml"
    src.write_text(BASE)
    monkeypatch.chdir(tmp_path / "d3")
    assert main(["run", "base.yaml", "--no-plots", "--no-jit", "--out", "../r1"]) == 0
    prov = json.loads((tmp_path / "r1" / "report.json").read_text())["provenance"]
    assert list(prov["file_sha256"]) == [str(src)]
    for folder in (tmp_path, tmp_path / "d"):       # unchanged: no warning from anywhere
        monkeypatch.chdir(folder)
        capsys.readouterr()
        assert main(["run", "--rerun", str(tmp_path / "r1"), "--out", str(tmp_path / "r2")]) == 0
        assert "has changed" not in capsys.readouterr().err
    src.write_text(BASE.replace("value: 1", "value: 5"))
    assert main(["run", "--rerun", str(tmp_path / "r1"), "--out", str(tmp_path / "r3")]) == 0
    assert f"{src} has changed since the reported run" in capsys.readouterr().err


@pytest.mark.parametrize("key, main_file, expected", [
    ("d3/base.yaml", "/w/d3/base.yaml", "/w/d3/base.yaml"),
    ("sub.yaml", "/w/d3/base.yaml", "/w/sub.yaml"),        # the run started in /w
    ("/abs/sub.yaml", "/w/d3/base.yaml", "/abs/sub.yaml"),
])
def test_relative_hash_keys_of_older_reports_resolve_from_the_run_folder(key, main_file,
                                                                         expected):
    """A report written before the keys were absolute gives paths relative to the folder
    the run started in; that folder is the diagram file's path less its key."""
    from spidersim.cli import _hashed_file
    hashes = {"d3/base.yaml": "x", key: "y"}
    assert _hashed_file(key, hashes, main_file) == expected
    assert _hashed_file("sub.yaml", {"../d3/base.yaml": "x"}, main_file) is None


@pytest.mark.parametrize("argv, words", [
    (["run", "--rerun", ""], "--rerun: give a run's results folder or its report.json"),
    (["run", "--rerun", " "], "--rerun: give a run's results folder or its report.json"),
    (["run", "F", "--timeout", "5"], "--timeout applies to a --remote run only"),
    (["run", "F", "--token", "t", "--timeout", "5"],
     "--timeout and --token apply to a --remote run only"),
    (["run", "F", "--method", ""], "--method: unknown method ''; methods: LSODA"),
    (["run", "servo", "--remote", "http://127.0.0.1:9", "--method", "DP54"],
     "--method: not available with --remote"),
    (["run", "servo", "--remote", "http://127.0.0.1:9", "--rerun", "r1", "--no-jit"],
     "--rerun, --no-jit: not available with --remote"),
])
def test_run_options_it_would_ignore_are_refused(tmp_path, capsys, monkeypatch, argv, words):
    """An empty --rerun ran the FILE (or asked for one), a local --timeout or --token and a
    --remote --method or --rerun were ignored without a word, and --method '' compiled
    the diagram before the run named the file instead of the option: each is refused
    before anything is compiled, exit status 2."""
    (tmp_path / "F").write_text(BASE)
    monkeypatch.chdir(tmp_path)
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert words in err and "Traceback" not in err, err
    assert " blocks, " not in err                 # nothing loaded for a run or compiled
    assert not (tmp_path / "results").exists()
