"""The parts of the sweep figures (spidersim.sweep.SweepResult.plot) on hand-made rows: which
runs go on which curve of which figure, titles and file names. Nothing is simulated; only
the last test draws (one small PNG). Real sweeps are tests/test_sweep.py."""
import os

import pytest

from spidersim import sweep as sw

METRIC = sw.Metric("x_end", "x.y", None, "final", "m")


def result(vary):
    """A SweepResult over the full grid of ``vary`` with x_end = sum of the parameters;
    the run with every parameter at its second value failed."""
    import itertools
    rows = []
    for k, combo in enumerate(itertools.product(*[v for _, v in vary])):
        point = dict(zip([p for p, _ in vary], combo))
        failed = all(point[p] == v[1] for p, v in vary if len(v) > 1)
        rows.append({"run": k, **point, "status": "failed" if failed else "ok",
                     **({} if failed else {"x_end": sum(combo)})})
    return sw.SweepResult("f.yaml", vary, [METRIC], rows, 0.0, 1)


def test_one_parameter_is_one_curve_with_its_failed_run():
    """With one parameter there is one figure and one unlabelled curve; the failed run is
    on it as a failed point, not as a value."""
    res = result([("a", [1.0, 2.0, 3.0])])
    assert res.figures() == [{}]
    (curve,) = res.curves({})
    assert curve.label is None
    assert [r["a"] for r in curve.ok] == [1.0, 3.0] and [r["a"] for r in curve.failed] == [2.0]


@pytest.mark.parametrize("status", [sw.INTERRUPTED, sw.NOT_RUN])
def test_an_unfinished_run_is_neither_a_value_nor_a_failure(status):
    """An interrupted sweep's unfinished runs have no value and did not fail: they are not
    drawn (a failure's cross would say the run failed)."""
    res = result([("a", [1.0, 2.0, 3.0])])
    res.rows[2] = {"run": 2, "a": 3.0, "status": status}
    (curve,) = res.curves({})
    assert [r["a"] for r in curve.ok] == [1.0] and [r["a"] for r in curve.failed] == [2.0]
    assert [r["run"] for r in res.failed] == [1] and [r["run"] for r in res.unfinished] == [2]


def test_second_parameter_gives_one_curve_per_value():
    """Each value of the second parameter is a labelled curve holding exactly its runs."""
    res = result([("a", [1.0, 2.0]), ("b", [0.5, 1.5])])
    curves = res.curves({})
    assert [c.label for c in curves] == ["b = 0.5", "b = 1.5"]
    assert [[r["x_end"] for r in c.ok] for c in curves] == [[1.5, 2.5], [2.5]]
    assert [len(c.failed) for c in curves] == [0, 1]


def test_third_parameter_gives_one_figure_per_value():
    """A third parameter makes one figure per value; its curves hold only the runs at that
    value, and the title and file name carry it."""
    res = result([("a", [1.0, 2.0]), ("b", [0.5, 1.5]), ("c", [10.0, 20.0])])
    assert res.figures() == [{"c": 10.0}, {"c": 20.0}]
    rows = [r for c in res.curves({"c": 20.0}) for r in c.ok + c.failed]
    assert len(rows) == 4 and {r["c"] for r in rows} == {20.0}
    assert sw._figure_title(METRIC, {"c": 20.0}) == "x_end (final of x.y), c = 20"
    assert sw._figure_path("out", METRIC, {"c": 20.0}) == os.path.join(
        "out", "sweep_x_end_c20.png")


def test_plot_writes_one_png_per_metric_and_figure(tmp_path):
    """plot() writes one file per figure and metric, named as _figure_path says."""
    pytest.importorskip("matplotlib")
    res = result([("a", [1.0, 2.0]), ("b", [0.5, 1.5]), ("c", [10.0, 20.0])])
    files = res.plot(str(tmp_path))
    assert [os.path.basename(f) for f in files] == ["sweep_x_end_c10.png",
                                                    "sweep_x_end_c20.png"]
    assert all(os.path.getsize(f) > 5000 for f in files)
