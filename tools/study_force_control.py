"""The paper's force-control study (Fig. 10) with and without the drive trains.

Runs ``diagrams/force_control_rigid.yaml`` (seven torque-mode SPIDER joints: driver, motor
(its ripple sources off: joint_torque.yaml's zeros), Harmonic Drive with compliance and
LuGre friction, active damping of the gear mode) with friction on and off, and ``diagrams/force_control_rigid_ideal.yaml`` (ideal joint
torques), prints for every force step the 2 % settling time, the overshoot and the steady
error (mean over the last 0.2 s before the next step), and writes one plot of the three
contact forces against the set point.

    python tools/study_force_control.py [--out DIR] [--skip-friction]

The drive-train runs take seconds with the file's NDF (seven drive trains with 2 kHz current
loops and a rigid contact closed by Newton: 3,921 steps without friction, 15,180 with LuGre,
measured 28 November 2026; minutes with LSODA, which took 86,000 and 850,000); each run's
steps, wall time and the wall's release and onset events are printed.
"""
from __future__ import annotations

import argparse
import os
import sys
import time

import numpy as np

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, ROOT)

import spidersim  # noqa: E402

STEPS_DRIVE = [0.1, 1.5, 3.0]        # force set point steps of force_control_rigid.yaml
STEPS_IDEAL = [0.1, 0.6, 1.2]        # and of force_control_rigid_ideal.yaml


def step_figures(r, steps):
    """Per step: (time, from, to, settling [s], overshoot [fraction], steady error [N])."""
    t, F, ref = r.t, r["wall.lam"].ravel(), r["fset.y"].ravel()
    ends = steps[1:] + [t[-1] + 1e-9]
    out = []
    for a, b in zip(steps, ends):
        m = (t > a) & (t < b)
        before = ref[t < a][-1] if np.any(t < a) else 0.0
        to = ref[m][-1]
        err = F[m] - to
        band = 0.02 * abs(to - before)
        late = np.flatnonzero(np.abs(err) > band)
        settle = t[m][late[-1]] - a if len(late) else 0.0
        rise = to > before
        over = ((F[m].max() - to) if rise else (to - F[m].min())) / abs(to - before)
        steady = float(np.mean(err[t[m] > b - 0.2]))
        out.append((a, before, to, settle, max(over, 0.0), steady))
    return out


def run(path, sets=None):
    d = spidersim.load(os.path.join(ROOT, "diagrams", path), set=sets or {})
    t0 = time.perf_counter()
    r = d.simulate()
    wall = time.perf_counter() - t0
    print(f"{path} {sets or ''}: {r.stats['steps']} steps, {wall:.1f} s wall", flush=True)
    for t, block, name in r.events:
        if block == "wall":
            print(f"  wall {name} at t = {t!r} s")
    return r


def plot(cases, out):
    """Contact forces of the drive-train cases (top) and the ideal case (bottom) against
    their set points; returns the PNG's path."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    os.makedirs(out, exist_ok=True)
    fig, axes = plt.subplots(2, 1, figsize=(8, 6.5))
    for ax, group in zip(axes, (cases[1:], cases[:1])):
        for name, r, _steps in group:
            ax.plot(r.t, r["wall.lam"], label=name)
        ref = group[0][1]
        ax.plot(ref.t, ref["fset.y"], "k--", lw=1, label="set point")
        ax.set_ylabel("contact force [N]")
        ax.grid(True, alpha=0.3)
        ax.legend(fontsize=8)
    axes[0].set_title("Force control on a rigid plane: SPIDER drive trains (top), ideal "
                      "torques (bottom)")
    axes[1].set_xlabel("t [s]")
    path = os.path.join(out, "force_control_drive_trains.png")
    fig.savefig(path, dpi=110, bbox_inches="tight")
    return path


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--out", default="results/force_control_study")
    ap.add_argument("--skip-friction", action="store_true",
                    help="only the friction-free drive trains (faster)")
    args = ap.parse_args(argv)
    cases = [("ideal torques", run("force_control_rigid_ideal.yaml"), STEPS_IDEAL),
             ("drive trains, no friction",
              run("force_control_rigid.yaml", {"friction": "0"}), STEPS_DRIVE)]
    if not args.skip_friction:
        cases.append(("drive trains, LuGre friction", run("force_control_rigid.yaml"),
                      STEPS_DRIVE))
    print(f"\n{'case':32s} {'step':>12s} {'settling':>9s} {'overshoot':>10s} {'steady':>9s}")
    for name, r, steps in cases:
        for a, before, to, settle, over, steady in step_figures(r, steps):
            print(f"{name:32s} {before:5.0f}->{to:3.0f} N {settle * 1e3:7.0f} ms "
                  f"{over * 100:9.1f} % {steady:8.3f} N")
    path = plot(cases, args.out)
    print(f"\nwrote {path}")


if __name__ == "__main__":
    main()
