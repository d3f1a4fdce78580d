"""The state layout of the compiled integration loop: codes, methods and array slots.

Shared by the loop's parts (:mod:`.loop_body`) and its Python side (:mod:`.loop`); see
:mod:`.loop` for what each array holds.
"""
from __future__ import annotations

from . import dp54, rosenbrock
from .events import (CHATTER_COUNT, MAX_EVENTS_AT_ONE_TIME,  # noqa: F401 (read by the loop)
                     STALL_COUNT, STALL_STEP)

# integration methods of the compiled loop (``ist[I_METHOD]``)
METHOD_DP54, METHOD_ROS34PW2, METHOD_NDF = 0, 1, 2
METHODS = {"DP54": METHOD_DP54, "ROS34PW2": METHOD_ROS34PW2, "NDF": METHOD_NDF}
# both methods leave f(t + h, x1) in the same row of K, copied to row 0 for the next step
assert rosenbrock.ROW_END == 6 and rosenbrock.K_ROWS >= dp54.K_ROWS

# return codes of run_loop
DONE, ROWS_FULL, EVENTS_FULL, PAUSE = 0, 1, 2, 3
FAIL_NONFINITE, FAIL_STALL, FAIL_SMALL_STEP, FAIL_CHATTER = 10, 11, 12, 13
FAIL_TIME_EVENTS, FAIL_SETTLE, FAIL_START, FAIL_ZENO = 14, 15, 16, 17

# integer state ``ist``
I_ROWS, I_EVENTS, I_GRID, I_TINY, I_STEPS, I_NFEV, I_STARTED, I_REJECTED = range(8)
I_SEGMENTS, I_TIMED, I_BLOCK, I_FRESH, I_NG, I_OVERFLOW, I_NEW_STEPS = range(8, 15)
# the method, Jacobians and LU factorisations made, accepted steps since the last Jacobian
# (-1: none valid)
I_METHOD, I_NJAC, I_NLU, I_JAGE = range(15, 19)
N_IST = 20
# float state ``fst``
F_T, F_H, F_TEND, F_RTOL, F_ATOL, F_MAXSTEP, F_FIRST, F_DT, F_T0, F_CHATTER_WINDOW = range(10)
F_TFAIL = 10
F_HLU = 11            # the step size of the LU factors in JW[1] (0: none)
# Jacobian and LU reuse of ROS34PW2 (see rosenbrock.JAC_MAX_AGE, JAC_REJECTIONS, HOLD_MAX)
F_JAC_MAX_AGE, F_JAC_REJECTIONS, F_HOLD_MAX = 12, 13, 14
# the largest step of the next advance (max_step, or the room left in a grid's buffer)
F_HCAP = 15
N_FST = 16
# rows of the guard work array ``G``
# (G_ARMED: :data:`spidersim.solver.events.ARMED` and its kin; G_FIRED: the direction a guard
# fired in at the event instant being applied, 0 if it did not)
G_OLD, G_NEW, G_TMP, G_ARMED, G_BEFORE, G_TIMES, G_NONE, G_FIRED = range(8)
N_G_ROWS = 8
# columns of the event log ``ev_i``: guard or timed-block index, kind, direction
KIND_STATE, KIND_TIME = 0, 1

#: rows kept free in the record buffer at the start of every step (pre/post event rows)
ROW_RESERVE = 4
