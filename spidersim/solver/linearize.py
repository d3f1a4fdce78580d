"""Linearization by central differences and frequency-domain figures of merit.

:func:`jacobians` differentiates ``xdot = f(x, u)`` and ``y = g(x, u)`` around an operating
point by central differences, each variable with its own step
``h_j = 6e-6 max(1, |v_j|)`` (about eps^(1/3), where truncation and round-off errors of a
central difference balance). ``f`` and ``g`` come from the compiled diagram, so algebraic
loops are solved at every perturbation, and blocks stay in their current event mode.

:func:`siso_figures` reads poles, zeros, DC gain, -3 dB bandwidth, gain and phase crossover
frequencies and margins from a SISO ``control.StateSpace``, through its minimal pole-zero
form (:mod:`.siso`: states the pair cannot move or see removed structurally and by
pole-zero cancellation on the eigenvalues, never through polynomial coefficients, which
lose the zeros of a model whose poles spread over decades). The bandwidth is the first
frequency where ``|G(jw)|`` falls to ``|G(0)|/sqrt(2)`` (half power, -3.01 dB; python-control's
``bandwidth()`` takes exactly -3 dB), for a negative DC gain as well; it
is undefined (reported as ``None`` with the reason) when the DC gain is infinite (an
integrator) or zero. Margins and crossovers follow ``control.margin``'s definitions.
"""
from __future__ import annotations

import math

import numpy as np

from ..errors import SpidersimError
from . import dense_size

STEP = 6e-6


def jacobians(evaluate, x0, u0):
    """``(A, B, C, D)`` of ``evaluate(x, u) -> (xdot, y)`` at ``(x0, u0)``."""
    x0 = np.asarray(x0, dtype=float)
    u0 = np.asarray(u0, dtype=float)
    if len(x0) > dense_size.MAX_DENSE_STATES:
        raise SpidersimError(f"linearization builds the {len(x0)} x {len(x0)} matrix A by "
                             f"{2 * len(x0)} evaluations: at most "
                             f"{dense_size.MAX_DENSE_STATES} states")
    f0, y0 = evaluate(x0, u0)
    nx, nu, ny = len(x0), len(u0), len(y0)
    A, C = np.zeros((nx, nx)), np.zeros((ny, nx))
    B, D = np.zeros((nx, nu)), np.zeros((ny, nu))
    for j in range(nx):
        h = STEP * max(1.0, abs(x0[j]))
        xp, xm = x0.copy(), x0.copy()
        xp[j] += h
        xm[j] -= h
        fp, yp = evaluate(xp, u0)
        fm, ym = evaluate(xm, u0)
        A[:, j] = (fp - fm) / (2 * h)
        C[:, j] = (yp - ym) / (2 * h)
    for j in range(nu):
        h = STEP * max(1.0, abs(u0[j]))
        up, um = u0.copy(), u0.copy()
        up[j] += h
        um[j] -= h
        fp, yp = evaluate(x0, up)
        fm, ym = evaluate(x0, um)
        B[:, j] = (fp - fm) / (2 * h)
        D[:, j] = (yp - ym) / (2 * h)
    evaluate(x0, u0)
    return A, B, C, D


def _zpk(sys):
    from .siso import Zpk
    return sys if isinstance(sys, Zpk) else Zpk.from_ss(sys)


def bandwidth(sys, w_max=None):
    """-3 dB bandwidth [rad/s] of a SISO system and a note: ``(value, note)``.

    ``value`` is None when undefined: infinite DC gain (integrator), zero DC gain, or no
    crossing below ``w_max`` (then the note says so). ``sys``: a SISO state space or its
    :class:`~.siso.Zpk`.
    """
    from scipy.optimize import brentq

    g = _zpk(sys)
    if g.has_integrator():
        return None, "undefined: infinite DC gain (the system has an integrator)"
    g0 = abs(g.dc_gain())
    if not np.isfinite(g0):
        return None, "undefined: infinite DC gain"
    if g0 == 0.0:
        return None, "undefined: zero DC gain"
    level = math.log(g0 / math.sqrt(2.0))
    mags = [abs(r) for r in list(g.poles) + list(g.zeros) if abs(r) > 0] or [1.0]
    w_max = w_max or 1e4 * max(mags)
    # from well below the slowest root (a pole at 0.05 rad/s beside one at 1e5 rad/s)
    w = np.logspace(np.log10(min(mags)) - 4, np.log10(w_max), 4000)
    # with the points at every pole and zero magnitude (:meth:`.siso.Zpk.grid`): a notch
    # narrower than the grid's spacing (zeros at 1 rad/s, damping 1e-4) fell between points
    w = np.union1d(w, g.grid()[g.grid() <= w_max])
    m = g.log_mag_phase(w)[0]
    below = np.flatnonzero(m < level)
    if not len(below):
        return None, f"undefined: |G| stays above -3 dB up to {w_max:.3g} rad/s"
    k = below[0]
    if k == 0:
        return float(w[0]), "below the lowest frequency examined"
    wb = brentq(lambda v: g.log_mag_phase(v)[0][0] - level, w[k - 1], w[k],
                xtol=1e-12 * w[k])
    return float(wb), ""


def siso_figures(sys):
    """Dict of poles, zeros, DC gain, bandwidth, crossovers and margins of SISO ``sys``,
    from its minimal pole-zero form (:class:`~.siso.Zpk`: modes the pair cannot move or
    see are removed first, without expanding polynomials)."""
    from .siso import margins

    g = _zpk(sys)
    out = {"poles": g.poles, "zeros": g.zeros, "states": len(g.poles),
           "dc_gain": g.dc_gain()}
    with np.errstate(all="ignore"):
        bw, note = bandwidth(g)
        out["bandwidth"] = bw
        out["bandwidth_note"] = note
        gm, pm, wcg, wcp = margins(g)
    out["gain_margin"] = float(gm)
    out["phase_margin"] = float(pm)
    out["phase_crossover"] = float(wcg)    # where the phase is -180 deg
    out["gain_crossover"] = float(wcp)     # where |G| = 1
    return out


def loop_notes(sys):
    """Stability notes of a loop transfer ``L`` (negative feedback: closed loop L/(1+L)):
    open-loop RHP poles P, Nyquist encirclements of -1, closed-loop RHP poles Z, and whether
    the closed loop is conditionally stable (gain margin below 1: it goes unstable when the
    loop gain *drops*)."""
    import control
    notes = []
    with np.errstate(all="ignore"):
        P = int(np.sum(np.real(control.poles(sys)) > 1e-9))
        cl = control.feedback(sys, 1)
        Z = int(np.sum(np.real(control.poles(cl)) > 1e-9))
        try:
            N = int(control.nyquist_response(sys, warn_encirclements=False,
                                             warn_nyquist=False).count)
        except Exception:                  # noqa: BLE001 (a plot helper; the count is a note)
            N = None
        gm = float(control.margin(sys)[0])
    if P:
        notes.append(f"open loop unstable: {P} right-half-plane pole(s); Nyquist: "
                     f"{N if N is not None else '?'} encirclement(s) of -1, closed loop has "
                     f"{Z} right-half-plane pole(s)" + (" (stable)" if Z == 0 else ""))
    elif Z:
        notes.append(f"closed loop UNSTABLE: {Z} right-half-plane pole(s) (Nyquist: "
                     f"{N if N is not None else '?'} encirclement(s) of -1)")
    if Z == 0 and np.isfinite(gm) and 0 < gm < 1:
        notes.append(f"conditionally stable: the gain margin {gm:.3g} "
                     f"({20 * math.log10(gm):.3g} dB) is a gain REDUCTION that destabilises "
                     f"the loop")
    return notes


def peak_gain(sys, n=800):
    """``(peak |G(jw)|, w at the peak [rad/s])``: the largest of ``|G(0)|`` (finite DC gain,
    ``w = 0``; inf with a free integrator), ``|G(j inf)|`` of a biproper pair (``w = inf``)
    and the maximum over a grid spanning the poles and zeros of the minimal form
    (:class:`~.siso.Zpk`), refined between the grid point's neighbours (bounded scalar
    search on ``ln w``), so that a resonance between grid points is not under-read."""
    from scipy.optimize import minimize_scalar
    g = _zpk(sys)
    marks = [abs(p) for p in list(g.poles) + list(g.zeros) if np.isfinite(p) and abs(p) > 0]
    lo, hi = min(marks + [1.0]) / 1e3, max(marks + [1.0]) * 1e3
    w = np.unique(np.concatenate([np.logspace(np.log10(lo), np.log10(hi), n),
                                  [m for m in marks if lo <= m <= hi]]))
    with np.errstate(all="ignore"):
        logm = g.log_mag_phase(w)[0]
    if np.all(np.isnan(logm)):
        raise SpidersimError("the frequency response cannot be evaluated (NaN at every "
                             "frequency): the model is badly scaled")
    k = int(np.nanargmax(logm))
    best, w_best = float(logm[k]), float(w[k])
    a, b = math.log(w[max(k - 1, 0)]), math.log(w[min(k + 1, w.size - 1)])
    if b > a:
        with np.errstate(all="ignore"):
            res = minimize_scalar(lambda lw: -float(g.log_mag_phase([math.exp(lw)])[0][0]),
                                  bounds=(a, b), method="bounded",
                                  options={"xatol": 1e-10})
        if np.isfinite(res.fun) and -res.fun > best:
            best, w_best = -float(res.fun), math.exp(float(res.x))
    dc = abs(g.dc_gain())
    if math.isinf(dc):
        return math.inf, 0.0                     # a free integrator: unbounded as w -> 0
    if dc > 0 and math.log(dc) >= best - 1e-12:
        return dc, 0.0
    if len(g.poles) == len(g.zeros) and g.k != 0 and math.log(abs(g.k)) >= best - 1e-12:
        return abs(float(g.k)), math.inf         # biproper: the supremum is |G(j inf)|
    return float(math.exp(best)), w_best


def format_figures(fig, name="", loop=False):
    """Text table of :func:`siso_figures`: margins and crossovers only for a loop transfer
    (``loop=True``), where they mean something; for other pairs bandwidth, peak and DC
    gain. Frequencies in rad/s and Hz."""
    def num(v, unit=""):
        if v is None or (isinstance(v, float) and not np.isfinite(v)):
            return "none" if v is None else ("inf" if v > 0 else "-inf") if not np.isnan(
                v) else "none"
        return f"{v:.6g}{unit}"

    def cplx(vals):
        return ", ".join(f"{z.real:.6g}{z.imag:+.6g}j" if abs(z.imag) > 1e-12 * max(1, abs(z))
                         else f"{z.real:.6g}" for z in sorted(vals, key=lambda z: (
                             z.real, z.imag))) or "none"

    def freq(v):
        if v is None or not np.isfinite(v):
            return num(v)
        return f"{v:.6g} rad/s ({v / 2 / math.pi:.6g} Hz)"

    bw = fig["bandwidth"]
    lines = [f"  {name}" if name else "",
             f"    minimal states:        {fig['states']}",
             f"    poles [rad/s]:         {cplx(fig['poles'])}",
             f"    zeros [rad/s]:         {cplx(fig['zeros'])}",
             f"    DC gain:               {num(fig['dc_gain'])}"
             + (" (a free integrator)" if np.isinf(fig["dc_gain"]) else "")]
    if loop:
        lines += [f"    gain crossover:        {freq(fig['gain_crossover'])}",
                  f"    phase crossover:       {freq(fig['phase_crossover'])}",
                  f"    gain margin:           {num(fig['gain_margin'])}"
                  + (f" ({20 * math.log10(fig['gain_margin']):.3g} dB)"
                     if np.isfinite(fig["gain_margin"]) and fig["gain_margin"] > 0 else ""),
                  f"    phase margin:          {num(fig['phase_margin'], ' deg')}"]
        lines += [f"    note: {n}" for n in fig.get("notes", [])]
    else:
        lines.append("    -3 dB bandwidth:       " + (freq(bw) if bw is not None
                                                      else fig["bandwidth_note"]))
        if "peak" in fig:
            pk, wk = fig["peak"]
            lines.append(f"    peak gain:             {pk:.6g} ({20 * math.log10(pk):.3g} dB) "
                         f"at {freq(wk)}" if pk > 0 else "    peak gain:             0")
    return "\n".join(ln for ln in lines if ln)
