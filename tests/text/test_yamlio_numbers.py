"""Numbers in a diagram file beyond the float range: the loader (spidersim.text.yamlio)
refuses a float literal that would be read as infinity (``1.0e+400``), at its line;
``.inf`` is the explicit spelling of infinity and stays."""
import math

import pytest

from spidersim.errors import DiagramError
from spidersim.text.yamlio import load_text, number_problem


@pytest.mark.parametrize("text", ["1.0e+400", "-1.5e+400", "1_0.0e+308", "1.8e+308"])
def test_a_float_literal_beyond_the_float_range_is_refused(text):
    """Was read as inf silently (a limit, a Step time that may be infinite took it)."""
    with pytest.raises(DiagramError, match=r"beyond the float range .*write \.inf") as ei:
        load_text(f"parameters:\n  tau: {text}\n", "d.yaml")
    assert ei.value.line == 2
    assert "beyond the float range" in number_problem(text)


@pytest.mark.parametrize("text, want", [(".inf", math.inf), ("-.Inf", -math.inf),
                                        ("+.INF", math.inf), ("1.7e+308", 1.7e308)])
def test_inf_spelt_out_and_large_finite_numbers_load(text, want):
    """The explicit infinity and the largest floats are kept; ``.nan`` loads (refused where
    it is used)."""
    assert load_text(f"a: {text}\n", "d.yaml")["a"] == want
    assert math.isnan(load_text("a: .nan\n", "d.yaml")["a"])
