"""The 6-D rigid contact demo, ``diagrams/peg_contact.yaml``: figures and plot.

Runs the diagram (compiled), prints the onset and release instants, the largest violation
of the engaged directions, the held multipliers, the integration statistics and the wall
time of a second (cached) run, and writes ``peg_contact.png`` (depth of the peg, turn
about its axis, multipliers, violation) into ``--out``.

    python tools/study_peg_contact.py [--out DIR]
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


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", default=os.path.join(ROOT, "docs"))
    args = ap.parse_args(argv)
    d = spidersim.load(os.path.join(ROOT, "diagrams", "peg_contact.yaml"))
    d.simulate(t_end=0.01)                                  # compile (or load) first
    t0 = time.perf_counter()
    r = d.simulate()
    wall = time.perf_counter() - t0
    s = r.stats
    for t, block, name in r.events:
        print(f"event {name:12s} {block:5s} t = {t:.9f} s")
    on = min(t for t, b, n in r.events if n.startswith("onset"))
    held = (r.t > on + 0.05) & (r.t < 0.6)
    print(f"max |drift| (engaged directions) {np.abs(r['wall.drift']).max():.2e}")
    print("held multipliers (mean, 0.05 s after the onset to the pull):",
          np.round(r["wall.lam"][held].mean(axis=0), 4))
    print(f"steps {s['steps']}, RHS calls {s['rhs_calls']}, Newton iterations "
          f"{s['newton_iterations']} ({s['newton_iterations'] / s['rhs_calls']:.2f} per RHS "
          f"call), wall {wall:.3f} s")
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    fig, ax = plt.subplots(4, 1, figsize=(8, 9), sharex=True)
    ax[0].plot(r.t, 1e3 * r["wall.error"][:, 2])
    ax[0].set_ylabel("depth above\nthe bottom [mm]")
    ax[1].plot(r.t, r["wall.error"][:, 5])
    ax[1].set_ylabel("turn about\nthe axis [rad]")
    for k, lab in ((0, "x [N]"), (1, "y [N]"), (2, "z [N]")):
        ax[2].plot(r.t, r["wall.lam"][:, k], label=lab)
    for k, lab in ((3, "rx [N.m]"), (4, "ry [N.m]")):
        ax[2].plot(r.t, r["wall.lam"][:, k], "--", label=lab)
    ax[2].set_ylabel("multipliers")
    ax[2].legend(ncol=5, fontsize=8)
    ax[3].semilogy(r.t, np.abs(r["wall.drift"]).max(axis=1) + 1e-18)
    ax[3].set_ylabel("max violation\n[m, rad]")
    ax[3].set_xlabel("time [s]")
    for a in ax:
        a.grid(alpha=0.3)
    fig.suptitle("Peg in a hole (RigidContact6): x, y, rx, ry held, z the bottom, rz free")
    fig.tight_layout()
    os.makedirs(args.out, exist_ok=True)
    path = os.path.join(args.out, "peg_contact.png")
    fig.savefig(path, dpi=90)
    print("wrote", path)


if __name__ == "__main__":
    main()
