"""The parts of ``validate_run`` (what ``spidersim check`` and ``run`` refuse before
integrating), alone on a stand-in for a loaded diagram: no compilation, no run. The hostile
corpus checks the same messages through the command line."""
import math
from types import SimpleNamespace

import pytest

from spidersim import cli
from spidersim.errors import DiagramError


def diagram(**simulation):
    """A stand-in with the ``simulation`` settings given, each on its own line 10, 11, ..."""
    lines = {k: 10 + i for i, k in enumerate(simulation)}
    return SimpleNamespace(file="d.yaml", simulation=simulation,
                           spec=SimpleNamespace(simulation_lines=lines))


def test_method_from_the_file_or_the_command_line():
    """A method from the file is reported at its line with the nearest name; one from the
    command line (``--method``) without a line."""
    with pytest.raises(DiagramError, match="simulation.method: unknown method 'LSODAA' "
                                           "\\(did you mean 'LSODA'\\?\\)") as ei:
        cli._check_method(diagram(method="LSODAA"), None)
    assert ei.value.line == 10
    with pytest.raises(DiagramError, match="--method: unknown method 'rk4'") as ei:
        cli._check_method(diagram(method="LSODA"), "rk4")
    assert ei.value.line is None
    assert cli._check_method(diagram(method="LSODA"), None) == "LSODA"


@pytest.mark.parametrize("t_end", [0, -1.0, math.inf, math.nan, "1", True])
def test_t_end_must_be_a_finite_positive_time(t_end):
    """Zero, negative, infinite, NaN, text, a boolean (``True`` is an int to Python, not a
    time: it was accepted as 1 s): refused, naming the source (``--t-end``)."""
    with pytest.raises(DiagramError, match="--t-end: t_end must be a finite time > 0 s"):
        cli._check_t_end(diagram(t_end=1.0), t_end)


def test_t_end_default_and_step_settings():
    """Without ``--t-end`` the file's value is used; output_interval may equal t_end but
    not exceed it; first_step must be shorter than t_end; tolerances must be finite."""
    d = diagram(t_end=2.0, output_interval=2.0, first_step=1e-3, rtol=1e-6)
    assert cli._check_t_end(d, None) == 2.0
    cli._check_simulation_steps(d, 2.0)
    with pytest.raises(DiagramError, match="output_interval \\(2 s\\) is longer than the "
                                           "run \\(t_end = 1 s\\)") as ei:
        cli._check_simulation_steps(d, 1.0)
    assert ei.value.line == 11
    with pytest.raises(DiagramError, match="first_step \\(1 s\\) must be shorter"):
        cli._check_simulation_steps(diagram(first_step=1.0), 1.0)
    with pytest.raises(DiagramError, match="simulation.rtol must be finite, got inf"):
        cli._check_simulation_steps(diagram(rtol=math.inf), 1.0)


def test_analysis_time():
    """``at`` is None, 'initial', 'trim', an operating point or a time within the run."""
    assert all(cli._valid_analysis_time(at, 2.0)
               for at in (None, "initial", "trim", {"x": 1}, 0, 2.0))
    assert not any(cli._valid_analysis_time(at, 2.0)
                   for at in ("end", -0.1, 2.5, True, [1]))


def test_t_end_bool_from_the_settings_is_refused_at_its_line():
    """A boolean that reached the settings (the API, not the YAML loader, which refuses it
    earlier) is refused at the line of ``t_end``, not run for 1 s."""
    with pytest.raises(DiagramError, match="simulation.t_end: t_end must be a finite time "
                                           "> 0 s, got True") as ei:
        cli._check_t_end(diagram(t_end=True), None)
    assert ei.value.line == 10
