"""The memory budget of a run's recorded rows.

A run records one row per accepted step (or per point of the ``output_interval`` grid), each
row ``record_size`` float64 values plus its time. The buffers double when full; without a
bound, a run with a tiny ``max_step`` or ``output_interval`` grows them until the operating
system kills the process and every computed row is lost. Both integration loops ask this
module instead:

- :func:`check_planned` before the run: rows that are certain to be needed (the grid, or at
  least ``(t_end - t0) / max_step`` steps when every step is recorded) must fit the budget,
  else a :class:`~spidersim.errors.SpidersimError` says what to change;
- :func:`grown_rows` when a buffer is full: the next capacity, never above the budget, or
  ``None`` at the budget, where the loop stops the run with an error that keeps the rows
  already recorded (``IntegrationError.partial``). The rows and the event log share one
  budget (each buffer gets what the other leaves); the SciPy steppers' event log, a Python
  list, is checked by :func:`events_fit`.

The budget bounds the memory the recorded data take, not only the buffers' final size: a
buffer grows and is trimmed in place (:func:`resize_rows`: ``realloc``, whose large blocks
the C library moves by remapping pages, so a doubling never holds the old and the new
buffer at once, which made the peak 1.5 times the budget), the result keeps views of the
buffers and of the compiled loop's event log (:class:`~spidersim.solver.result.EventLog`:
no Python object per event), and ``Result.save`` streams what it writes. Before these, a
run stopped at a 0.3 GB budget peaked at 1.78 GB of resident memory (3.45 million sampler
events turned into Python tuples and twice into JSON text, 4 bytes a character in the
NPZ).

The budget is 40 % of the machine's physical memory, or ``SPIDERSIM_RECORD_LIMIT_MB``
megabytes (10^6 bytes) if that environment variable is set to a positive number.
"""
from __future__ import annotations

import functools
import math
import os

from ..errors import SpidersimError

#: share of the physical memory the recorded rows may take by default
DEFAULT_FRACTION = 0.4
#: environment variable overriding the budget, in megabytes (10^6 bytes)
ENV = "SPIDERSIM_RECORD_LIMIT_MB"
_FALLBACK = 4e9              # bytes, when the physical memory cannot be read


def budget_bytes() -> float:
    """The recording budget [bytes] (see the module docstring)."""
    text = os.environ.get(ENV, "").strip()
    if text:
        try:
            mb = float(text)
        except ValueError:
            mb = math.nan
        if not (math.isfinite(mb) and mb > 0):
            raise SpidersimError(f"{ENV} must be a positive number of megabytes, "
                                 f"got {text[:40]!r}")
        return mb * 1e6
    phys = _physical_bytes()
    return _FALLBACK if phys is None else DEFAULT_FRACTION * phys


@functools.lru_cache(maxsize=1)
def _physical_bytes():
    """The machine's physical memory [bytes], None when it cannot be read (read once: two
    system calls were a quarter of ``simulate``'s Python time on short runs)."""
    try:
        return os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES")
    except (ValueError, OSError, AttributeError):
        return None


def row_bytes(record_size: int) -> int:
    """Bytes of one recorded row: its values and its time, float64."""
    return 8 * (int(record_size) + 1)


def max_rows(record_size: int) -> int:
    """The most rows of ``record_size`` values the budget holds (at least 1024)."""
    return max(1024, int(budget_bytes() // row_bytes(record_size)))


def _gb(nbytes: float) -> str:
    return f"{nbytes / 1e9:.3g} GB"


def check_planned(record_size, t0, t_end, max_step, output_interval):
    """Raise :class:`SpidersimError` if the rows the run is certain to record exceed the
    budget: the ``output_interval`` grid, or, when every step is recorded, at least
    ``(t_end - t0) / max_step`` steps."""
    span = t_end - t0
    if output_interval:
        rows, why = span / output_interval, (f"output_interval = {output_interval:g} s over "
                                             f"{span:g} s")
        advice = "raise simulation.output_interval or shorten t_end"
    elif math.isfinite(max_step):
        rows, why = span / max_step, (f"max_step = {max_step:g} s over {span:g} s, every "
                                      f"step recorded")
        advice = ("set simulation.output_interval (rows on a grid instead of every step), "
                  "raise max_step or shorten t_end")
    else:
        return
    limit = max_rows(record_size)
    if rows > limit:
        need = rows * row_bytes(record_size)
        raise SpidersimError(
            f"the recorded data would not fit in memory: {why} means at least {rows:.3g} "
            f"rows of {record_size + 1} values ({_gb(need)}), more than the recording "
            f"budget of {_gb(budget_bytes())} ({limit} rows); {advice} "
            f"(or set {ENV})")


def grown_rows(current: int, record_size: int, other_bytes: float = 0.0):
    """The capacity after a full buffer of ``current`` rows: twice as many, at most the
    rows the budget holds beside ``other_bytes`` already taken by the run's other buffer
    (the rows and the event log share one budget); ``None`` when ``current`` is already
    there."""
    limit = max(1024, int((budget_bytes() - other_bytes) // row_bytes(record_size)))
    if current >= limit:
        return None
    return min(2 * current, limit)


def resize_rows(a, rows):
    """Resize ``a`` to ``rows`` rows in place (new rows zero) and return it.

    ``ndarray.resize`` reallocates the buffer: a large block is moved by remapping its
    pages, so growing from ``n`` to ``2 n`` rows peaks at ``2 n`` rows of memory, not the
    ``3 n`` of a concatenation, and trimming frees the tail without a copy. No view of
    ``a`` may exist (the loops hold none between calls; the result's views are made after
    the last resize)."""
    a.resize((int(rows),) + a.shape[1:], refcheck=False)
    return a


#: bytes one event of the SciPy-stepper loop takes: the log's tuple of a float and two
#: shared strings in a list, and what the loop keeps besides per event (the process's peak
#: resident memory grew by 777 bytes an event beyond the rows, measured between runs
#: stopped at 10 and 40 MB with a sampler every 0.1 ms; 700 had been estimated from the
#: log alone and let a 20 MB run peak at 22.1 MB)
PY_EVENT_BYTES = 800


def events_fit(n_events: int, rows_bytes: float) -> bool:
    """Whether ``n_events`` entries of the SciPy-stepper loop's event log fit the budget
    beside ``rows_bytes`` of recorded rows; the log has at least 32 kB (40 entries) as the
    rows have at least 1024 rows, so that a budget smaller than the first row buffer still
    logs the first events (a 0.02 MB budget stopped a servo run at its first event with
    "0 entries")."""
    return n_events * PY_EVENT_BYTES <= max(budget_bytes() - rows_bytes, 1024 * 32)


def budget_message(rows: int, record_size: int, t: float, what="recorded data",
                   entry_bytes=None, other_bytes=0.0) -> str:
    """The error of a run stopped at the budget, at time ``t`` with ``rows`` rows (of the
    recorded data, or of the event log; ``entry_bytes``: bytes of one, when they are not
    ``record_size + 1`` floats; ``other_bytes``: what the other buffer holds, said when
    not 0, so that the message adds up to the budget)."""
    size = rows * (entry_bytes or row_bytes(record_size))
    other = "event log" if what != "event log" else "rows"
    beside = f" beside {_gb(other_bytes)} of {other}" if other_bytes else ""
    advice = ("shorten t_end or sample less often (every event is logged)"
              if what == "event log" else
              "set simulation.output_interval to record on a grid instead of every step, "
              "or shorten t_end")
    return (f"the {what} reached the memory budget at t = {t:.9g} s: {rows} entries "
            f"({_gb(size)}{beside}; the rows and the event log share the budget of "
            f"{_gb(budget_bytes())}); the rows so far are kept. To go on: {advice}, or "
            f"set {ENV}")
