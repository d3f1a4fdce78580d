"""Parameter sweeps: a grid of runs of one diagram on Dask, scalar metrics per run.

The grid is the Cartesian product of the ``--vary`` lists, first parameter slowest::

    spidersim sweep diagrams/impact_fault.yaml --vary V_ci=20,28,36 --vary K=1e4,1e5,1e6

A varied *path* is anything ``--set`` accepts: a diagram parameter (``V_ci``), a block
parameter (``wall.K``) or a parameter inside a subsystem (``joint1.q0``). The metrics are
declared in the diagram's ``metrics`` section::

    metrics:
      peak_force: {signal: wall.fn, reduce: max, unit: N}
      speed:      {signal: "arm.flange_twist[1]", reduce: final}

with ``reduce`` one of :data:`REDUCERS`. Each run is independent; one that fails (solver
failure, loop that does not converge, bad value) is a row with status ``failed`` and its
message, and the sweep goes on (as one that reaches the wall-time limit ``run_timeout``). An
interrupt (Ctrl-C, SIGTERM through the CLI) keeps the rows of the finished runs: the others
are marked :data:`INTERRUPTED` or :data:`NOT_RUN`.

Compiled code is shared: the generated module of a structure is compiled once (by the
process that starts the sweep, into the on-disk cache) and every run, in this process or in
a Dask worker, imports it from there; within a process a structure is imported once and
reused (:func:`spidersim.solver.compiled.load_module`). Parameter values are data, so a
grid over values never recompiles; the table's ``compiled`` column says if a run had to
(a varied value that changes the structure, e.g. a size).

Execution: ``workers=0`` runs the grid here, one run after the other; otherwise on Dask
(``dask.distributed``): a local cluster of ``workers`` processes by default, or an existing
scheduler at ``scheduler`` (its workers need spidersim installed and the diagram files at
the same paths, e.g. a shared filesystem).
"""
from __future__ import annotations

import csv
import itertools
import math
import os
import re
import shutil
import sys
import tempfile
import time
import warnings
from dataclasses import dataclass, field
from typing import NamedTuple

import numpy as np

from .errors import ASCII_RULE, DiagramError, SpidersimError, SweepWarning, non_ascii
from .outputs import safe_stem, save_figure, write_atomic
from .plots import element_problem, math_text_problem, signal_values, split_signal
from .text.yamlio import number_problem

_trapz = getattr(np, "trapezoid", None) or np.trapz      # numpy 2 renamed it

#: reduce -> (description, function of (t, y))
REDUCERS = {
    "max": ("largest value", lambda t, y: float(np.max(y))),
    "min": ("smallest value", lambda t, y: float(np.min(y))),
    "absmax": ("largest magnitude", lambda t, y: float(np.max(np.abs(y)))),
    "final": ("value at the end", lambda t, y: float(y[-1])),
    "initial": ("value at the start", lambda t, y: float(y[0])),
    "mean": ("time average", lambda t, y: float(_trapz(y, t) / (t[-1] - t[0]))
             if t[-1] > t[0] else float(y[0])),
    "rms": ("root mean square over time", lambda t, y: float(math.sqrt(
        _trapz(y * y, t) / (t[-1] - t[0]))) if t[-1] > t[0] else float(abs(y[0]))),
    "integral": ("time integral", lambda t, y: float(_trapz(y, t))),
}


_METRIC_NAME = re.compile(r"^[A-Za-z_][A-Za-z0-9_]{0,63}\Z")
#: the sweep table's own columns: a metric or a varied parameter of one of these names
#: would share its column (a metric 'status' broke the progress line, a parameter 'run'
#: doubled the column)
RESERVED = ("run", "status", "t_reached", "wall_s", "compiled", "worker", "message")


@dataclass
class Metric:
    """One scalar per run: ``reduce`` over the samples of ``signal`` (element ``index``)."""

    name: str
    signal: str
    index: int | None
    reduce: str
    unit: str = ""

    @property
    def label(self):
        """``signal`` or ``signal[index]``."""
        return self.signal if self.index is None else f"{self.signal}[{self.index}]"

    def evaluate(self, result):
        """The metric of a run (signal and index were checked by :func:`parse_metrics`)."""
        y = np.asarray(signal_values(result, self.label))
        if len(y) == 0:
            return math.nan
        return REDUCERS[self.reduce][1](result.t, y)


def parse_metrics(diagram) -> list[Metric]:
    """The ``metrics`` section of a loaded diagram, checked against its logged signals."""
    raw = diagram.spec.metrics
    sizes = diagram.logged_sizes()
    out = []
    for name, entry in raw.items():
        line = raw.line_of(name) if hasattr(raw, "line_of") else None

        def fail(msg):
            raise DiagramError(f"metric {name!r}: {msg}", file=diagram.file, line=line)
        if not isinstance(name, str) or not _METRIC_NAME.match(name):
            fail("a metric name is an identifier (letters, digits, _; it names a column "
                 "and a plot file), e.g. peak_force")
        if name in RESERVED:
            fail(f"the name of a column the sweep table has already ({', '.join(RESERVED)}); "
                 f"choose another, e.g. {name}_value")
        if not isinstance(entry, dict):
            fail("expected a mapping {signal: block.port, reduce: max|min|...}, got "
                 f"{entry!r}")
        unknown = set(entry) - {"signal", "reduce", "unit"}
        if unknown:
            fail(f"unknown key(s) {', '.join(sorted(unknown))}; keys are signal, reduce, "
                 f"unit")
        sig, idx, n = _metric_signal(entry.get("signal"), sizes, fail)
        red = entry.get("reduce", "max")
        if not isinstance(red, str) or red not in REDUCERS:
            fail(f"unknown reduce {_shown(red)}; one of {', '.join(REDUCERS)}")
        out.append(Metric(str(name), sig, idx if n > 1 else None, red,
                          _metric_unit(entry.get("unit", ""), fail)))
    return out


def _metric_signal(text, sizes, fail):
    """``(signal, index or None, size)`` of a metric's ``signal`` among the logged
    ``sizes`` (a negative index, from the end, given as the element it names: ``[-1]`` of 3
    is 2); ``fail(message)`` raises."""
    if not isinstance(text, str):
        fail(f"'signal' must be 'block.port' or 'block.port[i]', got {text!r}")
    if non_ascii(text):
        fail(f"signal '{text}': {non_ascii(text)}: {ASCII_RULE}")
    sig, idx = split_signal(text)
    if sig not in sizes:
        import difflib
        near = difflib.get_close_matches(sig, list(sizes), n=3)
        fail(f"no logged signal '{sig}'" + (f"; did you mean {', '.join(near)}?"
                                            if near else ""))
    n = sizes[sig]
    if idx is None and n > 1:
        fail(f"signal '{sig}' has {n} elements; pick one, e.g. '{sig}[0]' ('{sig}[-1]': "
             f"the last)")
    if idx is not None and element_problem(sig, idx, n):
        fail(element_problem(sig, idx, n))
    return sig, (None if idx is None else idx % n), n


def _metric_unit(unit, fail):
    """A metric's ``unit``: a label of its axis and column (not converted), one line that
    matplotlib can draw; ``fail(message)`` raises."""
    if isinstance(unit, bool) or not isinstance(unit, (str, int)):
        fail(f"'unit' must be a text (it labels the axis), got {_shown(unit)}")
    unit = str(unit)
    if len(unit) > 40 or not unit.isprintable():
        fail(f"'unit' labels the axis: one line of at most 40 characters, got "
             f"{unit[:40]!r}")
    problem = math_text_problem(unit)
    if problem:
        fail(f"'unit' holds math text ($...$) that matplotlib cannot draw: {problem}; "
             f"write a literal dollar as \\$")
    return unit


def _shown(v):
    """A value in a message: a text quoted, a list or mapping by its kind."""
    return (f"'{v}'" if isinstance(v, str) else "a list" if isinstance(v, list)
            else "a mapping" if isinstance(v, dict) else repr(v))


def parse_vary(items) -> list[tuple[str, list]]:
    """``["V_ci=20,28,36", "K=1e4,1e5"]`` -> ``[("V_ci", [20.0, 28.0, 36.0]), ...]``; a
    number form a diagram file refuses (``010``, YAML 1.1's octal 8) is refused."""
    out = []
    for item in items or []:
        if "=" not in item:
            raise SpidersimError(f"--vary expects path=v1,v2,..., got '{item}'")
        path, text = item.split("=", 1)
        path = path.strip()
        if not re.match(r"^[A-Za-z_][A-Za-z0-9_.]*\Z", path):
            raise SpidersimError(f"--vary: '{path}' is not a parameter path (name or "
                                 f"block.param)")
        if any(p == path for p, _ in out):
            raise SpidersimError(f"--vary: '{path}' given twice")
        _check_varied_name(path)
        values = []
        for tok in text.split(","):
            tok = tok.strip()
            if not tok:
                raise SpidersimError(f"--vary {path}: empty value in '{text}'")
            problem = number_problem(tok)         # 010 and 1:30, refused as in a file
            if problem:
                raise SpidersimError(f"--vary {path}: {problem}")
            try:
                v = float(tok)
            except ValueError:
                raise SpidersimError(f"--vary {path}: '{tok}' is not a number") from None
            if not math.isfinite(v):
                raise SpidersimError(f"--vary {path}: '{tok}' is not a finite number")
            values.append(v)
        out.append((path, values))
    if not out:
        raise SpidersimError("nothing to sweep: give at least one --vary path=v1,v2,...")
    check_grid_size(out)
    return out


#: runs in one sweep (the grid is built, run and tabulated in memory)
MAX_RUNS = 100_000


def check_set_and_varied(base, vary):
    """Refuse a parameter both set (``--set``, ``set=``) and varied: every run takes the
    varied values, so the set one was dropped without a word. Raises
    :class:`SpidersimError` naming the parameter."""
    both = [p for p, _ in vary if p in (base or {})]
    if both:
        names = ", ".join(f"'{p}'" for p in both)
        raise SpidersimError(f"{names}: both set (--set) and varied (--vary); each run takes "
                             f"the varied values, so the set value would be ignored: give "
                             f"{'it' if len(both) == 1 else 'them'} in one of the two only")


def _check_varied_name(path):
    """Refuse a varied parameter named like a column of the sweep table (:data:`RESERVED`):
    its values and the table's would share the column."""
    if path in RESERVED:
        raise SpidersimError(f"--vary {path}: '{path}' names a column of the sweep table "
                             f"({', '.join(RESERVED)}), so it cannot be varied under that "
                             f"name; rename the diagram parameter")


def _check_columns(d, metrics, vary):
    """Every column of the sweep table has one meaning: no varied parameter is named
    like a column of the table's own, and no metric like a varied parameter (the CSV had
    two 'k' columns)."""
    paths = [p for p, _ in vary]
    for p in paths:
        _check_varied_name(p)
    raw = d.spec.metrics
    for m in metrics:
        if m.name in paths:
            raise DiagramError(
                f"metric '{m.name}' has the name of the varied parameter '{m.name}': both "
                f"would be column '{m.name}' of the sweep table; rename the metric",
                file=d.file, line=raw.line_of(m.name) if hasattr(raw, "line_of") else None)


def check_grid_size(vary):
    """Raise :class:`SpidersimError` if the grid of ``vary`` has more than
    :data:`MAX_RUNS` runs (before any of it is built)."""
    sizes = [len(v) for _, v in vary]
    if math.prod(sizes) > MAX_RUNS:
        raise SpidersimError(
            f"the sweep grid has {' x '.join(map(str, sizes))} = {math.prod(sizes):,} runs, "
            f"more than {MAX_RUNS:,} (limit MAX_RUNS): vary fewer values, or split the "
            f"sweep")


def grid(vary) -> list[dict]:
    """Cartesian product of the varied values, first parameter slowest; at most
    :data:`MAX_RUNS` runs."""
    check_grid_size(vary)
    paths = [p for p, _ in vary]
    return [dict(zip(paths, combo)) for combo in itertools.product(*[v for _, v in vary])]


# --------------------------------------------------------------------------- one run
#: status of a run stopped part-way by an interrupt (no metrics: they would describe a
#: shorter run), and of a run that never started because the sweep was interrupted
INTERRUPTED, NOT_RUN = "interrupted", "not run"


def run_point(file, base_set, point, sim, index=0, should_stop=None, timeout=None):
    """Run one grid point; never raises for a failed run. Returns a row dict.

    Runs in the calling process or in a Dask worker. The diagram is rebuilt with the point's
    values (``--set`` semantics); its compiled module comes from this process's modules or
    the on-disk cache. ``should_stop`` (serial sweeps) is polled after every step: when it
    says stop, the row has status :data:`INTERRUPTED`, the time reached and no metrics.
    ``timeout`` [s] limits the run's wall time: the integration stops at the step that
    reaches it and the row is ``failed``, with the time reached.
    """
    from .diagram.model import load
    from .solver.compiled import COUNTS
    t0 = time.perf_counter()
    row = {"run": index, **point, "status": "ok", "message": "", "compiled": False,
           "worker": f"{os.uname().nodename}:{os.getpid()}"}
    written = COUNTS["written"]
    try:
        d = load(file, set={**base_set, **point})
        metrics = parse_metrics(d)
        limit = _Deadline(timeout, should_stop)
        r = d.simulate(**sim, **({"should_stop": limit} if limit.active else {}))
        row["t_reached"] = r.stats.get("t_reached")
        if r.status == INTERRUPTED and limit.reached:
            row["status"] = "failed"
            row["message"] = (f"stopped: the wall-time limit of {timeout:g} s per run "
                              f"(--run-timeout) was reached at t = {row['t_reached']:.6g} s")
        elif r.status == INTERRUPTED:
            row["status"] = INTERRUPTED
            row["message"] = (f"stopped by the interrupt at t = {row['t_reached']:.6g} s "
                              f"(no metrics: the run is incomplete)")
        else:
            row.update({m.name: m.evaluate(r) for m in metrics})  # all or none in the row
    except SpidersimError as exc:
        row["status"] = "failed"
        row["message"] = str(exc)
        partial = getattr(exc, "partial", None)
        if partial is not None:
            row["t_reached"] = partial.stats.get("t_reached")
    except Exception as exc:  # noqa: BLE001 - a crash of one run must not end the sweep
        row["status"] = "failed"
        row["message"] = f"{type(exc).__name__}: {exc}"
    row["compiled"] = COUNTS["written"] > written      # a structure new to the cache
    row["wall_s"] = time.perf_counter() - t0
    return row


class _Deadline:
    """The ``should_stop`` of one run: true once ``timeout`` seconds of wall time have
    passed since it was made (then ``reached``) or once ``outer()`` says stop."""

    def __init__(self, timeout, outer=None):
        self.end = None if timeout is None else time.monotonic() + timeout
        self.outer = outer
        self.reached = False
        self.active = timeout is not None or outer is not None

    def __call__(self):
        if self.outer is not None and self.outer():
            return True
        if self.end is not None and time.monotonic() > self.end:
            self.reached = True
        return self.reached


def _unfinished_row(k, point, status, message):
    """The row of run ``k`` at ``point`` that an interrupt left without a result."""
    return {"run": k, **point, "status": status, "message": message, "compiled": False,
            "worker": "", "wall_s": math.nan}


class SweepInterrupted(KeyboardInterrupt):
    """A KeyboardInterrupt (Ctrl-C, or a second signal to the CLI) during the runs of a
    sweep. ``result`` is the :class:`SweepResult` of the runs finished before it, the
    others marked :data:`INTERRUPTED` or :data:`NOT_RUN`; ``message`` and ``exit_code``
    are those of the interrupt (130 by default)."""

    def __init__(self, result, cause):
        self.result = result
        self.message = getattr(cause, "message", None) or "interrupted"
        self.exit_code = getattr(cause, "exit_code", 130)
        super().__init__(self.message)


@dataclass
class SweepResult:
    """Rows of a sweep (one dict per run, grid order) and what describes them."""

    file: str
    vary: list
    metrics: list
    rows: list
    wall_s: float
    workers: int
    extra: dict = field(default_factory=dict)

    @property
    def failed(self):
        """The rows of the runs that failed."""
        return [r for r in self.rows if r["status"] == "failed"]

    @property
    def unfinished(self):
        """The rows an interrupt left without metrics (:data:`INTERRUPTED`,
        :data:`NOT_RUN`); empty for a sweep that ran to its end."""
        return [r for r in self.rows if r["status"] in (INTERRUPTED, NOT_RUN)]

    def columns(self):
        """The CSV's columns: :data:`RESERVED` around the varied parameters and metrics."""
        return (["run"] + [p for p, _ in self.vary] + ["status"]
                + [m.name for m in self.metrics]
                + ["t_reached", "wall_s", "compiled", "worker", "message"])

    def value(self, metric, **point):
        for r in self.rows:
            if all(r[k] == v for k, v in point.items()):
                return r.get(metric, math.nan)
        raise KeyError(point)

    def write_csv(self, path):
        cols = self.columns()
        def rows(fh):
            w = csv.writer(fh)
            w.writerow(cols)
            for r in self.rows:
                w.writerow([_fmt(r.get(c, "")) for c in cols])
        write_atomic(path, rows)          # complete or absent, never truncated
        return path

    def table(self):
        """Plain-text table for the terminal."""
        cols = ["run"] + [p for p, _ in self.vary] + ["status"] + [m.name for m in
                                                                  self.metrics]
        rows = [[_fmt(r.get(c, ""), 6) for c in cols] for r in self.rows]
        width = [max(len(c), *(len(x[i]) for x in rows)) for i, c in enumerate(cols)]
        lines = ["  ".join(c.rjust(w) for c, w in zip(cols, width))]
        lines += ["  ".join(x.rjust(w) for x, w in zip(row, width)) for row in rows]
        for r in self.failed + [r for r in self.rows if r["status"] == INTERRUPTED]:
            lines.append(f"run {r['run']} {r['status']}: {r['message']}")
        not_run = sum(r["status"] == NOT_RUN for r in self.rows)
        if not_run:
            lines.append(f"{not_run} run(s) not run: the sweep was interrupted")
        return "\n".join(lines)

    def curves(self, fixed):
        """The curves of one sweep figure: the rows with the parameters ``fixed`` (name ->
        value of the third and later parameters), one :class:`Curve` per value of the
        second parameter (one curve without it), split into ok and failed runs."""
        if len(self.vary) < 2:
            return [self._curve(None, fixed)]
        p2, values = self.vary[1]
        return [self._curve(f"{p2} = {_num(v2)}", {**fixed, p2: v2}) for v2 in values]

    def _curve(self, label, point):
        """The :class:`Curve` of the rows whose parameters have the values in ``point``."""
        pts = [r for r in self.rows if all(r[k] == v for k, v in point.items())]
        return Curve(label, [r for r in pts if r["status"] == "ok"],
                     [r for r in pts if r["status"] == "failed"])

    def figures(self):
        """The ``fixed`` mapping of each figure per metric: one per combination of the
        values of the third and later parameters (one empty mapping for up to two)."""
        rest = self.vary[2:]
        combos = itertools.product(*[v for _, v in rest]) if rest else [()]
        return [dict(zip([p for p, _ in rest], combo)) for combo in combos]

    def plot(self, folder):
        """One PNG per metric: metric vs the first parameter, one line per value of the
        second (the paper's Fig. 9); further parameters give one figure per combination.
        Each figure has a file of its own (:func:`_unique_path`)."""
        taken = set()
        return [self._plot_metric(folder, m, fixed, taken)
                for fixed in self.figures() for m in self.metrics]

    def _plot_metric(self, folder, m, fixed, taken):
        """Draw metric ``m`` against the first parameter for the rows with ``fixed``;
        failed runs are crosses at the bottom edge. Returns the PNG's path, one not in
        ``taken`` (added to it)."""
        import matplotlib.pyplot as plt
        p1 = self.vary[0][0]
        fig, ax = plt.subplots(figsize=(7, 4.5))
        for curve in self.curves(fixed):
            _draw_curve(ax, p1, m.name, curve)
        ax.set_xlabel(p1)
        ax.set_ylabel(f"{m.name}" + (f" [{m.unit}]" if m.unit else ""))
        ax.set_title(_figure_title(m, fixed))
        ax.grid(True, alpha=0.3)
        if len(self.vary) > 1 or self.failed:
            ax.legend()
        fig.tight_layout()
        path = _unique_path(_figure_path(folder, m, fixed), taken)
        return save_figure(fig, path)


class Curve(NamedTuple):
    """One line of a sweep figure: its legend label (None for a single line), the rows
    of the runs that succeeded and of those that failed."""

    label: str | None
    ok: list
    failed: list


def _draw_curve(ax, p1, metric, curve):
    """Plot ``curve`` on ``ax``: the metric of the ok runs against parameter ``p1`` as a
    line with markers, the failed runs as crosses at the bottom edge in the same colour
    (they have no value to plot)."""
    line, = ax.plot([r[p1] for r in curve.ok], [r[metric] for r in curve.ok], "o-",
                    label=curve.label)
    if curve.failed:
        ax.plot([r[p1] for r in curve.failed], [0.03] * len(curve.failed), "x",
                transform=ax.get_xaxis_transform(), clip_on=False,
                color=line.get_color(), markersize=10,
                label=f"failed ({curve.label})" if curve.label else "failed")


def _figure_title(m, fixed):
    """``x_end (final value of x.y), K = 3`` for metric ``m`` and fixed parameters."""
    title = f"{m.name} ({m.reduce} of {m.label})"
    if fixed:
        title += ", " + ", ".join(f"{k} = {_num(v)}" for k, v in fixed.items())
    return title


def _figure_path(folder, m, fixed):
    """``folder/sweep_<metric>[_<param><value>...].png``, the name made safe."""
    tag = "".join(f"_{k}{_num(v)}" for k, v in fixed.items())
    return os.path.join(folder, f"sweep_{safe_stem(m.name + tag)}.png")


def _unique_path(path, taken):
    """``path``, or ``<stem>_2.png``, ``_3``, ... when a figure of this sweep took it (a
    name cut at its length limit); added to ``taken``."""
    stem, ext = os.path.splitext(path)
    n = 1
    while path in taken:
        n += 1
        path = f"{stem}_{n}{ext}"
    taken.add(path)
    return path


def _num(v):
    """A varied value as text that tells it from the others: ``:g`` (``20``, ``2.5e+05``)
    when that reads back as the value, else the shortest text that does (``1.0000001``
    and ``1.0000002`` were both ``1``: one file for two figures, the same titles)."""
    text = f"{v:g}"
    return text if float(text) == v else repr(float(v))


def _fmt(v, digits=None):
    """Text of a cell: full precision (round trip) unless ``digits`` is given."""
    if isinstance(v, bool):
        return "yes" if v else "no"
    if isinstance(v, float):
        return repr(float(v)) if digits is None else f"{v:.{digits}g}"
    if v is None:
        return ""
    return str(v)


# --------------------------------------------------------------------------- the sweep
def sweep(file, vary, workers=2, scheduler=None, set=None, sim=None, progress=None,
          connect_timeout=10.0, should_stop=None, run_timeout=None):
    """Run the grid of ``vary`` (see :func:`parse_vary`) over the diagram ``file``.

    Parameters
    ----------
    workers : int
        0: serial, in this process. N > 0: a local Dask cluster of N worker processes
        (one thread each), unless ``scheduler`` is given.
    scheduler : str, optional
        Address of a running Dask scheduler (``tcp://host:8786``).
    set : dict, optional
        Base ``--set`` values applied to every run.
    sim : dict, optional
        Simulation overrides (``t_end``, ``method``, ...) for every run.
    progress : callable, optional
        ``progress(row, done, total)`` after each finished run.
    connect_timeout : float
        Seconds to wait for the scheduler at ``scheduler``.
    should_stop : callable, optional
        ``should_stop() -> bool``, polled between runs (and, serially, after every step of
        the current run; keep it a flag check). Once it says stop, no run starts; the run
        in progress is stopped (serial) or abandoned (Dask): see :data:`INTERRUPTED`.
    run_timeout : float, optional
        Wall-time limit of each run's integration [s]: a run that reaches it stops there and
        is a failed row saying so (the sweep goes on).

    Returns
    -------
    SweepResult
        Its ``unfinished`` rows are those a stop left without metrics.

    Raises
    ------
    SweepInterrupted
        On a KeyboardInterrupt during the runs, carrying the result of the runs finished.
    """
    base = dict(set or {})
    check_set_and_varied(base, vary)
    sim = dict(sim or {})
    file = os.path.abspath(file)
    points = grid(vary)
    # check everything once, here, and compile into the shared cache
    d, metrics, notes = _prepare(file, base, vary, sim, run_timeout)
    t0 = time.perf_counter()
    d.compile()
    compile_s = time.perf_counter() - t0
    t0 = time.perf_counter()
    rows = [None] * len(points)
    interrupt = None
    try:
        n_workers = _run_points(file, base, points, sim, rows, workers, scheduler, progress,
                                connect_timeout, should_stop, run_timeout)
    except KeyboardInterrupt as exc:
        if not any(r is not None and r["status"] not in (INTERRUPTED, NOT_RUN)
                   for r in rows):
            raise                   # no run finished: nothing computed to keep
        interrupt, n_workers = exc, workers
    _mark_unfinished(rows, points)
    res = SweepResult(file, vary, metrics, rows, time.perf_counter() - t0, n_workers,
                      {"compile_s": compile_s, "structure_key": d._modules[True][1],
                       "name": d.spec.name, "warnings": notes})
    if interrupt is not None:
        raise SweepInterrupted(res, interrupt) from None
    return res


def _prepare(file, base, vary, sim, run_timeout):
    """Check a sweep before any run: the diagram loads with the base values and declares
    metrics, the table's column names do not collide, ``sim``'s ``t_end`` and
    ``run_timeout`` are positive, every varied value loads (``base`` and ``vary`` already
    checked against each other). Returns the loaded diagram,
    its metrics and the notes on varied parameters that change no run (each also issued
    as a :class:`SweepWarning`)."""
    from .diagram.model import load
    d = load(file, set=base)
    metrics = parse_metrics(d)
    if not metrics:
        raise DiagramError("the diagram declares no metrics: add a 'metrics' section, e.g. "
                           "metrics: {peak: {signal: block.port, reduce: max}}",
                           file=d.file)
    _check_columns(d, metrics, vary)
    t_end = sim.get("t_end")
    if t_end is not None and not (isinstance(t_end, (int, float)) and t_end > 0):
        raise SpidersimError(f"the simulated time of each run must be > 0 s, got {t_end}")
    if run_timeout is not None and not (isinstance(run_timeout, (int, float)) and not
                                        isinstance(run_timeout, bool) and
                                        math.isfinite(run_timeout) and run_timeout > 0):
        raise SpidersimError(f"the wall-time limit of a run must be a finite number of "
                             f"seconds > 0, got {run_timeout!r}")
    uses = {path: _check_varied(file, base, d, path, values) for path, values in vary}
    notes = ineffective_parameters(file, base, vary, uses)
    for note in notes:
        warnings.warn(note, SweepWarning, stacklevel=3)
    return d, metrics, notes


def _run_points(file, base, points, sim, rows, workers, scheduler, progress,
                connect_timeout, should_stop, run_timeout):
    """Run ``points``, filling ``rows``: serially here (``workers == 0`` and no
    scheduler) or on Dask; return the number of Dask workers (0 serially)."""
    if workers == 0 and scheduler is None:
        _run_serial(file, base, points, sim, rows, progress, should_stop, run_timeout)
        return 0
    return _run_dask(file, base, points, sim, rows, workers, scheduler, progress,
                     connect_timeout, should_stop, run_timeout)


def _run_serial(file, base, points, sim, rows, progress, should_stop, run_timeout=None):
    """Run ``points`` one after the other here, filling ``rows``; stop (leaving the rest
    None) when ``should_stop()`` says so (the run in progress polls it too)."""
    for k, pt in enumerate(points):
        if should_stop is not None and should_stop():
            return
        try:
            rows[k] = run_point(file, base, pt, sim, k, should_stop, run_timeout)
        except KeyboardInterrupt:
            rows[k] = _unfinished_row(k, pt, INTERRUPTED, "stopped by the interrupt (no "
                                      "metrics: the run is incomplete)")
            raise
        if progress:
            progress(rows[k], k + 1, len(points))


def _mark_unfinished(rows, points):
    """Mark :data:`NOT_RUN` the rows an interrupt left empty (the runs never started)."""
    for k, pt in enumerate(points):
        if rows[k] is None:
            rows[k] = _unfinished_row(k, pt, NOT_RUN, "not run: the sweep was interrupted")


def _check_varied(file, base, d, path, values):
    """Every value of a varied path loads (a bad value is refused before any run, not
    found in the table afterwards), and the path is a scalar (a scalar given to a vector
    parameter would be spread over its elements: every run the same direction). Returns
    the block parameters (``block.param``) whose values differ between the values."""
    from .diagram.flatten import eval_parameters
    from .diagram.model import load
    size = None
    block, _, name = path.rpartition(".")
    if not block:
        if path in d.spec.parameters:
            size = np.size(eval_parameters(d.spec, {}, "")[0][path])
    elif block in d.blocks and name in d.blocks[block].params:
        size = np.size(d.blocks[block].params[name])
    if size is not None and size != 1:
        raise SpidersimError(f"--vary {path}: a vector parameter ({size} elements); a sweep "
                             f"varies scalars: make the varied quantity a scalar "
                             f"parameter of the diagram and build the vector from it")
    first, changed = None, set()
    for v in values:
        try:
            dv = load(file, set={**base, path: v})
        except SpidersimError as exc:
            raise SpidersimError(f"--vary {path}={v:g}: {exc}") from None
        first = dv if first is None else first
        changed |= set(_changed(first, dv))
    return sorted(changed)


def ineffective_parameters(file, base, vary, uses):
    """Notes on the varied top-level parameters whose values change no run: none of the
    block parameters depends on it (with the base ``--set`` values), or every one that does
    (``uses[path]``, from :func:`_check_varied`) is itself set by another varied path
    (``g.k`` varied while ``g.k: a`` and ``a`` varied): its column varies, the runs do not. The
    other paths are tried at their first and at their last values (a value such as 0 in
    ``k: a*b`` may hide ``a`` at one of them only)."""
    from .diagram.model import load
    notes = []
    for path, values in vary:
        if "." in path or len(values) < 2:
            continue
        if not uses[path]:
            notes.append(f"--vary {path}: no block parameter changes with '{path}' over "
                         f"these values (nothing depends on it"
                         + (" once the --set values are applied" if base else "")
                         + ", or its values give the same block parameters): its values "
                         "change nothing in the runs")
            continue
        others = [(p, v) for p, v in vary if p != path]
        if not others:
            continue
        ends = [{p: v[0] for p, v in others}, {p: v[-1] for p, v in others}]
        if not any(_changed(load(file, set={**base, **fixed, path: values[0]}),
                            load(file, set={**base, **fixed, path: v}))
                   for fixed in ends for v in values[1:]):
            used = ", ".join(uses[path][:5]) + (", ..." if len(uses[path]) > 5 else "")
            setters = ", ".join(f"--vary {p}" for p, _ in others if _may_set(p, uses[path]))
            notes.append(f"--vary {path}: its values change nothing in the runs: the block "
                         f"parameter(s) that depend on '{path}' ({used}) are set "
                         f"themselves by {setters}; vary one of them, not both")
    return notes


def _may_set(key, params):
    """An override ``key`` may set one of the block parameters ``params``: a top-level
    parameter (through expressions), the parameter itself, or one of a subsystem or block
    containing one of them."""
    return "." not in key or any(p == key or p.startswith(key.rpartition(".")[0] + ".")
                                 for p in params)


def _changed(d1, d2):
    """The block parameters (``block.param``) whose values differ between the loaded
    diagrams ``d1`` and ``d2`` (a block of only one of them counts as its path). Nothing
    else decides a sweep's metrics (the simulation settings take no parameters; the
    ``microgravity`` section is not part of a sweep)."""
    out = [p for p in d2.blocks if p not in d1.blocks]
    for path, inst in d1.blocks.items():
        other = d2.blocks.get(path)
        if other is None:
            out.append(path)
            continue
        out += [f"{path}.{k}" for k, v in inst.params.items()
                if k not in other.params or not _same(v, other.params[k])]
    return out


def _same(a, b):
    """``a`` and ``b`` (parameter values: numbers, arrays, texts, mappings) are equal; a
    value that cannot be compared counts as different."""
    if isinstance(a, dict) or isinstance(b, dict):
        return (isinstance(a, dict) and isinstance(b, dict) and a.keys() == b.keys()
                and all(_same(a[k], b[k]) for k in a))
    try:
        return bool(np.array_equal(np.asarray(a), np.asarray(b),
                                   equal_nan=np.asarray(a).dtype.kind in "fc"))
    except Exception:  # noqa: BLE001 - objects without a comparison: not the same
        return a is b


def _run_dask(file, base, points, sim, rows, workers, scheduler, progress, connect_timeout,
              should_stop=None, run_timeout=None):
    """Run ``points`` on Dask, filling ``rows``; returns the number of workers. A stop
    (``should_stop()``, polled every :data:`POLL_S`, or a KeyboardInterrupt) cancels the
    runs not finished and marks them :data:`INTERRUPTED`."""
    client, cluster = _dask_client(workers, scheduler, connect_timeout)
    futures = []
    try:
        n_workers = len(client.scheduler_info().get("workers", {}))
        if n_workers == 0:
            try:
                client.wait_for_workers(1, timeout=connect_timeout)
            except Exception:  # noqa: BLE001 - dask raises TimeoutError here
                raise SpidersimError(f"the Dask scheduler at {scheduler} has no workers "
                                     f"(waited {connect_timeout:g} s)") from None
            n_workers = len(client.scheduler_info().get("workers", {}))
        futures = [client.submit(run_point, file, base, pt, sim, k, None, run_timeout,
                                 pure=False,
                                 key=f"spidersim-run-{k}-{os.getpid()}-{time.time_ns()}")
                   for k, pt in enumerate(points)]
        _collect(futures, points, rows, progress, should_stop)
        return n_workers
    finally:
        unfinished = [k for k, f in enumerate(futures) if rows[k] is None]
        for k in unfinished:
            rows[k] = _unfinished_row(k, points[k], INTERRUPTED, "unfinished when the sweep "
                                      "was interrupted (queued or running on a worker)")
        if unfinished:
            client.cancel([futures[k] for k in unfinished])
        client.close()
        if cluster is not None:
            _close_local_cluster(cluster)


#: seconds between two looks at ``should_stop`` while waiting for Dask runs
POLL_S = 0.1


def _collect(futures, points, rows, progress, should_stop):
    """Fill ``rows`` as the runs of ``futures`` finish (a worker's failure is a failed row);
    return early when ``should_stop()`` says so."""
    from dask.distributed import as_completed
    index = {f.key: k for k, f in enumerate(futures)}
    done = 0
    pending = as_completed(futures)
    while not pending.is_empty():
        if should_stop is not None and should_stop():
            return
        batch = pending.next_batch(block=False)
        if not batch:
            time.sleep(POLL_S)
        for fut in batch:
            k = index[fut.key]
            try:
                rows[k] = fut.result()
            except Exception as exc:  # noqa: BLE001 - a worker died: report, go on
                rows[k] = {"run": k, **points[k], "status": "failed",
                           "message": f"worker failure: {type(exc).__name__}: {exc}",
                           "compiled": False, "worker": "", "wall_s": math.nan}
            done += 1
            if progress:
                progress(rows[k], done, len(futures))


def _dask_client(workers, scheduler, connect_timeout):
    """``(client, cluster)``: a client of the scheduler at ``scheduler`` (cluster None), or
    of a new local cluster of ``workers`` processes."""
    try:
        from dask.distributed import Client, LocalCluster
    except ImportError as exc:  # pragma: no cover - a dependency
        raise SpidersimError(f"sweeps on Dask need dask.distributed ({exc}); "
                             f"pip install 'dask[distributed]' or use --workers 0") from None
    import logging
    if scheduler:
        try:
            return Client(scheduler, timeout=f"{connect_timeout}s"), None
        except Exception as exc:  # noqa: BLE001 - OSError, TimeoutError, bad address
            raise SpidersimError(f"cannot reach the Dask scheduler at {scheduler}: "
                                 f"{type(exc).__name__}: {exc}") from None
    if workers < 1:
        raise SpidersimError(f"--workers must be >= 0, got {workers}")
    scratch = tempfile.mkdtemp(prefix="spidersim-dask-")
    try:
        cluster = LocalCluster(n_workers=workers, threads_per_worker=1, processes=True,
                               dashboard_address=None, silence_logs=logging.ERROR,
                               local_directory=scratch,
                               scheduler_kwargs={"local_directory": scratch})
    except Exception as exc:  # noqa: BLE001 - e.g. no ports, no process start-up
        shutil.rmtree(scratch, ignore_errors=True)
        raise SpidersimError(f"cannot start a local Dask cluster of {workers} worker(s): "
                             f"{type(exc).__name__}: {exc} (--workers 0 runs serially)") \
            from None
    cluster.spidersim_scratch = scratch
    try:
        return Client(cluster), cluster
    except BaseException:
        _close_local_cluster(cluster)
        raise


def _close_local_cluster(cluster):
    """Close a local cluster of :func:`_dask_client` and remove its scratch folder.

    Dask's workers keep their scratch space (and lock files that outlive them) in the
    cluster's ``local_directory``, by default ``<temp>/dask-scratch-space``: a sweep gives
    its cluster a temporary folder of its own instead, so nothing is left behind.

    Parameters
    ----------
    cluster : distributed.LocalCluster
        Made by :func:`_dask_client` (its folder is ``cluster.spidersim_scratch``).
    """
    try:
        cluster.close()
    finally:
        shutil.rmtree(cluster.spidersim_scratch, ignore_errors=True)


def print_progress(row, done, total, stream=None):
    """Default progress line for the CLI (on ``sys.stderr`` as it is at the call)."""
    stream = stream or sys.stderr
    vals = " ".join(f"{k}={_num(v)}" for k, v in row.items()
                    if k not in RESERVED and isinstance(v, float))
    what = "ok" if row["status"] == "ok" else f"{row['status'].upper()}: {row['message'][:200]}"
    stream.write(f"  [{done}/{total}] run {row['run']}: {vals}  {what}  "
                 f"({row.get('wall_s', math.nan):.2f} s)\n")
    stream.flush()
