"""Microgravity assessment: station acceleration from the base wrench, one-third-octave band
RMS levels against the ISS vibratory limit curve, and the peak transient acceleration.

The question of the paper's Fig. 8: does the arm, moving with its drive trains' torque
ripple, disturb the station beyond what the microgravity experiments tolerate?

Model
-----
The station is one rigid body of mass ``M`` [kg]; the force ``F(t)`` [N] the arm applies to
its mounting accelerates it by ``a(t) = F(t) / M`` [m/s^2] (a diagram's signal in another
force unit is converted, see :func:`newtons_per_unit`; any other unit is refused); levels are given in micro-g,
``1 micro-g = 9.80665e-6 m/s^2``. Each axis is assessed separately and the worst axis decides
each band.

Band analysis
-------------
One-third-octave bands with base-10 centres (IEC 61260-1 / ANSI S1.11):
``f_c = 1000 * 10^(n/10)`` Hz, edges ``f_c * 10^(-1/20)`` and ``f_c * 10^(+1/20)``. Over the
chosen window the signal must be sampled uniformly (a run with
``simulation.output_interval``; a record of the solver's own steps is refused, see
:mod:`spidersim.sampling`), its mean is removed, and the mean square in a band is the sum
of the one-sided periodogram over the FFT bins inside the band (Parseval, rectangular
window)::

    ms_band = sum_{f_lo <= f_k < f_hi} c_k |X_k|^2 / N^2,    c_k = 2 (1 for 0 and Nyquist)

so a sine of amplitude ``A`` in a band gives ``A / sqrt(2)``. A band is reported only where
the record resolves it: at least two bins wide (``f_hi - f_lo >= 2 / T``) and below the
Nyquist frequency. The band centres considered (``f_min..f_max``) must lie on the limit
curve (0.01..300 Hz): a band without a limit has no verdict, so such a range is refused
rather than left out of the verdict.

Limit curve
-----------
The ISS vibratory microgravity requirement (NASA SSP 41000, ISS System Specification, the
vibratory limit as RMS per one-third-octave band, also in SSP 57000):

- 1.6 micro-g for 0.01 <= f <= 0.1 Hz,
- f x 16 micro-g for 0.1 < f <= 100 Hz,
- 1600 micro-g for 100 < f <= 300 Hz,

evaluated at each band's centre frequency. The margin of a band is
``20 log10(limit / level)`` dB (positive: inside the limit); the verdict is PASS when every
band assessed has a margin >= 0 (at least one band is always assessed: a window that
resolves none is an error, not a PASS).

Peak transient
--------------
The largest ``|a_k(t)|`` over the whole record and the axes ``k`` (per axis, as the bands;
not the magnitude ``|a|`` of the vector, which can be up to ``sqrt(3)`` times larger).
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from .sampling import uniform_window

G0 = 9.80665            # m/s^2 per g (standard gravity)
MICRO_G = G0 * 1e-6     # m/s^2 per micro-g
#: frequency range of the ISS limit curve [Hz]
LIMIT_RANGE = (0.01, 300.0)


def iss_limit(f):
    """ISS vibratory limit [micro-g RMS per one-third-octave band] at frequency ``f`` [Hz].

    NaN outside 0.01..300 Hz, where the requirement says nothing.
    """
    f = np.asarray(f, dtype=float)
    out = np.where(f <= 0.1, 1.6, np.where(f <= 100.0, 16.0 * f, 1600.0))
    return np.where((f >= LIMIT_RANGE[0]) & (f <= LIMIT_RANGE[1]), out, np.nan)


def band_range_problem(f_min, f_max):
    """``(message, key)`` when band centres in ``[f_min, f_max]`` [Hz] cannot all be judged
    against the limit curve (a bound outside 0.01..300 Hz) or there is no band centre in
    the range; None when the range is fine. ``key`` is the setting to change."""
    lo, hi = LIMIT_RANGE
    for key, v in (("f_min", f_min), ("f_max", f_max)):
        if not lo <= v <= hi:
            return (f"{key} ({v:g} Hz) is outside the ISS limit curve ({lo:g}..{hi:g} Hz; "
                    f"SSP 41000 sets no limit beyond it, so a band there has no verdict): "
                    f"give f_min and f_max within {lo:g}..{hi:g} Hz", key)
    if not len(third_octave_bands(f_min, f_max)):
        return (f"no one-third-octave band centre (1000 * 10^(n/10) Hz) lies in "
                f"{f_min:g}..{f_max:g} Hz: widen the range", "f_min")
    return None


def top_band_edge(f_max):
    """Upper edge [Hz] of the highest band whose centre is at most ``f_max``: the Nyquist
    frequency ``1 / (2 dt)`` of the samples must exceed it for that band to be assessed."""
    n1 = int(np.floor(10 * np.log10(f_max / 1000.0) + 1e-9))
    return 1000.0 * 10.0 ** (n1 / 10.0) * 10 ** 0.05


def third_octave_bands(f_min=0.01, f_max=300.0):
    """Base-10 one-third-octave bands whose centres lie in ``[f_min, f_max]``.

    Returns an array of shape (n, 3): lower edge, centre, upper edge [Hz].
    """
    n0 = int(np.ceil(10 * np.log10(f_min / 1000.0) - 1e-9))
    n1 = int(np.floor(10 * np.log10(f_max / 1000.0) + 1e-9))
    fc = 1000.0 * 10.0 ** (np.arange(n0, n1 + 1) / 10.0)
    return np.column_stack([fc * 10 ** -0.05, fc, fc * 10 ** 0.05])


def uniform(t, y, t0=None, t1=None, resample=False):
    """``(dt, samples)`` of ``y(t)`` on a uniform grid over ``[t0, t1]`` inside the record.

    The recorded points must be uniform (see :func:`spidersim.sampling.uniform_window`,
    which raises :class:`~spidersim.sampling.NonUniformRecord` otherwise); ``resample=True``
    interpolates them linearly at the median step instead, which is right only where the
    points are dense compared with the signal's content.
    """
    t = np.asarray(t, dtype=float)
    t0 = t[0] if t0 is None else t0
    t1 = t[-1] if t1 is None else t1
    if not t[0] <= t0 < t1 <= t[-1]:
        raise ValueError(f"window [{t0}, {t1}] s is not inside the record "
                         f"[{t[0]}, {t[-1]}] s")
    return uniform_window(t, y, t0, t1, resample=resample)


def band_rms(x, dt, bands):
    """RMS of ``x`` (1-D, uniform step ``dt`` [s]) in each band of ``bands`` (n, 3).

    The mean is removed first. Bands the record cannot resolve (narrower than two bins or
    above Nyquist) get NaN.
    """
    x = np.asarray(x, dtype=float)
    x = x - x.mean()
    n = x.size
    X = np.fft.rfft(x)
    f = np.fft.rfftfreq(n, dt)
    p = np.abs(X) ** 2 / n ** 2
    p[1:] *= 2.0
    if n % 2 == 0:
        p[-1] /= 2.0                       # the Nyquist bin is not doubled
    df = 1.0 / (n * dt)
    out = np.full(len(bands), np.nan)
    for k, (lo, _, hi) in enumerate(bands):
        if hi - lo < 2 * df or hi > f[-1]:
            continue
        out[k] = np.sqrt(p[(f >= lo) & (f < hi)].sum())
    return out


@dataclass
class Assessment:
    """Band levels and verdict of one microgravity assessment (levels in micro-g)."""

    bands: np.ndarray                 # (n, 3) lower, centre, upper [Hz]
    levels: np.ndarray                # (n, axes) RMS per band and axis [micro-g]
    limit: np.ndarray                 # (n,) ISS limit at the centres [micro-g]
    peak: float                       # largest |a| over the whole record, worst axis [micro-g]
    peak_time: float                  # when [s]
    window: tuple                     # (t0, t1) [s]
    axes: list = field(default_factory=list)
    #: why the assessment covers less than was asked ('' when it does not): a window cut
    #: by the run's end resolves fewer low bands, so a PASS there is no verdict
    incomplete: str = ""

    @property
    def verdict(self):
        """``PASS``, ``FAIL`` (a band exceeds its limit: also when incomplete) or
        ``INCOMPLETE`` (no band assessed exceeds, but not every band asked for was
        assessed)."""
        if not self.passed:
            return "FAIL"
        return "INCOMPLETE" if self.incomplete else "PASS"

    @property
    def worst(self):
        """Worst axis level per band [micro-g]."""
        return np.nanmax(self.levels, axis=1)

    @property
    def margin_db(self):
        """``20 log10(limit / level)`` per band (positive: inside the limit)."""
        with np.errstate(divide="ignore", invalid="ignore"):
            return 20 * np.log10(self.limit / self.worst)

    @property
    def passed(self):
        """Every band assessed has a margin >= 0 dB, and there is at least one."""
        m = self.margin_db
        return bool(m.size > 0 and np.all(np.isfinite(m)) and np.all(m >= 0.0))

    def table(self):
        """Printable per-band table with the verdict."""
        rows = [f"microgravity: window {self.window[0]:g}..{self.window[1]:g} s, "
                f"{len(self.bands)} one-third-octave bands (ISS limit, SSP 41000)",
                f"  {'band [Hz]':>18} {'level [ug]':>11} {'limit [ug]':>11} "
                f"{'margin [dB]':>11}  verdict"]
        for (lo, fc, hi), lev, lim, m in zip(self.bands, self.worst, self.limit,
                                             self.margin_db):
            verdict = "ok" if m >= 0 else "EXCEEDS"
            rows.append(f"  {fc:8.3g} ({lo:.3g}-{hi:.3g}) {lev:11.3g} {lim:11.3g} "
                        f"{m:11.1f}  {verdict}")
        m = self.margin_db
        worst = int(np.nanargmin(m)) if np.isfinite(m).any() else None
        rows.append(f"  peak transient (whole run): {self.peak:.3g} micro-g at t = "
                    f"{self.peak_time:.3f} s")
        if worst is not None:
            rows.append(f"  verdict: {self.verdict}; smallest margin "
                        f"{m[worst]:.1f} dB in the {self.bands[worst, 1]:.3g} Hz band")
        if self.incomplete:
            rows.append(f"  not a complete assessment: {self.incomplete}")
        return "\n".join(rows)

    def as_dict(self):
        """The assessment as plain data for strict JSON: a value that is not a finite
        number (none is expected: the bands lie on the limit curve and are resolved)
        becomes None (``null``), never a bare NaN."""
        def num(v):
            v = float(v)
            return v if np.isfinite(v) else None
        return {"window": [num(v) for v in self.window],
                "passed": None if self.verdict == "INCOMPLETE" else self.passed,
                "verdict": self.verdict, "incomplete": self.incomplete or None,
                "peak_ug": num(self.peak), "peak_time": num(self.peak_time),
                "bands": [{"center_hz": num(b[1]), "lower_hz": num(b[0]),
                           "upper_hz": num(b[2]), "level_ug": num(lev),
                           "limit_ug": num(lim), "margin_db": num(m)}
                          for b, lev, lim, m in zip(self.bands, self.worst, self.limit,
                                                    self.margin_db)]}


#: units of a signal whose unit was not inferred (no unit anywhere on its path): read as N
_UNSTATED = ("?", "*")


def newtons_per_unit(unit):
    """The factor that turns a force signal in ``unit`` (a unit text, as in a result's
    ``units``) into newtons: ``kN`` -> 1000; a signal without a stated unit (``?``) is
    taken to be in N (factor 1).

    Raises
    ------
    ValueError
        ``unit`` is not a force (``m``, ``N.m``, dimensionless ``1``): the assessment
        divides a force by the station mass.
    """
    if unit is None or unit in _UNSTATED:
        return 1.0
    from .text import units as U
    try:
        return U.factor(U.parse(unit), U.parse("N"))
    except U.UnitError:
        raise ValueError(f"the signal is in {unit}, not a force (N, kN, ...): the "
                         f"assessment is the force on the station divided by its mass"
                         ) from None


def assess(t, force, mass, window=None, f_range=LIMIT_RANGE, resample=False):
    """Assess a base-force record against the ISS vibratory limit.

    Parameters
    ----------
    t : (n,) array
        Times [s].
    force : (n,) or (n, k) array
        Force the arm applies to the station [N], one column per axis.
    mass : float
        Station mass [kg] (rigid body).
    window : (t0, t1), optional
        Part of the record whose band levels are assessed [s] (default: all of it); the
        peak transient is taken over the whole record.
    f_range : (f_min, f_max)
        Band centres considered [Hz], within the limit curve's 0.01..300 Hz. The samples'
        Nyquist frequency must exceed the top band's upper edge (:func:`top_band_edge`);
        low bands the window is too short to resolve are left out.
    resample : bool
        Interpolate a record that is not on a uniform time grid (linearly, at its median
        step) instead of refusing it: right only for points dense compared with the
        signal's content (a measured record with jitter), never for a solver's steps.

    Raises
    ------
    ValueError
        A bad mass, window or frequency range, a window that resolves no band, or
        (:class:`~spidersim.sampling.NonUniformRecord`) a non-uniform record.
    """
    if not mass > 0:
        raise ValueError(f"station mass must be > 0, got {mass}")
    if not f_range[0] < f_range[1]:
        raise ValueError(f"f_min ({f_range[0]:g}) must be below f_max ({f_range[1]:g})")
    problem = band_range_problem(*f_range)
    if problem:
        raise ValueError(problem[0])
    force = np.asarray(force, dtype=float)
    if force.ndim == 1:
        force = force[:, None]
    t0, t1 = window if window is not None else (t[0], t[-1])
    dt, f_u = uniform(t, force, t0, t1, resample=resample)
    edge = top_band_edge(f_range[1])
    if not 1.0 / (2.0 * dt) > edge:
        raise ValueError(f"samples every {dt:g} s resolve bands up to {1 / (2 * dt):.4g} Hz "
                         f"(Nyquist) only: the top band of f_max = {f_range[1]:g} Hz "
                         f"reaches {edge:.4g} Hz; sample at least every "
                         f"{1 / (2 * edge):.4g} s (simulation.output_interval) or lower "
                         f"f_max")
    a_ug = f_u / mass / MICRO_G
    bands = third_octave_bands(*f_range)
    levels = np.column_stack([band_rms(a_ug[:, k], dt, bands) for k in range(a_ug.shape[1])])
    keep = np.isfinite(levels).any(axis=1)
    if not keep.any():
        raise ValueError(f"the window {t1 - t0:g} s with step {dt:g} s resolves no "
                         f"one-third-octave band in {f_range[0]:g}..{f_range[1]:g} Hz")
    bands, levels = bands[keep], levels[keep]
    # the peak transient is taken over the whole record: starts and stops are transients
    a_rec = np.abs(force) / mass / MICRO_G
    i, k = np.unravel_index(int(np.argmax(a_rec)), a_rec.shape)
    return Assessment(bands, levels, iss_limit(bands[:, 1]), float(a_rec[i, k]),
                      float(np.asarray(t)[i]), (float(t0), float(t1)))


def plot(assessment, path, title="Station acceleration vs ISS vibratory limit"):
    """Band levels per axis with the limit curve (log-log), written to ``path``."""
    import matplotlib.pyplot as plt
    a = assessment
    fig, ax = plt.subplots(figsize=(8, 5))
    f = np.logspace(-2, np.log10(300), 400)
    ax.loglog(f, iss_limit(f), "k-", lw=2, label="ISS limit (SSP 41000)")
    names = a.axes or [f"axis {k}" for k in range(a.levels.shape[1])]
    for k in range(a.levels.shape[1]):
        ax.loglog(a.bands[:, 1], a.levels[:, k], "o-", ms=4, label=names[k])
    bad = a.margin_db < 0
    if bad.any():
        ax.loglog(a.bands[bad, 1], a.worst[bad], "rx", ms=10, mew=2, label="exceeds")
    ax.set_xlabel("one-third-octave band centre [Hz]")
    ax.set_ylabel("RMS acceleration per band [micro-g]")
    verdict = a.verdict
    ax.set_title(f"{title}\n{verdict}; window {a.window[0]:g}-{a.window[1]:g} s; "
                 f"peak {a.peak:.3g} micro-g")
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
