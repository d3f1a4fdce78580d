"""Variable-step integration through our own loop over SciPy's step-by-step solvers.

The run is cut into *segments* at the time events of the system (a step source switching,
a table corner, later sampled blocks): each segment is integrated by a fresh SciPy solver
object whose ``t_bound`` is the next event time, so no step straddles a discontinuity; at
the segment end the due events are applied and the solver restarts from the new state.

Output is recorded at every accepted step (``output_interval=None``) or on a uniform grid
through the solver's dense output. A failure (solver failure or a non-finite state) stops
the run and raises :class:`~spidersim.errors.IntegrationError` whose ``partial`` holds the
samples computed so far.
"""
from __future__ import annotations

import math

import numpy as np

from ..errors import SpidersimError
from . import record_budget
from .dense_size import check_dense_size
from .events import MIN_SPAN, STALL_STEP
from .scipy_loop import SciPyLoop

METHODS = {"LSODA": "LSODA", "RK45": "RK45", "RK23": "RK23", "DOP853": "DOP853",
           "Radau": "Radau", "BDF": "BDF", "DP54": "RK45", "ROS34PW2": "Radau", "NDF": "BDF"}
#: methods integrated by the compiled loop (:mod:`spidersim.solver.loop`) when the system
#: has one (numba-compiled diagrams); interpreted diagrams run them through the SciPy
#: stepper of the same tableau and controller (DP54), SciPy's Radau (ROS34PW2) or SciPy's BDF
#: (NDF, the same family)
COMPILED = ("DP54", "ROS34PW2", "NDF")
#: the compiled methods that use a Jacobian (the analytic one when the system has it)
STIFF = ("ROS34PW2", "NDF")
#: methods given the structural Jacobian pattern (ROS34PW2 runs SciPy's Radau here)
IMPLICIT = ("Radau", "BDF", "ROS34PW2", "NDF")


class _Clock:
    """A system without states seen through one dummy state ``c' = 1``, so that diagrams of
    sources and static blocks get the same stepping, events and dense output."""

    n_x = 1
    jac_sparsity = None

    def __init__(self, system):
        self._s = system
        self.x0 = np.zeros(1)

    def __getattr__(self, name):
        return getattr(self._s, name)

    def rhs(self, t, x):
        return np.ones(1)

    def outputs(self, t, x):
        self._s.outputs(t, x[:0])

    def record_row(self, t, x, buf, row):
        return self._s.record_row(t, x[:0], buf, row)

    def guards(self, t, x):
        return self._s.guards(t, x[:0])

    def apply_event(self, t, x, k, direction):
        self._s.apply_event(t, x[:0], k, direction)

    def initialize(self, t, x):
        self._s.initialize(t, x[:0])

    def time_events(self, t, x, tol):
        return self._s.time_events(t, x[:0], tol)

    def diagnose(self, t, x):
        return self._s.diagnose(t, x[:0])


def _scipy_stepper(method):
    """SciPy's stepper class for ``method`` (:data:`METHODS`), imported on first use:
    ``scipy.integrate`` takes 0.3 s to import, paid by every process before, also those
    that run only the compiled loop."""
    import scipy.integrate
    return getattr(scipy.integrate, METHODS[method])


def _compiled_loop():
    """:func:`spidersim.solver.loop.integrate_dp54`, imported on first use (it brings
    numba; an import statement in the call cost 2 us per run)."""
    global _INTEGRATE_COMPILED
    if _INTEGRATE_COMPILED is None:
        from .loop import integrate_dp54
        _INTEGRATE_COMPILED = integrate_dp54
    return _INTEGRATE_COMPILED


_INTEGRATE_COMPILED = None


def integrate(system, t_end, **kw):
    """Integrate ``system`` to ``t_end`` (see :func:`_integrate`). Floating-point warnings
    are silenced around SciPy's steppers (the compiled loop raises none): non-finite
    values are detected and reported by name instead."""
    return _integrate(system, t_end, **kw)


def _integrate(system, t_end, t0=0.0, method="LSODA", rtol=1e-6, atol=1e-8, max_step=math.inf,
              first_step=None, output_interval=None, progress=None, stats=None,
              should_stop=None, jacobian="auto"):
    """Integrate ``system`` from ``t0`` to ``t_end``; return a :class:`Result`.

    Parameters
    ----------
    system : CompiledSystem
        See :mod:`spidersim.solver.system` for the contract.
    method : str
        ``LSODA`` (default), ``RK45``, ``RK23``, ``DOP853``, ``Radau`` or ``BDF`` (SciPy's
        steppers driven by this loop), or ``DP54``: Dormand-Prince 5(4) in the compiled loop
        of :mod:`spidersim.solver.loop` (stepping, events and recording in machine code), or
        ``ROS34PW2``: the stiff Rosenbrock-W method of :mod:`spidersim.solver.rosenbrock` in
        the same loop (finite-difference Jacobian over coloured column groups); interpreted
        diagrams run SciPy's Radau for it. ``NDF``: the variable-order (1-5) numerical
        differentiation formulas of :mod:`spidersim.solver.bdf` in the same loop (long
        Jacobian reuse, for large stiff models such as spider.yaml); interpreted diagrams
        run SciPy's BDF for it.
    rtol, atol, max_step, first_step : float
        Passed to the SciPy solver.
    output_interval : float, optional
        Record on a uniform grid of this spacing instead of at every step.
    progress : callable, optional
        ``progress(t)`` after every accepted step.
    should_stop : callable, optional
        ``should_stop() -> bool`` polled after every accepted step (keep it a flag check);
        when true the run stops at that step and the result up to it is returned with
        ``status == "interrupted"`` (the CLI sets it from SIGINT/SIGTERM).
    stats : dict, optional
        Extra entries for ``Result.stats``.
    jacobian : {"auto", "fd", "analytic"}
        The Jacobian of the compiled ``ROS34PW2`` and ``NDF``: ``auto`` the system's
        analytic one when it has one (``system.analytic_jacobian``), else finite
        differences over coloured column groups; ``fd`` always those; ``analytic`` the
        analytic one or an error saying why there is none. SciPy's steppers ignore it.
    """
    _check_arguments(method, t0, t_end, rtol, atol, max_step, output_interval, jacobian)
    record_budget.check_planned(system.record_size, t0, t_end, max_step, output_interval)
    check_dense_size(system.n_x, method)
    entry = getattr(system, "compiled_entry", None)
    if method in COMPILED and entry is not None:
        return _compiled_loop()(system, entry, t_end, t0=t0, rtol=rtol, atol=atol,
                              max_step=max_step, first_step=first_step,
                              output_interval=output_interval, progress=progress,
                              stats=stats, should_stop=should_stop, method=method,
                              jacobian=jacobian)
    return _run_scipy(system, method, t0, t_end, rtol, atol, max_step, first_step,
                      output_interval, progress, should_stop, stats)


def _check_arguments(method, t0, t_end, rtol, atol, max_step, output_interval, jacobian):
    """Raise :class:`SpidersimError` for an argument of :func:`integrate` out of its domain
    (unknown method or Jacobian kind, an empty or too short run, non-positive tolerances or
    step limit, an output interval outside ``(0, t_end - t0]``)."""
    if jacobian not in ("auto", "fd", "analytic"):
        raise SpidersimError(f"jacobian must be 'auto', 'fd' or 'analytic', got "
                             f"{jacobian!r}")
    if method not in METHODS:
        import difflib
        near = difflib.get_close_matches(str(method), METHODS, n=1)
        raise SpidersimError(f"unknown method '{method}'"
                             + (f" (did you mean {near[0]}?)" if near else "")
                             + f"; methods: {', '.join(METHODS)}")
    if not (t_end > t0):
        raise SpidersimError(f"t_end must be > {t0}, got {t_end}")
    if t_end - t0 < MIN_SPAN:
        raise SpidersimError(f"the run is {t_end - t0:g} s long, shorter than the shortest "
                             f"run of {MIN_SPAN:g} s (steps below {STALL_STEP:g} s are "
                             f"taken as a stall)")
    for name, v in (("rtol", rtol), ("atol", atol), ("max_step", max_step)):
        if not (v > 0):
            raise SpidersimError(f"{name} must be > 0, got {v}")
    if output_interval is not None and not (0 < output_interval <= t_end - t0):
        raise SpidersimError(f"output_interval must be in (0, {t_end - t0}], "
                             f"got {output_interval}")


def _run_scipy(system, method, t0, t_end, rtol, atol, max_step, first_step, output_interval,
               progress, should_stop, stats):
    """Run ``system`` with SciPy's stepper for ``method`` in :class:`SciPyLoop` (arguments
    as :func:`integrate`'s). A system without states runs on a dummy clock state
    (:class:`_Clock`, at most 200 steps over the run unless ``max_step`` says otherwise),
    removed from the final state again."""
    clock = system.n_x == 0
    if clock:
        system = _Clock(system)
        if max_step == math.inf:
            max_step = (t_end - t0) / 200
    kw = dict(rtol=rtol, atol=atol, max_step=max_step)
    if first_step is not None:
        kw["first_step"] = first_step
    if method in IMPLICIT and system.jac_sparsity is not None and system.n_x > 1:
        from scipy.sparse import csr_matrix    # only for SciPy's BDF and Radau (0.1 s)
        kw["jac_sparsity"] = csr_matrix(system.jac_sparsity)
    st = dict(stats or {})
    st.update(method=method, rtol=rtol, atol=atol, max_step=max_step, t_end=t_end)
    if METHODS[method] != method:        # an interpreted DP54 / ROS34PW2 / NDF: say what ran
        st["stepper"] = f"SciPy {METHODS[method]} (the interpreted form of {method})"
    with np.errstate(all="ignore"):
        result = SciPyLoop(system, _scipy_stepper(method), kw, t0, t_end, output_interval,
                           progress, should_stop, st).run()
    if clock:                     # the dummy state is not the system's
        t, x, modes = result.final
        result.final = (t, x[:0], modes)
    return result
