"""Notebook and script use (issue #16 item 8): no backend forced on import, Result.plot,
Result.to_dataframe, the HTML repr."""
import os
import subprocess
import sys

import numpy as np

import spidersim

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


def test_importing_does_not_choose_a_backend():
    code = ("import matplotlib; matplotlib.use('svg'); import spidersim, spidersim.plots, "
            "spidersim.animation; print(matplotlib.get_backend())")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         env={k: v for k, v in os.environ.items() if k != "MPLBACKEND"})
    assert out.returncode == 0 and out.stdout.strip() == "svg", out.stderr


def _servo():
    d = spidersim.load(os.path.join(ROOT, "diagrams", "servo.yaml"))
    return d.simulate(t_end=0.05, jit=False)


def test_plot_returns_a_figure_with_one_panel_per_unit():
    r = _servo()
    fig = r.plot(["motor.w", "motor.i", "motor.phi"])
    units = {r.units[n] for n in ("motor.w", "motor.i", "motor.phi")}
    assert len(fig.axes) == len(units)
    line = fig.axes[0].lines[0]
    assert np.array_equal(line.get_xdata(), r.t)
    assert len(r.plot(["motor.w", "motor.i"], one_panel=True).axes) == 1


def test_dataframe_and_html():
    r = _servo()
    df = r.to_dataframe()
    assert list(df.columns) == [h for h, _ in r.columns()]
    assert np.array_equal(df.index.to_numpy(), r.t)
    assert np.array_equal(df["motor.w"].to_numpy(), r["motor.w"])
    assert df.attrs["units"]["motor.w"] == r.units["motor.w"]
    html = r._repr_html_()
    assert "<table>" in html and "motor.w" in html and r.units["motor.w"] in html
