"""Step-size control shared by the integration methods (pure helper, compiled by numba).

After a trial step with error norm ``err`` (accepted when ``err <= 1``) the step is scaled by

    f = clip(safety err^(-1/(order + 1)), min_factor, max_factor)

with no growth right after a rejection (``f <= 1``), where ``order`` is the order of the
method's error estimator. ``err == 0`` gives ``max_factor``.
"""
from __future__ import annotations

from ._jit import njit, njit_borrowed


@njit_borrowed
def factor(err, rejected, order, safety, min_factor, max_factor):
    """Step-size factor after a trial step with error norm ``err``."""
    if err == 0.0:
        f = max_factor
    else:
        f = safety * err ** (-1.0 / (order + 1))
    if err <= 1.0:
        f = min(max_factor, f)
        if rejected:
            f = min(1.0, f)
        return f
    return max(min_factor, f)
