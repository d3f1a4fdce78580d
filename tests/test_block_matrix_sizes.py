"""Matrices a linear block builds from its parameters are bounded before they are
allocated (the security review: a TransferFunction's ``den`` of 6,501 coefficients, a
19.6 KB service request, built a 6,500 x 6,500 state matrix at submit: 4.2 s, +650 MB;
the default 256 KiB body allowed 58 GB). The limit is MAX_ARRAY_ELEMENTS, the one of an
array parameter, at load time: the CLI and the service alike."""
from __future__ import annotations

import time

import numpy as np
import psutil
import pytest

from spidersim.blocks.continuous import StateSpace, TransferFunction
from spidersim.blocks.discrete import DiscreteTransferFunction
from spidersim.cli import main
from spidersim.errors import ParameterError
from spidersim.text import limits


def diagram(tmp_path, block):
    """A diagram file: a Step into ``block`` (YAML flow text)."""
    p = tmp_path / "tf.yaml"
    p.write_text(f"name: tf\nblocks:\n  u: {{type: Step}}\n  sys: {block}\n"
                 f"connections:\n  - u.y -> sys.u\nsimulation: {{t_end: 0.01}}\n")
    return str(p)


def den(n):
    """Coefficients of s^n + 1."""
    return [1.0] + [0.0] * (n - 1) + [1.0]


def test_transfer_function_degree_over_the_limit_is_refused_by_the_cli(tmp_path, capsys):
    """``spidersim check``: exit 2, the message names the matrix, its size, the limit and
    what to do, within a second of the load and without the 338 MB matrix."""
    path = diagram(tmp_path, f"{{type: TransferFunction, num: [1], den: {den(6500)}}}")
    rss = psutil.Process().memory_info().rss
    t0 = time.perf_counter()
    assert main(["check", path]) == 2
    assert time.perf_counter() - t0 < 5
    assert psutil.Process().memory_info().rss - rss < 100e6
    err = capsys.readouterr().err
    for needle in ("block 'sys'", "6500 x 6500 matrix", "MAX_ARRAY_ELEMENTS",
                   "at most degree 1000", "cascade of lower-order TransferFunction"):
        assert needle in err, err
    assert "Traceback" not in err


def test_transfer_function_at_the_limit_is_accepted():
    """Degree 1000 (a 1000 x 1000 state matrix, 8 MB) is the largest accepted."""
    n = int(np.sqrt(limits.MAX_ARRAY_ELEMENTS))
    p = TransferFunction.validate_params({"num": [1.0], "den": den(n)})
    assert TransferFunction.derive(p)["A"].shape == (n, n)
    with pytest.raises(ParameterError, match="1001 x 1001 matrix"):
        TransferFunction.validate_params({"num": [1.0], "den": den(n + 1)})


def test_state_space_zero_feedthrough_is_bounded():
    """``D = 0`` becomes a zero matrix of (outputs x inputs): with one state, a C of
    30,000 rows and a B of 30,000 columns (a few hundred KB of text) asked for 7.2 GB."""
    A, B, C = np.zeros((1, 1)), np.ones((1, 30000)), np.ones((30000, 1))
    with pytest.raises(ParameterError, match=r"30000 x 30000 matrix .*MAX_ARRAY_ELEMENTS"):
        StateSpace.validate_params({"A": A, "B": B, "C": C})
    p = StateSpace.validate_params({"A": A, "B": B[:, :100], "C": C[:100]})
    assert p["D"].shape == (100, 100)


def test_discrete_transfer_function_stays_linear_in_its_degree():
    """DiscreteTransferFunction builds no n x n matrix: its derived values grow with n."""
    p = DiscreteTransferFunction.validate_params({"num": [1.0], "den": den(100_000),
                                                  "Ts": 0.1})
    assert all(v.size <= 100_001 for v in DiscreteTransferFunction.derive(p).values())
