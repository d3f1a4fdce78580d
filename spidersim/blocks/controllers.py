"""Continuous PI and PID controllers with output limits and anti-windup.

Parallel form, error ``e`` in, command ``y`` out::

    v = kp e + I + D,   y = min(max(v, y_min), y_max)
    dI/dt = ki e                              (antiwindup = "none")
    dI/dt = ki e + kb (y - v)                 (antiwindup = "backcalc", kb in 1/s)
    dI/dt = 0 in the clamped mode, ki e otherwise
                                              (antiwindup = "clamping", the default)
    D = kd N (e - f),  df/dt = N (e - f)      (PID only: derivative filtered at N rad/s)

``I`` is the integral term in units of the output, so the initial value ``I0`` is the
initial command of a controller at zero error.

Clamping is event-driven (conditional integration), with modes ``clamp``:

- ``0`` free: ``dI/dt = ki e``, ``y = sat(v)``;
- ``+1`` clamped: entered when ``v > y_max`` and ``e > 0`` begin to hold together (guard
  ``min(v - y_max, e)`` rising): ``I`` is held, ``y = sat(v)``. It ends when the error
  reverses (``y`` may then jump with ``e``), or when ``v`` falls back through ``y_max``
  while ``e > 0``: integration resumes, and the block remembers it (``armed``);
- ``+2`` sliding: if ``v`` reaches ``y_max`` again before the error has reversed, free
  integration would at once push ``v`` back over the limit: the exact (Filippov) motion
  slides along ``v = y_max``, which an integrator without events can only crawl along.
  The block then holds ``y = y_max`` and ``I`` until the error reverses, and resets
  ``I := y_max - kp e`` there so that ``y`` is continuous. This is an approximation: the
  exact sliding leaves the limit when ``kp de/dt + ki e`` turns negative (the block does
  not see ``de/dt``), before the error reverses, so the command stays on the limit longer
  and the overshoot is larger than the exact one. Not small in a loop that slides long: a
  pulse of +-1.1 to 1.5 into a clamped PI and a second-order plant was off by 0.17 to 0.32
  against exact conditional integration (peak 2.966 for 2.822); use ``backcalc`` where
  the transient after saturation matters.

(``-1``, ``-2`` symmetrically at ``y_min``.)
"""
import math

from .base import Block, Dim, Event, Mode, Param, Port, State

_AW = ("clamping", "backcalc", "none")


def _i_rate(e, v, ki, y_min, y_max, aw, kb, clamp):
    """dI/dt for the anti-windup scheme ``aw`` (0 clamping, 1 back-calculation, 2 none)."""
    if aw == 0.0:
        return 0.0 if clamp != 0.0 else ki * e
    if aw == 1.0:
        y = min(max(v, y_min), y_max)
        return ki * e + kb * (y - v)
    return ki * e


def _limited(v, y_min, y_max, clamp):
    """Output: the limit while sliding, ``sat(v)`` otherwise."""
    if clamp >= 1.5:
        return y_max
    if clamp <= -1.5:
        return y_min
    return min(max(v, y_min), y_max)


def _clamp_guard(e, v, y_min, y_max, aw, clamp, armed, zc):
    """Guards: 0 enter at y_max, 1 enter at y_min, 2 the error reverses, 3 v leaves the
    limit while held (see the module docstring). Called with clamping only."""
    zc[0] = -1.0
    zc[1] = 1.0
    zc[2] = 1.0
    zc[3] = 1.0
    if clamp == 0.0:
        zc[0] = min(v - y_max, e)
        zc[1] = max(v - y_min, e)
        if armed != 0.0:
            zc[2] = e * armed
    else:
        zc[2] = e * clamp
        if clamp == 1.0:
            zc[3] = v - y_max
        elif clamp == -1.0:
            zc[3] = y_min - v


def _clamp_event(which, e, kp, y_min, y_max, I, clamp, armed):
    if which == 0:
        clamp[0] = 2.0 if armed[0] > 0.0 else 1.0
    elif which == 1:
        clamp[0] = -2.0 if armed[0] < 0.0 else -1.0
    elif which == 2:
        if clamp[0] >= 1.5:
            I[0] = y_max - kp * e
        elif clamp[0] <= -1.5:
            I[0] = y_min - kp * e
        clamp[0] = 0.0
        armed[0] = 0.0
    else:
        armed[0] = 1.0 if clamp[0] > 0.0 else -1.0
        clamp[0] = 0.0


def _clamp_init(e, v, kp, y_min, y_max, aw, I, clamp, armed):
    """At the start and after any event (the error may have jumped)."""
    if aw != 0.0:
        return
    if clamp[0] * e <= 0.0 and clamp[0] != 0.0:
        rest = v - kp * e - I[0]
        _clamp_event_jit(2, e, kp, y_min, y_max, I, clamp, armed)
        v = kp * e + I[0] + rest
    if armed[0] * e <= 0.0:
        armed[0] = 0.0
    if clamp[0] == 0.0:
        if v > y_max and e > 0.0:
            clamp[0] = 2.0 if armed[0] > 0.0 else 1.0
        elif v < y_min and e < 0.0:
            clamp[0] = -2.0 if armed[0] < 0.0 else -1.0


def _aw_params(params):
    if params["antiwindup"] == "backcalc" and params["kb"] <= 0:
        raise ValueError("antiwindup 'backcalc' needs a tracking gain kb > 0 [1/s] "
                         "(ki/kp is a common choice)")
    if params["y_min"] >= params["y_max"]:
        raise ValueError(f"y_min ({params['y_min']}) must be below y_max ({params['y_max']})")


_COMMON = {
    "kp": Param(1.0, "@y/@e", "proportional gain [output/input]"),
    "ki": Param(0.0, "@y/@e/s", "integral gain [output/(input s)]"),
    "y_min": Param(-math.inf, "@y", "lower output limit", allow_inf=True),
    "y_max": Param(math.inf, "@y", "upper output limit", allow_inf=True),
    "antiwindup": Param("clamping", kind="str", choices=_AW,
                        doc="anti-windup scheme while the output is limited"),
    "kb": Param(0.0, "1/s", "back-calculation tracking gain", ge=0.0),
    "I0": Param(0.0, "@y", "initial integral term (output units)"),
}
_MODES = {"clamp": Mode(doc="clamping mode: 0 free, +-1 integral held, +-2 sliding"),
          "armed": Mode(doc="+-1 after leaving a limit before the error reversed")}
# the clamping events exist only with antiwindup = clamping (size 0 otherwise: no guards)
_CLAMP = Dim("1 with clamping, else 0", lambda p: 1 if p["antiwindup"] == "clamping" else 0)
_EVENTS = {"clamp_upper": Event(1, "v > y_max with e > 0 begins: hold the integral", _CLAMP),
           "clamp_lower": Event(-1, "v < y_min with e < 0 begins: hold the integral", _CLAMP),
           "release": Event(-1, "the error reverses: integrate again", _CLAMP),
           "leave": Event(-1, "v comes back inside the limit while the integral is held",
                          _CLAMP)}


class PI(Block):
    """PI controller ``kp e + ki int(e)`` with limits and anti-windup (see module doc)."""

    category = "control"
    parameters = dict(_COMMON)
    inputs = {"e": Port("*", doc="control error")}
    outputs = {"y": Port("*", feedthrough=("e",), doc="limited command")}
    states = {"I": State("@y", initial="I0", doc="integral term (output units)")}
    modes = _MODES
    events = _EVENTS

    @classmethod
    def check(cls, params):
        _aw_params(params)

    @classmethod
    def derive(cls, params):
        return {"aw": float(_AW.index(params["antiwindup"]))}

    @staticmethod
    def output(t, I, e, kp, y_min, y_max, clamp, y):
        y[0] = _limited_jit(kp * e[0] + I[0], y_min, y_max, clamp[0])

    @staticmethod
    def derivative(t, I, e, kp, ki, y_min, y_max, aw, kb, clamp, der_I):
        v = kp * e[0] + I[0]
        der_I[0] = _i_rate_jit(e[0], v, ki, y_min, y_max, aw, kb, clamp[0])

    @staticmethod
    def partials(t, I, e, kp, ki, y_min, y_max, aw, kb, clamp, dfdx, dfdu, dydx, dydu):
        """State ``I``, input ``e``, output ``y``; ``v = kp e + I``, ``s = dsat/dv`` (1
        strictly inside the limits, 0 outside or while sliding, ``|clamp| = 2``)::

            dy/dI = s,   dy/de = kp s
            dI'/de = ki (0 while clamped),            clamping
            dI'/dI = kb (s - 1), dI'/de = ki + kb (s - 1) kp    back-calculation
        """
        v = kp * e[0] + I[0]
        inside = 1.0 if y_min < v < y_max else 0.0
        s = 0.0 if abs(clamp[0]) >= 1.5 else inside
        dydx[0, 0] = s
        dydu[0, 0] = kp * s
        if aw == 0.0:
            dfdu[0, 0] = 0.0 if clamp[0] != 0.0 else ki
        elif aw == 1.0:
            dfdx[0, 0] = kb * (inside - 1.0)
            dfdu[0, 0] = ki + kb * (inside - 1.0) * kp
        else:
            dfdu[0, 0] = ki

    @staticmethod
    def guard(t, I, e, kp, y_min, y_max, aw, clamp, armed, zc):
        _clamp_guard_jit(e[0], kp * e[0] + I[0], y_min, y_max, aw, clamp[0], armed[0], zc)

    @staticmethod
    def on_event(t, which, direction, I, e, kp, y_min, y_max, clamp, armed):
        _clamp_event_jit(which, e[0], kp, y_min, y_max, I, clamp, armed)

    @staticmethod
    def initialize(t, I, e, kp, y_min, y_max, aw, clamp, armed):
        _clamp_init_jit(e[0], kp * e[0] + I[0], kp, y_min, y_max, aw, I, clamp, armed)


class PID(Block):
    """PID controller with a first-order derivative filter (see module doc)."""

    category = "control"
    parameters = dict(_COMMON, kd=Param(0.0, "@y*s/@e", "derivative gain [output s/input]"),
                      N=Param(100.0, "rad/s", "derivative filter bandwidth", gt=0.0))
    inputs = {"e": Port("*", doc="control error")}
    outputs = {"y": Port("*", feedthrough=("e",), doc="limited command")}
    states = {"I": State("@y", initial="I0", doc="integral term (output units)"),
              "f": State("@e", doc="filtered error for the derivative term")}
    modes = _MODES
    events = _EVENTS

    @classmethod
    def check(cls, params):
        _aw_params(params)

    @classmethod
    def derive(cls, params):
        return {"aw": float(_AW.index(params["antiwindup"]))}

    @staticmethod
    def output(t, I, f, e, kp, kd, N, y_min, y_max, clamp, y):
        v = kp * e[0] + I[0] + kd * N * (e[0] - f[0])
        y[0] = _limited_jit(v, y_min, y_max, clamp[0])

    @staticmethod
    def derivative(t, I, f, e, kp, ki, kd, N, y_min, y_max, aw, kb, clamp, der_I, der_f):
        v = kp * e[0] + I[0] + kd * N * (e[0] - f[0])
        der_I[0] = _i_rate_jit(e[0], v, ki, y_min, y_max, aw, kb, clamp[0])
        der_f[0] = N * (e[0] - f[0])

    @staticmethod
    def partials(t, I, f, e, kp, ki, kd, N, y_min, y_max, aw, kb, clamp, dfdx, dfdu, dydx,
                 dydu):
        """States ``(I, f)``, input ``e``, output ``y``; ``v = kp e + I + kd N (e - f)``,
        ``dv/d(I, f, e) = (1, -kd N, kp + kd N)``, ``s = dsat/dv`` (1 strictly inside the
        limits, 0 outside or while sliding, ``|clamp| = 2``)::

            dy/d(I, f, e) = s dv/d(I, f, e)
            dI'/de = ki (0 while clamped)                         clamping
            dI'/d(I, f, e) = (0, 0, ki) + kb (s_in - 1) dv/d(...)  back-calculation
            df'/d(f, e) = (-N, N)
        """
        dv = (1.0, -kd * N, kp + kd * N)
        v = kp * e[0] + I[0] + kd * N * (e[0] - f[0])
        inside = 1.0 if y_min < v < y_max else 0.0
        s = 0.0 if abs(clamp[0]) >= 1.5 else inside
        dydx[0, 0] = s * dv[0]
        dydx[0, 1] = s * dv[1]
        dydu[0, 0] = s * dv[2]
        if aw == 0.0:
            dfdu[0, 0] = 0.0 if clamp[0] != 0.0 else ki
        elif aw == 1.0:
            dfdx[0, 0] = kb * (inside - 1.0) * dv[0]
            dfdx[0, 1] = kb * (inside - 1.0) * dv[1]
            dfdu[0, 0] = ki + kb * (inside - 1.0) * dv[2]
        else:
            dfdu[0, 0] = ki
        dfdx[1, 1] = -N
        dfdu[1, 0] = N

    @staticmethod
    def guard(t, I, f, e, kp, kd, N, y_min, y_max, aw, clamp, armed, zc):
        v = kp * e[0] + I[0] + kd * N * (e[0] - f[0])
        _clamp_guard_jit(e[0], v, y_min, y_max, aw, clamp[0], armed[0], zc)

    @staticmethod
    def on_event(t, which, direction, I, f, e, kp, kd, N, y_min, y_max, clamp, armed):
        # the reset keeps the output continuous: I := limit - kp e - D
        d = kd * N * (e[0] - f[0])
        _clamp_event_jit(which, e[0], kp, y_min - d, y_max - d, I, clamp, armed)

    @staticmethod
    def initialize(t, I, f, e, kp, kd, N, y_min, y_max, aw, clamp, armed):
        # against the limits shifted by the derivative term D: v - D = kp e + I
        d = kd * N * (e[0] - f[0])
        _clamp_init_jit(e[0], kp * e[0] + I[0], kp, y_min - d, y_max - d, aw, I, clamp,
                        armed)


def _jit_helper(fn):
    """Compile a helper the kernels call when numba is used; the plain function otherwise.

    Kernels run in plain Python in interpreted mode, where calling the numba dispatcher
    still works (it is compiled on first call).
    """
    import numba
    return numba.njit(cache=True, inline="always", error_model="numpy")(fn)


_i_rate_jit = _jit_helper(_i_rate)
_clamp_guard_jit = _jit_helper(_clamp_guard)
_clamp_event_jit = _jit_helper(_clamp_event)
_limited_jit = _jit_helper(_limited)
_clamp_init_jit = _jit_helper(_clamp_init)


class JointCascade(Block):
    """SPIDER's independent joint controller: outer P on the load position (load resolver),
    inner PI on the motor speed (motor resolver), references scaled by the gear ratio
    ``ratio`` (``N`` before spidersim 0.1)::

        w_ref = ratio (kp_q (q_ref - q) + ff qd_ref)                (motor-side speed reference)
        e = w_ref - w_m,   v = kp_w e + I,   i_cmd = sat(v, +-I_max)
        dI/dt = ki_w e + kb (i_cmd - v)                         (back-calculation)

    ``i_cmd`` is the current amplitude for the driver (torque / K_t).

    Digital controller (``Ts > 0``): the inputs are read only at the samples
    ``t_k = k Ts`` (time events, ``k = 0, 1, ...``), the command is computed at once and held
    (zero-order hold) until the next sample; the integral is the forward-Euler discrete
    equivalent of the same law::

        w_ref_k = ratio (kp_q (q_ref_k - q_k) + ff qd_ref_k),   e_k = w_ref_k - w_m_k
        v_k = kp_w e_k + I_k,   i_cmd(t) = sat(v_k, +-I_max)  for t_k <= t < t_k+1
        I_k+1 = I_k + Ts (ki_w e_k + kb (i_cmd_k - v_k)),        I_0 = 0

    (the computation delay within a sample is neglected). Quantized measurements (a
    resolver's staircase) then reach the continuous plant only through the held command, as
    in the real joint electronics, and the integrator sees no discontinuity between
    samples. ``Ts`` is structural (the outputs are direct feedthrough only when ``Ts = 0``).
    """

    category = "control"
    parameters = {
        "ratio": Param(160.0, "1", "gear ratio", gt=0.0),
        "kp_q": Param(20.0, "1/s", "position gain (load side)", ge=0.0),
        "kp_w": Param(0.05, "A.s/rad", "speed proportional gain (motor side)", ge=0.0),
        "ki_w": Param(1.0, "A/rad", "speed integral gain", ge=0.0),
        "ff": Param(1.0, "1", "speed feed-forward weight (0 off, 1 on)", ge=0.0),
        "I_max": Param(4.0, "A", "current command limit", gt=0.0),
        "kb": Param(100.0, "1/s", "anti-windup back-calculation gain", ge=0.0),
        "Ts": Param(0.0, "s", "sample period of the digital controller (0: continuous)",
                    ge=0.0, structural=True),
    }
    renamed = {"N": "ratio"}
    inputs = {"q_ref": Port("rad", doc="load position reference"),
              "qd_ref": Port("rad/s", optional=True, doc="load speed reference (feed-forward)"),
              "q": Port("rad", doc="measured load position"),
              "w_m": Port("rad/s", doc="measured motor speed")}
    outputs = {"i_cmd": Port("A", feedthrough=lambda p: "all" if p["Ts"] == 0 else (),
                             doc="current amplitude command (held when sampled)"),
               "w_ref": Port("rad/s", feedthrough=lambda p: ("q_ref", "qd_ref", "q")
                             if p["Ts"] == 0 else (),
                             doc="motor speed reference (held when sampled)")}
    states = {"I": State("A", size=Dim("1 if Ts = 0 else 0", lambda p: 1 if p["Ts"] == 0
                                       else 0), doc="speed-loop integral term (continuous)")}
    modes = {"I_k": Mode(doc="speed-loop integral term (sampled, A)"),
             "i_held": Mode(doc="held current command (sampled, A)"),
             "w_held": Mode(doc="held speed reference (sampled, rad/s)"),
             "k": Mode(doc="samples taken")}
    sample_period = "Ts"

    @classmethod
    def check(cls, params):
        if params["Ts"] > 0 and params["Ts"] * params["kb"] >= 2.0:
            raise ValueError(f"Ts kb = {params['Ts'] * params['kb']:g} >= 2: the sampled "
                             "back-calculation (forward Euler) is unstable; lower Ts or kb")

    @staticmethod
    def output(t, I, q_ref, qd_ref, q, w_m, ratio, kp_q, kp_w, ff, I_max, Ts, i_held,
               w_held, i_cmd, w_ref):
        if Ts > 0.0:
            i_cmd[0] = i_held[0]
            w_ref[0] = w_held[0]
            return
        wr = ratio * (kp_q * (q_ref[0] - q[0]) + ff * qd_ref[0])
        v = kp_w * (wr - w_m[0]) + I[0]
        i_cmd[0] = min(max(v, -I_max), I_max)
        w_ref[0] = wr

    @staticmethod
    def derivative(t, I, q_ref, qd_ref, q, w_m, ratio, kp_q, kp_w, ki_w, ff, I_max, kb, Ts,
                   der_I):
        if Ts > 0.0:
            return
        e = ratio * (kp_q * (q_ref[0] - q[0]) + ff * qd_ref[0]) - w_m[0]
        v = kp_w * e + I[0]
        der_I[0] = ki_w * e + kb * (min(max(v, -I_max), I_max) - v)

    @staticmethod
    def next_time(t, Ts, k):
        return k[0] * Ts if Ts > 0.0 else math.inf

    @staticmethod
    def partials(t, I, q_ref, qd_ref, q, w_m, ratio, kp_q, kp_w, ki_w, ff, I_max, kb, Ts,
                 dfdx, dfdu, dydx, dydu):
        """Inputs ``(q_ref, qd_ref, q, w_m)``, outputs ``(i_cmd, w_ref)``; sampled
        (``Ts > 0``): the held outputs depend on nothing between samples, all zero.
        Continuous, with ``s = 1`` while ``v = kp_w e + I`` is strictly inside the limit
        (else 0)::

            d w_ref/du = ratio (kp_q, ff, -kp_q, 0),   d e/du = d w_ref/du - (0, 0, 0, 1)
            d i_cmd/dI = s,  d i_cmd/du = s kp_w d e/du
            d(dI/dt)/dI = kb (s - 1),  d(dI/dt)/du = (ki_w + kb (s - 1) kp_w) d e/du
        """
        if Ts > 0.0:
            return
        wr = ratio * (kp_q * (q_ref[0] - q[0]) + ff * qd_ref[0])
        v = kp_w * (wr - w_m[0]) + I[0]
        s = 1.0 if -I_max < v < I_max else 0.0
        dwr = (ratio * kp_q, ratio * ff, -ratio * kp_q, 0.0)
        g_f = ki_w + kb * (s - 1.0) * kp_w
        dfdx[0, 0] = kb * (s - 1.0)
        dydx[0, 0] = s
        for j in range(4):
            de = dwr[j] - (1.0 if j == 3 else 0.0)
            dfdu[0, j] = g_f * de
            dydu[0, j] = s * kp_w * de
            dydu[1, j] = dwr[j]

    @staticmethod
    def time_event(t, q_ref, qd_ref, q, w_m, ratio, kp_q, kp_w, ki_w, ff, I_max, kb, Ts, I_k,
                   i_held, w_held, k):
        wr = ratio * (kp_q * (q_ref[0] - q[0]) + ff * qd_ref[0])
        e = wr - w_m[0]
        v = kp_w * e + I_k[0]
        i = min(max(v, -I_max), I_max)
        i_held[0] = i
        w_held[0] = wr
        I_k[0] += Ts * (ki_w * e + kb * (i - v))
        k[0] += 1.0
