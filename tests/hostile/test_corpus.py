"""The hostile-diagram corpus: every file gets a clear error, exit status 2, no traceback.

Each file in ``diagrams/`` starts with two header lines::

    # expect-line: N
    # expect-words: word1, word2

and ``spidersim check FILE`` and ``spidersim run FILE --out OUT`` must both exit with status
2, print ``FILE:N`` and every word (case-insensitive) on stderr, never a Python traceback, and
write nothing outside OUT (the commands run in an empty working folder). Files that cannot
carry a text header (binary, not UTF-8, empty) have their expectation in ``BINARY`` below.
Payloads in the corpus try to create a file named ``pwned``: it must never appear.
"""
import contextlib
import io
import os
import re
import subprocess
import sys

import pytest

from spidersim import cli

HERE = os.path.dirname(os.path.abspath(__file__))
CORPUS = os.path.join(HERE, "diagrams")
ROOT = os.path.dirname(os.path.dirname(HERE))

BINARY = {
    "a_binary_latin1.yaml": (1, ["not utf-8", "byte offset 9"]),
    "a_binary_junk.yaml": (2, ["not utf-8", "byte offset 128"]),
    "a_binary_nul.yaml": (2, ["nul", "not a text file"]),
    "a_binary_utf16.yaml": (1, ["not utf-8", "byte offset 0"]),
    "a_binary_empty.yaml": (None, ["empty"]),
}


def _expectation(path):
    name = os.path.basename(path)
    if name in BINARY:
        return BINARY[name]
    with open(path, encoding="utf-8") as fh:
        head = [fh.readline(), fh.readline()]
    m1 = re.match(r"# expect-line: (\d+|none)\s*$", head[0])
    m2 = re.match(r"# expect-words: (.*)$", head[1])
    assert m1 and m2, f"{name}: the first two lines must be the expectation header"
    line = None if m1.group(1) == "none" else int(m1.group(1))
    return line, [w.strip().lower() for w in m2.group(1).split(",") if w.strip()]


FILES = sorted(f for f in os.listdir(CORPUS) if f.endswith(".yaml"))


def _run_cli(argv):
    err = io.StringIO()
    with contextlib.redirect_stderr(err), contextlib.redirect_stdout(io.StringIO()):
        code = cli.main(argv)
    return code, err.getvalue()


def _tree(folder):
    return sorted(os.path.relpath(os.path.join(d, f), folder)
                  for d, _, fs in os.walk(folder) for f in fs)


def test_corpus_is_large_enough():
    assert len(FILES) >= 60


@pytest.mark.parametrize("name", FILES)
@pytest.mark.parametrize("command", ["check", "run"])
def test_hostile_file(name, command, tmp_path, monkeypatch):
    path = os.path.join(CORPUS, name)
    line, words = _expectation(path)
    work = tmp_path / "cwd"
    work.mkdir()
    monkeypatch.chdir(work)
    out = tmp_path / "out"
    argv = [command, path] + (["--out", str(out), "--no-plots"] if command == "run" else [])
    code, err = _run_cli(argv)
    assert code == 2, f"exit {code}; stderr:\n{err}"
    assert "Traceback" not in err
    where = f"{name}:{line}:" if line is not None else f"{name}:"
    assert where in err, f"expected '{where}' in:\n{err}"
    for w in words:
        assert w in err.lower(), f"expected '{w}' in:\n{err}"
    # nothing written in the working folder; outside OUT nothing at all
    assert _tree(work) == []
    assert not any(p.name == "pwned" for p in tmp_path.rglob("*"))
    assert not os.path.exists(os.path.join(ROOT, "pwned"))


@pytest.mark.parametrize("name", ["a_alias_bomb_parameters.yaml", "a_nesting_deep_list.yaml",
                                  "a_binary_junk.yaml", "a_expr_deep.yaml"])
def test_real_process_exit_status(name, tmp_path):
    """The same files through the real console entry point: status 2, no traceback, quick
    and small (an alias bomb is refused before it is expanded)."""
    res = subprocess.run([sys.executable, "-m", "spidersim.cli", "check",
                          os.path.join(CORPUS, name)], capture_output=True, text=True,
                         cwd=tmp_path, timeout=60)
    assert res.returncode == 2, res.stderr
    assert "Traceback" not in res.stderr and name in res.stderr


def test_oversized_file(tmp_path, monkeypatch):
    from spidersim.text import limits
    big = tmp_path / "big.yaml"
    big.write_text("description: " + "x" * (limits.MAX_FILE_BYTES + 10) + "\n")
    monkeypatch.chdir(tmp_path)
    code, err = _run_cli(["check", str(big)])
    assert code == 2 and "big.yaml" in err and "limit" in err and "Traceback" not in err


def test_shipped_diagrams_far_inside_the_limits():
    """The limits are generous: the largest shipped file uses a small part of each."""
    from spidersim.text import limits
    sizes = [os.path.getsize(os.path.join(ROOT, p)) for p in
             ["spider.yaml"] + [os.path.join("diagrams", f)
                                for f in os.listdir(os.path.join(ROOT, "diagrams"))
                                if f.endswith(".yaml")]]
    assert max(sizes) < limits.MAX_FILE_BYTES / 20
