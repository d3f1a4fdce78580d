"""Maintained integrators on spidersim's benchmark problems: SUNDIALS CVODE (scikit-sundae).

    pip install -e ".[bench]"          # scikit-sundae, besides the test extras
    python tools/bench_cvode.py [servo|lugre|ball]

Issue 14 asks to evaluate the maintained options before writing an integration loop. This
prints, interleaved in one process (best of 7), for the same equations and tolerances:

* **CVODE BDF / Adams**: SUNDIALS' CVODE through scikit-sundae with the numba right-hand
  side (called back from C through Python on every evaluation); the ball's impacts with
  CVODE's root finding (a terminal event, then a restart with the jumped state), the
  servo's step input as a restart at the step time (as spidersim's segments);
* **numba RHS + SciPy LSODA**: the same function stepped by SciPy from Python;
* **spidersim**: the diagram (``LSODA`` and the compiled ``DP54`` loop).

Steps are printed per variant; the impact times of the ball are checked against the
closed form so that a fast wrong answer cannot win.
"""
from __future__ import annotations

import math
import os
import sys

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from bench_loop import (_best, _lsoda_hand, ball_f, ball_guard, ball_jump,  # noqa: E402
                        lugre_f, no_guard, no_jump, servo_f)

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


def _cvode(f, y0, t_end, rtol, atol, method, tev=(), guard=None, jump=None):
    """A run of CVODE from 0 to t_end, restarted at each time in ``tev`` and after each
    root of ``guard`` (falling through zero, then ``jump``); returns a function that runs
    it and returns (steps, event times)."""
    from sksundae.cvode import CVODE

    def rhs(t, y, yp):
        f(t, y, yp)

    opts = dict(method=method, rtol=rtol, atol=atol, max_num_steps=1000000)
    if guard is not None:
        def events(t, y, ev):
            ev[0] = guard(t, y)
        events.terminal = [True]
        events.direction = [-1]
        opts.update(eventsfn=events, num_events=1)
    solver = CVODE(rhs, **opts)

    def run():
        t, y, steps, hits = 0.0, np.array(y0, float), 0, []
        bounds = [x for x in tev if x < t_end] + [t_end]
        for t_seg in bounds:
            while t < t_seg:
                sol = solver.solve(np.array([t, t_seg]), y)
                steps += int(sol.nfev)
                if not sol.success:
                    raise RuntimeError(sol.message)
                # the solver object keeps every event since its creation: a new one is
                # an event of this call
                n_ev = 0 if sol.t_events is None else len(sol.t_events)
                if guard is not None and n_ev > len(hits) + run.before:
                    t = float(sol.t_events[-1])
                    y = np.array(sol.y_events[-1], float)
                    jump(y)
                    hits.append(t)
                else:
                    t, y = float(sol.t[-1]), np.array(sol.y[-1], float)
        run.before += len(hits)
        return steps, hits
    run.before = 0
    return run


def _spidersim(path, sets, t_end, rtol, atol, method):
    import spidersim
    d = spidersim.load(os.path.join(ROOT, path), set=sets)
    kw = dict(t_end=t_end, rtol=rtol, atol=atol, method=method)
    d.simulate(**kw)

    def run():
        r = d.simulate(**kw)
        return r.stats["rhs_calls"], [t for t, _b, name in r.events if name == "impact"]
    return run


def _row(name, run):
    best, med, (calls, hits) = _best(run)
    print(f"{name:34s} {1e3 * best:10.3f} {1e3 * med:12.3f} {calls:10d}")
    return best, hits


def _header(title):
    print(f"== {title} ==")
    print(f"{'variant':34s} {'best [ms]':>10s} {'median [ms]':>12s} {'RHS calls':>10s}")


def bench_servo():
    _header("servo (5 states, step at 10 ms), 1 s, rtol 1e-6, atol 1e-8")
    y0, kw = np.zeros(5), dict(rtol=1e-6, atol=1e-8)
    rows = [
        ("CVODE BDF (numba RHS)", _cvode(servo_f, y0, 1.0, method="BDF", tev=(0.01,), **kw)),
        ("CVODE Adams (numba RHS)", _cvode(servo_f, y0, 1.0, method="Adams", tev=(0.01,),
                                           **kw)),
        ("numba RHS + SciPy LSODA", _counted(_lsoda_hand(servo_f, no_guard, no_jump, y0,
                                                         [0.01], 1.0, **kw))),
        ("spidersim LSODA", _spidersim("diagrams/servo.yaml", {}, 1.0, method="LSODA", **kw)),
        ("spidersim DP54 (compiled loop)", _spidersim("diagrams/servo.yaml", {}, 1.0,
                                                      method="DP54", **kw)),
    ]
    return [(n, *_row(n, r)) for n, r in rows]


def bench_lugre():
    _header("LuGre stick-slip (3 states, stiff), 25 s, rtol 1e-7, atol 1e-10")
    y0, kw = np.zeros(3), dict(rtol=1e-7, atol=1e-10)
    rows = [
        ("CVODE BDF (numba RHS)", _cvode(lugre_f, y0, 25.0, method="BDF", **kw)),
        ("numba RHS + SciPy LSODA", _counted(_lsoda_hand(lugre_f, no_guard, no_jump, y0, [],
                                                         25.0, **kw))),
        ("spidersim LSODA", _spidersim("diagrams/lugre_stick_slip.yaml", {}, 25.0,
                                       method="LSODA", **kw)),
    ]
    return [(n, *_row(n, r)) for n, r in rows]


def bench_ball():
    e, h0 = 0.95, 10.0
    v1 = math.sqrt(2 * 9.81 * h0)
    exact = [v1 / 9.81]
    for k in range(1, 100):
        exact.append(exact[-1] + 2 * e ** k * v1 / 9.81)
    t_end = exact[99] + 0.5 * (exact[99] - exact[98])
    _header(f"bouncing ball, e = {e}, first 100 impacts ({t_end:.2f} s), rtol 1e-10, "
            f"atol 1e-12")
    y0, kw = np.array([h0, 0.0]), dict(rtol=1e-10, atol=1e-12)
    rows = [
        ("CVODE Adams + root finding", _cvode(ball_f, y0, t_end, method="Adams",
                                              guard=ball_guard, jump=ball_jump, **kw)),
        ("CVODE BDF + root finding", _cvode(ball_f, y0, t_end, method="BDF",
                                            guard=ball_guard, jump=ball_jump, **kw)),
        ("spidersim DP54 (compiled loop)", _spidersim(
            "diagrams/bouncing_ball.yaml", {"ball.e": e, "ball.v_rest": 0.0}, t_end,
            method="DP54", **kw)),
        ("spidersim LSODA", _spidersim(
            "diagrams/bouncing_ball.yaml", {"ball.e": e, "ball.v_rest": 0.0}, t_end,
            method="LSODA", **kw)),
    ]
    out = []
    for n, r in rows:
        best, hits = _row(n, r)
        k = min(len(hits), 100)
        err = max(abs(a - b) for a, b in zip(hits[:k], exact[:k])) if k else float("nan")
        print(f"{'':34s} impacts {len(hits)}, worst impact-time error {err:.1e} s")
        out.append((n, best, hits))
    return out


def _counted(run):
    """Adapt bench_loop's LSODA runner (rows, steps) to (calls, hits)."""
    def wrapped():
        rows, steps = run()
        return steps, []
    return wrapped


def main(argv):
    which = argv[1:] or ["servo", "lugre", "ball"]
    for name in which:
        {"servo": bench_servo, "lugre": bench_lugre, "ball": bench_ball}[name]()
        print()
    print("RHS calls: CVODE's nfev (its finite-difference Jacobians included); for the\n"
          "numba + LSODA baseline the column is its accepted steps.")


if __name__ == "__main__":
    main(sys.argv)
