"""Where a compile's time goes: numba's compile events per function, in a fresh process.

    python tools/profile_compile.py [cold|new|cached] [DIAGRAM] [--top N]

Runs ``import spidersim; load(DIAGRAM).compile(jit=True, loop=True)`` in a child process
with a numba event listener on ``numba:compile`` and prints, per compiled function, its
*exclusive* time (the compile minus the compiles it triggered, which nest), the number of
compiles (one per type signature) and the module, largest first; then the totals by module
and the wall and CPU time of the import and of the compile.

* ``cold``: empty ``SPIDERSIM_CACHE`` and ``NUMBA_CACHE_DIR`` (the first run after
  installing: every kernel, the loop and the diagram compile);
* ``new``: empty ``SPIDERSIM_CACHE`` only (a new diagram structure; spidersim's own kernels and
  loop come from numba's cache, if they are there);
* ``cached``: both caches as they are (run it after one of the others).

DIAGRAM defaults to spider.yaml. Loading from numba's cache is not a ``numba:compile``
event; its time shows in the totals, not in the table.
"""
from __future__ import annotations

import json
import os
import subprocess
import sys
import tempfile

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))

_CHILD = r"""
import json, sys, time
from numba.core import event

spans = []          # (name, module, start, end)
stack = []

class _Listener(event.Listener):
    def on_start(self, ev):
        stack.append((ev.data["dispatcher"], time.perf_counter()))

    def on_end(self, ev):
        disp, t0 = stack.pop()
        py = getattr(disp, "py_func", None)
        name = getattr(py, "__qualname__", str(disp))
        mod = getattr(py, "__module__", "?")
        spans.append((name, mod, t0, time.perf_counter(), len(stack)))

event.register("numba:compile", _Listener())
t0, c0 = time.perf_counter(), time.process_time()
import spidersim
t1, c1 = time.perf_counter(), time.process_time()
d = spidersim.load(sys.argv[1])
d.compile(jit=True, loop=True)
t2, c2 = time.perf_counter(), time.process_time()
print(json.dumps({"spans": spans, "import": [t1 - t0, c1 - c0],
                  "compile": [t2 - t1, c2 - c1]}))
"""


def _exclusive(spans):
    """Exclusive seconds per (name, module): a span minus the spans directly inside it."""
    spans = sorted(spans, key=lambda s: (s[2], -s[3]))
    excl, count = {}, {}
    for k, (name, mod, a, b, depth) in enumerate(spans):
        inner = sum(s[3] - s[2] for s in spans
                    if s[4] == depth + 1 and a <= s[2] and s[3] <= b)
        key = (name, mod)
        excl[key] = excl.get(key, 0.0) + (b - a) - inner
        count[key] = count.get(key, 0) + 1
    return excl, count


def main(argv):
    mode = argv[0] if argv and argv[0] in ("cold", "new", "cached") else "cold"
    rest = [a for a in argv if a not in ("cold", "new", "cached")]
    top = 25
    if "--top" in rest:
        i = rest.index("--top")
        top = int(rest[i + 1])
        del rest[i:i + 2]
    path = os.path.abspath(rest[0]) if rest else os.path.join(ROOT, "spider.yaml")
    with tempfile.TemporaryDirectory() as tmp:
        env = dict(os.environ, PYTHONPATH=ROOT + os.pathsep + os.environ.get("PYTHONPATH", ""))
        if mode in ("cold", "new"):
            env["SPIDERSIM_CACHE"] = os.path.join(tmp, "spidersim")
        if mode == "cold":
            env["NUMBA_CACHE_DIR"] = os.path.join(tmp, "numba")
        res = subprocess.run([sys.executable, "-c", _CHILD, path], env=env,
                             capture_output=True, text=True)
    if res.returncode:
        sys.stderr.write(res.stderr[-3000:])
        return 1
    data = json.loads(res.stdout.strip().splitlines()[-1])
    excl, count = _exclusive([tuple(s) for s in data["spans"]])
    total = sum(excl.values())
    print(f"== {mode}: {os.path.relpath(path, ROOT)}; import {data['import'][0]:.1f} s wall "
          f"({data['import'][1]:.1f} s CPU), load + compile {data['compile'][0]:.1f} s wall "
          f"({data['compile'][1]:.1f} s CPU); numba compiles {total:.1f} s in "
          f"{sum(count.values())} compiles of {len(excl)} functions")
    print(f"{'exclusive [s]':>13s} {'n':>3s}  function (module)")
    for (name, mod), sec in sorted(excl.items(), key=lambda kv: -kv[1])[:top]:
        print(f"{sec:13.2f} {count[(name, mod)]:3d}  {name} ({mod})")
    by_mod = {}
    for (name, mod), sec in excl.items():
        by_mod[mod] = by_mod.get(mod, 0.0) + sec
    print("== by module")
    for mod, sec in sorted(by_mod.items(), key=lambda kv: -kv[1])[:15]:
        print(f"{sec:13.2f}  {mod}")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
