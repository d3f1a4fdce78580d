"""Mux, Demux and Selector: exact element routing."""
import numpy as np
import pytest

import spidersim
from spidersim import ParameterError

from .harness import Probe, simulate


def test_mux_concatenates_in_order():
    sizes = {"u1": 2, "u2": 1, "u3": 3}
    p = Probe("Mux", {"n": 3}, sizes=sizes)
    vals = {"u1": [1.0, 2.0], "u2": [3.0], "u3": [4.0, 5.0, 6.0]}
    for n, v in vals.items():
        p.set_input(n, v)
    y = p.outputs()["y"]
    np.testing.assert_array_equal(y, [1.0, 2.0, 3.0, 4.0, 5.0, 6.0])
    assert p.layout.ports[("out", "y")].size == 6


def test_mux_default_two_inputs():
    p = Probe("Mux", {}, sizes={"u1": 1, "u2": 2})
    p.set_input("u1", 7.0)
    p.set_input("u2", [8.0, 9.0])
    np.testing.assert_array_equal(p.outputs()["y"], [7.0, 8.0, 9.0])


def test_demux_splits_by_sizes():
    p = Probe("Demux", {"sizes": [2, 1, 3]}, sizes={"u": 6})
    assert p.outputs_names == ["y1", "y2", "y3"]
    p.set_input("u", np.arange(6.0) + 10)
    out = p.outputs()
    np.testing.assert_array_equal(out["y1"], [10.0, 11.0])
    np.testing.assert_array_equal(out["y2"], [12.0])
    np.testing.assert_array_equal(out["y3"], [13.0, 14.0, 15.0])


def test_demux_rejects_size_mismatch():
    with pytest.raises(ParameterError, match="add up to 3"):
        spidersim.loads("blocks:\n  c: {type: Constant, value: [1, 2, 3, 4]}\n"
                        "  d: {type: Demux, sizes: [1, 2]}\nconnections:\n  - c.y -> d.u\n")


def test_demux_rejects_non_integer_sizes():
    with pytest.raises(ParameterError, match="integers"):
        spidersim.loads("blocks:\n  c: {type: Constant, value: [1, 2, 3]}\n"
                        "  d: {type: Demux, sizes: [1.5, 1.5]}\nconnections:\n  - c.y -> d.u\n")


def test_selector_picks_and_repeats():
    p = Probe("Selector", {"index": [3, 0, 3, 1]}, sizes={"u": 4})
    p.set_input("u", [5.0, 6.0, 7.0, 8.0])
    np.testing.assert_array_equal(p.outputs()["y"], [8.0, 5.0, 8.0, 6.0])


@pytest.mark.parametrize("index", ["[3]", "[0.5]"])
def test_selector_rejects_bad_index(index):
    with pytest.raises(ParameterError, match="index"):
        spidersim.loads(f"blocks:\n  c: {{type: Constant, value: [1, 2, 3]}}\n"
                        f"  s: {{type: Selector, index: {index}}}\nconnections:\n"
                        f"  - c.y -> s.u\n")


def test_mux_demux_selector_round_trip_in_a_simulation():
    """Sine and Ramp muxed with a constant pair, split again and re-ordered."""
    text = """
blocks:
  a: {type: Sine, f: 2}
  b: {type: Ramp, slope: 3}
  c: {type: Constant, value: [10, 20]}
  m: {type: Mux, n: 3}
  d: {type: Demux, sizes: [3, 1]}
  s: {type: Selector, index: [3, 0]}
connections:
  - a.y -> m.u1
  - b.y -> m.u2
  - c.y -> m.u3
  - m.y -> d.u, s.u
"""
    r = simulate(text, t_end=1.0, output_interval=0.1)
    t = r.t
    np.testing.assert_allclose(r["m.y"][:, 0], np.sin(4 * np.pi * t), atol=1e-14)
    np.testing.assert_allclose(r["d.y1"], np.column_stack(
        [np.sin(4 * np.pi * t), 3 * t, np.full_like(t, 10.0)]), atol=1e-14)
    np.testing.assert_array_equal(r["d.y2"], np.full_like(t, 20.0))
    np.testing.assert_allclose(r["s.y"], np.column_stack([np.full_like(t, 20.0),
                                                          np.sin(4 * np.pi * t)]), atol=1e-14)
