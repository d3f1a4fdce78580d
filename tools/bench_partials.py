"""Analytic Jacobian (blocks' declared partials) against coloured finite differences.

    python tools/bench_partials.py            # lugre, servo, then n = 8, 24, 48
    python tools/bench_partials.py 24         # one size
    python tools/bench_partials.py lugre      # one shipped diagram

Diagrams: ``lags``, a stiff chain of ``n`` first-order lags (StateSpace blocks ``x' =
-a_k x + a_k u``, ``a_k`` from 1 to 1e4 geometrically), each fed by a Sum of the previous lag
and a feedback Gain from the last one (a sparse Jacobian: 3 column groups); ``dense``, one
StateSpace of ``n`` states with a dense stiff ``A`` (``n`` groups), both for 2 s; and two
shipped diagrams whose blocks all declare partials, ``lugre_stick_slip.yaml`` (20 s,
1e-7/1e-10) and ``servo.yaml`` (1 s, 1e-6/1e-8). Each is integrated with ROS34PW2 and NDF,
with ``jacobian="analytic"`` and ``"fd"``. Printed per case: the cost of one Jacobian in the
compiled loop's own ``_jacobian`` (timed in a compiled loop of calls, best of 7: the
analytic one is one system call, the differences one evaluation per column group), then per
run the wall time (runs interleaved, best of 9), steps, RHS evaluations, Jacobians and the
largest difference of the final state from the analytic run's. Compare ratios within one
run (the machines are shared and noisy).
"""
from __future__ import annotations

import sys
import time

import numpy as np

import spidersim
from spidersim.solver import loop_body, rosenbrock
from spidersim.solver.loop_state import N_IST


def chain_text(n):
    a = np.geomspace(1.0, 1e4, n)
    lines = ["name: lags", "blocks:", "  r: {type: Step, t_step: 0.0}",
             "  fb: {type: Gain, k: -0.5}"]
    conns = []
    for k in range(n):
        lines.append(f"  s{k}: {{type: Sum, signs: '++'}}")
        lines.append(f"  x{k}: {{type: StateSpace, A: [[{-a[k]:.6g}]], B: [[{a[k]:.6g}]], "
                     f"C: [[1.0]]}}")
        conns += [f"{'r' if k == 0 else f'x{k - 1}'}.y -> s{k}.u1", f"fb.y -> s{k}.u2",
                  f"s{k}.y -> x{k}.u"]
    conns.append(f"x{n - 1}.y -> fb.u")
    lines += ["connections:"] + [f"  - {c}" for c in conns]
    lines.append("simulation: {t_end: 2.0, rtol: 1e-6, atol: 1e-9}")
    return "\n".join(lines) + "\n"


def dense_text(n):
    """One StateSpace of ``n`` states with a dense, stiff ``A`` (eigenvalues -1 .. -1e4
    rotated by a fixed orthogonal matrix): every column its own group for the
    differences."""
    rng = np.random.default_rng(1)
    Q, _ = np.linalg.qr(rng.standard_normal((n, n)))
    A = Q @ np.diag(-np.geomspace(1.0, 1e4, n)) @ Q.T
    rows = ", ".join("[" + ", ".join(f"{v:.12g}" for v in r) + "]" for r in A)
    B = ", ".join("[1.0]" for _ in range(n))
    C = "[" + ", ".join("1.0" for _ in range(n)) + "]"
    return (f"name: dense\nblocks:\n  u: {{type: Step, t_step: 0.0}}\n"
            f"  ss: {{type: StateSpace, A: [{rows}], B: [{B}], C: [{C}]}}\n"
            f"connections:\n  - u.y -> ss.u\n"
            f"simulation: {{t_end: 2.0, rtol: 1e-6, atol: 1e-9}}\n")


def _jacobian_cost(system, analytic, reps=2000):
    """Seconds per call of the loop's ``_jacobian`` (compiled loop of ``reps`` calls, best of
    7)."""
    import numba

    @numba.njit
    def many(fn, t, x, K, J, jpat, ist, sig, p, modes, reps):
        for _ in range(reps):
            loop_body._jacobian(fn, t, x, K, J, jpat, ist, sig, p, modes)

    n = system.n_x
    x = system.x0 + 0.1
    K = rosenbrock.work_array(n)
    K[0] = system.rhs(0.0, x)
    J = np.zeros((n, n))
    jpat = rosenbrock.pattern_array(system.jac_sparsity, n, analytic)
    ist = np.zeros(N_IST, dtype=np.int64)
    args = (system.fn, 0.0, x, K, J, jpat, ist, system.sig, system.p, system.modes)
    many(*args, 3)
    best = np.inf
    for _ in range(7):
        t0 = time.perf_counter()
        many(*args, reps)
        best = min(best, (time.perf_counter() - t0) / reps)
    return best, int(rosenbrock.n_groups(jpat)), J.copy()


#: shipped diagrams made only of blocks with partials: (file, t_end, rtol, atol)
FILES = {"lugre": ("diagrams/lugre_stick_slip.yaml", 20.0, 1e-7, 1e-10),
         "servo": ("diagrams/servo.yaml", 1.0, 1e-6, 1e-8)}


def run(n, kind="lags"):
    if kind in FILES:
        import os
        path, t_end, rtol, atol = FILES[kind]
        root = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
        d = spidersim.load(os.path.join(root, path))
        d.simulation.update(t_end=t_end, rtol=rtol, atol=atol)
    else:
        d = spidersim.loads(chain_text(n) if kind == "lags" else dense_text(n))
    s = d.compile(jit=True, loop=True, jacobian=True)
    assert s.analytic_jacobian
    ca, ng, Ja = _jacobian_cost(s, True)
    cf, _, Jf = _jacobian_cost(s, False)
    print(f"\n{kind}, n = {s.n_x if kind in FILES else n}: {ng} column groups; one Jacobian: analytic {ca * 1e6:.2f} us, "
          f"finite differences {cf * 1e6:.2f} us ({cf / ca:.1f}x); "
          f"max |J_a - J_fd| / max |J| = {np.abs(Ja - Jf).max() / np.abs(Ja).max():.1e}")
    print(f"  {'method':9} {'jacobian':9} {'wall ms':>8} {'steps':>6} {'RHS':>6} "
          f"{'Jac':>4}  final state diff")
    for method in ("ROS34PW2", "NDF"):
        res, best = {}, {"analytic": np.inf, "fd": np.inf}
        for _ in range(9):                   # interleaved, best of 9 each
            for jac in ("analytic", "fd"):
                t0 = time.perf_counter()
                res[jac] = d.simulate(method=method, jacobian=jac)
                best[jac] = min(best[jac], time.perf_counter() - t0)
        for jac in ("analytic", "fd"):
            r = res[jac]
            st = r.stats
            diff = np.abs(r.final[1] - res["analytic"].final[1]).max()
            print(f"  {method:9} {jac:9} {best[jac] * 1e3:8.2f} {st['steps']:6d} "
                  f"{st['rhs_calls']:6d} {st['jacobian_calls']:4d}  {diff:.1e}")


def main(argv):
    names = [a for a in argv if a in FILES]
    sizes = [int(a) for a in argv if a not in FILES]
    if not argv:
        names, sizes = list(FILES), [8, 24, 48]
    for name in names:
        run(0, name)
    for n in sizes:
        run(n, "lags")
    for n in sizes:
        run(n, "dense")


if __name__ == "__main__":
    main(sys.argv[1:])
