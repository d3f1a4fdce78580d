"""Outputs stay where the user said (issue #12 item 2): the default results folder comes
from a sanitised ``name:``; an unusable ``--out`` is refused before compiling."""
import os

import pytest

from spidersim.cli import main

DIAGRAM = """\
name: {name!r}
blocks:
  c: {{type: Constant, value: 1}}
  g: {{type: Gain, k: 2}}
connections:
  - c.y -> g.u
simulation: {{t_end: 0.01}}
plots:
  - signals: [g.y]
"""


def _files(folder):
    return sorted(os.path.relpath(os.path.join(d, f), folder)
                  for d, _, fs in os.walk(folder) for f in fs)


@pytest.mark.parametrize("name,folder", [
    ("../../escape", "escape"),
    ("/abs/path/x", "abs_path_x"),
    ("a b/c\\d", "a_b_c_d"),
    ("..", "diagram"),            # nothing left: the file's stem
    ("servo-2_ok", "servo-2_ok"),
])
def test_default_folder_is_a_sanitised_name(tmp_path, monkeypatch, capsys, name, folder):
    work = tmp_path / "work"
    work.mkdir()
    path = work / "diagram.yaml"
    path.write_text(DIAGRAM.format(name=name))
    monkeypatch.chdir(work)
    assert main(["run", str(path), "--no-jit"]) == 0, capsys.readouterr().err
    written = _files(tmp_path)
    assert written and all(w.startswith(os.path.join("work", "results", folder) + os.sep)
                           or w == os.path.join("work", "diagram.yaml") for w in written), written


def test_out_that_is_a_file_is_refused_before_compiling(tmp_path, capsys):
    path = tmp_path / "d.yaml"
    path.write_text(DIAGRAM.format(name="x"))
    blocker = tmp_path / "blocker"
    blocker.write_text("")
    for out in (blocker, blocker / "sub"):
        assert main(["run", str(path), "--out", str(out), "--no-jit"]) == 2
        err = capsys.readouterr().err
        assert "output folder" in err and "Traceback" not in err and "compiling" not in err
