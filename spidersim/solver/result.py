"""Simulation results: named time series, events, statistics; saved as NPZ, CSV and a report.
"""
from __future__ import annotations

import collections.abc
import csv
import json
import math
import os
import zipfile

import numpy as np

from ..errors import ResultError, SignalError, described
from ..outputs import write_atomic  # noqa: F401 (also imported from here)


class Result:
    """Named time series of one run.

    ``r.t`` is the time vector; ``r["block.port"]`` a 1-D array for a scalar signal and an
    (n_samples, size) array for a vector signal; ``r.events`` a sequence of ``(t, block,
    event)`` (a list, or an :class:`EventLog` over the compiled loop's arrays);
    ``r.stats`` a dict (method, rtol, atol, steps, rhs_calls, jacobian_calls, lu_decompositions,
    events, wall_time, compile_time, ...); ``r.status`` ``"ok"`` or ``"failed"`` with
    ``r.message``; ``r.final`` is ``(t, x, modes)`` at the end of a successful run (the
    operating point a linearization can start from).
    """

    final = None
    #: how the run was made (versions, platform, date, file hashes, command line, --set);
    #: filled by the CLI, written into report.txt, report.json and the NPZ metadata
    provenance: dict = {}
    #: names of the files the run wrote into its folder (set by the CLI before the reports
    #: are written; listed in report.txt and report.json as ``files``)
    files: tuple = ()
    #: the largest record written as result.csv too (None: :data:`CSV_MAX_VALUES`)
    csv_max_values = None

    def __init__(self, t, data, slices, units, events, stats, status="ok", message=""):
        self.t = np.asarray(t)
        self._data = data
        self._slices = slices
        self.units = units
        self.events = events
        self.stats = stats
        self.status = status
        self.message = message
        self.provenance = {}

    @property
    def names(self):
        return list(self._slices)

    def __contains__(self, name):
        return name in self._slices

    def __getitem__(self, name):
        if not isinstance(name, str):
            raise SignalError(f"a signal is named by a text 'block.port', got "
                              f"{described(name)}")
        if name not in self._slices:
            import difflib
            near = difflib.get_close_matches(name, self.names, n=3)
            hint = f"; did you mean {', '.join(near)}?" if near else ""
            raise SignalError(f"no logged signal '{name}'{hint}")
        a, b = self._slices[name]
        col = self._data[:, a:b]
        return col[:, 0] if b - a == 1 else col

    def __repr__(self):
        return (f"<Result {self.status}: {len(self.t)} samples to t = "
                f"{self.t[-1] if len(self.t) else 0:g} s, {len(self._slices)} signals>")

    def plot(self, signals=None, title=None, one_panel=False, ax=None):
        """Plot ``signals`` (default: every logged signal, up to 8) against time, one panel
        per unit (or one panel); returns the matplotlib Figure. For notebooks and scripts:
        the current matplotlib backend is used (nothing is written)."""
        import matplotlib.pyplot as plt
        from ..plots import split_signal
        signals = self._plot_signals(signals)
        units = []
        for s_ in signals:
            u = self.units.get(split_signal(s_)[0], "1")
            if u not in units:
                units.append(u)
        if one_panel or ax is not None:
            units = [", ".join(units)]
        if ax is None:
            fig, axes = plt.subplots(len(units), 1, sharex=True, squeeze=False,
                                     figsize=(8, 2.2 + 2.0 * len(units)))
            axes = axes[:, 0]
        else:
            fig, axes = ax.figure, [ax]
        from ..plots import signal_values
        for a, unit in zip(axes, units):
            for s_ in signals:
                if len(units) > 1 and self.units.get(split_signal(s_)[0], "1") != unit:
                    continue
                y = signal_values(self, s_)
                if y.ndim == 1:
                    a.plot(self.t, y, label=s_)
                else:
                    for i in range(y.shape[1]):
                        a.plot(self.t, y[:, i], label=f"{s_}[{i}]")
            a.set_ylabel(f"[{unit}]")
            a.grid(True, alpha=0.3)
            a.legend(fontsize="small", loc="best")
        axes[-1].set_xlabel("time [s]")
        if title:
            axes[0].set_title(title)
        return fig

    def _plot_signals(self, signals):
        """The ``signals`` argument of :meth:`plot` as a list of logged names (``name`` or
        ``name[i]``): None is every logged signal (up to 8), a text one signal, else a
        non-empty list or tuple of texts; a :class:`SignalError` names what is wrong."""
        from ..plots import element_problem, split_signal
        if signals is None:
            return self.names[:8]
        if isinstance(signals, str):
            signals = [signals]
        if not isinstance(signals, (list, tuple)) or not signals:
            raise SignalError(f"plot: signals must be a signal name or a non-empty list of "
                              f"them (None: every logged signal), got {described(signals)}")
        for s_ in signals:
            if not isinstance(s_, str):
                raise SignalError(f"plot: a signal is named by a text 'block.port', got "
                                  f"{described(s_)}")
            name, idx = split_signal(s_)
            size = self[name].shape[1] if self[name].ndim > 1 else 1
            problem = element_problem(name, idx, size) if idx is not None else None
            if problem:
                raise SignalError(f"plot: '{s_}': {problem}")
        return list(signals)

    def to_dataframe(self):
        """A pandas DataFrame indexed by time, one column per element (``name[i]`` for
        vectors); the units are in ``df.attrs["units"]``. Needs pandas
        (``pip install spidersim[pandas]``)."""
        try:
            import pandas as pd
        except ImportError:
            raise ImportError("Result.to_dataframe needs pandas: pip install "
                              "'spidersim[pandas]' (or pip install pandas)") from None
        df = pd.DataFrame({h: c for h, c in self.columns()},
                          index=pd.Index(self.t, name="t [s]"))
        df.attrs["units"] = dict(self.units)
        return df

    def _repr_html_(self):
        import html
        rows = "".join(f"<tr><td><code>{html.escape(n)}</code></td>"
                       f"<td>{html.escape(self.units.get(n, '1'))}</td><td>{b - a}</td></tr>"
                       for n, (a, b) in self._slices.items())
        s = self.stats
        return (f"<div><b>spidersim Result</b>: {html.escape(self.status)}, "
                f"{len(self.t)} samples to t = {self.t[-1] if len(self.t) else 0:g} s; "
                f"{s.get('steps', '?')} steps, {s.get('rhs_calls', '?')} RHS calls, "
                f"{len(self.events)} events"
                + (f"<br><i>{html.escape(self.message)}</i>" if self.message else "")
                + "<table><tr><th>signal</th><th>unit</th><th>size</th></tr>"
                + rows + "</table></div>")

    def columns(self):
        """(header, column) pairs with one column per element (``name[i]`` for vectors)."""
        for name, (a, b) in self._slices.items():
            for k in range(a, b):
                yield (name if b - a == 1 else f"{name}[{k - a}]"), self._data[:, k]

    def save(self, folder, reports=True, csv_max_values=None):
        """Write ``result.npz``, ``result.csv`` (up to ``csv_max_values`` values, default
        :data:`CSV_MAX_VALUES`: :meth:`csv_written`), and with ``reports`` ``report.txt``
        and ``report.json`` (:meth:`save_reports`; strict JSON, non-finite numbers as null)
        into ``folder``.

        Each file is written to a temporary name in ``folder`` and renamed when complete, so
        a full disk or a crash leaves either the complete file or none (an OSError names the
        file; the temporary is removed).
        """
        folder = _folder_name(folder, "Result.save: folder")
        if csv_max_values is not None:
            self.csv_max_values = _csv_max(csv_max_values)
        os.makedirs(folder, exist_ok=True)
        arrays = {"t": self.t}
        arrays.update({n: self[n] for n in self.names})
        write_atomic(os.path.join(folder, "result.npz"),
                     lambda fh: self._write_npz(fh, arrays), binary=True)

        def csv_rows(fh):
            w = csv.writer(fh)
            cols = list(self.columns())
            w.writerow(["t [s]"] + [f"{h} [{self.units.get(h.split('[')[0], '1')}]"
                                    for h, _ in cols])
            # in blocks of rows: one table of every row would copy the whole record
            for lo in range(0, len(self.t), CSV_BLOCK):
                hi = lo + CSV_BLOCK
                data = np.column_stack([self.t[lo:hi]] + [c[lo:hi] for _, c in cols])
                for row in data:
                    w.writerow([repr(float(v)) for v in row])
        csv_path = os.path.join(folder, "result.csv")
        if self.csv_written():
            write_atomic(csv_path, csv_rows)
        elif os.path.isfile(csv_path):
            os.remove(csv_path)              # an earlier run's table would pass for this one's
        if reports:
            self.save_reports(folder)
        return folder

    def save_reports(self, folder):
        """``report.txt`` and ``report.json`` (with :attr:`files`, the files of the run,
        when set) into ``folder``."""
        write_atomic(os.path.join(folder, "report.txt"), lambda fh: fh.write(self.report()))
        write_atomic(os.path.join(folder, "report.json"),
                     lambda fh: write_meta_json(fh, self._meta_head(), self.events, indent=1))

    def csv_values(self):
        """Values the CSV table would hold: rows x (time + every column)."""
        return len(self.t) * (1 + sum(b - a for a, b in self._slices.values()))

    def csv_written(self, max_values=None):
        """Whether :meth:`save` writes ``result.csv``: at most ``max_values`` values (default
        :attr:`csv_max_values`, else :data:`CSV_MAX_VALUES`; as text about 24 bytes each,
        three times the binary record); a larger record is in ``result.npz`` only (a 1e300 s
        run at the default recording budget wrote 6.6 GB of CSV beside its 7.8 GB NPZ)."""
        return self.csv_values() <= self._csv_limit(max_values)

    def _csv_limit(self, max_values=None):
        if max_values is not None:
            return max_values
        return CSV_MAX_VALUES if self.csv_max_values is None else self.csv_max_values

    def meta(self):
        """Everything but the samples: status, units, sizes, statistics, events, provenance."""
        return dict(self._meta_head(), events=[list(e) for e in self.events])

    def _meta_head(self):
        """:meth:`meta` without the events (they are written by :func:`write_meta_json`)."""
        head = {"status": self.status, "message": self.message, "units": self.units,
                "sizes": {n: b - a for n, (a, b) in self._slices.items()},
                "stats": self.stats, "provenance": self.provenance}
        if self.files:
            head["files"] = list(self.files)
        return head

    def _write_npz(self, fh, arrays):
        """``result.npz`` as ``np.savez`` writes it (one ``.npy`` entry per array, stored),
        with ``__meta__`` the JSON of :meth:`meta` as UTF-8 bytes (``uint8``), streamed
        into its entry: built as one text and stored as a NumPy string (4 bytes a
        character), the meta of 3.45 million events took 0.6 GB of memory and of file."""
        fmt = np.lib.format
        with zipfile.ZipFile(fh, mode="w", compression=zipfile.ZIP_STORED,
                             allowZip64=True) as zf:
            for name, a in arrays.items():
                with zf.open(name + ".npy", "w", force_zip64=True) as f:
                    _write_npy(f, np.asarray(a))
            head = self._meta_head()
            counter = _Counter()               # first pass: the length of the header
            write_meta_json(counter, head, self.events)
            with zf.open("__meta__.npy", "w", force_zip64=True) as f:
                fmt.write_array_header_2_0(f, {"descr": "|u1", "fortran_order": False,
                                               "shape": (counter.n,)})
                write_meta_json(_Utf8(f), head, self.events)

    @classmethod
    def load(cls, folder):
        """The result a ``save(folder)`` wrote (``result.npz`` with its metadata).

        A :class:`~spidersim.errors.ResultError` when ``folder`` is not a folder path, does
        not exist, is a file, holds no ``result.npz``, or that file is not one
        :meth:`save` wrote (damaged, truncated, another NPZ, metadata of other keys, types
        or sizes: :func:`_meta_problem`)."""
        folder = _folder_name(folder, "Result.load: folder")
        path = os.path.join(folder, "result.npz")
        if not os.path.isdir(folder):
            what = ("a file, not a results folder" if os.path.exists(folder) else
                    "no such folder")
            raise ResultError(f"Result.load: {what}: {folder}")
        if not os.path.isfile(path):
            raise ResultError(f"Result.load: no result.npz in {folder} (the folder of a "
                              f"run or of Result.save)")
        try:
            return cls._read_npz(path)
        except (OSError, ValueError, KeyError, TypeError, EOFError, zipfile.BadZipFile) as exc:
            # json's and UnicodeDecodeError are ValueErrors
            raise ResultError(f"Result.load: cannot read {path}: not a result saved by "
                              f"Result.save, or damaged ({type(exc).__name__}: "
                              f"{str(exc)[:200]})") from None

    @classmethod
    def _read_npz(cls, path):
        with np.load(path, allow_pickle=False) as z:
            raw = z["__meta__"]         # UTF-8 bytes; a NumPy string in older files
            meta = json.loads(raw.tobytes().decode("utf-8") if raw.dtype == np.uint8
                              else str(raw))
            problem = _meta_problem(meta)
            if problem:
                raise ResultError(f"Result.load: cannot read {path}: its metadata (__meta__) "
                                  f"is not one Result.save writes: {problem}")
            t = z["t"]
            cols, slices, k = [], {}, 0
            for name, size in meta["sizes"].items():
                cols.append(np.asarray(z[name], dtype=float).reshape(len(t), size))
                slices[name] = (k, k + size)
                k += size
        data = np.hstack(cols) if cols else np.zeros((len(t), 0))
        r = cls(t, data, slices, meta["units"], [tuple(e) for e in meta["events"]],
                meta["stats"], meta["status"], meta["message"])
        r.provenance = meta.get("provenance", {})
        return r

    def report(self):
        s = self.stats
        lines = [f"status: {self.status}"]
        if self.message:
            lines.append(f"message: {self.message}")
        keys = ["diagram", "method", "stepper", "rtol", "atol", "max_step", "t_end", "t_reached", "steps",
                "rhs_calls", "newton_iterations", "jacobian_calls", "lu_decompositions",
                "time_events", "events", "samples", "compile_time", "from_cache", "wall_time",
                "jit", "structure_key"]
        exact = ("rtol", "atol", "max_step", "t_end", "t_reached")   # as given: 1.0000001
        for k in keys:
            if k in s:
                v = s[k]
                if isinstance(v, float):
                    v = repr(v) if k in exact else f"{v:.6g}"
                lines.append(f"{k}: {v}")
        for k, v in self.provenance.items():
            if isinstance(v, dict):
                lines += [f"{k}:"] + [f"  {a}: {b}" for a, b in v.items()]
            else:
                lines.append(f"{k}: {v}")
        if not self.csv_written():
            limit = self._csv_limit()
            lines.append(f"result.csv: not written ({self.csv_values():,} values, more than "
                         f"{limit:,}); the data is in result.npz")
        if self.files:
            lines.append(f"files of this run: {', '.join(self.files)}")
        if self.events:
            counts = event_counts(self.events)
            shown = ", ".join(f"{blk} {ev} {n}" for (blk, ev), n in counts[:12])
            more = f", and {len(counts) - 12} more" if len(counts) > 12 else ""
            # a sampled block logs every sample: the counts show what else happened
            lines.append(f"events by block and kind ({len(counts)}): {shown}{more}")
            lines.append(f"event log ({len(self.events)}, first 20):")
            lines += [f"  t = {t:.9g} s  {blk}  {ev}" for t, blk, ev in self.events[:20]]
        return "\n".join(lines) + "\n"

    def to_json(self):
        return json.dumps({"status": self.status, "message": self.message,
                           "stats": self.stats}, default=float, indent=1)


#: the metadata keys :meth:`Result.load` needs, with the JSON type each must have
META_TYPES = {"sizes": dict, "units": dict, "events": list, "stats": dict, "status": str,
              "message": str}


def _meta_problem(meta):
    """What is wrong with the metadata of a ``result.npz`` (its keys, their types, the
    signal sizes: whole numbers >= 0), or '' when nothing is."""
    if not isinstance(meta, dict):
        return f"a mapping was expected, got {described(meta)}"
    for key, kind in META_TYPES.items():
        if key not in meta:
            return f"no '{key}'"
        if not isinstance(meta[key], kind):
            return f"'{key}' must be a {_JSON_NAMES[kind]}, got {described(meta[key])}"
    if not isinstance(meta.get("provenance", {}), dict):
        return f"'provenance' must be a mapping, got {described(meta['provenance'])}"
    for name, size in meta["sizes"].items():
        if isinstance(size, bool) or not isinstance(size, int) or size < 0:
            return (f"'sizes' must give each signal its number of columns (a whole number "
                    f">= 0), got {size!r} for '{name}'")
    for e in meta["events"]:
        if not (isinstance(e, list) and len(e) == 3):
            return f"each event must be [t, block, event], got {str(e)[:60]}"
    return ""


_JSON_NAMES = {dict: "mapping", list: "list", str: "text"}


#: rows of the CSV table converted at a time
CSV_BLOCK = 1 << 12
#: the largest record written as ``result.csv`` too (values; about 240 MB of text)
CSV_MAX_VALUES = 10_000_000
#: events of a log converted to text (or to tuples) at a time
EVENT_BLOCK = 1 << 12


def event_counts(events):
    """``[((block, event), count), ...]`` of an event log, most frequent first (ties by
    name); from the log's arrays when it is an :class:`EventLog` (one count per kind of
    event: no per-event work or memory beyond the log itself)."""
    if isinstance(events, EventLog):
        n = np.bincount(events.code, minlength=len(events.blocks))
        pairs = [((events.blocks[c], events.kinds[c]), int(n[c]))
                 for c in np.flatnonzero(n)]
    else:
        pairs = list(collections.Counter((blk, ev) for _t, blk, ev in events).items())
    pairs.sort(key=lambda p: (-p[1], p[0]))
    return pairs


class EventLog(collections.abc.Sequence):
    """A run's event log as ``(t, block, event)`` entries, kept as arrays.

    The compiled loop logs an event as 4 numbers (32 bytes, counted in the recording
    budget); as Python tuples the same entry took about 150 bytes more, so a sampled block
    at 10 MHz stopped at a 0.3 GB budget peaked at 1.78 GB. This sequence keeps the arrays and
    makes a tuple only when an entry is read: ``log[k]``, ``log[a:b]`` (a list), iteration
    (in blocks of :data:`EVENT_BLOCK`), ``len``, ``==`` with any sequence of triples.

    Parameters
    ----------
    t : ndarray, float, shape (n,)
        The event times [s].
    code : ndarray, int, shape (n,)
        Each event's index into ``blocks`` and ``kinds``.
    blocks, kinds : sequence of str
        The block path and the event name (``"time"`` for a time event) of each code.
    """

    def __init__(self, t, code, blocks, kinds):
        self.t, self.code = t, code
        self.blocks, self.kinds = list(blocks), list(kinds)

    def __len__(self):
        return len(self.t)

    def __getitem__(self, k):
        if isinstance(k, slice):
            return list(self._entries(*k.indices(len(self))))
        c = int(self.code[k])
        return float(self.t[k]), self.blocks[c], self.kinds[c]

    def __iter__(self):
        return self._entries(0, len(self), 1)

    def _entries(self, start, stop, step):
        b, k = self.blocks, self.kinds
        for lo in range(start, stop, EVENT_BLOCK * step) if step > 0 else ():
            hi = min(stop, lo + EVENT_BLOCK * step)
            for tk, c in zip(self.t[lo:hi:step].tolist(), self.code[lo:hi:step].tolist()):
                yield tk, b[c], k[c]
        if step < 0:
            yield from (self[i] for i in range(start, stop, step))

    def __eq__(self, other):
        if not isinstance(other, collections.abc.Sequence) or isinstance(other, str):
            return NotImplemented
        return len(self) == len(other) and all(tuple(a) == tuple(b)
                                               for a, b in zip(self, other))

    __hash__ = None

    def __repr__(self):
        return f"EventLog({len(self)} events: {self[:3]}{' ...' if len(self) > 3 else ''})"


def _folder_name(folder, what):
    """``folder`` (a text, bytes or an ``os.PathLike``) as a text; anything else is a
    :class:`ResultError` naming the argument ``what``."""
    if not isinstance(folder, (str, bytes, os.PathLike)):
        raise ResultError(f"{what} must be a folder path (a str or a pathlib.Path), got "
                          f"{described(folder)}")
    return os.fsdecode(os.fspath(folder))


def finite_json(v):
    """``v`` with every non-finite float (inf, -inf, nan) replaced by None: strict JSON
    (RFC 8259 has no Infinity or NaN; browsers and strict parsers refuse them)."""
    if isinstance(v, float):
        return v if math.isfinite(v) else None
    if isinstance(v, dict):
        return {k: finite_json(x) for k, x in v.items()}
    if isinstance(v, (list, tuple)):
        return [finite_json(x) for x in v]
    return v


def write_meta_json(fh, head, events, indent=None):
    """Write ``head`` (a dict) with ``"events": events`` appended as JSON into ``fh`` (a
    text file or anything with ``write(str)``), the events in blocks: a log of millions of
    events is never one list of lists nor one text (``json.dump`` of ``Result.meta()`` held
    both, about 300 bytes an event)."""
    text = json.dumps(finite_json(head), indent=indent, default=_jsonable, allow_nan=False)
    sep = ",\n" + " " * indent if indent is not None else ", "
    fh.write(text[:text.rindex("}")].rstrip() + (sep if head else "") + '"events": [')
    first, tails = True, {}
    for lo in range(0, len(events), EVENT_BLOCK):
        part = []
        for t, blk, ev in events[lo:lo + EVENT_BLOCK]:
            tail = tails.get((blk, ev))
            if tail is None:
                tail = tails[(blk, ev)] = ", " + json.dumps([blk, ev])[1:]
            t = float(t)
            part.append("[" + (repr(t) if math.isfinite(t) else "null") + tail)
        fh.write(("" if first else ", ") + ", ".join(part))
        first = False
    fh.write("]}" if indent is None else "]\n}")


def _write_npy(f, a):
    """``a`` as a ``.npy`` file into the stream ``f``, its rows in blocks: ``np.save``
    into a ZIP entry copies a whole contiguous array (``tobytes``) and buffers 16 MB of a
    column view, more memory than the rows the budget counts."""
    fmt = np.lib.format
    head = fmt.header_data_from_array_1_0(a)
    head["fortran_order"] = False              # written in C order below
    fmt.write_array_header_2_0(f, head)
    step = max(1, CSV_BLOCK * 16 // max(1, a[:1].size))
    for lo in range(0, len(a), step):
        f.write(np.ascontiguousarray(a[lo:lo + step]).tobytes())


class _Counter:
    """A text sink that counts the UTF-8 bytes written into it."""

    def __init__(self):
        self.n = 0

    def write(self, text):
        self.n += len(text.encode("utf-8"))


class _Utf8:
    """A text sink writing UTF-8 into the binary file ``f``."""

    def __init__(self, f):
        self.f = f

    def write(self, text):
        self.f.write(text.encode("utf-8"))


def _jsonable(v):
    if isinstance(v, np.generic):
        return v.item()
    if isinstance(v, np.ndarray):
        return v.tolist()
    return str(v)


def _csv_max(v):
    """``csv_max_values`` of :meth:`Result.save` checked before it is kept: a whole number
    >= 0 (a text was kept and broke every later save and report with a TypeError)."""
    if isinstance(v, (bool, np.bool_)) or not isinstance(v, (int, np.integer, float,
                                                                np.floating)):
        raise ResultError(f"Result.save: csv_max_values must be a number of values >= 0, "
                          f"got {type(v).__name__} {v!r:.40}")
    if not (v >= 0) or (isinstance(v, (float, np.floating)) and not float(v).is_integer()
                        and math.isfinite(v)):
        raise ResultError(f"Result.save: csv_max_values must be a whole number >= 0 (or "
                          f"inf), got {v!r}")
    return v
