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
