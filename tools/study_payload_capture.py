"""The capture of a drifting payload (Fig. 6, issue 13 item 5): figures and a plot.

Runs ``diagrams/payload_capture_ideal.yaml`` (ideal joint torques) and, unless
``--skip-drive``, ``diagrams/payload_capture.yaml`` (seven torque-mode drive trains), prints
the flange-to-fixture distance at the latch, the joint-speed jump (from the two rows the run
records at the latch event), the truss force around the capture and while carrying (peaks
from every step's row: the runs have no output grid) and the rms of its y component, the
carry error, and the generalized momentum ``M qd + J_c^T M_p V_p`` across the latch (numpy,
from the DH table); writes ``payload_capture_drift.png`` (fixture and flange y and z, joint
speeds, truss force). ``--set NAME=VALUE`` sets a parameter of both diagrams (``--set
v_drift=0 --set w_spin=0``: the payload at rest), ``--set-drive NAME=VALUE`` one of
``payload_capture.yaml`` only (``--set-drive friction=0``).

    python tools/study_payload_capture.py [--out DIR] [--skip-drive] [--set NAME=VALUE]
                                          [--set-drive NAME=VALUE]
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


def latch_rows(r):
    """The two rows the run records at the latch event (before, after): the joint-speed
    jump is read there, not from output samples around it (with the drive trains the gear
    mode undoes half of the jump within 5 ms)."""
    rows = np.flatnonzero(r.t == T_LATCH)
    if len(rows) < 2:
        raise SystemExit(f"no latch event recorded at t = {T_LATCH} s (rows there: "
                         f"{len(rows)})")
    return rows[0], rows[-1]


def rms(t, y, a, b):
    """Time-weighted rms of ``y`` over a < t < b (rows at any spacing)."""
    m = (t > a) & (t < b)
    return float(np.sqrt(np.trapezoid(y[m] ** 2, t[m]) / (t[m][-1] - t[m][0])))


def figures(r):
    """The study's figures of one run recorded at every step (peaks from every row)."""
    t = r.t
    k0, k1 = latch_rows(r)
    P = Chain.from_yaml().P
    q, qd0, qd1 = r["arm.q"][k0], r["arm.qd"][k0], r["arm.qd"][k1]
    x, R = r["arm.payload_pos"][k0], r["arm.payload_rot"][k0].reshape(3, 3)
    V = r["arm.payload_twist"][k0]
    Mp = np.block([[M_P * np.eye(3), np.zeros((3, 3))],
                   [np.zeros((3, 3)), R @ np.diag(I_P) @ R.T]])
    Jc = ref.point_jacobian(P, q, 7, x)
    M = ref.mass_matrix(P, q)
    h0 = M @ qd0 + Jc.T @ Mp @ V
    h1 = (M + Jc.T @ Mp @ Jc) @ qd1
    F = r["arm.base_force"]
    cap = (t > T_LATCH) & (t < 3.5)
    carry = t > 3.5
    return {
        "fixture distance at latch [mm]":
            1e3 * np.linalg.norm(r["arm.flange_pos"][k0] - r["arm.grapple_pos"][k0]),
        "payload momentum [N s]": M_P * np.linalg.norm(V[:3]),
        "joint speed jump max [rad/s]": np.abs(qd1 - qd0).max(),
        "joint with the largest jump": 1 + int(np.argmax(np.abs(qd1 - qd0))),
        "generalized momentum before (norm) [N m s]": np.linalg.norm(h0),
        "generalized momentum after - before (relative)":
            np.linalg.norm(h1 - h0) / np.linalg.norm(h0),
        "truss force 3.0-3.5 s max [N]": np.abs(F[cap]).max(),
        "time of that peak [s]": t[cap][np.argmax(np.abs(F[cap]).max(axis=1))],
        "truss y force rms 3.2-6 s [N]": rms(t, F[:, 1], 3.2, 6.0),
        "truss y force rms after 6 s [N]": rms(t, F[:, 1], 6.0, t[-1] + 1),
        "truss force carrying max [N]": np.abs(F[carry]).max(),
        "tracking error 3.0-3.5 s max [mm]": 1e3 * np.abs(r["perr.y"][cap]).max(),
        "tracking error carrying max [mm]": 1e3 * np.abs(r["perr.y"][carry]).max(),
    }


def run(name, sets=None):
    """One study diagram with the file's settings but recorded at every step (no output
    grid: the peaks of the truss force last a few milliseconds)."""
    d = spidersim.load(os.path.join(ROOT, "diagrams", name), set=sets or {})
    d.simulation["output_interval"] = None
    r = d.simulate()
    print(f"{name} {sets or ''}: {r.stats['steps']} steps", flush=True)
    return r


def parse_sets(items):
    """``NAME=VALUE`` strings into ``{NAME: VALUE}`` (a clear exit on anything else)."""
    sets = {}
    for item in items:
        name, sep, value = item.partition("=")
        if not sep or not name.strip():
            raise SystemExit(f"--set takes NAME=VALUE, got {item!r}")
        sets[name.strip()] = value.strip()
    return sets


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--out", default=os.path.join(ROOT, "docs"))
    ap.add_argument("--skip-drive", action="store_true")
    ap.add_argument("--set", action="append", default=[], metavar="NAME=VALUE",
                    help="a parameter of both diagrams, e.g. v_drift=0; repeatable")
    ap.add_argument("--set-drive", action="append", default=[], metavar="NAME=VALUE",
                    help="a parameter of payload_capture.yaml only (the drive-train run), "
                         "e.g. friction=0; repeatable")
    a = ap.parse_args()
    sets, drive_sets = parse_sets(a.set), parse_sets(a.set_drive)
    if drive_sets and a.skip_drive:
        raise SystemExit("--set-drive applies to the drive-train run: not with --skip-drive")
    try:
        runs = {"ideal torques": run("payload_capture_ideal.yaml", sets)}
        if not a.skip_drive:
            runs["drive trains"] = run("payload_capture.yaml", {**sets, **drive_sets})
    except spidersim.SpidersimError as exc:
        raise SystemExit(f"error: {exc}")
    for name, r in runs.items():
        print(name)
        for key, val in figures(r).items():
            print(f"  {key}: {val:.5g}")
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
