"""Parameter sweeps (``spidersim sweep``): grid, Dask execution, metrics, failures, output.

The swept diagram is a point mass hitting an undamped elastic plane at ``v0``; per run the
closed forms are: peak contact force ``v0 sqrt(K m)``, rebound speed ``v0`` and impulse
``2 m v0``. The same 2x3 grid runs serially and on a local Dask cluster of 2 worker
processes and must give the same numbers (same compiled code, same inputs: bit for bit).
"""
from __future__ import annotations

import csv
import math
import os

import numpy as np
import pytest

from spidersim import sweep as sw
from spidersim.cli import main
from spidersim.errors import DiagramError, SpidersimError

DROP = """
name: drop
parameters: {K: 1.0e4, m: 1.0, v0: 1.0}
blocks:
  body: {type: PointMass, m: m, v0: [0, 0, -v0]}
  wall: {type: ElasticContact, point: [0, 0, 0], normal: [0, 0, 1], K: K}
connections:
  - body.pos -> wall.pos
  - body.vel -> wall.vel
  - wall.force -> body.f
simulation: {t_end: 0.08, rtol: 1e-10, atol: 1e-12}
metrics:
  peak_force: {signal: wall.fn, reduce: max, unit: N}
  rebound:    {signal: "body.vel[2]", reduce: final, unit: m/s}
  impulse:    {signal: wall.fn, reduce: integral, unit: N.s}
"""
# x' = a x from x(0) = 1: fine for a = 1, overflows (the integration stalls) for a = 1000
GROW = """
name: grow
parameters: {a: 1.0}
blocks:
  x: {type: Integrator, x0: 1}
  g: {type: Gain, k: a}
connections:
  - x.y -> g.u
  - g.y -> x.u
simulation: {t_end: 1.0, rtol: 1e-9, atol: 1e-12}
metrics:
  x_end: {signal: x.y, reduce: final}
"""
VARY = [("m", [1.0, 4.0]), ("K", [1e4, 1e5, 1e6])]
METRICS = ["peak_force", "rebound", "impulse"]


@pytest.fixture(scope="module")
def drop_file(tmp_path_factory):
    path = tmp_path_factory.mktemp("sweep") / "drop.yaml"
    path.write_text(DROP)
    return str(path)


@pytest.fixture(scope="module")
def grow_file(tmp_path_factory):
    path = tmp_path_factory.mktemp("sweep") / "grow.yaml"
    path.write_text(GROW)
    return str(path)


GROW_VARY = [("a", [1.0, 1e3, -1.0])]     # the middle run overflows


@pytest.fixture(scope="module")
def grow_on_dask(grow_file):
    """The failing grid on a local Dask cluster of 2 workers, run once for the two tests
    that look at it (a row per failure, the message kept), instead of a cluster each."""
    return sw.sweep(grow_file, GROW_VARY, workers=2)


@pytest.fixture(scope="module")
def serial(drop_file):
    return sw.sweep(drop_file, VARY, workers=0)


@pytest.fixture(scope="module")
def on_dask(drop_file):
    return sw.sweep(drop_file, VARY, workers=2)


def test_grid_is_the_product_first_parameter_slowest():
    g = sw.grid(VARY)
    assert len(g) == 6
    assert g[0] == {"m": 1.0, "K": 1e4} and g[1] == {"m": 1.0, "K": 1e5}
    assert g[3] == {"m": 4.0, "K": 1e4} and g[5] == {"m": 4.0, "K": 1e6}


def test_serial_runs_match_the_closed_forms(serial):
    assert [r["status"] for r in serial.rows] == ["ok"] * 6
    for r, pt in zip(serial.rows, sw.grid(VARY)):
        assert {k: r[k] for k in pt} == pt
        m, K = pt["m"], pt["K"]
        # the sampled maximum is within a step of the true peak (error ~ (w dt)^2 / 2)
        assert r["peak_force"] == pytest.approx(math.sqrt(K * m), rel=1e-3)
        assert r["peak_force"] <= math.sqrt(K * m) * (1 + 1e-9)
        assert r["rebound"] == pytest.approx(1.0, rel=1e-7)
        assert r["impulse"] == pytest.approx(2.0 * m, rel=1e-3)


def test_dask_with_two_workers_gives_the_serial_numbers(serial, on_dask):
    assert on_dask.workers == 2
    assert [r["status"] for r in on_dask.rows] == ["ok"] * 6
    for a, b in zip(serial.rows, on_dask.rows):
        assert a["run"] == b["run"] and a["m"] == b["m"] and a["K"] == b["K"]
        for name in METRICS:
            assert a[name] == b[name], (name, a, b)
    # the runs happened in worker processes, not in this one
    here = f"{os.uname().nodename}:{os.getpid()}"
    workers = {r["worker"] for r in on_dask.rows}
    assert here not in workers and 1 <= len(workers) <= 2
    assert {r["worker"] for r in serial.rows} == {here}


def test_runs_never_recompile(serial, on_dask):
    """Compiled once by the caller; every run (here or in a worker) imports it."""
    assert not any(r["compiled"] for r in serial.rows + on_dask.rows)


def test_a_failed_run_is_a_row_with_its_message(grow_on_dask, tmp_path):
    res = grow_on_dask
    status = [r["status"] for r in res.rows]
    assert status == ["ok", "failed", "ok"]
    bad = res.rows[1]
    assert "integration failed at t = " in bad["message"]
    # the table, the CSV and the plots say so too
    assert "run 1 failed: " in res.table()
    path = res.write_csv(tmp_path / "sweep.csv")
    with open(path) as fh:
        rows = list(csv.DictReader(fh))
    assert [r["status"] for r in rows] == status
    assert rows[1]["message"] == bad["message"] and rows[1]["x_end"] == ""
    assert float(rows[2]["x_end"]) == res.rows[2]["x_end"]      # full precision
    pngs = res.plot(str(tmp_path))
    assert [os.path.basename(p) for p in pngs] == ["sweep_x_end.png"]
    assert os.path.getsize(pngs[0]) > 5000


def test_a_bad_value_is_refused_before_any_run(drop_file):
    with pytest.raises(SpidersimError, match=r"--vary K=-5: .*K") as info:
        sw.sweep(drop_file, [("K", [1e4, -5.0, 1e6])], workers=0)
    assert "must be" in str(info.value) or "> 0" in str(info.value)


@pytest.mark.parametrize("path", ["wall.normal", "body.p0"])
def test_a_vector_parameter_cannot_be_swept(drop_file, path):
    """A scalar given to a vector parameter would be spread over its elements."""
    with pytest.raises(SpidersimError, match=f"--vary {path}: a vector parameter "
                                             r"\(3 elements\)"):
        sw.sweep(drop_file, [(path, [1.0, 2.0])], workers=0)


def test_a_non_positive_run_time_is_refused(drop_file):
    with pytest.raises(SpidersimError, match="must be > 0 s, got -1"):
        sw.sweep(drop_file, [("K", [1e4])], workers=0, sim={"t_end": -1.0})


@pytest.mark.parametrize("workers", [0, 2])
def test_a_run_that_fails_while_integrating_keeps_its_message(grow_file, workers, request):
    res = (request.getfixturevalue("grow_on_dask") if workers
           else sw.sweep(grow_file, GROW_VARY, workers=0))
    assert res.workers == workers
    assert [r["status"] for r in res.rows] == ["ok", "failed", "ok"]
    assert res.rows[0]["x_end"] == pytest.approx(math.e, rel=1e-6)
    assert res.rows[2]["x_end"] == pytest.approx(1 / math.e, rel=1e-6)
    bad = res.rows[1]
    assert "integration failed at t = " in bad["message"]
    assert math.isnan(res.value("x_end", a=1e3))
    # how far it got: ln(1.8e308) / 1000 = 0.71 s
    assert 0.5 < bad["t_reached"] < 0.72


def test_existing_scheduler(drop_file):
    """--scheduler: the runs go to a cluster started elsewhere (here: a LocalCluster)."""
    import logging

    from dask.distributed import LocalCluster
    with LocalCluster(n_workers=1, threads_per_worker=1, processes=True,
                      dashboard_address=None, silence_logs=logging.ERROR) as cluster:
        res = sw.sweep(drop_file, [("K", [1e4, 1e6])], scheduler=cluster.scheduler_address)
    assert res.workers == 1
    assert [r["status"] for r in res.rows] == ["ok", "ok"]
    assert res.rows[1]["peak_force"] == pytest.approx(1e3, rel=1e-3)


@pytest.mark.parametrize("address", ["tcp://127.0.0.1:9", "foo"])
def test_unreachable_scheduler_is_a_clear_error(drop_file, address):
    with pytest.raises(SpidersimError, match=f"cannot reach the Dask scheduler at {address}"):
        sw.sweep(drop_file, [("K", [1e4])], scheduler=address, connect_timeout=1.0)


@pytest.mark.parametrize("items, message", [
    ([], "nothing to sweep"),
    (["K"], "expects path=v1,v2"),
    (["K=1,x"], "'x' is not a number"),
    (["K=1,,2"], "empty value"),
    (["K=1", "K=2"], "given twice"),
    (["K=inf"], "not a finite number"),
    # a diagram file refuses these YAML 1.1 forms; --vary read 010 as 10
    (["K=1,010"], "--vary K: '010' has a leading zero, which YAML 1.1 reads as an octal"),
    (["K=-00"], "'-00' has a leading zero"),
    (["K=1:30"], "--vary K: '1:30' is a base-60 number"),
    (["1K=2"], "not a parameter path"),
    (["a=" + ",".join(["1"] * 1000), "b=" + ",".join(["2"] * 101)],
     "the sweep grid has 1000 x 101 = 101,000 runs, more than 100,000"),
])
def test_vary_errors(items, message):
    with pytest.raises(SpidersimError, match=message):
        sw.parse_vary(items)


def test_grid_at_the_run_limit_is_accepted():
    """1000 x 100 = 100,000 runs: exactly the limit, built in full."""
    vary = sw.parse_vary(["a=" + ",".join(map(str, range(1000))),
                          "b=" + ",".join(map(str, range(100)))])
    g = sw.grid(vary)
    assert len(g) == 100_000 and g[-1] == {"a": 999.0, "b": 99.0}


def test_vary_values():
    assert sw.parse_vary(["wall.K=1e4, 2.5e5", "V_ci=20"]) == [("wall.K", [1e4, 2.5e5]),
                                                              ("V_ci", [20.0])]
    assert sw.parse_vary(["k=0,0.5,010.5,-0,1_0"]) == [("k", [0.0, 0.5, 10.5, 0.0, 10.0])]


@pytest.mark.parametrize("entry, message", [
    ("{signal: wall.f, reduce: max}", "no logged signal 'wall.f'; did you mean wall.fn"),
    ("{signal: body.vel, reduce: max}", "has 3 elements; pick one"),
    ("{signal: 'body.vel[3]', reduce: max}", "index 3 out of range"),
    ("{signal: 'body.vel[-4]', reduce: max}", r"index -4 out of range, 'body.vel' has 3 "
                                              r"element\(s\) \(0..2, or -3..-1 from the end\)"),
    ("{signal: 'body.vel[٢]', reduce: max}", r"signal 'body.vel\[٢\]': non-ASCII character "
                                             r"'٢' \(U\+0662 ARABIC-INDIC DIGIT TWO\) at "
                                             r"character 10"),
    ("{signal: wall.fn, reduce: biggest}", "unknown reduce 'biggest'"),
    ("{signal: wall.fn, reduce: max, scale: 2}", "unknown key"),
    # the unit labels the sweep plot's axis: math text matplotlib cannot draw failed the
    # plots after every run (an internal error)
    ("{signal: wall.fn, reduce: max, unit: '$\\\\foo$'}", "math text"),
    ("{signal: wall.fn, reduce: max, unit: \"N\\nm\"}", "one line"),
])
def test_metric_errors_name_the_metric_and_line(tmp_path, entry, message):
    text = DROP.split("metrics:")[0] + f"metrics:\n  bad: {entry}\n"
    path = tmp_path / "bad.yaml"
    path.write_text(text)
    with pytest.raises(DiagramError, match=message) as info:
        sw.sweep(str(path), [("K", [1e4])], workers=0)
    assert "metric 'bad'" in str(info.value)
    assert str(path) in str(info.value) or "bad.yaml" in str(info.value)


def test_a_metric_index_counts_from_the_end(tmp_path):
    """``body.vel[-1]`` is ``body.vel[2]``, as in connections (it was 'no logged signal
    'body.vel[-1]''); the metric keeps the element it names."""
    text = DROP.split("metrics:")[0] + ("metrics:\n  last: {signal: 'body.vel[-1]', reduce: "
                                        "final}\n  third: {signal: 'body.vel[2]', reduce: "
                                        "final}\n  first: {signal: 'body.vel[-3]', reduce: "
                                        "final}\n")
    path = tmp_path / "neg.yaml"
    path.write_text(text)
    res = sw.sweep(str(path), [("K", [1e4])], workers=0)
    row, = res.rows
    assert row["status"] == "ok"
    assert row["last"] == row["third"] == pytest.approx(1.0, rel=1e-3)   # rebound speed
    assert row["first"] == 0.0
    import spidersim
    assert [(m.signal, m.index) for m in sw.parse_metrics(spidersim.load(str(path)))] == [
        ("body.vel", 2), ("body.vel", 2), ("body.vel", 0)]

def test_a_diagram_without_metrics_is_refused(tmp_path):
    path = tmp_path / "nometrics.yaml"
    path.write_text(DROP.split("metrics:")[0])
    with pytest.raises(DiagramError, match="declares no metrics"):
        sw.sweep(str(path), [("K", [1e4])], workers=0)


def test_an_unknown_varied_path_is_refused_before_running(drop_file):
    with pytest.raises(SpidersimError, match="--vary wall.Kx"):
        sw.sweep(drop_file, [("wall.Kx", [1.0])], workers=0)


def test_cli_sweep_writes_table_and_plots(drop_file, tmp_path, capsys):
    out = tmp_path / "out"
    rc = main(["sweep", drop_file, "--vary", "m=1,4", "--vary", "K=1e4,1e6",
               "--workers", "0", "--out", str(out)])
    assert rc == 0
    with open(out / "sweep.csv") as fh:
        rows = list(csv.DictReader(fh))
    assert [(float(r["m"]), float(r["K"])) for r in rows] == [(1, 1e4), (1, 1e6), (4, 1e4),
                                                              (4, 1e6)]
    np.testing.assert_allclose([float(r["peak_force"]) for r in rows],
                               [100, 1000, 200, 2000], rtol=1e-3)
    assert all(r["compiled"] == "no" for r in rows)
    assert sorted(os.listdir(out)) == ["sweep.csv"] + [f"sweep_{m}.png" for m in
                                                       sorted(METRICS)]
    printed = capsys.readouterr()
    assert "4 run(s), 0 failed" in printed.out


def test_a_dask_sweep_leaves_nothing_in_the_temporary_folder(grow_file, tmp_path):
    """A local cluster's scratch space (Dask's default ``<temp>/dask-scratch-space``, with
    lock files that outlive the cluster) is a folder of the sweep's own, removed at the
    end: a sweep in a fresh TMPDIR leaves it empty."""
    import subprocess
    import sys
    tmp = tmp_path / "tmp"
    tmp.mkdir()
    out = tmp_path / "out"
    env = {**os.environ, "TMPDIR": str(tmp)}
    res = subprocess.run([sys.executable, "-m", "spidersim.cli", "sweep", grow_file,
                          "--vary", "a=1,2", "--workers", "1", "--no-plots", "--out",
                          str(out)], capture_output=True, text=True, env=env,
                         cwd=tmp_path, timeout=300)
    assert res.returncode == 0, res.stderr
    assert "2 run(s), 0 failed" in res.stdout
    left = sorted(os.path.relpath(os.path.join(d, f), tmp)
                  for d, ds, fs in os.walk(tmp) for f in ds + fs)
    assert left == []
    assert sorted(os.listdir(out)) == ["sweep.csv"]


def test_cli_sweep_with_a_failed_run_exits_nonzero_after_writing(grow_file, tmp_path,
                                                                 capsys):
    rc = main(["sweep", grow_file, "--vary", "a=1,1e3", "--workers", "0", "--out",
               str(tmp_path), "--no-plots"])
    assert rc == 1
    assert "2 run(s), 1 failed" in capsys.readouterr().out
    with open(tmp_path / "sweep.csv") as fh:
        assert [r["status"] for r in csv.DictReader(fh)] == ["ok", "failed"]


def test_cli_sweep_bad_vary_exits_with_a_message(drop_file, capsys):
    rc = main(["sweep", drop_file, "--vary", "K=1,abc", "--workers", "0"])
    assert rc != 0
    assert "'abc' is not a number" in capsys.readouterr().err


def test_a_parameter_both_set_and_varied_is_refused(drop_file, tmp_path, capsys):
    """--set K=5 with --vary K=...: refused naming K, before the output folder is made
    (the --set was dropped without a word); sweep(set=) says the same."""
    out = tmp_path / "out"
    rc = main(["sweep", drop_file, "--set", "K=5", "--vary", "K=1e4,1e6", "--vary", "m=1",
               "--set", "m=2", "--workers", "0", "--out", str(out)])
    err = capsys.readouterr().err
    assert rc == 2 and "'K', 'm': both set (--set) and varied (--vary)" in err, err
    assert not out.exists()
    with pytest.raises(SpidersimError, match="'K': both set"):
        sw.sweep(drop_file, [("K", [1e4])], set={"K": 5}, workers=0)


# ------------------------------------------------------------------ interrupts
def _interrupt_at(monkeypatch, run):
    """Make run number ``run`` of a sweep end in a KeyboardInterrupt (Ctrl-C in Python)."""
    real = sw.run_point

    def run_point(file, base, point, sim, index=0, *more):
        if index == run:
            raise KeyboardInterrupt
        return real(file, base, point, sim, index, *more)
    monkeypatch.setattr(sw, "run_point", run_point)


def test_ctrl_c_in_a_serial_sweep_carries_the_finished_rows(grow_file, monkeypatch):
    _interrupt_at(monkeypatch, 1)
    with pytest.raises(sw.SweepInterrupted) as exc:
        sw.sweep(grow_file, [("a", [1.0, 2.0, 3.0])], workers=0)
    res = exc.value.result
    assert exc.value.exit_code == 130
    assert [r["status"] for r in res.rows] == ["ok", sw.INTERRUPTED, sw.NOT_RUN]
    assert res.rows[0]["x_end"] == pytest.approx(math.e, rel=1e-6)
    assert [r["run"] for r in res.unfinished] == [1, 2] and res.failed == []


def test_ctrl_c_before_any_run_finished_is_the_plain_interrupt(grow_file, monkeypatch):
    """Nothing computed: the KeyboardInterrupt itself, not an empty table."""
    _interrupt_at(monkeypatch, 0)
    with pytest.raises(KeyboardInterrupt) as exc:
        sw.sweep(grow_file, [("a", [1.0, 2.0])], workers=0)
    assert type(exc.value) is KeyboardInterrupt


# ------------------------------------------------------------------ varied in vain
SHADOW = """
parameters: {a: 1.0, b: 1.0, unused: 0.0}
subsystems: {LAG: lag.yaml}
blocks:
  c: {type: Constant, value: 1}
  g: {type: Gain, k: a}
  h: {type: Gain, k: a*b}
  j: {type: LAG, gain: a}
connections: [c.y -> g.u, g.y -> h.u, h.y -> j.u]
metrics: {y: {signal: j.y, reduce: final}}
"""
LAG = """
parameters: {gain: 1.0}
blocks: {k: {type: Gain, k: gain}}
inputs: {u: k.u}
outputs: {y: k.y}
"""


@pytest.mark.parametrize("vary, base, note", [
    # every use of 'a' (g.k, h.k, j's gain) overridden: its values change nothing
    ([("a", [1, 2]), ("g.k", [1, 2]), ("h.k", [3]), ("j.gain", [1]), ("b", [2])], {},
     "--vary a: its values change nothing in the runs: the block parameter(s) that depend "
     "on 'a' (g.k, h.k, j.k.k) are set themselves by --vary g.k, --vary h.k, --vary j.gain, "
     "--vary b; vary one"),
    ([("a", [1, 2]), ("g.k", [1, 2]), ("c.value", [1, 2]), ("j.k.k", [1])], {"h.k": 2},
     "(g.k, j.k.k) are set themselves by --vary g.k, --vary j.k.k; vary one"),
    ([("unused", [1, 2]), ("a", [1, 2])], {},
     "--vary unused: no block parameter changes with 'unused' over these values (nothing "
     "depends on it, or its values give the same block parameters): its values change "
     "nothing"),
    ([("a", [1, 2])], {"g.k": 1, "h.k": 1, "j.gain": 1},
     "no block parameter changes with 'a' over these values (nothing depends on it once "
     "the --set values are applied"),
    ([("a", [1, 1.0])], {}, "its values give the same block parameters"),
    # one use left (h.k through a*b, j's gain): a real grid, nothing said
    ([("a", [1, 2]), ("g.k", [1, 2]), ("j.gain", [1])], {}, None),
    ([("a", [1, 2]), ("g.k", [1, 2]), ("h.k", [1])], {}, None),
    # b = 0 hides 'a' in h.k = a*b at its first value only
    ([("a", [1, 2]), ("g.k", [1]), ("j.gain", [1]), ("b", [0, 1])], {}, None),
    ([("g.k", [1, 2]), ("b", [1, 2])], {}, None),
    ([("unused", [1])], {}, None),              # one value: nothing varies anyway
])
def test_a_varied_parameter_that_changes_nothing_is_named(tmp_path, vary, base, note):
    """A varied top-level parameter that no run depends on (unused, or every block
    parameter using it overridden by another varied path or a --set) is said, with the
    parameters it reaches and what overrides them; a parameter with one use left is not."""
    from spidersim import load
    (tmp_path / "lag.yaml").write_text(LAG)
    f = tmp_path / "shadow.yaml"
    f.write_text(SHADOW)
    d = load(str(f), set=base)
    uses = {p: sw._check_varied(str(f), base, d, p, v) for p, v in vary}
    notes = sw.ineffective_parameters(str(f), base, vary, uses)
    if note is None:
        assert notes == []
    else:
        assert len(notes) == 1 and note in notes[0], notes


def test_sweep_and_cli_say_a_varied_parameter_changes_nothing(grow_file, tmp_path, capsys):
    """grow.yaml has g.k: a; varying both makes the a column meaningless: warned before
    the runs (a SweepWarning) and again after the table."""
    with pytest.warns(sw.SweepWarning, match="--vary a: its values change nothing"):
        res = sw.sweep(grow_file, [("a", [1.0, 2.0]), ("g.k", [1.0])], workers=0)
    assert res.extra["warnings"] == [
        "--vary a: its values change nothing in the runs: the block parameter(s) that "
        "depend on 'a' (g.k) are set themselves by --vary g.k; vary one of them, not both"]
    assert res.rows[0]["x_end"] == res.rows[1]["x_end"]          # what it warns about
    rc = main(["sweep", grow_file, "--vary", "a=1,2", "--vary", "g.k=1", "--workers", "0",
               "--out", str(tmp_path), "--no-plots"])
    err = capsys.readouterr().err
    assert rc == 0 and err.count("spidersim: warning: --vary a: its values change") == 2
    assert err.rstrip().endswith("vary one of them, not both"), err


# ------------------------------------------------------------------ wall-time limit
# z.Ts = 1e-8 asks for 1e8 samples (the most a run may take): a run that would take hours
with open(os.path.join(os.path.dirname(__file__), "data", "held_sweep.yaml")) as _fh:
    HELD = _fh.read()


def test_run_timeout_stops_a_run_and_the_sweep_goes_on(tmp_path, capsys):
    f = tmp_path / "held.yaml"
    f.write_text(HELD)
    rc = main(["sweep", str(f), "--vary", "z.Ts=0.1,1e-8,0.2", "--workers", "0",
               "--run-timeout", "0.5", "--out", str(tmp_path / "out"), "--no-plots"])
    assert rc == 1
    with open(tmp_path / "out" / "sweep.csv") as fh:
        rows = list(csv.DictReader(fh))
    assert [r["status"] for r in rows] == ["ok", "failed", "ok"]
    assert rows[1]["message"].startswith("stopped: the wall-time limit of 0.5 s per run "
                                         "(--run-timeout) was reached at t = ")
    assert rows[1]["x_end"] == "" and 0 < float(rows[1]["t_reached"]) < 1
    assert 0.5 <= float(rows[1]["wall_s"]) < 20
    assert float(rows[2]["x_end"]) == pytest.approx(math.exp(-1), rel=1e-3)


@pytest.mark.parametrize("value", ["0", "-1", "nan", "inf", "x"])
def test_run_timeout_must_be_a_positive_time(drop_file, capsys, value):
    with pytest.raises(SystemExit) as exc:
        main(["sweep", drop_file, "--vary", "m=1", "--run-timeout", value])
    assert exc.value.code == 2 and "--run-timeout" in capsys.readouterr().err
    with pytest.raises(SpidersimError, match="wall-time limit of a run"):
        sw.sweep(drop_file, [("m", [1.0])], workers=0, run_timeout=float(
            value.replace("x", "nan")))


COLUMNS = """
name: cols
parameters: {run: 1.0, k: 1.0}
blocks:
  c: {type: Constant, value: run}
  g: {type: Gain, k: k}
  i: {type: Integrator}
connections: [c.y -> g.u, g.y -> i.u]
simulation: {t_end: 0.1}
metrics:
  METRIC: {signal: i.y, reduce: final}
"""


@pytest.mark.parametrize("metric, vary, words, line", [
    ("status", [("k", [5.0])], "metric 'status': the name of a column the sweep table has "
                               "already (run, status, t_reached, wall_s", 11),
    ("wall_s", [("k", [5.0])], "metric 'wall_s': the name of a column", 11),
    ("x_end", [("run", [2.0, 3.0])], "--vary run: 'run' names a column of the sweep table",
     None),
    ("k", [("k", [5.0, 7.0])], "metric 'k' has the name of the varied parameter 'k': both "
                               "would be column 'k'", 11),
])
def test_metrics_and_varied_parameters_do_not_take_a_column_twice(tmp_path, metric, vary,
                                                                  words, line):
    """A metric 'status' ran the grid and then failed the progress line (AttributeError,
    exit 3, no sweep.csv); a parameter 'run' and a metric named like a varied parameter
    gave a CSV with two 'run' or two 'k' columns. Each is refused before any run, the
    metric at its line; ``check`` refuses a metric named like a column too."""
    path = tmp_path / "cols.yaml"
    path.write_text(COLUMNS.replace("METRIC", metric))
    with pytest.raises(SpidersimError) as ei:
        sw.sweep(str(path), vary, workers=0)
    assert words in ei.value.message and ei.value.line == line
    if metric in sw.RESERVED:
        assert main(["check", str(path)]) == 2
    if line is None:              # a varied name is refused as the command line is read
        with pytest.raises(SpidersimError, match=words):
            sw.parse_vary(["run=2,3"])


def test_figures_of_values_that_differ_beyond_6_digits_have_their_own_files(tmp_path,
                                                                             capsys):
    """c = 1.0000001 and 1.0000002 as a third varied parameter were both 'c1' in the file
    name and 'c = 1' in the title: 2 plots reported, 1 file. Values are written as short as
    reads back to them; a name still taken (cut at its length limit) gets a number."""
    path = tmp_path / "three.yaml"
    path.write_text("parameters: {a: 1, b: 1, c: 1}\nblocks:\n  k: {type: Constant, "
                    "value: a*b*c}\n  i: {type: Integrator}\nconnections: [k.y -> i.u]\n"
                    "simulation: {t_end: 0.1}\nmetrics:\n  x_end: {signal: i.y, reduce: "
                    "final}\n")
    out = tmp_path / "out"
    assert main(["sweep", str(path), "--vary", "a=1,2", "--vary", "b=1,2", "--vary",
                 "c=1.0000001,1.0000002", "--workers", "0", "--out", str(out)]) == 0
    assert sorted(os.listdir(out)) == ["sweep.csv", "sweep_x_end_c1_0000001.png",
                                       "sweep_x_end_c1_0000002.png"]
    assert "c=1.0000002" in capsys.readouterr().err          # the progress lines too
    m = sw.Metric("x_end", "i.y", None, "final")
    assert sw._figure_title(m, {"c": 1.0000002}).endswith("c = 1.0000002")
    assert sw._figure_title(m, {"c": 20.0}).endswith("c = 20")
    taken = set()
    assert [sw._unique_path("f/a.png", taken) for _ in range(3)] == [
        "f/a.png", "f/a_2.png", "f/a_3.png"]
