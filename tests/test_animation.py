"""Arm stick-figure animation (``kind: animation``): the GIF and the checks of the entry."""
from __future__ import annotations

import pytest
from PIL import Image

import spidersim
from spidersim.animation import arm_animation
from spidersim.errors import DiagramError
from spidersim.plots import check_plot_specs, make_plots

SMALL = """
name: arm_small
blocks:
  tau: {type: Constant, value: [0, 0, 0, 0, 0, 0, 0]}
  arm: {type: Arm, q0: [0, 0.6, 0, -1.3, 0, 0.8, 0],
        qd0: [0.8, -0.5, 0.6, 0.9, 0.7, -0.6, 1.0]}
connections: [tau.y -> arm.tau]
simulation: {t_end: 0.5}
"""


@pytest.fixture(scope="module")
def result():
    return spidersim.loads(SMALL).simulate(t_end=0.5, jit=False)


def _sizes(r):
    return {s: (1 if r[s].ndim == 1 else r[s].shape[1]) for s in r.names}


def _frames(path):
    with Image.open(path) as im:
        assert im.format == "GIF"
        return im.n_frames


def test_gif_has_the_requested_frames(result, tmp_path):
    path = tmp_path / "arm.gif"
    spec = {"title": "Arm", "kind": "animation", "signals": ["arm.q"], "frames": 12,
            "fps": 10, "trace": True}
    assert arm_animation(result, spec, str(path)) == str(path)
    assert path.read_bytes()[:6] in (b"GIF87a", b"GIF89a")
    assert _frames(path) == 12


def test_time_window_and_defaults(result, tmp_path):
    path = tmp_path / "w.gif"
    arm_animation(result, {"signals": ["arm.q"], "t_min": 0.1, "t_max": 0.3}, str(path))
    assert _frames(path) == 60


def test_make_plots_writes_a_gif_next_to_the_pngs(result, tmp_path):
    plots = [{"title": "Angles", "signals": ["arm.q"]},
             {"title": "Arm motion", "kind": "animation", "signals": ["arm.q"],
              "frames": 5}]
    check_plot_specs(plots, _sizes(result))
    written = make_plots(result, plots, str(tmp_path))
    assert [p.rsplit("/", 1)[-1] for p in written] == ["angles.png", "arm_motion.gif"]
    assert _frames(tmp_path / "arm_motion.gif") == 5


@pytest.mark.parametrize("spec, words", [
    ({"signals": ["arm.q", "arm.qd"]}, ["exactly one signal", "got 2"]),
    ({"signals": ["arm.flange_pos"]}, ["arm.flange_pos", "3 values", "7 joints"]),
    ({"signals": ["arm.q"], "frames": 0}, ["frames"]),
    ({"signals": ["arm.q"], "model": "no_such_arm.yaml"}, ["not found", "no_such_arm"]),
    ({"signals": ["arm.q"], "file": "arm.png"}, [".gif"]),
])
def test_bad_spec_is_a_clear_diagram_error(result, tmp_path, spec, words):
    spec = {"kind": "animation", **spec}
    with pytest.raises(DiagramError) as exc:          # checked before the run ...
        check_plot_specs([{"title": "x", "signals": ["arm.q"]}, spec], _sizes(result))
    assert "plots[1]" in str(exc.value)
    for w in words:
        assert w in str(exc.value)
    with pytest.raises(DiagramError) as exc:          # ... and when drawing
        arm_animation(result, spec, str(tmp_path / "bad.gif"))
    for w in words:
        assert w in str(exc.value)
    assert not (tmp_path / "bad.gif").exists()


def test_names_only_check_catches_the_signal_count(result):
    """The CLI checks against the names of the logged signals (no sizes): the count is
    checked there, the size when drawing."""
    with pytest.raises(DiagramError, match="exactly one signal"):
        check_plot_specs([{"kind": "animation", "signals": ["arm.q", "arm.qd"]}],
                         set(result.names))
    check_plot_specs([{"kind": "animation", "signals": ["arm.flange_pos"]}],
                     set(result.names))


ARM2 = """\
name: two_links
gravity: [0, 0, 0]
links:
  - {d: 0, a: 0.5, alpha: 0, mass: 1, com: [0.25, 0, 0], inertia: [0.01, 0.01, 0.01]}
  - {d: 0, a: 0.5, alpha: 0, mass: 1, com: [0.75, 0, 0], inertia: [0.01, 0.01, 0.01]}
"""

ANIMATED = """\
name: an
blocks:
  tau: {type: Constant, value: [0.1, 0.1]}
  arm: {type: Arm, model: arm2.yaml}
connections: [tau.y -> arm.tau]
simulation: {t_end: 0.2}
plots:
  - {title: motion, kind: animation, signals: [arm.q], model: arm2.yaml, frames: 3}
"""


def test_animation_model_is_beside_the_diagram_like_the_arms(tmp_path, monkeypatch,
                                                             capsys):
    """``model: arm2.yaml`` names the file beside the diagram, as the Arm's own ``model``
    does: run from another folder, check said 'arm data file not found: arm2.yaml'."""
    from spidersim.cli import main
    sub = tmp_path / "anim"
    sub.mkdir()
    (sub / "arm2.yaml").write_text(ARM2)
    (sub / "an.yaml").write_text(ANIMATED)
    monkeypatch.chdir(tmp_path)
    assert main(["check", "anim/an.yaml"]) == 0, capsys.readouterr().err
    assert main(["run", "anim/an.yaml", "--out", "o", "--no-jit"]) == 0
    assert Image.open(tmp_path / "o" / "motion.gif").n_frames == 3
