"""Outputs stay where the user said (issue #12 item 2): the default results folder comes
from a sanitised ``name:``; an unusable ``--out`` is refused before compiling."""
import os

import numpy as np
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


LIN = """\
name: {name!r}
blocks:
  c: {{type: Step}}
  g: {{type: TransferFunction, num: [1], den: [1, 1]}}
connections:
  - c.y -> g.u
simulation: {{t_end: 0.5}}
analysis:
  {analysis}: {{inputs: [c.y], outputs: [g.y]}}
metrics:
  peak: {{signal: g.y, reduce: max}}
"""


def test_linearize_and_sweep_folders_are_sanitised(tmp_path, monkeypatch, capsys):
    """Default folders of linearize and sweep come from the safe stem of ``name:``, and an
    analysis name is an identifier ('../../up' is refused before anything is written):
    nothing is written outside ``results/``."""
    work = tmp_path / "work"
    work.mkdir()
    path = work / "d.yaml"
    path.write_text(LIN.format(name="../../../esc ape", analysis='"../../up"'))
    monkeypatch.chdir(work)
    assert main(["linearize", str(path), "--no-jit"]) == 2
    assert "an analysis name is an identifier" in capsys.readouterr().err
    assert _files(tmp_path) == [os.path.join("work", "d.yaml")]
    path.write_text(LIN.format(name="../../../esc ape", analysis="up"))
    assert main(["linearize", str(path), "--no-jit"]) == 0, capsys.readouterr().err
    assert main(["sweep", str(path), "--vary", "c.after=1,2", "--workers", "0"]) == 0, \
        capsys.readouterr().err
    written = _files(tmp_path)
    assert all(w.startswith(os.path.join("work", "results") + os.sep)
               or w == os.path.join("work", "d.yaml") for w in written), written
    assert os.path.join("work", "results", "esc_ape", "linearize_up", "bode.png") in written
    assert os.path.join("work", "results", "esc_ape_sweep", "sweep_peak.png") in written


@pytest.mark.parametrize("command", ["linearize", "sweep"])
def test_unusable_out_is_refused_before_computing(tmp_path, capsys, command):
    path = tmp_path / "d.yaml"
    path.write_text(LIN.format(name="x", analysis="a"))
    blocker = tmp_path / "blocker"
    blocker.write_text("")
    extra = ["--vary", "c.after=1,2", "--workers", "0"] if command == "sweep" else ["--no-jit"]
    for out in (blocker, blocker / "sub"):
        assert main([command, str(path), "--out", str(out)] + extra) == 2
        cap = capsys.readouterr()
        assert "output folder" in cap.err and "Traceback" not in cap.err
        assert "sweep of" not in cap.err and cap.out == ""      # nothing computed


def test_metric_name_is_an_identifier(tmp_path, capsys):
    path = tmp_path / "d.yaml"
    path.write_text(LIN.format(name="x", analysis="a").replace("  peak:", '  "../../p":'))
    assert main(["check", str(path)]) == 2
    err = capsys.readouterr().err
    assert f"{path}:11:" in err and "identifier" in err


def test_make_plots_refuses_a_path_from_the_api(tmp_path):
    """Direct callers of make_plots get the same confinement as the CLI."""
    import spidersim
    from spidersim.errors import DiagramError
    from spidersim.plots import make_plots
    r = spidersim.loads(DIAGRAM.format(name="x")).simulate(jit=False)
    out = tmp_path / "out"
    for bad in ("../x.png", "/tmp/x.png", "sub/x.png", "x.py"):
        with pytest.raises(DiagramError, match="file"):
            make_plots(r, [{"signals": ["g.y"], "file": bad}], str(out))
    assert not (tmp_path / "x.png").exists() and not os.listdir(out)


def test_full_disk_while_drawing_a_plot(tmp_path, monkeypatch, capsys):
    """ENOSPC in the middle of a PNG: exit 2 naming the plot file, no half-written PNG and
    no temporary left; the data files written before it are complete."""
    import errno

    import matplotlib.figure
    import numpy as np
    path = tmp_path / "d.yaml"
    path.write_text(DIAGRAM.format(name="x").replace("  - signals: [g.y]",
                                                     "  - signals: [g.y]\n    file: gain.png"))

    def full(self, fname, *a, **kw):
        with open(fname, "wb") as fh:
            fh.write(b"\x89PNG partial")
        raise OSError(errno.ENOSPC, "No space left on device")
    monkeypatch.setattr(matplotlib.figure.Figure, "savefig", full)
    out = tmp_path / "out"
    assert main(["run", str(path), "--no-jit", "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert "gain.png" in err and "No space left" in err and "Traceback" not in err
    files = sorted(os.listdir(out))
    assert "gain.png" not in files and not [f for f in files if "tmp" in f], files
    assert np.load(out / "result.npz")["g.y"][0] == 2.0


def test_interrupt_while_writing_removes_the_temporary(tmp_path):
    from spidersim.outputs import atomic_path, write_atomic
    target = tmp_path / "a.csv"
    target.write_text("old complete file")

    def interrupted(fh):
        fh.write("half")
        raise KeyboardInterrupt
    with pytest.raises(KeyboardInterrupt):
        write_atomic(str(target), interrupted)
    with pytest.raises(KeyboardInterrupt):
        with atomic_path(str(tmp_path / "b.png")) as tmp:
            open(tmp, "w").write("half")
            raise KeyboardInterrupt
    assert sorted(os.listdir(tmp_path)) == ["a.csv"]
    assert target.read_text() == "old complete file"


def test_safe_stem():
    from spidersim.outputs import safe_stem
    assert safe_stem("../../x") == "x"
    assert safe_stem("/etc/passwd") == "etc_passwd"
    assert safe_stem("..", "file stem") == "file_stem"
    assert safe_stem("", None, "..") == "diagram"
    assert safe_stem("a" * 500) == "a" * 80
    assert safe_stem("süß\n\"x\"") == "s_x"


def test_csv_only_up_to_its_size_limit(tmp_path, monkeypatch):
    """result.csv holds every value as text (about 3x the binary record): written up to
    CSV_MAX_VALUES values; a larger record is in result.npz only, report.txt says so, and a
    table left by an earlier run in the folder is removed (it would pass for this run's)."""
    import spidersim
    from spidersim.solver import result as res
    r = spidersim.loads("blocks:\n  c: {type: Constant, value: 2}\n  i: {type: Integrator}\n"
                        "connections:\n  - c.y -> i.u\n").simulate(t_end=1.0, jit=False,
                                                                    output_interval=0.01)
    n = r.csv_values()
    assert n == len(r.t) * (1 + len(list(r.columns())))
    r.save(tmp_path)
    assert (tmp_path / "result.csv").stat().st_size > 0
    monkeypatch.setattr(res, "CSV_MAX_VALUES", n - 1)
    r.save(tmp_path)
    assert not (tmp_path / "result.csv").exists()
    assert f"result.csv: not written ({n:,} values" in (tmp_path / "report.txt").read_text()
    back = res.Result.load(tmp_path)
    assert np.array_equal(back["i.y"], r["i.y"])


def test_meta_json_is_strict_json():
    """report.json / meta.json are written by write_meta_json: strict JSON (RFC 8259 has no
    Infinity or NaN; they were written as such and broke the service's job list), every
    non-finite number as null, in the head and in the event times."""
    import io
    import json
    from spidersim.solver.result import write_meta_json
    fh = io.StringIO()
    write_meta_json(fh, {"stats": {"t_reached": float("inf"), "x": [1.0, float("nan")]}},
                    [(float("-inf"), "b", "e"), (0.5, "b", "e")], indent=1)

    def refuse(name):
        raise ValueError(f"{name} in the JSON")
    js = json.loads(fh.getvalue(), parse_constant=refuse)
    assert js["stats"] == {"t_reached": None, "x": [1.0, None]}
    assert js["events"] == [[None, "b", "e"], [0.5, "b", "e"]]


def _fifo_reader(path):
    """Start a thread reading FIFO ``path`` to its end; returns (thread, chunks)."""
    import threading
    chunks = []

    def read():
        with open(path, "rb") as fh:
            chunks.append(fh.read())
    th = threading.Thread(target=read, daemon=True)
    th.start()
    return th, chunks


def test_special_files_are_written_through_not_replaced(tmp_path, capsys):
    """``schema -o`` onto a FIFO delivers the schema to its reader and the FIFO stays a
    FIFO (the write-then-rename replaced it by a regular file; as root /dev/null too);
    write_atomic and atomic_path onto /dev/null leave it a character device; a regular
    file is still replaced atomically. A FIFO nobody reads is an error at once (opened
    without blocking), not a wait forever."""
    import json
    import stat
    from spidersim.outputs import atomic_path, is_special, write_atomic
    fifo = tmp_path / "fifo"
    os.mkfifo(fifo)
    th, chunks = _fifo_reader(fifo)
    assert main(["schema", "-o", str(fifo)]) == 0
    th.join(30)
    assert stat.S_ISFIFO(os.stat(fifo).st_mode)
    assert json.loads(chunks[0])["$schema"].startswith("https://json-schema.org/")
    with pytest.raises(OSError, match="a FIFO that no process is reading"):
        write_atomic(str(fifo), lambda fh: fh.write("nobody reads"))   # not a hang
    assert main(["schema", "-o", str(fifo)]) == 2
    assert "no process is reading" in capsys.readouterr().err
    write_atomic(os.devnull, lambda fh: fh.write("x"))
    with atomic_path(os.devnull) as p:
        assert p == os.devnull
        open(p, "w").write("y")
    assert stat.S_ISCHR(os.stat(os.devnull).st_mode)
    assert is_special(os.devnull) and not is_special(tmp_path) and not is_special(fifo / "no")
    reg = tmp_path / "r.txt"
    reg.write_text("old")
    write_atomic(str(reg), lambda fh: fh.write("new"))
    assert reg.read_text() == "new" and sorted(os.listdir(tmp_path)) == ["fifo", "r.txt"]


RUN = """\
name: two
blocks:
  c: {type: Constant, value: 1}
  g: {type: Gain, k: 2}
connections: [c.y -> g.u]
simulation: {t_end: 0.01}
plots:
  - {title: Gain out, signals: [g.y]}
"""


def test_second_run_removes_the_first_runs_files_and_lists_its_own(tmp_path, capsys):
    """A first run writes its plot; a second run into the same --out with --no-plots
    removes it (the first report.json listed it), keeps a file of the user's, and lists
    its own files in report.txt and report.json."""
    import json
    path = tmp_path / "d.yaml"
    path.write_text(RUN)
    out = tmp_path / "o"
    assert main(["run", str(path), "--out", str(out), "--no-jit"]) == 0
    assert "gain_out.png" in os.listdir(out)
    (out / "mine.png").write_text("user's")
    capsys.readouterr()
    assert main(["run", str(path), "--out", str(out), "--no-jit", "--no-plots"]) == 0
    assert "removed the previous run's gain_out.png" in capsys.readouterr().err
    own = ["result.npz", "result.csv", "report.txt", "report.json"]
    assert sorted(os.listdir(out)) == sorted(own + ["mine.png"])
    assert json.loads((out / "report.json").read_text())["files"] == own
    assert "files of this run: " + ", ".join(own) in (out / "report.txt").read_text()


def test_empty_out_and_dotdot_out(tmp_path, monkeypatch, capsys):
    """``--out ""`` is refused (it meant results/<name> without a word) for run, linearize
    and sweep; ``--out x/../y`` writes into y and does not create x."""
    path = tmp_path / "d.yaml"
    path.write_text(RUN)
    monkeypatch.chdir(tmp_path)
    for argv in (["run", str(path)], ["linearize", str(path), "--input", "c.y", "--output",
                                       "g.y"], ["sweep", str(path), "--vary", "g.k=1"]):
        with pytest.raises(SystemExit) as ei:
            main(argv + ["--out", ""])
        assert ei.value.code == 2
        assert "--out: must name a folder" in capsys.readouterr().err
    assert not (tmp_path / "results").exists()
    assert main(["run", str(path), "--out", "x/../y", "--no-jit", "--no-plots"]) == 0
    assert (tmp_path / "y" / "result.npz").exists() and not (tmp_path / "x").exists()


def test_report_and_summary_keep_the_digits_of_the_times(tmp_path, capsys):
    """t_end 1.0000001 was printed as 1 in report.txt and in the CLI's last line (a hostile
    review, session 12); both now keep the digits (report.json and result.csv did)."""
    path = tmp_path / "d.yaml"
    path.write_text("blocks:\n  c: {type: Constant, value: 1}\n"
                    "simulation: {t_end: 1.0000001, rtol: 1.5e-7}\nlog: [c.y]\n")
    assert main(["run", str(path), "--out", str(tmp_path / "o"), "--no-plots"]) == 0
    cap = capsys.readouterr()
    assert "done: t = 1.0000001 s" in cap.out + cap.err
    text = (tmp_path / "o" / "report.txt").read_text()
    assert "t_end: 1.0000001\n" in text and "t_reached: 1.0000001\n" in text
    assert "rtol: 1.5e-07\n" in text


def test_report_counts_events_by_block_and_kind(tmp_path, capsys):
    """A sampled block logs every sample (spider.yaml: 140,011 events, all controller
    samples in the first 20 shown): report.txt counts the events per block and kind, most
    frequent first, so the step's one event is visible beside 101 samples."""
    path = tmp_path / "d.yaml"
    path.write_text("blocks:\n  s: {type: Step, t_step: 0.55}\n"
                    "  h: {type: ZeroOrderHold, Ts: 0.01}\nconnections:\n  - s.y -> h.u\n"
                    "simulation: {t_end: 1}\nlog: [h.y]\n")
    assert main(["run", str(path), "--out", str(tmp_path / "o"), "--no-plots"]) == 0
    text = (tmp_path / "o" / "report.txt").read_text()
    line = [ln for ln in text.splitlines() if ln.startswith("events by block and kind")]
    assert line == ["events by block and kind (2): h time 101, s time 1"], text


def test_event_counts_of_a_list_and_of_the_compiled_log_agree():
    from spidersim.solver.result import EventLog, event_counts
    entries = [(0.0, "h", "time"), (0.1, "s", "time"), (0.1, "h", "time"), (0.2, "b", "impact")]
    log = EventLog(np.array([e[0] for e in entries]), np.array([0, 1, 0, 2]),
                   ["h", "s", "b"], ["time", "time", "impact"])
    expect = [(("h", "time"), 2), (("b", "impact"), 1), (("s", "time"), 1)]
    assert event_counts(entries) == expect and event_counts(log) == expect


MG_PLOT = """\
name: mgp
blocks:
  s: {{type: Sine, f: 10, amplitude: 1}}
simulation: {{t_end: 1, output_interval: 0.001, method: DP54}}
microgravity: {{signal: s.y, mass: 1000, f_min: 5, f_max: 20}}
plots:
  - {plot}
"""


def test_a_plot_file_named_like_the_microgravity_plot_is_refused(tmp_path, capsys):
    """``file: microgravity.png`` was overwritten by the assessment's plot (2 plots
    reported, one file, listed twice): check and run refuse it at the key's line."""
    f = tmp_path / "mgp.yaml"
    f.write_text(MG_PLOT.format(plot="{title: my sine, signals: [s.y], "
                                     "file: Microgravity.png}"))
    for argv in (["check", str(f)], ["run", str(f), "--out", str(tmp_path / "o")]):
        assert main(argv) == 2
        err = capsys.readouterr().err
        assert "mgp.yaml:7: plots[0]: 'file' 'Microgravity.png' is reserved for the " \
               "microgravity assessment's plot" in err, err


def test_a_plot_titled_microgravity_is_renamed(tmp_path, capsys):
    import json
    f = tmp_path / "mgp.yaml"
    f.write_text(MG_PLOT.format(plot="{title: Microgravity, signals: [s.y]}"))
    out = tmp_path / "o"
    assert main(["run", str(f), "--out", str(out), "--no-jit"]) == 0
    files = json.loads((out / "report.json").read_text())["files"]
    assert "microgravity.png" in files and "microgravity_1.png" in files
    assert len(files) == len(set(files))
    assert (out / "microgravity_1.png").stat().st_size > 1000
