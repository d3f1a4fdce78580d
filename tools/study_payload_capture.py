"""The capture of a drifting payload (Fig. 6, issue 13 item 5): figures and a plot.

Runs ``diagrams/payload_capture_ideal.yaml`` (ideal joint torques) and, unless
``--skip-drive``, ``diagrams/payload_capture.yaml`` (seven torque-mode drive trains), prints
the flange-to-fixture distance at the latch, the joint-speed jump, the truss force around
the capture and while carrying, the carry error, and the generalized momentum
``M qd + J_c^T M_p V_p`` across the latch (numpy, from the DH table); writes
``payload_capture_drift.png`` (fixture and flange y and z, joint speeds, truss force).

    python tools/study_payload_capture.py [--out DIR] [--skip-drive]
"""
from __future__ import annotations

import argparse
import os
import sys

import numpy as np

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, ROOT)
sys.path.insert(0, os.path.join(ROOT, "tests"))

import spidersim  # noqa: E402
from spidersim.multibody import Chain  # noqa: E402

from multibody import rigid_ref as ref  # noqa: E402

T_LATCH, M_P, I_P = 3.0, 30.0, [0.3, 0.3, 0.3]


def figures(r):
    t = r.t
    k0 = np.flatnonzero(t < T_LATCH)[-1]
    k1 = np.flatnonzero(t > T_LATCH)[0]
    k = np.searchsorted(t, T_LATCH)
    P = Chain.from_yaml().P
    q, qd0 = r["arm.q"][k], r["arm.qd"][k0]
    x, R = r["arm.payload_pos"][k], r["arm.payload_rot"][k].reshape(3, 3)
    V = r["arm.payload_twist"][k0]
    Mp = np.block([[M_P * np.eye(3), np.zeros((3, 3))],
                   [np.zeros((3, 3)), R @ np.diag(I_P) @ R.T]])
    Jc = ref.point_jacobian(P, q, 7, x)
    M = ref.mass_matrix(P, q)
    F = r["arm.base_force"]
    cap = (t > T_LATCH) & (t < 3.5)
    carry = t > 3.5
    return {
        "fixture distance at latch [mm]":
            1e3 * np.linalg.norm(r["arm.flange_pos"][k] - r["arm.grapple_pos"][k]),
        "payload momentum [N s]": M_P * np.linalg.norm(V[:3]),
        "joint speed jump max [rad/s]": np.abs(r["arm.qd"][k1] - qd0).max(),
        "generalized momentum before (norm) [N m s]": np.linalg.norm(M @ qd0 + Jc.T @ Mp @ V),
        "truss force 3.0-3.5 s max [N]": np.abs(F[cap]).max(),
        "truss force carrying max [N]": np.abs(F[carry]).max(),
        "tracking error 3.0-3.5 s max [mm]": 1e3 * np.abs(r["perr.y"][cap]).max(),
        "tracking error carrying max [mm]": 1e3 * np.abs(r["perr.y"][carry]).max(),
    }


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--out", default=os.path.join(ROOT, "docs"))
    ap.add_argument("--skip-drive", action="store_true")
    a = ap.parse_args()
    runs = {"ideal torques": spidersim.load(
        os.path.join(ROOT, "diagrams", "payload_capture_ideal.yaml")).simulate()}
    if not a.skip_drive:
        runs["drive trains"] = spidersim.load(
            os.path.join(ROOT, "diagrams", "payload_capture.yaml")).simulate()
    for name, r in runs.items():
        print(name)
        for key, val in figures(r).items():
            print(f"  {key}: {val:.4g}")
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    fig, ax = plt.subplots(3, 1, figsize=(8, 8), sharex=True)
    for name, r in runs.items():
        ls = "-" if name == "ideal torques" else "--"
        ax[0].plot(r.t, r["arm.flange_pos"][:, 1], "C0" + ls, label=f"flange y ({name})")
        ax[0].plot(r.t, r["arm.flange_pos"][:, 2] - 0.5, "C1" + ls,
                   label=f"flange z - 0.5 m ({name})")
        for j, c in enumerate("xyz"):
            ax[2].plot(r.t, r["arm.base_force"][:, j], f"C{j}" + ls,
                       label=f"{c} ({name})")
        ax[1].plot(r.t, r["arm.qd"], ls)
    r = runs["ideal torques"]
    ax[0].plot(r.t, r["arm.grapple_pos"][:, 1], "k:", label="fixture y")
    ax[0].plot(r.t, r["arm.grapple_pos"][:, 2] - 0.5, "k-.", label="fixture z - 0.5 m")
    ax[0].axvline(T_LATCH, color="0.6", lw=0.8)
    ax[0].set_ylabel("m")
    ax[0].legend(fontsize=7, ncol=2)
    ax[0].set_title("Capture of a payload drifting at 2 cm/s (latch at 3 s)")
    ax[1].set_ylabel("joint speeds [rad/s]")
    ax[2].set_ylabel("force on the truss [N]")
    ax[2].legend(fontsize=7, ncol=2)
    ax[2].set_xlabel("t [s]")
    fig.tight_layout()
    os.makedirs(a.out, exist_ok=True)
    path = os.path.join(a.out, "payload_capture_drift.png")
    fig.savefig(path, dpi=90)
    print("wrote", path)


if __name__ == "__main__":
    main()
