"""Command line: ``spidersim run | check | linearize | sweep | blocks``.

Errors of the user's making (:class:`~spidersim.errors.SpidersimError`) are printed as
``file:line: block 'path': message`` without a traceback, and the exit status is 2. A run
that fails part-way still writes the data it computed and a report saying where and why.
"""
from __future__ import annotations

import argparse
import math
import os
import sys
import time
import warnings

from .errors import DiagramError, SpidersimError, printable
from .outputs import prepare_out, safe_stem


class Progress:
    """Progress bar on stderr for runs longer than a second (a line per 25 % off a tty)."""

    def __init__(self, t_end, stream=None):
        self.t_end = t_end
        # sys.stderr of the moment (a default bound at import kept a closed stream once
        # the caller had replaced it: a notebook's, or pytest's capture of an earlier test)
        self.stream = stream if stream is not None else sys.stderr
        self.t0 = time.perf_counter()
        self.last = 0.0
        self.tty = self.stream.isatty()
        self.shown = False
        self.next_mark = 0.25

    def __call__(self, t):
        now = time.perf_counter()
        if now - self.t0 < 1.0 or now - self.last < 0.2:
            return
        self.last = now
        frac = min(1.0, t / self.t_end) if self.t_end > 0 else 1.0
        if self.tty:
            n = int(30 * frac)
            self.stream.write(f"\r  [{'#' * n}{'.' * (30 - n)}] {100 * frac:5.1f}%  "
                              f"t = {t:.4g} / {self.t_end:g} s  ({now - self.t0:.1f} s)")
            self.stream.flush()
            self.shown = True
        elif frac >= self.next_mark:
            self.stream.write(f"  {100 * frac:.0f}%  t = {t:.4g} / {self.t_end:g} s  "
                              f"({now - self.t0:.1f} s)\n")
            while self.next_mark <= frac:
                self.next_mark += 0.25

    def close(self):
        if self.shown:
            self.stream.write("\n")


def _parse_sets(items):
    """``--set path=VALUE`` items -> ``{path: value}``, each value read by the rules of a
    diagram file's values (:func:`~spidersim.text.yamlio.command_line_value`: ``010``
    and ``1:30`` are refused as in a file; they were 8 and 90)."""
    from .text.yamlio import command_line_value
    out = {}
    for item in items or []:
        if "=" not in item:
            raise SpidersimError(f"--set expects path=value, got '{item}'")
        k, v = item.split("=", 1)
        out[k.strip()] = command_line_value(v, f"--set {k.strip()}")
    return out


def _compile_with_progress(d, jit, loop=False, jacobian=False):
    """Compile (or load) the diagram, saying what happens and for how long: generation,
    numba compilation of a new structure with a heartbeat every 10 s, or a cache hit."""
    import threading
    from .solver.compiled import is_cached
    head = f"spidersim: {printable(d.spec.name)}: {len(d.blocks)} blocks, {d.layout.n_x} states"
    t0 = time.perf_counter()
    if not jit:
        print(f"{head}; interpreted mode (no numba) ...", file=sys.stderr)
        d.compile(jit=False)
        return
    cached = is_cached(d.source(True, jacobian), loop=loop)
    print(f"{head}; " + ("loading compiled code from the cache ..." if cached else
                         "new structure: compiling with numba (the first run of a "
                         "structure takes seconds to a minute; later runs load it) ..."),
          file=sys.stderr)
    done = threading.Event()

    def heartbeat():
        while not done.wait(10.0):
            print(f"  ... still compiling ({time.perf_counter() - t0:.0f} s)",
                  file=sys.stderr)
    beat = threading.Thread(target=heartbeat, daemon=True)
    if not cached:
        beat.start()
    try:
        d.compile(jit=True, loop=loop, jacobian=jacobian)
    finally:
        done.set()
    dt = time.perf_counter() - t0
    print(f"spidersim: {'loaded from the cache' if cached else 'compiled'} in {dt:.1f} s",
          file=sys.stderr)


def _raw_sets(items):
    """``--set`` items as given (path -> the value's text), for the report."""
    return dict(item.split("=", 1) for item in items or [] if "=" in item)


def provenance(args, d, sets):
    """What a run's report must hold to be repeated: versions, platform, date, the hashes
    of the diagram file and its subsystem files (keyed by absolute path: ``--rerun`` from
    another folder checks the same files), the command line, every --set."""
    import datetime
    import hashlib
    import platform
    from importlib.metadata import PackageNotFoundError, version

    def v(pkg):
        try:
            return version(pkg)
        except PackageNotFoundError:
            return "not installed"

    files = [d.file] + sorted(set(d.flat.subsystem_instances.values()))
    hashes = {}
    for f in files:
        with open(f, "rb") as fh:
            hashes[os.path.abspath(f)] = hashlib.sha256(fh.read()).hexdigest()
    return {
        "versions": {"spidersim": _version(), "python": platform.python_version(),
                     **{p: v(p) for p in ("numpy", "scipy", "numba", "networkx",
                                          "control")}},
        "platform": platform.platform(),
        "date_utc": datetime.datetime.now(datetime.timezone.utc).isoformat(timespec="seconds"),
        "file": os.path.abspath(d.file),
        "file_sha256": hashes,
        "command": " ".join(sys.argv) if sys.argv and sys.argv[0] else "",
        "rerun": {"file": os.path.abspath(d.file), "set": dict(sets),
                  "t_end": args.t_end, "method": args.method, "jit": not args.no_jit,
                  "plots": not args.no_plots},
    }


def _check_rerun_spec(name, prov, spec):
    """The fields of a report's ``provenance`` that ``--rerun`` reads have the types a run
    writes (a hand-edited or foreign report is refused, naming the field)."""
    def bad(field, expected):
        raise SpidersimError(f"--rerun {name}: not a spidersim run report: provenance "
                             f"'{field}' must be {expected}")

    scalar = (str, int, float, bool)
    if not isinstance(spec, dict):
        bad("rerun", "a mapping")
    if not isinstance(spec.get("file"), str):
        bad("rerun.file", "a path")
    sets = spec.get("set")
    if not isinstance(sets, dict) or not all(
            isinstance(k, str) and isinstance(v, scalar) for k, v in sets.items()):
        bad("rerun.set", "a mapping of names to values")
    t_end = spec.get("t_end")
    if t_end is not None and (isinstance(t_end, bool) or not isinstance(t_end, (int, float))):
        bad("rerun.t_end", "a number or null")
    if spec.get("method") is not None and not isinstance(spec.get("method"), str):
        bad("rerun.method", "a method name or null")
    if not isinstance(spec.get("jit"), bool):
        bad("rerun.jit", "true or false")
    if not isinstance(spec.get("plots", True), bool):    # absent in reports before 0.1.x
        bad("rerun.plots", "true or false")
    hashes = prov.get("file_sha256", {})
    if not isinstance(hashes, dict) or not all(
            isinstance(k, str) and isinstance(v, str) for k, v in hashes.items()):
        bad("file_sha256", "a mapping of paths to hashes")


def _rerun_args(args):
    """Fill ``args`` from a run's report (``report.json``, or the folder holding it)."""
    import hashlib
    import json
    path = args.rerun
    if os.path.isdir(path):
        path = os.path.join(path, "report.json")
    elif path.endswith("report.txt"):
        path = path[:-4] + ".json"
    try:
        with open(path, encoding="utf-8") as fh:
            prov = json.load(fh)["provenance"]
        spec = prov["rerun"]
    except (OSError, ValueError, KeyError, TypeError) as exc:
        raise SpidersimError(f"--rerun {args.rerun}: not a spidersim run report "
                             f"(report.json with its provenance): {exc}") from None
    _check_rerun_spec(args.rerun, prov, spec)
    if (args.file is not None or args.set or args.t_end is not None
            or args.method is not None):
        raise SpidersimError("--rerun repeats a run exactly: give no FILE, --set, --t-end "
                             "or --method with it")
    args.file = spec["file"]
    args.set = [f"{k}={v}" for k, v in spec["set"].items()]
    args.t_end, args.method, args.no_jit = spec["t_end"], spec["method"], not spec["jit"]
    args.no_plots = args.no_plots or not spec.get("plots", True)   # a --no-plots run's too
    hashes = prov.get("file_sha256", {})
    for key, h in hashes.items():
        f = _hashed_file(key, hashes, spec["file"])
        if f is None:
            print(f"spidersim: warning: cannot check whether {key} has changed: the report "
                  f"gives its path relative to the folder the run was started in",
                  file=sys.stderr)
            continue
        try:
            with open(f, "rb") as fh:
                now = hashlib.sha256(fh.read()).hexdigest()
        except OSError:
            now = None
        if now != h:
            print(f"spidersim: warning: {f} has changed since the reported run (its SHA-256 "
                  f"differs): the rerun uses the file as it is now", file=sys.stderr)
    return args


def _hashed_file(key, hashes, main):
    """The file a key of a report's ``file_sha256`` names: an absolute path as it is; a
    relative one (reports before 0.1.x: relative to the folder the run was started in)
    resolved against that folder, found from the diagram file's key (its first) and
    absolute path ``main``; None when that folder cannot be told (a key with ``..``)."""
    if os.path.isabs(key):
        return key
    first = os.path.normpath(next(iter(hashes)))
    if os.path.isabs(first) or first.split(os.sep)[0] == os.pardir:
        return None
    main = os.path.normpath(main)
    if not main.endswith(os.sep + first):
        return None
    return os.path.normpath(os.path.join(main[:-len(first)], key))


def cmd_run(args):
    if args.remote:
        return cmd_run_remote(args)
    from . import load
    _check_local_options(args)
    if args.rerun is not None:
        args = _rerun_args(args)
    if args.file is None:
        raise SpidersimError("spidersim run: give a diagram FILE (or --rerun REPORT)")

    sets = _parse_sets(args.set)
    d = load(args.file, set=sets)
    validate_run(d, args.t_end, args.method)    # None: the file's, located at its line
    t_end = args.t_end if args.t_end is not None else d.simulation["t_end"]
    out = args.out or default_out(d)
    out = prepare_out(out)
    stop = StopRequest()
    # SIGINT/SIGTERM handled from here to the last file written: before the integration
    # they end the command at once; during it they stop it at the current step; while the
    # results are written the writing finishes first (a second signal ends it at once,
    # leaving complete files only)
    with stop.installed():
        from .solver.integrate import COMPILED, STIFF
        method = args.method or d.simulation["method"]
        _compile_with_progress(d, jit=not args.no_jit, loop=method in COMPILED and method,
                               jacobian=method in STIFF)
        prog = Progress(t_end)
        try:
            r = d.simulate(t_end=t_end, method=args.method, jit=not args.no_jit,
                           progress=prog, should_stop=stop)
        except SpidersimError as exc:
            prog.close()
            if getattr(exc, "partial", None) is not None:
                stop.writing()
                exc.partial.provenance = provenance(args, d, _raw_sets(args.set))
                _write_results(exc.partial, d, out, args.no_plots)
                print(f"spidersim: partial data up to the failure (data and plots) written "
                      f"to {out}/", file=sys.stderr)
            raise
        prog.close()
        stop.writing()
        r.provenance = provenance(args, d, _raw_sets(args.set))
        pngs = _write_results(r, d, out, args.no_plots)
    if r.status == "interrupted":
        print(f"spidersim: {stop.name} at t = {r.stats['t_reached']:.6g} s: results up to "
              f"there written to {out}/ (report says 'status: interrupted')",
              file=sys.stderr)
        return stop.exit_code
    if stop.requested:                    # the signal came while the results were written
        print(f"spidersim: {stop.name} after the run had finished: the results in {out}/ "
              f"are complete", file=sys.stderr)
        return stop.exit_code
    if getattr(args, "show", False):
        _show(r, d)
    s = r.stats
    print(f"spidersim: done: t = {s['t_reached']:.10g} s, {s['steps']} steps, "
          f"{s['rhs_calls']} RHS calls, "
          + (f"{s['wall_time']:.3f} s" if s['wall_time'] >= 0.1 else
             f"{1e3 * s['wall_time']:.2f} ms") + " integration")
    print(f"spidersim: wrote {out}/result.npz, "
          + ("result.csv, " if r.csv_written() else "") + "report.txt"
          + (f" and {len(pngs)} plot(s)" if pngs else ""))
    if s.get("method") in EXPLICIT and s["steps"] >= STIFF_HINT_STEPS:
        print(f"spidersim: note: {s['method']} took {s['steps']:,} steps; if the diagram is "
              f"stiff (a fast electrical, bristle or contact mode), a stiff method takes "
              f"far fewer: --method NDF (or ROS34PW2, LSODA)", file=sys.stderr)
    return 0


#: explicit methods, and the step count from which a run with one of them says the diagram
#: may be stiff (a DC motor with L = 1e-8 H took 60 million DP54 steps without a word)
EXPLICIT = ("DP54", "RK45", "RK23", "DOP853")
STIFF_HINT_STEPS = 1_000_000
#: seconds ``run --remote`` waits for its job when no --timeout is given
REMOTE_TIMEOUT = 3600.0


def _show(r, d):
    """The diagram's time plots in windows (``run --show``); files are written already."""
    import matplotlib
    import matplotlib.pyplot as plt
    if matplotlib.get_backend().lower() == "agg":
        try:
            plt.switch_backend("TkAgg")
        except Exception:          # noqa: BLE001 (no display or no Tk: say so, keep files)
            print("spidersim: --show: no interactive display available; the plots are in "
                  "the results folder", file=sys.stderr)
            return
    for spec in d.spec.plots:
        if spec.get("kind", "time") == "time":
            r.plot(spec["signals"], title=spec.get("title"),
                   one_panel=bool(spec.get("one_panel")))
    if not d.spec.plots:
        r.plot(title=d.spec.name)
    plt.show()


class StopRequest:
    """SIGINT/SIGTERM during ``spidersim run``.

    Before the integration starts (loading, compiling) a signal ends the command at once
    (nothing computed yet). During the integration the first signal asks it to stop at the
    current step: ``stop()`` is the integration's ``should_stop`` (a flag read after each
    accepted step) and the results up to there are written. While the results are written a
    signal lets the writing finish. A second signal always ends the command at once (every
    file is still either complete or absent). Exit status 130 (SIGINT) or 143 (SIGTERM).
    """

    CODES = {"SIGINT": 130, "SIGTERM": 143}
    #: what had not started when a signal ends the command at once
    BEFORE = "the integration started"

    def __init__(self):
        self.requested = False
        self.name = None
        self.phase = "before"          # "before" -> "integrating" -> "writing"

    def __call__(self):
        self.phase = "integrating"
        return self.requested

    def writing(self):
        """The integration is over; from now on a first signal lets the files be written."""
        self.phase = "writing"

    @property
    def exit_code(self):
        return self.CODES.get(self.name, 130)

    def _handle(self, signum, frame):
        import signal
        name = signal.Signals(signum).name
        if self.requested:
            raise _Interrupted(name, f"interrupted again ({name}): stopped at once")
        if self.phase == "before":
            raise _Interrupted(name, f"interrupted ({name}) before {self.BEFORE}: nothing "
                                     f"computed to keep")
        self.requested, self.name = True, name
        if self.phase == "writing":
            sys.stderr.write(f"spidersim: {name}: finishing writing the results "
                             f"(send it again to stop at once)\n")

    def installed(self):
        import contextlib
        import signal
        import threading

        @contextlib.contextmanager
        def ctx():
            if threading.current_thread() is not threading.main_thread():
                yield
                return
            old = {s: signal.signal(s, self._handle) for s in (signal.SIGINT, signal.SIGTERM)}
            try:
                yield
            finally:
                for s_, h in old.items():
                    signal.signal(s_, h)
        return ctx()


class _Interrupted(KeyboardInterrupt):
    """A signal that ends the command at once: before the integration (nothing computed to
    keep) or a second signal. A KeyboardInterrupt, so that no ``except Exception`` on the
    way (numba, the cache's retry) mistakes it for a failure; :func:`main` prints it."""

    def __init__(self, name, message=None):
        self.message = message or (f"interrupted ({name}) before the integration started: "
                                   f"nothing computed to keep")
        super().__init__(self.message)
        self.exit_code = StopRequest.CODES.get(name, 130)


def _write_results(r, d, out, no_plots):
    """Data, report, plots and the microgravity assessment of a (possibly partial) result;
    a file that cannot be written is an error naming it (never a truncated file)."""
    from .plots import make_plots
    try:
        _remove_previous_run(out)
        r.save(out, reports=False)
        if no_plots or len(r.t) < 2:
            pngs = _microgravity_report(d, r, out, plots=False) if len(r.t) > 1 else []
        else:
            pngs = make_plots(r, d.spec.plots, out)
            pngs += _microgravity_report(d, r, out, plots=True)
        mg = ["microgravity.json"] if os.path.isfile(os.path.join(out, "microgravity.json")) \
            and d.microgravity is not None else []
        r.files = tuple(["result.npz"] + (["result.csv"] if r.csv_written() else [])
                        + ["report.txt", "report.json"] + mg
                        + [os.path.basename(p) for p in pngs])
        r.save_reports(out)
        return pngs
    except OSError as exc:
        raise SpidersimError(f"{exc.strerror or exc}; the results folder {out} keeps only "
                             f"complete files (free some space or choose another --out)"
                             ) from None


def _remove_previous_run(out):
    """Remove the files the previous run into ``out`` wrote (the ``files`` of its
    ``report.json``), so that the folder holds this run's files only (a second run with
    --no-plots left the first run's plots beside the new data); other files stay."""
    import json
    import re

    from .outputs import remove_stale
    try:
        # the list is in the head, before the event log (which may be hundreds of MB)
        with open(os.path.join(out, "report.json"), encoding="utf-8", errors="replace") as fh:
            head = fh.read(1 << 22)
        m = re.search(r'\n "files": (\[[^\]]*\])', head)
        listed = json.loads(m.group(1)) if m else []
    except (OSError, ValueError):
        return []
    removed = remove_stale(out, listed if isinstance(listed, list) else ())
    other = [n for n in removed if n not in ("result.npz", "result.csv", "report.txt",
                                             "report.json")]      # rewritten anyway
    if other:
        print(f"spidersim: removed the previous run's {', '.join(other)} from {out}/",
              file=sys.stderr)
    return removed


def _microgravity_report(d, r, out, plots=True):
    """The diagram's ``microgravity`` assessment of a run: table on stdout,
    ``microgravity.json`` (and ``microgravity.png``) in ``out``; returns the plots written."""
    mg_spec = d.microgravity
    if mg_spec is None:
        return []
    import json

    from . import microgravity as mg
    t_end = float(r.t[-1])
    t0, t1 = mg_spec["window"] or (0.0, t_end)
    cut = ""
    if t1 > t_end:
        print(f"spidersim: microgravity: window ends at {t1:g} s after the run's end "
              f"({t_end:g} s); assessing up to {t_end:g} s", file=sys.stderr)
        cut = (f"the run ended at {t_end:g} s, inside the window {t0:g}..{t1:g} s: the "
               f"low bands only the whole window resolves were not assessed; run to "
               f"{t1:g} s for a verdict")
        t1 = t_end
    if not t0 < t1:
        print(f"spidersim: microgravity: the run ended ({t_end:g} s) before the window "
              f"starts ({t0:g} s): no assessment", file=sys.stderr)
        return []
    try:
        newtons = mg.newtons_per_unit(r.units.get(mg_spec["signal"]))
        a = mg.assess(r.t, r[mg_spec["signal"]] * newtons, mg_spec["mass"],
                      window=(t0, t1), f_range=(mg_spec["f_min"], mg_spec["f_max"]))
    except ValueError as exc:
        print(f"spidersim: microgravity: {exc}", file=sys.stderr)
        return []
    a.axes = ["x", "y", "z"][:a.levels.shape[1]] if a.levels.shape[1] <= 3 else []
    a.incomplete = cut
    print(a.table())
    from .outputs import atomic_path, write_atomic
    write_atomic(os.path.join(out, "microgravity.json"),      # strict JSON: no NaN
                 lambda fh: json.dump(a.as_dict(), fh, indent=1, allow_nan=False))
    if not plots:
        return []
    path = os.path.join(out, "microgravity.png")
    with atomic_path(path) as tmp:
        mg.plot(a, tmp)
    return [path]


def default_out(d, suffix=""):
    """``results/<name><suffix>``: the diagram's ``name:`` made safe (else the file name's
    stem), so that a name can never choose a folder elsewhere."""
    return os.path.join("results", safe_stem(d.spec.name, os.path.splitext(
        os.path.basename(d.file))[0]) + suffix)


def _check_method(d, method):
    """The integration method (``--method`` or ``simulation.method``) is one of
    ``METHODS``; return it. A value from the command line (None: not given; an empty
    text is given) is reported without a line."""
    from .solver.integrate import METHODS
    where, line = (("--method", None) if method is not None else
                   ("simulation.method", d.spec.simulation_lines.get("method")))
    method = d.simulation["method"] if method is None else method
    if method not in METHODS:
        import difflib
        near = difflib.get_close_matches(str(method), list(METHODS), n=1)
        raise DiagramError(f"{where}: unknown method '{method}'"
                           + (f" (did you mean '{near[0]}'?)" if near else "")
                           + f"; methods: {', '.join(METHODS)}", file=d.file, line=line)
    return method


def _check_t_end(d, t_end):
    """The run length (``--t-end`` or ``simulation.t_end``) is a finite time > 0 s; return
    it."""
    where, line = (("--t-end", None) if t_end is not None else
                   ("simulation.t_end", d.spec.simulation_lines.get("t_end")))
    t_end = d.simulation["t_end"] if t_end is None else t_end
    if not (isinstance(t_end, (int, float)) and not isinstance(t_end, bool)
            and math.isfinite(t_end) and t_end > 0):
        raise DiagramError(f"{where}: t_end must be a finite time > 0 s, got {t_end!r}",
                           file=d.file, line=line)
    from .solver.events import MIN_SPAN
    if t_end < MIN_SPAN:
        raise DiagramError(f"{where}: t_end must be at least {MIN_SPAN:g} s (the solvers "
                           f"take steps shorter than 1e-10 s as a stall), got {t_end!r}",
                           file=d.file, line=line)
    return t_end


def _check_simulation_steps(d, t_end):
    """``output_interval`` at most ``t_end``, ``first_step`` shorter than ``t_end``, and
    ``rtol``, ``atol``, ``max_step``, ``first_step`` finite."""
    sim_line = d.spec.simulation_lines
    oi = d.simulation.get("output_interval")
    if oi is not None and not oi <= t_end:
        raise DiagramError(f"simulation.output_interval ({oi:g} s) is longer than the run "
                           f"(t_end = {t_end:g} s); make it at most t_end", file=d.file,
                           line=sim_line.get("output_interval"))
    fs = d.simulation.get("first_step")
    if fs is not None and not fs < t_end:
        raise DiagramError(f"simulation.first_step ({fs:g} s) must be shorter than the run "
                           f"(t_end = {t_end:g} s)", file=d.file,
                           line=sim_line.get("first_step"))
    for k in ("rtol", "atol", "max_step", "first_step"):
        v = d.simulation.get(k)
        if v is not None and not math.isfinite(v):
            raise DiagramError(f"simulation.{k} must be finite, got {v!r}", file=d.file,
                               line=sim_line.get(k))


def _check_analysis_signal(d, name, s_, line):
    """Signal ``s_`` named by analysis entry ``name`` is a signal of the diagram."""
    from .diagram.analysis import _signal_ref
    try:
        if not isinstance(s_, str):
            raise DiagramError(f"a signal name, got {s_!r}")
        _signal_ref(d, s_)
    except SpidersimError as exc:
        raise DiagramError(f"analysis '{name}': {exc.message}", file=d.file,
                           line=line) from None


def _valid_analysis_time(at, t_end):
    """``at`` of an analysis entry: None, 'initial', 'trim', a mapping (an operating
    point) or a time in [0, t_end]: 0 (the initial point) or at least the shortest run
    (the operating point at ``at`` is a simulation to ``at``)."""
    from .solver.events import MIN_SPAN
    return at is None or at in ("initial", "trim") or isinstance(at, dict) or (
        isinstance(at, (int, float)) and not isinstance(at, bool)
        and (at == 0 or MIN_SPAN <= at <= t_end))


def _check_analysis(d, t_end):
    """Every ``analysis`` entry (:func:`_check_analysis_entry`)."""
    for name in d.spec.analysis:
        _check_analysis_entry(d, name, t_end)


def _check_analysis_entry(d, name, t_end, check_at=True):
    """The analysis entry ``name`` has a loop or inputs and outputs (not both), names
    signals of the diagram, has a valid ``at`` (unless ``check_at`` is False: ``--at``
    replaces it) and no sampled block on its path; returns
    ``(inputs, outputs, open, at, loop)``."""
    from .linreport import analysis_request
    line = getattr(d.spec.data.get("analysis"), "line_of", lambda k: None)(name)
    inputs, outputs, opened, at, loop = analysis_request(d, name)
    if loop is None and not (inputs and outputs):
        raise DiagramError(f"analysis '{name}' needs a 'loop' signal, or 'inputs' and "
                           f"'outputs' (at least one of each), got "
                           f"{len(inputs)} input(s) and {len(outputs)} output(s)",
                           file=d.file, line=line)
    for s_ in inputs + outputs + opened + ([loop] if loop is not None else []):
        _check_analysis_signal(d, name, s_, line)
    if check_at and not _valid_analysis_time(at, t_end):
        raise DiagramError(f"analysis '{name}': 'at' must be 'initial', 'trim', a "
                           f"mapping or a time in [0, t_end] (0 or at least 1e-07 "
                           f"s), got {at!r}", file=d.file, line=line)
    if check_at and isinstance(at, dict):
        _check_trim_at(d, name, at, line)
    if loop is not None and (inputs or outputs):
        raise DiagramError(f"analysis '{name}': give either 'loop' or 'inputs' and "
                           f"'outputs', not both", file=d.file, line=line)
    _check_continuous(d, name, inputs, outputs, opened, loop, line)
    return inputs, outputs, opened, at, loop


def _check_continuous(d, name, inputs, outputs, opened, loop, line=None):
    """No sampled block on the path of a linearization (analysis ``name``, or the command
    line's signals when None); a :class:`DiagramError` naming the blocks and parameters."""
    from .diagram.analysis import AnalysisError, check_continuous_path
    try:
        if loop is not None:
            check_continuous_path(d, [loop], [loop], [loop])
        else:
            check_continuous_path(d, inputs, outputs, opened)
    except AnalysisError as exc:
        raise DiagramError((f"analysis '{name}': " if name else "") + exc.message,
                           file=d.file, line=line) from None


def _check_trim_at(d, name, at, line):
    """The trim operating point ``at`` of analysis ``name``: keys and values
    (:func:`~spidersim.diagram.analysis.trim_request`), each target's size against its
    signal's, ``x0``'s against the states'; a :class:`DiagramError` at the entry's line."""
    from .diagram.analysis import AnalysisError, trim_request, trim_targets
    try:
        kw = trim_request(at)
        trim_targets(d, kw["targets"])
        if kw.get("x0") is not None and len(kw["x0"]) != d.layout.n_x:
            raise AnalysisError(f"trim: 'x0' has {len(kw['x0'])} value(s), the diagram "
                                f"has {d.layout.n_x} state(s)")
    except AnalysisError as exc:
        raise DiagramError(f"analysis '{name}': {exc.message}", file=d.file,
                           line=line) from None


def validate_run(d, t_end=None, method=None):
    """Every check ``run`` makes before integrating, so that ``check`` refuses what ``run``
    would: method, t_end, output_interval, plots (keys, signals, sizes, files), analysis
    entries, windows, and the uniform grid a spectrum or the microgravity bands need.
    (Loading already checked the blocks, parameters, wiring, log, metrics and the
    microgravity section's own settings.)"""
    from .plots import check_plot_specs
    from .sweep import parse_metrics
    _check_method(d, method)
    t_end = _check_t_end(d, t_end)
    _check_simulation_steps(d, t_end)
    d.check_samples(t_end)
    raw = d.spec.data.get("plots") if hasattr(d.spec.data, "get") else None
    check_plot_specs(d.spec.plots, d.logged_sizes(), d.file,
                     lines=getattr(raw, "lines", None))
    parse_metrics(d)
    _check_analysis(d, t_end)
    _check_windows(d, raw)
    _check_uniform_grid(d, raw)


def _check_uniform_grid(d, raw_plots):
    """A spectrum plot and the microgravity bands need samples on a uniform time grid:
    ``simulation.output_interval`` (without it the rows are the solver's steps, and a tone
    faster than the steps was aliased to nothing: a PASS with 290 dB of margin); for the
    bands its Nyquist frequency must exceed the top band's upper edge."""
    oi = d.simulation.get("output_interval")
    lines = getattr(raw_plots, "lines", None) or []
    for k, p in enumerate(d.spec.plots):
        if p.get("kind") == "spectrum" and oi is None:
            raise DiagramError(f"plots[{k}]: a spectrum needs samples on a uniform time "
                               f"grid: add simulation.output_interval (without it the rows "
                               f"are the solver's steps, and content faster than the steps "
                               f"is lost)", file=d.file,
                               line=lines[k] if k < len(lines) else None)
    mg = d.microgravity
    if not mg:
        return
    from .microgravity import top_band_edge
    edge = top_band_edge(mg["f_max"])
    longest = 1.0 / (2.0 * edge)
    if oi is None:
        raise DiagramError(f"microgravity: the band levels need samples on a uniform time "
                           f"grid: add simulation.output_interval, at most {longest:.4g} s "
                           f"for f_max = {mg['f_max']:g} Hz (the top band reaches "
                           f"{edge:.4g} Hz, which must be below the Nyquist frequency "
                           f"1 / (2 output_interval)); without it the rows are the solver's "
                           f"steps, and content faster than the steps is lost",
                           file=d.file, line=getattr(d.spec.data, "line_of",
                                                     lambda k: None)("microgravity"))
    if not 1.0 / (2.0 * oi) > edge:
        raise DiagramError(f"microgravity: simulation.output_interval ({oi:g} s) is too "
                           f"long for f_max = {mg['f_max']:g} Hz: its Nyquist frequency "
                           f"{1 / (2 * oi):.4g} Hz must exceed the top band's upper edge "
                           f"{edge:.4g} Hz; make output_interval shorter than {longest:.4g} "
                           f"s or f_max lower", file=d.file,
                           line=d.spec.simulation_lines.get("output_interval"))


def _check_windows(d, raw_plots):
    """A plot's ``t_min`` and the microgravity ``window`` start before the file's own
    ``t_end`` (a spectrum window after it was drawn from the whole record under a title
    naming the window; a microgravity window after it gave no verdict, with exit status 0).
    A shorter ``--t-end`` is a deliberate short run: it keeps its note at the end."""
    t_end = d.simulation["t_end"]
    lines = getattr(raw_plots, "lines", None) or []
    for k, p in enumerate(d.spec.plots):
        if isinstance(p.get("t_min"), (int, float)) and p["t_min"] >= t_end:
            raise DiagramError(f"plots[{k}]: 't_min' ({p['t_min']:g} s) is not before the end "
                               f"of the run (simulation.t_end = {t_end:g} s)", file=d.file,
                               line=lines[k] if k < len(lines) else None)
    mg = d.microgravity
    if mg and mg.get("window") is not None and mg["window"][0] >= t_end:
        raise _microgravity_error(d, f"the window starts at {mg['window'][0]:g} s, not before "
                                     f"the end of the run (simulation.t_end = {t_end:g} s): "
                                     f"no verdict could be given")
    if mg:
        _check_window_length(d, mg, t_end)


def _microgravity_error(d, message):
    """A :class:`DiagramError` ``microgravity: <message>`` at the section's line."""
    return DiagramError(f"microgravity: {message}", file=d.file,
                        line=getattr(d.spec.data, "line_of", lambda k: None)("microgravity"))


def _check_window_length(d, mg, t_end):
    """The microgravity window resolves at least its widest (top) band: a band needs two
    frequency bins, ``df = 1 / (n dt)``, so the window must last ``2 / (hi - lo)`` of the top
    band (a shorter one resolved no band: no verdict, exit status 0)."""
    from .microgravity import third_octave_bands
    bands = third_octave_bands(mg["f_min"], mg["f_max"])
    if not len(bands):
        return
    lo, _fc, hi = bands[-1]
    t0, t1 = mg.get("window") or (0.0, t_end)
    t1 = min(t1, t_end)
    oi = d.simulation.get("output_interval")
    # the samples in the window: n = floor(T / dt) + 1, spanning n dt in frequency terms
    length = (math.floor((t1 - t0) / oi + 1e-9) + 1) * oi if oi else t1 - t0
    need = 2.0 / (hi - lo)
    if length < need * (1 - 1e-9):
        need_t = (math.ceil(need / oi - 1e-9) - 1) * oi if oi else need
        raise _microgravity_error(d, f"the window [{t0:g}, {t1:g}] s lasts {t1 - t0:g} s; "
                                     f"the widest band ({lo:.4g}-{hi:.4g} Hz) needs at least "
                                     f"{need_t:.4g} s (two frequency bins), and lower bands "
                                     f"longer: no band would be assessed")


def cmd_check(args):
    from . import load
    d = load(args.file, set=_parse_sets(args.set))
    validate_run(d)
    cmds = _check_commands(d, args)
    print(d.summary())
    if cmds:
        print(f"named commands (spidersim serve): {', '.join(cmds)}")
    print("OK")
    return 0


def _check_commands(d, args):
    """The file's ``commands`` section as the service reads it, each argument naming a
    parameter of the model in a unit that converts to the parameter's, and each
    command's ``set`` values and argument defaults (in the argument's declared unit)
    applied to the model (a path the model does not have, or a value it refuses, is an
    error naming the command)."""
    from . import load
    from .service.commands import (argument_value, check_argument_paths,
                                   check_argument_units, named_commands)
    cmds = named_commands(d.spec)
    check_argument_paths(d, cmds)
    check_argument_units(d, cmds)
    base = _parse_sets(args.set)
    line = d.spec.data.line_of("commands") if hasattr(d.spec.data, "line_of") else None
    for name, c in cmds.items():
        trial = {str(k): v for k, v in c["set"].items()}
        try:
            trial.update({k: argument_value(d, k, a["default"], a["unit"],
                                            f"argument '{k}': default")
                          for k, a in c["arguments"].items() if a["default"] is not None})
            if not trial:
                continue
            load(args.file, set={**base, **trial})
        except SpidersimError as exc:
            raise SpidersimError(f"command '{name}': {exc.message}", file=d.file,
                                 line=line, block=exc.block) from None
    return cmds


def cmd_blocks(args):
    from .blocks import REGISTRY, lookup
    if args.type is not None:
        if not args.type.strip():
            raise SpidersimError("blocks: the block type is empty (`spidersim blocks` "
                                 "lists them)")
        print(lookup(args.type).describe())
        return 0
    by_cat = {}
    for name, cls in sorted(REGISTRY.items()):
        by_cat.setdefault(cls.category, []).append(cls)
    for cat in sorted(by_cat):
        print(f"{cat}:")
        for cls in by_cat[cat]:
            first = (cls.__doc__ or "").strip().splitlines()[0] if cls.__doc__ else ""
            print(f"  {cls.type_name:20s} {first}")
    print("\n`spidersim blocks TYPE` prints the parameters, ports and states of one type.")
    return 0


def cmd_linearize(args):
    from . import load

    d = load(args.file, set=_parse_sets(args.set))
    jit = not args.no_jit
    _check_linearize_options(args)
    if args.name is None and not (args.input or args.loop):
        if not d.spec.analysis:
            raise SpidersimError("the file has no 'analysis' section: give --input/--output "
                                 "(or --loop)", file=d.file)
        names = list(d.spec.analysis)          # every analysis of the file
    else:
        names = [args.name]
    # every request checked before a folder is made (a bad analysis left empty folders)
    requests = {name: _linearize_request(d, args, name) for name in names}
    outs = {name: prepare_out(_linearize_out(d, args, name)) for name in names}
    for name in names:
        _linearize_one(d, args, name, *requests[name], jit, outs[name])
    return 0


def _linearize_request(d, args, name):
    """``(inputs, outputs, opened, at, loop)`` of one linearization: the named analysis of
    the file (``name``, checked as ``check`` checks it) or the command line's signals,
    ``--at`` applied."""
    from .linreport import parse_at
    if name is not None:
        inputs, outputs, opened, at, loop = _check_analysis_entry(
            d, name, d.simulation["t_end"], check_at=args.at is None)
        if isinstance(at, str):
            at = parse_at(at)
    else:
        inputs, outputs, opened = args.input or [], args.output or [], args.open or []
        at, loop = None, args.loop
        if loop is not None or (inputs and outputs):
            _check_continuous(d, None, inputs, outputs, opened, loop)
    if args.at is not None:
        at = parse_at(args.at)
        if not _valid_analysis_time(at, d.simulation["t_end"]):
            raise DiagramError(f"--at: the operating point's time must be in [0, t_end] "
                               f"= [0, {d.simulation['t_end']:g}] s (simulation.t_end), "
                               f"0 or at least 1e-07 s, got {args.at}", file=d.file)
    return inputs, outputs, opened, at, loop


def _check_linearize_options(args):
    """An analysis NAME, ``--loop`` and ``--input``/``--output`` choose what to linearize:
    one of them, never two (the others were dropped without a word); ``--output`` and
    ``--open`` need ``--input``."""
    given = [what for what, on in (("an analysis name", args.name is not None),
                                   ("--loop", bool(args.loop)),
                                   ("--input/--output", bool(args.input or args.output)))
             if on]
    if len(given) > 1:
        raise SpidersimError(f"linearize: give {' or '.join(given)}, not both (they choose "
                             f"different linearizations)")
    if (args.output or args.open) and not args.input and not args.loop:
        raise SpidersimError("linearize: --output and --open need at least one --input")


def _linearize_out(d, args, name):
    """Folder of one analysis: ``--out`` (one sub-folder per analysis when several run),
    else ``results/<stem>/linearize[_<analysis>]``, every part a safe stem."""
    if args.out and name is not None and args.name is None:
        return os.path.join(args.out, safe_stem(name))     # several analyses: one each
    return args.out or os.path.join(default_out(d), "linearize" + (
        f"_{safe_stem(name)}" if name else ""))


def _linearize_one(d, args, name, inputs, outputs, opened, at, loop, jit, out):
    """One analysis: report on stdout, matrices and Bode plot in its folder."""
    from .linreport import bode_png, report, save_matrices
    title = name or (f"loop at {loop}" if loop else d.spec.name)
    if loop:
        sys_ = d.loop_transfer(loop, at=at, jit=jit)
    else:
        if not outputs:
            raise SpidersimError("give at least one --output signal", file=d.file)
        sys_ = d.linearize(inputs, outputs, at=at, open=opened, jit=jit)
    print(report(sys_, title, loop=bool(loop)))
    try:
        save_matrices(sys_, out)
        bode_png(sys_, os.path.join(out, "bode.png"), title)
    except OSError as exc:
        raise SpidersimError(f"{exc.strerror or exc} (free some space or choose another "
                             f"--out)") from None
    print(f"spidersim: wrote {out}/linearization.npz, linearization.json and bode.png")


def cmd_sweep(args):
    from .sweep import (SweepInterrupted, check_set_and_varied, parse_vary, print_progress,
                        sweep)

    vary = parse_vary(args.vary)
    sets = _parse_sets(args.set)
    check_set_and_varied(sets, vary)         # before the output folder is made
    if args.workers is not None and args.workers < 0:
        raise SpidersimError(f"--workers must be >= 0, got {args.workers}")
    workers = args.workers if args.workers is not None else min(os.cpu_count() or 1, 4)
    sim = {"t_end": args.t_end} if args.t_end is not None else {}
    out = _sweep_out(args)                # before any run: a bad --out is refused at once
    n = math.prod(len(v) for _p, v in vary)
    where = (f"Dask scheduler {args.scheduler}" if args.scheduler else
             "serial, this process" if workers == 0 else
             f"local Dask cluster, {workers} worker(s)")
    print(f"spidersim: sweep of {n} run(s) over {', '.join(p for p, _ in vary)} ({where}); "
          f"compiling once ...", file=sys.stderr)
    stop = SweepStop()
    with stop.installed():     # a signal during the runs: the table of those finished
        try:
            res = sweep(args.file, vary, workers=workers, scheduler=args.scheduler,
                        set=sets, sim=sim, progress=print_progress,
                        should_stop=stop, run_timeout=args.run_timeout)
            code = stop.exit_code if res.unfinished else None
        except SweepInterrupted as exc:       # a second signal: the run in progress ended
            res, code = exc.result, exc.exit_code
        stop.writing()
        pngs = _write_sweep(res, out, args.no_plots)
    print(res.table())
    return _sweep_report(res, out, pngs, stop, code)


def _sweep_out(args):
    """The output folder of ``spidersim sweep`` (``--out``, or ``results/<name>_sweep``),
    made and checked for writing (see :func:`prepare_out`)."""
    if args.out:
        out = args.out
    else:
        from .diagram.spec import parse_file
        out = os.path.join("results", safe_stem(parse_file(args.file).name, os.path.splitext(
            os.path.basename(args.file))[0]) + "_sweep")
    return prepare_out(out)


def _sweep_report(res, out, pngs, stop, code):
    """Print the closing lines of a sweep (counts, rate, files, warnings, a stop by a
    signal) and return the exit status: ``code`` when a signal left runs unfinished, the
    signal's status when it came while the table was written, 1 when a run failed, else
    0."""
    rate = len(res.rows) / res.wall_s * 60 if res.wall_s > 0 else math.inf
    print(f"spidersim: {len(res.rows)} run(s), {len(res.failed)} failed"
          + (f", {len(res.unfinished)} unfinished" if res.unfinished else "")
          + f", {res.wall_s:.1f} s ({rate:.1f} runs/min); wrote {out}/sweep.csv"
          + (f" and {len(pngs)} plot(s)" if pngs else ""))
    for note in res.extra.get("warnings", []):      # said before the runs, and again here
        print(f"spidersim: warning: {note}", file=sys.stderr)
    if code is not None:
        done = len(res.rows) - len(res.unfinished)
        print(f"spidersim: {stop.name or 'interrupted'}: sweep stopped after {done} of "
              f"{len(res.rows)} run(s); {out}/sweep.csv has their rows, the others with "
              f"status 'interrupted' or 'not run'", file=sys.stderr)
        return code
    if stop.requested:                  # the signal came while the table was written
        print(f"spidersim: {stop.name} after the last run: the results in {out}/ are "
              f"complete", file=sys.stderr)
        return stop.exit_code
    return 1 if res.failed else 0        # the table is written either way


def _write_sweep(res, out, no_plots):
    """``sweep.csv`` and (unless ``no_plots``) the plots of ``res`` in ``out``; returns
    the plots' paths. A file that cannot be written is an error naming it."""
    try:
        res.write_csv(os.path.join(out, "sweep.csv"))
        return res.plot(out) if not no_plots else []
    except OSError as exc:
        raise SpidersimError(f"{exc.strerror or exc} (free some space or choose another "
                             f"--out)") from None


class SweepStop(StopRequest):
    """SIGINT/SIGTERM during ``spidersim sweep``: before the first run the command ends at
    once; during the runs the first signal stops the sweep (serially, the run in progress
    at its current step) and the table of the finished runs is written; a second signal
    ends the run in progress at once, the table is still written if a run had finished
    (see :class:`StopRequest` for the rest)."""

    BEFORE = "the first run started"


def _check_local_options(args):
    """A local ``run`` refuses the options only ``--remote`` reads (they were ignored
    without a word), and an empty ``--rerun`` (it ran the FILE, or asked for one)."""
    given = [o for o, v in (("--timeout", args.timeout), ("--token", args.token))
             if v is not None]
    if given:
        verb = "apply" if len(given) > 1 else "applies"
        raise SpidersimError(f"{' and '.join(given)} {verb} to a --remote run only; a local "
                             f"run has no wait limit (Ctrl-C stops it, keeping its data)")
    if args.rerun is not None and not args.rerun.strip():
        raise SpidersimError("--rerun: give a run's results folder or its report.json, got "
                             "an empty text")


def _check_remote_options(args):
    """A ``--remote`` run refuses the options the service does not take (they were
    ignored without a word): the service runs the model with its own method and code."""
    given = [o for o, v in (("--rerun", args.rerun is not None),
                            ("--method", args.method is not None),
                            ("--no-jit", args.no_jit), ("--show", args.show)) if v]
    if given:
        raise SpidersimError(f"{', '.join(given)}: not available with --remote (the service "
                             f"runs the model with its own method and compiled code; "
                             f"--set, --t-end, --no-plots and --out apply)")


def _remote_model_name(file, url):
    """The model a ``--remote`` run names: a name of the service's library (``m1``), not a
    local file (a path with ``/`` or a ``.yaml``/``.yml`` name: it ran the service's model
    of that base name without a word); a SpidersimError otherwise."""
    if file is None:
        raise SpidersimError(f"spidersim run --remote: give the NAME of a model of the "
                             f"service's library (the list: GET {url}/models)")
    if "/" in file or os.sep in file or file.lower().endswith((".yaml", ".yml")):
        raise SpidersimError(f"spidersim run --remote: '{printable(file)}' is a file path; "
                             f"the remote service runs its own models by name (spidersim "
                             f"run NAME --remote URL; the list: GET {url}/models), not "
                             f"local files (run a local file without --remote)")
    return file


def cmd_run_remote(args):
    """``spidersim run MODEL --remote URL``: run on a service, fetch the results."""
    from .remote import Client
    _check_remote_options(args)
    name = _remote_model_name(args.file, args.remote)
    c = Client(args.remote, args.token or os.environ.get("SPIDERSIM_TOKEN"))
    timeout = REMOTE_TIMEOUT if args.timeout is None else args.timeout
    out = args.out or os.path.join("results", safe_stem(name))
    out = prepare_out(out)          # before submitting: a bad --out runs no job
    with c.deadline(timeout):        # submit and wait together; each download request
        job = c.submit(name, parameters=_parse_sets(args.set), t_end=args.t_end,
                       plots=not args.no_plots)          # keeps its own time limit
        print(f"spidersim: job {job} on {args.remote} ...", file=sys.stderr)
        st = c.wait(job, timeout=timeout)
    paths = c.download(job, out)
    print(f"spidersim: {st['state']}: t = {st['progress']:g} / {st['t_end']:g} s"
          + (f" ({st['message']})" if st["message"] else "")
          + f"; wrote {len(paths)} file(s) to {out}/")
    return 0 if st["state"] == "done" else 1


def cmd_serve(args):
    from . import service
    if args.add_user:
        tok = service.add_user(args.add_user, args.data)
        print(f"user '{args.add_user}': token (shown once, keep it secret):\n{tok}")
        return 0
    if args.revoke_user:
        try:
            n = service.revoke_user(args.revoke_user, args.data)
        except KeyError:
            print(f"spidersim: error: no user '{args.revoke_user}'", file=sys.stderr)
            return 1
        print(f"user '{args.revoke_user}': {n} token(s) revoked (refused from the next "
              f"request on; --add-user gives a new one)")
        return 0
    if args.max_user_mb < args.max_record_mb:
        print(f"spidersim: error: --max-user-mb {args.max_user_mb:g} is less than "
              f"--max-record-mb {args.max_record_mb:g}: every job reserves its recording "
              f"budget of the user's quota, so no job could be submitted", file=sys.stderr)
        return 2
    from .service.app import Limits
    lim = Limits(max_t_end=args.max_t_end, max_active=args.max_jobs,
                 max_body=args.max_body, max_signals=args.max_signals,
                 max_streams=args.max_streams, max_record_mb=args.max_record_mb,
                 max_points=args.max_points,
                 keep_days=args.keep_days, max_user_mb=args.max_user_mb)
    service.serve(args.host, args.port, args.models, args.data, args.workers, args.scheduler,
                  lim, args.job_timeout, not args.no_jit)
    return 0


def out_folder(text):
    """An ``--out`` value: a folder name, not empty (``--out ""`` silently meant the
    default ``results/<name>``)."""
    if not text.strip():
        raise argparse.ArgumentTypeError("must name a folder, got an empty text (leave "
                                         "--out out for the default results/<name>)")
    return text


def out_file(text):
    """An ``-o`` value: a file name, not empty (``-o ""`` silently wrote to standard output,
    as leaving ``-o`` out does; ``--out ""`` is refused the same way)."""
    if not text.strip():
        raise argparse.ArgumentTypeError("must name a file, got an empty text (leave -o out "
                                         "for standard output)")
    return text


def positive_float(text):
    """argparse type of a time or a limit: a finite number > 0 (``nan``, ``inf``, ``0``,
    ``-1`` and ``true`` are refused with the option's name, exit status 2)."""
    try:
        v = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number > 0, got '{text}'") from None
    if not (math.isfinite(v) and v > 0):
        raise argparse.ArgumentTypeError(f"expected a finite number > 0, got '{text}'")
    return v


def count(low, high=None):
    """argparse type of an integer in ``[low, high]`` (a count of workers, bytes, jobs; a
    port)."""
    span = f">= {low}" if high is None else f"in {low}..{high}"

    def parse(text):
        try:
            v = int(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected an integer {span}, got "
                                             f"'{text}'") from None
        if v < low or (high is not None and v > high):
            raise argparse.ArgumentTypeError(f"expected an integer {span}, got {v}")
        return v
    parse.__name__ = f"integer {span}"
    return parse


def build_parser():
    ap = argparse.ArgumentParser(prog="spidersim", description=__doc__.splitlines()[0])
    sub = ap.add_subparsers(dest="command", required=True)
    r = sub.add_parser("run", help="simulate a diagram, write data, report and plots")
    r.add_argument("file", nargs="?")
    r.add_argument("--rerun", metavar="REPORT",
                   help="repeat a run from its report.json (or its results folder)")
    r.add_argument("--set", action="append", metavar="PATH=VALUE",
                   help="override a parameter (name, block.param or sub.block.param)")
    r.add_argument("--t-end", type=positive_float, help="simulated time [s]")
    r.add_argument("--out", type=out_folder, help="results folder (default results/<diagram name>)")
    r.add_argument("--method", help="LSODA (default), RK45, RK23, DOP853, Radau, BDF; "
                   "DP54, ROS34PW2 (stiff), NDF (stiff, variable order): the compiled loop")
    r.add_argument("--no-jit", action="store_true", help="interpreted mode (no numba)")
    r.add_argument("--no-plots", action="store_true", help="skip the PNG plots")
    r.add_argument("--show", action="store_true",
                   help="also show the plots in a window (interactive matplotlib backend)")
    r.add_argument("--remote", metavar="URL", help="run on a spidersim service (FILE is the "
                   "name of a model of its library, not a local path) and download the "
                   "results")
    r.add_argument("--token", help="service token (default: $SPIDERSIM_TOKEN)")
    r.add_argument("--timeout", type=positive_float,
                   help=f"seconds to wait (--remote; default {REMOTE_TIMEOUT:g})")
    r.set_defaults(fn=cmd_run)
    c = sub.add_parser("check", help="validate a diagram and print its structure")
    c.add_argument("file")
    c.add_argument("--set", action="append", metavar="PATH=VALUE")
    c.set_defaults(fn=cmd_check)
    lz = sub.add_parser("linearize", help="linear model between signals: poles, zeros, "
                                          "bandwidth, margins, Bode plot, matrices")
    lz.add_argument("file")
    lz.add_argument("name", nargs="?", help="an entry of the file's 'analysis' section")
    lz.add_argument("--input", action="append", metavar="SIGNAL",
                    help="perturbation added to this signal (repeatable)")
    lz.add_argument("--output", action="append", metavar="SIGNAL", help="measured signal")
    lz.add_argument("--open", action="append", metavar="SIGNAL",
                    help="cut the connection carrying this signal")
    lz.add_argument("--loop", metavar="SIGNAL",
                    help="loop transfer L with the loop opened at this signal")
    lz.add_argument("--at", help="operating point: a time [s], 'initial' (default) or 'trim'")
    lz.add_argument("--set", action="append", metavar="PATH=VALUE")
    lz.add_argument("--out", type=out_folder, help="folder for the matrices and the Bode plot")
    lz.add_argument("--no-jit", action="store_true")
    lz.set_defaults(fn=cmd_linearize)
    sw = sub.add_parser("sweep", help="grid of runs on Dask, scalar metrics per run "
                                      "(CSV table and plots)")
    sw.add_argument("file")
    sw.add_argument("--vary", action="append", metavar="PATH=V1,V2,...", required=True,
                    help="parameter and its values (repeat for a grid; first slowest)")
    sw.add_argument("--workers", type=count(0, 256), default=None,
                    help="local Dask worker processes, at most 256 (default: CPUs, at most "
                         "4; 0: serial in this process)")
    sw.add_argument("--scheduler", metavar="ADDRESS",
                    help="use a running Dask scheduler (tcp://host:8786) instead")
    sw.add_argument("--set", action="append", metavar="PATH=VALUE",
                    help="base parameter value for every run")
    sw.add_argument("--t-end", type=positive_float, help="simulated time of each run [s]")
    sw.add_argument("--run-timeout", type=positive_float, metavar="S",
                    help="wall-time limit of each run [s]: a run that reaches it stops there "
                         "and is a failed row (the sweep goes on)")
    sw.add_argument("--out", type=out_folder, help="results folder (default results/<diagram>_sweep)")
    sw.add_argument("--no-plots", action="store_true", help="skip the PNG plots")
    sw.set_defaults(fn=cmd_sweep)

    sv = sub.add_parser("serve", help="remote simulation service (HTTP, web page, API)")
    sv.add_argument("--host", default="127.0.0.1", help="address to bind (default loopback)")
    sv.add_argument("--port", type=count(1, 65535), default=8050)
    sv.add_argument("--models", action="append", metavar="DIR",
                    help="folder (or file) of models (repeatable; default: shipped models)")
    sv.add_argument("--data", help="database and results (default ~/.spidersim/service)")
    sw_ = sv.add_mutually_exclusive_group()
    sw_.add_argument("--workers", type=count(1, 256), default=None,
                     help="worker processes, at most 256 (default 2)")
    sw_.add_argument("--scheduler", metavar="ADDRESS", help="run jobs on this Dask scheduler")
    sv_ = sv.add_mutually_exclusive_group()
    sv_.add_argument("--add-user", metavar="NAME", help="create a user / new token and exit")
    sv_.add_argument("--revoke-user", metavar="NAME",
                     help="delete every token of a user and exit (effective at once)")
    sv.add_argument("--max-t-end", type=positive_float, default=60.0,
                    help="simulated s per run")
    sv.add_argument("--max-jobs", type=count(1), default=8, help="queued+running jobs per user")
    sv.add_argument("--max-body", type=count(1), default=256 * 1024, help="request bytes")
    sv.add_argument("--max-signals", type=count(1), default=64,
                    help="signals a request's 'log' may name (a model's own log list is "
                         "bounded by --max-record-mb)")
    sv.add_argument("--max-streams", type=count(1), default=8,
                    help="open event streams (GET /jobs/{id}/events) per user (more: 429)")
    sv.add_argument("--max-record-mb", type=positive_float, default=256.0,
                    help="recorded data of one job, MB (a run stops there keeping its data)")
    sv.add_argument("--max-points", type=count(1000), default=200_000,
                    help="values of one /signals answer (more: 413)")
    sv.add_argument("--keep-days", type=positive_float, default=7.0,
                    help="days a finished job's files are kept (then 410 Gone)")
    sv.add_argument("--max-user-mb", type=positive_float, default=4096.0,
                    help="disk quota of one user's jobs, MB: stored results plus "
                         "--max-record-mb for each queued or running job (more: 507)")
    sv.add_argument("--job-timeout", type=positive_float, default=3600.0, help="wall s per job")
    sv.add_argument("--no-jit", action="store_true", help="interpreted runs (debugging)")
    sv.set_defaults(fn=cmd_serve)

    b = sub.add_parser("blocks", help="list block types or document one")
    b.add_argument("type", nargs="?")
    b.set_defaults(fn=cmd_blocks)

    sc = sub.add_parser("schema", help="JSON Schema of diagram files (editor completion)")
    sc.add_argument("-o", "--output", type=out_file,
                    help="file to write (default, or -: standard output)")
    sc.set_defaults(fn=cmd_schema)

    ca = sub.add_parser("cache", help="the compiled-code cache: info or clear")
    ca.add_argument("action", choices=("info", "clear"))
    ca.set_defaults(fn=cmd_cache)
    ap.add_argument("--version", action="version", version=f"spidersim {_version()}")
    return ap


def _version():
    from importlib.metadata import PackageNotFoundError, version
    try:
        return version("spidersim")
    except PackageNotFoundError:
        return "unknown (not installed)"


def cmd_schema(args):
    from .schema import dumps
    text = dumps()
    if not args.output or args.output == "-":         # "-": standard output, as usual
        sys.stdout.write(text)
        return 0
    from .solver.result import write_atomic
    try:
        write_atomic(args.output, lambda fh: fh.write(text))
    except OSError as exc:
        raise SpidersimError(str(exc.strerror or exc)) from None
    print(f"spidersim: wrote {args.output}", file=sys.stderr)
    return 0


def cmd_cache(args):
    from .solver import compiled
    if args.action == "clear":
        n = compiled.clear()
        fb = compiled.fallback_path()
        print(f"spidersim: cache: removed {n} file(s) from {compiled.configured_dir()}"
              + (f" and {fb}" if os.path.isdir(fb) else ""))
        return 0
    i = compiled.info()
    why = i["usable"]
    state = ("not created yet" if why is None else "writable, private" if why is True else
             f"NOT used: it {why}; a private folder in the temporary directory is used "
             f"instead")
    fallback = (f"in use:  {i['fallback']} ({i['fallback_entries']} structure(s), "
                f"{i['fallback_bytes'] / 1e6:.1f} MB)\n" if "fallback" in i else "")
    print(f"folder:  {i['folder']} ({state})\n"
          f"entries: {i['entries']} compiled diagram structure(s)\n"
          f"size:    {i['bytes'] / 1e6:.1f} MB\n" + fallback +
          "set SPIDERSIM_CACHE to move it; 'spidersim cache clear' empties it")
    return 0


def _show_warning(message, category, filename, lineno, file=None, line=None):
    """spidersim's own warnings as one line (``spidersim: warning: ...``), others as usual."""
    from .errors import LinearizationWarning, RenamedParameterWarning, SweepWarning
    if issubclass(category, (RenamedParameterWarning, SweepWarning)):
        print(f"spidersim: warning: {message}", file=sys.stderr)
    elif issubclass(category, LinearizationWarning):
        print(f"spidersim: note: {message}", file=sys.stderr)
    else:
        _SHOW_WARNING(message, category, filename, lineno, file, line)


_SHOW_WARNING = warnings.showwarning


def _check_arguments(argv):
    """Refuse an argument that is not text: bytes that are not UTF-8 reach Python as lone
    surrogates (``--set V_max=$'\\xff'``), which no name, value or path can hold."""
    from .text.yamlio import lone_surrogate
    for a in argv:
        if isinstance(a, str) and lone_surrogate(a):
            shown = a.encode("utf-8", "backslashreplace").decode("utf-8")
            raise DiagramError(f"argument '{shown}' is not UTF-8 text (a byte that is not "
                               f"UTF-8 arrives as an escape \\udcXX)")


def main(argv=None):
    # plots are files here: a non-interactive backend unless the user chose one
    os.environ.setdefault("MPLBACKEND", "Agg")
    warnings.showwarning = _show_warning
    args = build_parser().parse_args(argv)
    try:
        _check_arguments(sys.argv[1:] if argv is None else argv)
        return args.fn(args)
    except SpidersimError as exc:
        print(f"spidersim: error: {exc}", file=sys.stderr)
        return exc.exit_code
    except BrokenPipeError:
        return 0
    except KeyboardInterrupt as exc:
        print(f"spidersim: {getattr(exc, 'message', 'interrupted')}", file=sys.stderr)
        return getattr(exc, "exit_code", 130)
    except (RecursionError, MemoryError) as exc:
        print(f"spidersim: error: input too large or too deeply nested to process "
              f"({type(exc).__name__}); see 'Limits' in the README", file=sys.stderr)
        return 2
    except Exception as exc:  # a bug of spidersim: say so, keep the traceback for reports
        if os.environ.get("SPIDERSIM_DEBUG"):
            raise
        print(f"spidersim: internal error: {type(exc).__name__}: {exc}\n"
              f"  this is a bug of spidersim, not of your diagram; rerun with "
              f"SPIDERSIM_DEBUG=1 for the traceback and report it", file=sys.stderr)
        return 3


if __name__ == "__main__":
    sys.exit(main())
