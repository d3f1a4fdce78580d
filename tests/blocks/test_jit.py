"""Compiled (numba) and interpreted runs of the same small diagram agree to 1e-12."""
import numpy as np

import spidersim

TEXT = """
name: jit_check
blocks:
  ref:   {type: Step, t_step: 0.05, after: 1.0}
  err:   {type: Sum, signs: "+-"}
  ctrl:  {type: PI, kp: 2, ki: 2, y_min: -1.5, y_max: 1.5, antiwindup: backcalc, kb: 5}
  sat:   {type: Saturation, lower: -1.3, upper: 1.3}
  plant: {type: TransferFunction, num: [1], den: [1, 2, 1]}
connections:
  - ref.y -> err.u1
  - plant.y -> err.u2
  - err.y -> ctrl.e
  - ctrl.y -> sat.u
  - sat.y -> plant.u
"""


def test_jit_agrees_with_interpreted():
    d = spidersim.loads(TEXT)
    kw = dict(t_end=6.0, rtol=1e-8, atol=1e-10, output_interval=0.01)
    a = d.simulate(jit=False, **kw)
    b = d.simulate(jit=True, **kw)
    assert a.stats["jit"] is False and b.stats["jit"] is True
    np.testing.assert_array_equal(a.t, b.t)
    assert a.names == b.names and len(a.t) == 601
    for name in a.names:
        np.testing.assert_allclose(b[name], a[name], rtol=1e-12, atol=1e-12, err_msg=name)
    assert [e[:2] for e in a.events] == [e[:2] for e in b.events]
    assert np.any(a["sat.y"] == 1.3)                  # the limit and its events were used
    assert abs(a["plant.y"][-1] - 1.0) < 0.05
