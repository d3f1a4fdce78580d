"""Every diagram gives the same numbers as a saved reference run (for code-generation work).

    python tools/check_same_results.py save REF.npz     # before a change
    python tools/check_same_results.py compare REF.npz  # after it: max relative difference
    python tools/check_same_results.py diff A.npz B.npz # two saved runs (e.g. two checkouts)

Each diagram of ``diagrams/`` and ``spider.yaml`` is run for a short time (its own method and
tolerances, compiled) and every logged array is stored; ``compare`` prints per diagram the
largest difference relative to the array's largest magnitude and fails above 1e-12.
"""
from __future__ import annotations

import glob
import os
import sys

import numpy as np

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
T_END = {"spider.yaml": 0.6, "impact_fault.yaml": 0.3, "payload_capture.yaml": 0.5,
         "payload_capture_ideal.yaml": 0.5}


def runs():
    import spidersim
    from spidersim.errors import DiagramError
    paths = sorted(glob.glob(os.path.join(ROOT, "diagrams", "*.yaml"))) + [
        os.path.join(ROOT, "spider.yaml")]
    out = {}
    for path in paths:
        name = os.path.basename(path)
        try:
            d = spidersim.load(path)
        except DiagramError as exc:
            if "subsystem" not in str(exc):
                raise
            print(f"{name}: a subsystem, run inside its parents", flush=True)
            continue
        t_end = min(T_END.get(name, 0.2), float(d.simulation["t_end"]))
        r = d.simulate(t_end=t_end)
        out[f"{name}|t"] = np.asarray(r.t)
        for key in r.names:
            out[f"{name}|{key}"] = np.asarray(r[key], dtype=float)
        print(f"{name}: {len(r.t)} samples to {t_end} s", flush=True)
    return out


def main(argv):
    mode, ref = argv[0], argv[1]
    res = dict(np.load(argv[2])) if mode == "diff" else runs()
    if mode == "save":
        np.savez(ref, **res)
        return 0
    old = dict(np.load(ref))
    worst = {}
    for k, v in old.items():
        name = k.split("|")[0]
        w = res.get(k)
        if w is None or w.shape != v.shape:
            worst[name] = np.inf
            continue
        scale = max(np.max(np.abs(v)) if v.size else 0.0, 1e-300)
        worst[name] = max(worst.get(name, 0.0), float(np.max(np.abs(w - v), initial=0.0)) / scale)
    bad = 0
    for name, e in worst.items():
        print(f"{name:32s} max relative difference {e:.2e}")
        bad += not e <= 1e-12
    return 1 if bad else 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
