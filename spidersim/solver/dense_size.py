"""How many states the methods with dense n_x x n_x matrices take.

LSODA, SciPy's BDF and Radau, and the compiled ROS34PW2 and NDF keep n_x x n_x matrices (a
Jacobian, an iteration matrix and its LU factors; LSODA allocates its n_x^2 work array at the
start, before it ever switches to BDF). A wide vector state (a Constant of 99,000 values into
an Integrator: a 1 MB diagram) would ask for hundreds of GB; such a run is refused before
anything is allocated, saying what it would take and what to use instead (an explicit
method, whose memory grows with n_x only). Linearization (the n_x x n_x matrix A by 2 n_x
evaluations) takes the same bound.
"""
from __future__ import annotations

from ..errors import SpidersimError

#: the methods with n_x x n_x matrices
DENSE = ("LSODA", "Radau", "BDF", "ROS34PW2", "NDF")
#: the most states they take: 3 x 8 n^2 bytes is 384 MB at 4,000 states, and each
#: factorization O(n^3)
MAX_DENSE_STATES = 4000


def check_dense_size(n_x, method):
    """Refuse ``n_x`` states for a method of :data:`DENSE` beyond :data:`MAX_DENSE_STATES`,
    before anything is allocated, saying what it would take and what to use instead."""
    if method in DENSE and n_x > MAX_DENSE_STATES:
        gb = 3 * 8 * float(n_x) ** 2 / 1e9
        raise SpidersimError(f"method {method} keeps {n_x} x {n_x} matrices (the Jacobian and "
                             f"its factorization, about {gb:.3g} GB for {n_x} states): at most "
                             f"{MAX_DENSE_STATES} states with {', '.join(DENSE)}; use an "
                             f"explicit method (DP54, RK45, DOP853) for this many states")
