"""The compiled loop gives bit-for-bit the same runs as a saved reference (loop work).

    python tools/check_loop_identical.py save REF.npz      # before a change
    python tools/check_loop_identical.py compare REF.npz   # after it: exit 1 on any difference
    python tools/check_loop_identical.py save REF.npz --stiff   # the stiff methods' cases too

Runs the servo (1 s, DP54), the bouncing ball (100 impacts, DP54), the algebraic loop (2 s,
DP54) as in ``tools/bench_loop.py``, and ``spider.yaml`` for 2 s with its own method, and
stores every logged array, ``t``, the event log and the step/RHS counts; ``compare`` requires
exact equality (not a tolerance). ``--stiff`` adds the compiled stiff methods: the bouncing
ball (20 impacts) with NDF and with ROS34PW2, the LuGre stick-slip (ROS34PW2), servo.yaml and
joint_ripple.yaml (NDF) with a finite-difference and with the analytic Jacobian.
"""
from __future__ import annotations

import math
import os
import sys

import numpy as np

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


def _ball_t_end(e_=0.95, g=9.81, h0=10.0):
    t1 = math.sqrt(2 * h0 / g)
    t100 = t1 + sum(2 * e_ ** k * g * t1 / g for k in range(1, 100))
    return t100 + 0.5 * 2 * e_ ** 100 * t1


CASES = {
    "servo": ("diagrams/servo.yaml", {}, dict(t_end=1.0, rtol=1e-6, atol=1e-8,
                                              max_step=math.inf, method="DP54")),
    "ball": ("diagrams/bouncing_ball.yaml", {"ball.e": 0.95, "ball.v_rest": 0},
             dict(t_end=_ball_t_end(), rtol=1e-10, atol=1e-12, max_step=math.inf,
                  method="DP54")),
    "loop": ("diagrams/algebraic_loop.yaml", {}, dict(t_end=2.0, rtol=1e-9, atol=1e-12,
                                                      max_step=math.inf, method="DP54")),
    "spider": ("spider.yaml", {}, dict(t_end=2.0)),
}
STIFF = {
    "ball_ndf": ("diagrams/bouncing_ball.yaml", {"ball.e": 0.9, "ball.v_rest": 0},
                 dict(t_end=12.0, rtol=1e-8, atol=1e-10, method="NDF")),
    "ball_ros": ("diagrams/bouncing_ball.yaml", {"ball.e": 0.9, "ball.v_rest": 0},
                 dict(t_end=12.0, rtol=1e-8, atol=1e-10, method="ROS34PW2")),
    "lugre_ros": ("diagrams/lugre_stick_slip.yaml", {}, dict(method="ROS34PW2")),
    "lugre_ndf": ("diagrams/lugre_stick_slip.yaml", {}, dict(method="NDF", jacobian="fd")),
    "servo_ndf": ("diagrams/servo.yaml", {}, dict(t_end=1.0, method="NDF", jacobian="fd")),
    "ripple_ndf": ("diagrams/joint_ripple.yaml", {}, dict(t_end=0.05, method="NDF")),
    "ripple_ros_grid": ("diagrams/joint_ripple.yaml", {},
                        dict(t_end=0.05, method="ROS34PW2", output_interval=1e-4)),
}


def runs(stiff=False):
    import spidersim
    out = {}
    for name, (path, sets, kw) in (CASES | STIFF if stiff else CASES).items():
        d = spidersim.load(os.path.join(ROOT, path), set=sets)
        r = d.simulate(**kw)
        out[f"{name}|t"] = np.asarray(r.t)
        for key in r.names:
            out[f"{name}|{key}"] = np.asarray(r[key], dtype=float)
        out[f"{name}|events_t"] = np.array([e[0] for e in r.events], dtype=float)
        st = r.stats
        out[f"{name}|counts"] = np.array([st.get(k, -1) for k in (
            "steps", "rhs_calls", "rejected_steps", "segments", "time_events",
            "jacobian_calls", "lu_decompositions")], dtype=float)
        print(f"{name}: {len(r.t)} rows, {st['steps']} steps, {st['rhs_calls']} RHS, "
              f"{len(r.events)} events", flush=True)
    return out


def main(argv):
    mode, ref = argv[0], argv[1]
    res = runs("--stiff" in argv)
    if mode == "save":
        np.savez(ref, **res)
        return 0
    old = dict(np.load(ref))
    bad = 0
    for k in sorted(set(old) | set(res)):
        a, b = old.get(k), res.get(k)
        if a is None or b is None or a.shape != b.shape or not np.array_equal(
                a, b, equal_nan=True):
            print(f"DIFFERENT: {k}")
            bad += 1
    print("bit for bit identical" if not bad else f"{bad} arrays differ")
    return 1 if bad else 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
