"""Renamed parameters (issue 17, item 6): the current names are the ones of the README's
names table; an old name is still accepted for one release with a warning that says where
(file:line) and what the new name is, gives the same result, and both names at once is an
error."""
import subprocess
import sys
import warnings

import numpy as np
import pytest

import spidersim
from spidersim.blocks import REGISTRY
from spidersim.errors import ParameterError, RenamedParameterWarning

SERVO_LIKE = """\
blocks:
  v: {type: Constant, value: 12}
  motor:
    type: DCMotor
    R: 1.2
    %s: 0.05
connections:
  - v.y -> motor.v
simulation: {t_end: 0.05}
"""


def test_old_name_gives_the_same_run_with_a_located_warning(tmp_path):
    """DCMotor's K (now K_t): same trajectory to the last bit, one warning naming the
    file, the line of 'K:' and both names."""
    new = spidersim.loads(SERVO_LIKE % "K_t").simulate(jit=False)
    p = tmp_path / "old.yaml"
    p.write_text(SERVO_LIKE % "K")
    with warnings.catch_warnings(record=True) as w:
        warnings.simplefilter("always")
        old = spidersim.load(str(p)).simulate(jit=False)
    msgs = [str(x.message) for x in w if issubclass(x.category, RenamedParameterWarning)]
    assert len(msgs) == 1, msgs
    assert msgs[0].startswith(f"{p}:6: DCMotor: parameter 'K' is now called 'K_t'")
    assert np.array_equal(old["motor.w"], new["motor.w"])


def test_both_names_at_once_is_an_error_at_the_old_names_line(tmp_path):
    p = tmp_path / "both.yaml"
    p.write_text((SERVO_LIKE % "K_t").replace("    R: 1.2\n", "    R: 1.2\n    K: 0.06\n"))
    with pytest.raises(ParameterError) as ei:
        spidersim.load(str(p))
    assert ei.value.line == 6 and "'K' is the old name of 'K_t'" in str(ei.value)


def test_a_bound_violation_under_the_old_name_points_at_its_line(tmp_path):
    p = tmp_path / "neg.yaml"
    p.write_text((SERVO_LIKE % "K").replace("K: 0.05", "K: -1"))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        with pytest.raises(ParameterError) as ei:
            spidersim.load(str(p))
    assert ei.value.line == 6 and "'K_t'" in str(ei.value) and "> 0" in str(ei.value)


def test_set_accepts_the_old_name():
    d = spidersim.loads(SERVO_LIKE % "K_t")
    with pytest.warns(RenamedParameterWarning, match="'K' is now called 'K_t'"):
        d.set("motor.K", 0.07)
    assert d.blocks["motor"].params["K_t"] == 0.07


def test_cli_prints_the_warning_on_one_line(tmp_path):
    p = tmp_path / "old.yaml"
    p.write_text(SERVO_LIKE % "K")
    out = subprocess.run([sys.executable, "-m", "spidersim.cli", "check", str(p)],
                         capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr
    line = [ln for ln in out.stderr.splitlines() if "is now called" in ln]
    assert line == [f"spidersim: warning: {p}:6: DCMotor: parameter 'K' is now called "
                    f"'K_t' (the names table in the README); 'K' is accepted until "
                    f"spidersim 0.2"], out.stderr


@pytest.mark.parametrize("name", sorted(n for n, c in REGISTRY.items() if c.renamed))
def test_every_renamed_parameter_maps_to_a_declared_one(name):
    cls = REGISTRY[name]
    for old, new in cls.renamed.items():
        assert new in cls.parameters and old not in cls.parameters
