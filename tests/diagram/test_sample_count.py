"""A sampled block may take at most ``model.MAX_SAMPLES`` samples in a run: ``Ts: 1e-9``
(a typo for 1e-3) over 1 s was 1e9 time events, about a day of computing with ``check``
saying OK and nothing on the screen but the progress."""
import pytest

import spidersim
from spidersim.diagram import model
from spidersim.errors import DiagramError

DTF = """\
blocks:
  s: {type: Step}
  t: {type: DiscreteTransferFunction, num: [1], den: [1, -0.5], Ts: %s}
connections: [s.y -> t.u]
simulation: {t_end: %s}
"""


def test_too_many_samples_are_refused_at_the_blocks_line():
    d = spidersim.loads(DTF % ("1e-9", "1"))
    with pytest.raises(DiagramError, match=r"DiscreteTransferFunction samples every Ts = "
                       r"1e-09 s: 1e\+09 samples in the run \(t_end = 1 s\)") as e:
        d.check_samples(1.0)
    assert e.value.line == 3 and e.value.block == "t"
    with pytest.raises(DiagramError, match="more than the 1e\\+08"):
        d.simulate()


def test_a_shorter_run_of_the_same_diagram_is_allowed():
    """The limit is on the run, not the file: 1e-9 s over 1e-3 s is 1e6 samples."""
    d = spidersim.loads(DTF % ("1e-9", "1"))
    d.check_samples(1e-3)
    r = d.simulate(t_end=1e-5, jit=False)
    assert r.status == "ok"


def test_the_limit_itself_is_allowed():
    """Exactly MAX_SAMPLES (a 1 us sampler for 100 s: the recording-memory test's run)."""
    d = spidersim.loads(DTF % ("1e-6", "100"))
    d.check_samples(100.0)
    with pytest.raises(DiagramError):
        d.check_samples(100.0 * 1.001)
    assert model.MAX_SAMPLES == 1e8


def test_check_refuses_it_with_exit_status_2(tmp_path, capsys):
    from spidersim.cli import main
    f = tmp_path / "fast.yaml"
    f.write_text(DTF % ("1e-9", "1"))
    assert main(["check", str(f)]) == 2
    err = capsys.readouterr().err
    assert "fast.yaml:3" in err and "1e+09 samples" in err and "Traceback" not in err
