"""`spidersim blocks TYPE`: complete plain-text documentation of every block type."""
import pytest

from spidersim.blocks import REGISTRY
from spidersim.text.plain import has_markup, plain


@pytest.mark.parametrize("name", sorted(REGISTRY))
def test_every_block_is_documented_in_plain_text(name):
    cls = REGISTRY[name]
    text = cls.describe()
    assert not has_markup(text), [ln for ln in text.splitlines() if has_markup(ln)][:3]
    assert "module docstring" not in text
    assert len(text) > 150
    for section in (cls.parameters, cls.inputs, cls.outputs):
        for n in section:
            assert f"    {n} [" in text, n


def test_plain_removes_the_markup_the_docstrings_use():
    src = ("Torque ``tau = K_t i`` (:math:`\\tau`), see :func:`~spidersim.a.b`.\n"
           ".. math::\n\n    x' = -x\n\nExample::\n\n    y = 1")
    out = plain(src)
    assert not has_markup(out)
    assert "tau = K_t i" in out and "\\tau" in out and "spidersim.a.b" in out
    assert "x' = -x" in out and "Example:" in out and "Example::" not in out
