"""The parts of the ``microgravity`` section check (spidersim.diagram.model), alone on
small sections; loading whole diagrams with the section is tests/test_microgravity.py and
the hostile corpus."""
import pytest

from spidersim.diagram import model as M
from spidersim.errors import DiagramError


def err(msg, key=None):
    """The located-error maker the parts receive: the key goes into the message here."""
    return DiagramError(f"{msg} [{key}]")


def test_keys_known_and_required():
    """Unknown keys are named with the list of keys; signal and mass are required."""
    with pytest.raises(DiagramError, match=r"unknown key 'colour'; keys are f_max, f_min, "
                                           r"mass, signal, window \[colour\]"):
        M._check_microgravity_keys({"signal": "a.y", "mass": 1, "colour": 2}, err)
    with pytest.raises(DiagramError, match="'mass' is required"):
        M._check_microgravity_keys({"signal": "a.y"}, err)
    M._check_microgravity_keys({"signal": "a.y", "mass": 1, "window": [0, 1]}, err)


def test_positive_setting_numbers_expressions_defaults():
    """A number, an expression of the parameters (4.2e5 from m/2 with m = 8.4e5) or the
    default; booleans, zero, infinity and unknown names are refused at the key."""
    scope = {"m": 8.4e5}
    assert M._positive_setting({"mass": "m/2"}, "mass", None, scope, err) == 4.2e5
    assert M._positive_setting({}, "f_max", 300.0, scope, err) == 300.0
    for v, words in ((True, "finite number > 0, got True"), (0, "finite number > 0"),
                     (float("inf"), "finite number > 0"), ("mm", "expression of parameters"),
                     ([1], "expression of parameters")):
        with pytest.raises(DiagramError, match=words):
            M._positive_setting({"mass": v}, "mass", None, scope, err)


def test_time_window():
    """[t0, t1] with 0 <= t0 < t1 as floats; absent is None; reversed, negative, boolean
    or three-element windows are refused."""
    assert M._time_window(None, err) is None
    assert M._time_window([0, 2], err) == (0.0, 2.0)
    for w in ([2, 1], [-1, 2], [True, 2], [0, 1, 2], 3, [1, 1]):
        with pytest.raises(DiagramError, match=r"'window' must be \[t0, t1\]"):
            M._time_window(w, err)
