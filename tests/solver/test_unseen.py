"""The compiled loop's test for a guard that leaves zero and returns inside one step
(spidersim.solver.events.left_zero_unseen), on plain arrays."""
import numpy as np

from spidersim.solver.events import left_zero_unseen, zero_start_candidates

DOWN = np.array([-1.0])


def test_ball_that_bounced_and_landed_within_the_step_is_found():
    """After an impact the ball's guard x is exactly 0 and disarmed; the step ends below
    the floor (x < 0) while an Euler probe along f(t, x) shows it first went up (x > 0):
    a landing the crossing test cannot see."""
    g_old, g_new, armed = np.array([0.0]), np.array([-1e-9]), np.array([0.0])
    assert zero_start_candidates(g_old, g_new, DOWN, armed)
    assert left_zero_unseen(g_old, g_new, DOWN, armed, np.array([1e-15])) == 0


def test_guard_going_straight_to_its_firing_side_is_not_a_return():
    """A saturation entered at its corner: the guard is 0, disarmed, and the input keeps
    going the firing way (probe on the same side as the step end): no hidden return."""
    g_old, g_new, armed = np.array([0.0]), np.array([-1e-3]), np.array([0.0])
    assert left_zero_unseen(g_old, g_new, DOWN, armed, np.array([-1e-6])) == -1


def test_armed_or_nonzero_or_other_side_guards_are_not_candidates():
    """Only a disarmed guard starting exactly at zero and ending on its firing side is a
    candidate; an armed one is seen by the crossing test, one ending on the other side has
    simply left zero."""
    assert not zero_start_candidates(np.array([0.0]), np.array([-1.0]), DOWN, np.array([1.0]))
    assert not zero_start_candidates(np.array([1e-9]), np.array([-1.0]), DOWN, np.array([0.0]))
    assert not zero_start_candidates(np.array([0.0]), np.array([1.0]), DOWN, np.array([0.0]))
    both = np.array([0.0])
    assert zero_start_candidates(np.array([0.0]), np.array([1.0]), both, np.array([0.0]))
