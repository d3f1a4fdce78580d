"""What one generated right-hand side costs, and what its parts cost (issue 14): measured.

    python tools/bench_rhs.py [servo|ball|loop ...] [--rounds N]

For a diagram of ``tools/check_loop_identical.py`` (default: the servo) the generated module
(``Diagram.source(jit=True)``) is written again as scratch variants, each imported from a
temporary folder (numba compiles it there), and one task of each variant's system function is
called 20,000 times in a compiled loop through its pointer, as ``run_loop`` calls it, with two
alternating states (ns per call, best of 7 calls of the loop minus the loop with one call).
The variants are timed interleaved, ``--rounds`` times (default 5): the range over rounds is
printed, since the machine is shared.

Variants (a variant whose text substitution does not apply to the current generator is
skipped, and says so):

* ``as is``: the module as spidersim generates it (small kernels marked ``alwaysinline``
  for LLVM, :mod:`spidersim.blocks.inlining`);
* ``kernels not inlined``: every kernel compiled by plain ``njit``, as before issue 14's
  session 8: LLVM's cost model then left ``outputs``, ``Gain.output`` and
  ``DCMotor.derivative`` as calls;
* ``numba inline='always'``: every kernel inlined by numba at the IR level (copied and typed
  again at each call site; the compile time column shows its price);
* ``as is, direct``: the generated ``evaluate`` compiled by ``njit`` and called directly
  (no function pointer, arrays instead of data pointers): the price of the indirection;

and hand-written references for the servo (the equations of ``tools/bench_loop.py``'s
``servo_f``):

* ``hand, direct``: ``servo_f`` called directly in the compiled loop;
* ``hand, pointer``: ``servo_f`` behind a C function of the system signature (the same
  indirect call as the generated one);
* ``hand, pointer, sig``: the same, also storing the ten signals into ``sig`` as the
  generated function must (the loop records them and ``GUARDS_AT_SIG`` reads them).

``--perf PROBLEM``: instead of the table, write a perf symbol map of the compiled loop's and
the diagram's functions and run ``run_loop`` for 8 s, for
``perf record -F 10000 python tools/bench_rhs.py --perf ball`` then ``perf report --sort sym``
(numba's code then shows by function name, not as hex addresses).
"""
from __future__ import annotations

import importlib
import os
import sys
import tempfile
import time

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from bench_common import best_time as _best  # noqa: E402
from check_loop_identical import CASES  # noqa: E402

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))

#: how a variant compiles the kernels: numba's njit with these options (None: as generated)
VARIANTS = {
    "as is": None,
    "kernels not inlined": "inline='never'",
    "numba inline='always'": "inline='always'",
}

_LOADER = "from spidersim.blocks.base import load_kernel\n"
_KERNEL_JIT = "    from spidersim.blocks.inlining import njit_inlinable as _jit_kernel\n"


def _variant_text(text, name):
    """The module text of variant ``name`` (see the module docstring), or None when its
    substitutions do not apply to the current generator."""
    how = VARIANTS[name]
    if how is None:
        return text
    if _LOADER not in text or _KERNEL_JIT not in text:
        return None
    text = text.replace(_LOADER, (
        "import importlib as _il\n"
        "from numba import njit as _nj\n"
        "def load_kernel(module, cls_name, kernel, jit):\n"
        "    return _nj(cache=True, nogil=True, error_model='numpy', __HOW__)(\n"
        "        getattr(getattr(_il.import_module(module), cls_name), kernel))\n"))
    text = text.replace(_KERNEL_JIT, (
        "    def _jit_kernel(f):\n"
        "        return njit(cache=True, nogil=True, error_model='numpy', __HOW__)(f)\n"))
    return text.replace("__HOW__", how)


def _import_text(text, tag, tmp):
    name = f"rhs_variant_{tag}_{os.getpid()}"
    path = os.path.join(tmp, name + ".py")
    with open(path, "w") as fh:
        fh.write(text)
    if tmp not in sys.path:
        sys.path.insert(0, tmp)
    return importlib.import_module(name)


def _hand_servo():
    """Hand-written servo system functions (addresses): without and with the sig stores."""
    from numba import carray, cfunc
    from spidersim.solver.sysfn import SYSTEM_SIG
    sys.path.insert(0, os.path.join(ROOT, "tools"))
    from bench_loop import servo_f

    @cfunc(SYSTEM_SIG, nogil=True, error_model="numpy")
    def hand(task, t, x_ptr, sig_ptr, p_ptr, modes_ptr, out_ptr, k, f):
        x = carray(x_ptr, 5)
        out = carray(out_ptr, 5)
        if task == 1:
            servo_f(t, x, out)
        return 0.0

    @cfunc(SYSTEM_SIG, nogil=True, error_model="numpy")
    def hand_sig(task, t, x_ptr, sig_ptr, p_ptr, modes_ptr, out_ptr, k, f):
        y = carray(x_ptr, 5)
        sig = carray(sig_ptr, 10)
        out = carray(out_ptr, 5)
        if task == 1:
            i, w, th, I_s, I_c = y[0], y[1], y[2], y[3], y[4]
            ref = 1.0 if t >= 0.01 else 0.0
            sig[0] = ref
            sig[1] = 0.05 * i
            sig[2] = ref - th
            w_ref = 20.0 * sig[2]
            sig[3] = w_ref
            e_w = w_ref - w
            sig[4] = e_w
            i_ref = 0.05 * e_w + I_s
            sig[5] = i_ref
            e_i = i_ref - i
            sig[6] = e_i
            sig[7] = 5.0 * e_i + I_c
            v = min(max(5.0 * e_i + I_c, -24.0), 24.0)
            sig[8] = v
            sig[9] = 0.0
            out[0] = (v - 1.0 * i - 0.05 * w) / 1e-3
            out[1] = (0.05 * i - 1e-5 * w) / 1e-4
            out[2] = w
            out[3] = 1.0 * e_w
            out[4] = 5000.0 * e_i
        return 0.0

    return {"hand, pointer": hand.address, "hand, pointer, sig": hand_sig.address}


def _many():
    import numba
    from bench_common import pointer_loop
    many = pointer_loop()

    # not cached: its type names the variant module's dispatcher, which a later process
    # cannot import
    @numba.njit(error_model="numpy")
    def many_direct(ev, task, n, t, x, sig, p, modes, out, x2):
        acc = 0.0
        for i in range(n):
            xx = x if (i & 1) == 0 else x2
            acc += ev(task, t + 1e-9 * i, xx, sig, p, modes, out, 0, 0.0)
        return acc
    return many, many_direct


def _hand_direct():
    """``servo_f`` as a compiled function of the arguments of ``evaluate``."""
    from numba import njit
    from bench_loop import servo_f

    @njit(error_model="numpy")
    def hand(task, t, x, sig, p, modes, out, k, f):
        if task == 1:
            servo_f(t, x, out)
        return 0.0
    return hand




def measure(problem, rounds):
    import spidersim
    from spidersim.solver import sysfn
    path, sets, kw = CASES[problem]
    d = spidersim.load(os.path.join(ROOT, path), set=sets)
    system = d.compile(True)
    text = d.source(jit=True)
    tmp = tempfile.mkdtemp(prefix="bench_rhs_")
    os.environ.setdefault("NUMBA_CACHE_DIR", os.path.join(tmp, "numba"))
    from numba import njit
    many, many_direct = _many()
    entries = {}
    t_compile = {}
    for k, name in enumerate(VARIANTS):
        vt = _variant_text(text, name)
        if vt is None:
            print(f"(variant '{name}' does not apply to this generator: skipped)")
            continue
        t0 = time.process_time()
        mod = _import_text(vt, k, tmp)
        entries[name] = (many, mod.SYSTEM)
        t_compile[name] = time.process_time() - t0
        if name == "as is":
            direct = njit(error_model="numpy")(mod.evaluate)
    entries["as is, direct"] = (many_direct, direct)
    if problem == "servo":
        entries.update({k: (many, a) for k, a in _hand_servo().items()})
        entries["hand, direct"] = (many_direct, _hand_direct())
    x = system.x0.copy() + 0.1
    x2 = x * 1.0001
    sig, p = system.sig.copy(), system.p.copy()
    modes = system.modes.copy()
    out = np.zeros(max(system.n_x, system.n_g, len(system.timed), 1))
    tasks = [("DERIVATIVES", sysfn.DERIVATIVES), ("OUTPUTS", sysfn.OUTPUTS)]
    if system.n_g:
        tasks.append(("GUARDS", sysfn.GUARDS))
    n = 20000
    res = {(v, tn): [] for v in entries for tn, _ in tasks}
    for v, (many, fn) in entries.items():
        for _tn, task in tasks:
            many(fn, task, 10, 0.5, x, sig, p, modes, out, x2)
    for _ in range(rounds):
        for v, (many, fn) in entries.items():
            for tn, task in tasks:
                if v.startswith("hand") and task != sysfn.DERIVATIVES:
                    continue
                base = _best(lambda: many(fn, task, 1, 0.5, x, sig, p, modes, out, x2), 7)
                tt = _best(lambda: many(fn, task, n, 0.5, x, sig, p, modes, out, x2), 7)
                res[(v, tn)].append(1e9 * (tt - base) / n)
    print(f"== {problem}: ns per system-function call through its pointer "
          f"(best of 7 x {n} calls; min - max over {rounds} interleaved rounds) ==")
    print(f"{'variant':24s} " + " ".join(f"{tn:>16s}" for tn, _ in tasks)
          + f" {'compile [s CPU]':>16s}")
    for v in entries:
        cells = []
        for tn, _ in tasks:
            r = res[(v, tn)]
            cells.append(f"{min(r):7.1f} - {max(r):6.1f}" if r else f"{'':16s}")
        comp = f"{t_compile[v]:16.2f}" if v in t_compile else f"{'':16s}"
        print(f"{v:24s} " + " ".join(f"{c:>16s}" for c in cells) + comp)
    print()


def write_perf_map(libraries, path=None):
    """``/tmp/perf-PID.map`` naming the machine code of every function defined in numba's
    ``libraries`` (perf then shows numba's functions by name instead of hex addresses; a
    function's extent is taken up to the next one's start). Returns the path."""
    import re
    addrs = {}
    for lib in libraries:
        for m in (getattr(lib, "_final_module", None), getattr(lib, "_shared_module", None)):
            for f in (m.functions if m is not None else ()):
                if f.is_declaration or f.name in addrs.values():
                    continue
                try:
                    a = lib._codegen._engine.get_function_address(f.name)
                except Exception:        # noqa: BLE001 - not in this engine: skip
                    a = 0
                if a:
                    addrs[a] = f.name
    items = sorted(addrs.items())
    path = path or f"/tmp/perf-{os.getpid()}.map"
    with open(path, "w") as fh:
        for (a, name), (nxt, _) in zip(items, items[1:] + [(items[-1][0] + 4096, "")]):
            parts = re.findall(r"\d+([A-Za-z_][A-Za-z0-9_]*)", name[:200])
            label = ".".join(parts[-3:]) if name.startswith("_ZN") and parts else name
            fh.write(f"{a:x} {min(nxt - a, 1 << 20):x} {label}\n")
    return path


def perf_loop(problem, seconds=8.0):
    """``run_loop`` of ``problem`` again and again for ``seconds`` (run this under
    ``perf record``), after writing a perf symbol map of the loop's and the diagram's
    compiled functions (:func:`write_perf_map`)."""
    import spidersim
    from spidersim.solver import loop as L
    from spidersim.solver.system import loop_entry
    from spidersim.solver.sysfn import entry_point
    path, sets, kw = CASES[problem]
    d = spidersim.load(os.path.join(ROOT, path), set=sets)
    d.simulate(**kw)
    method = kw.get("method", d.simulation["method"])
    run_loop = loop_entry(method)             # the compiled loop's entry of the method
    system = d.compile(True, loop=method)
    mod = d._modules[True][0]
    libs = [c.library for c in run_loop.overloads.values()] + [mod._system._library]
    print(f"perf map: {write_perf_map(libs)}", flush=True)

    def args():
        r = L.CompiledLoop(system.compiled_entry, system, 0.0, kw["t_end"], kw["rtol"],
                           kw["atol"], kw["max_step"], None, None, method=kw["method"],
                           capacity=1 << 12)
        return (r.entry,) + r.arguments()
    entry = entry_point(run_loop, args())
    t0, n = time.perf_counter(), 0
    while time.perf_counter() - t0 < seconds:
        entry(*args())
        n += 1
    print(f"{n} runs, {1e3 * (time.perf_counter() - t0) / n:.3f} ms each (with the Python "
          f"that sets each run up)")


def main(argv):
    rounds = 5
    if "--rounds" in argv:
        i = argv.index("--rounds")
        rounds = int(argv[i + 1])
        del argv[i:i + 2]
    if argv and argv[0] == "--perf":
        perf_loop(argv[1] if len(argv) > 1 else "servo")
        return
    unknown = [a for a in argv if a not in CASES]
    if unknown:
        print(__doc__)
        print(f"problems: {', '.join(CASES)}; not known: {', '.join(unknown)}")
        sys.exit(0 if unknown in (["--help"], ["-h"]) else 2)
    for problem in argv or ["servo"]:
        measure(problem, rounds)


if __name__ == "__main__":
    main(sys.argv[1:])
