"""Sensors: the resolver (angle quantization, noise, optional sampling).

A resolver with an R/D converter of ``bits`` bits reports the angle in steps of
``q = 2 pi / 2^bits``: ``theta_q = q round(theta / q)``. With ``Ts > 0`` the converter is
sampled (time events) and each sample gets Gaussian noise of standard deviation
``noise`` [rad], drawn from a counter-based generator seeded by ``seed`` (the same noise in
compiled and interpreted runs, and for any step size). With ``Ts = 0`` the output is the
continuous staircase without noise: every step is a discontinuity the step-size control
sees, so prefer sampling in a closed loop.
"""
import math

import numpy as np

from .base import Block, Mode, Param, Port, State


#: splitmix64's constants (Steele, Lea and Flood 2014), as unsigned 64-bit numbers so that
#: numba's arithmetic wraps modulo 2^64 exactly as the pure-Python reference does
_GOLDEN = np.uint64(0x9E3779B97F4A7C15)
_MIX1 = np.uint64(0xBF58476D1CE4E5B9)
_MIX2 = np.uint64(0x94D049BB133111EB)
_S11, _S27, _S30, _S31 = np.uint64(11), np.uint64(27), np.uint64(30), np.uint64(31)


def _gauss(seed, k):
    """Standard normal number ``k`` of stream ``seed``: two uniforms in (0, 1) from
    splitmix64 of the counter, then Box-Muller ``sqrt(-2 ln u1) cos(2 pi u2)``.

    All integer arithmetic is unsigned 64-bit (wrapping modulo 2^64); with signed integers
    numba's shifts are arithmetic and the top bit of each draw was lost (uniforms in
    (0, 0.5), a standard deviation of 1.30 instead of 1). :func:`_gauss_reference` is the
    same generator in Python integers; a test compares the two.
    """
    x = np.uint64(seed) * _GOLDEN + np.uint64(k) * _MIX1 + np.uint64(1)
    u1 = u2 = 0.5
    for j in range(2):
        x = x + _GOLDEN
        z = (x ^ (x >> _S30)) * _MIX1
        z = (z ^ (z >> _S27)) * _MIX2
        z = z ^ (z >> _S31)
        u = (float(z >> _S11) + 0.5) / 9007199254740992.0       # 53 bits, in (0, 1)
        if j == 0:
            u1 = u
        else:
            u2 = u
    return math.sqrt(-2.0 * math.log(u1)) * math.cos(2.0 * math.pi * u2)


def _gauss_reference(seed, k):
    """:func:`_gauss` in Python integers (masked to 64 bits): the reference of the tests."""
    mask = 0xFFFFFFFFFFFFFFFF
    x = (int(seed) * 0x9E3779B97F4A7C15 + int(k) * 0xBF58476D1CE4E5B9 + 1) & mask
    vals = [0.0, 0.0]
    for j in range(2):
        x = (x + 0x9E3779B97F4A7C15) & mask
        z = ((x ^ (x >> 30)) * 0xBF58476D1CE4E5B9) & mask
        z = ((z ^ (z >> 27)) * 0x94D049BB133111EB) & mask
        z = z ^ (z >> 31)
        vals[j] = ((z >> 11) + 0.5) / 9007199254740992.0
    return math.sqrt(-2.0 * math.log(vals[0])) * math.cos(2.0 * math.pi * vals[1])


def _quantize(theta, bits):
    """``theta`` on the grid ``q = 2 pi / 2^bits``: ``q round(theta / q)`` (half counts
    up); ``theta`` itself for ``bits = 0``.

    The count stays a float (:func:`numpy.floor`): under numba ``math.floor`` returns an
    int64, which wrapped to -2^63 once ``|theta| / q > 2^63`` (1e8 rad at 40 bits read
    -5.3e7 rad). From 2^52 counts on, ``theta / q`` is a whole number and ``theta``'s own
    spacing is about ``q``: ``theta`` is returned (its grid value to round-off; ``theta / q``
    overflowed to infinity for ``|theta| > 1.7e311 q``).
    """
    if bits <= 0:
        return theta
    q = 2.0 * math.pi / 2.0 ** bits
    x = theta / q
    if not abs(x) < 4503599627370496.0:        # 2^52 counts, infinite or NaN
        return theta
    return q * np.floor(x + 0.5)


def _quantize_speed(w, bits, w_max):
    """The converter's velocity word: a ``bits``-bit two's-complement count of
    ``lsb = w_max / 2^(bits - 1)`` (full scale ``+-w_max``), rounded to the nearest count
    and saturated at ``-2^(bits-1)`` and ``2^(bits-1) - 1`` counts; ``w`` itself for
    ``bits = 0``.

    The count is a float (no int64 to wrap: ``w / lsb`` beyond 2^63, e.g. ``w_max =
    1e-300``, read as the negative full scale) and is formed as ``w / w_max 2^(bits-1)``,
    the same number as ``w / lsb`` in the normal range, with no ``lsb`` that underflows to
    0 for a subnormal ``w_max``.
    """
    if bits <= 0:
        return w
    half = 2.0 ** (bits - 1)
    n = np.floor(w / w_max * half + 0.5)
    if n > half - 1.0:
        n = half - 1.0
    elif n < -half:
        n = -half
    return w_max * (n / half)


def _jit(fn):
    import numba
    return numba.njit(cache=True, error_model="numpy")(fn)


quantize_jit = _jit(_quantize)
quantize_speed_jit = _jit(_quantize_speed)


class Resolver(Block):
    """Angle sensor: quantization to ``bits`` bits per revolution, optional sampling and
    noise (see the module docstring); the speed is passed through (the R/D converter's
    velocity output)."""

    category = "sensors"
    parameters = {
        "bits": Param(16, "1", "bits per revolution (0: no quantization)", kind="int", ge=0,
                      le=40),
        "Ts": Param(0.0, "s", "sample period (0: continuous, no noise)", ge=0.0,
                    structural=True),
        "noise": Param(0.0, "rad", "standard deviation of the angle noise (sampled only)",
                       ge=0.0),
        "seed": Param(1, "1", "noise stream (at most 2^53: an exact float)", kind="int",
                      ge=0, le=2 ** 53),
    }
    inputs = {"theta": Port("rad", doc="true angle"),
              "w": Port("rad/s", optional=True, doc="true speed")}
    outputs = {"theta_m": Port("rad", feedthrough=lambda p: ("theta",) if p["Ts"] == 0 else (),
                               doc="measured angle"),
               "w_m": Port("rad/s", feedthrough=("w",), doc="measured speed")}
    modes = {"held": Mode(doc="last sample (sampled mode)"), "k": Mode(doc="samples taken")}
    sample_period = "Ts"
    quantizer = {"bits": 0}       # linearized as theta_m = theta

    @classmethod
    def check(cls, params):
        if params["noise"] > 0 and params["Ts"] == 0:
            raise ValueError("noise needs a sample period Ts > 0")

    @staticmethod
    def output(t, theta, w, bits, Ts, held, theta_m, w_m):
        theta_m[0] = quantize_jit(theta[0], bits) if Ts == 0.0 else held[0]
        w_m[0] = w[0]

    @staticmethod
    def partials(t, bits, Ts, dydu):
        """Inputs ``(theta, w)``, outputs ``(theta_m, w_m)``: ``d w_m / d w = 1``;
        ``d theta_m / d theta = 1`` without quantization (continuous, ``bits = 0``), 0 for
        the staircase and for the held sample (between its steps and samples)."""
        if Ts == 0.0 and bits <= 0:
            dydu[0, 0] = 1.0
        dydu[1, 1] = 1.0

    @staticmethod
    def next_time(t, Ts, k):
        return k[0] * Ts if Ts > 0.0 else math.inf

    @staticmethod
    def time_event(t, theta, bits, noise, seed, held, k):
        n = noise * gauss_jit(seed, k[0]) if noise > 0.0 else 0.0
        held[0] = quantize_jit(theta[0] + n, bits)
        k[0] += 1.0


gauss_jit = _jit(_gauss)


class WrenchSensor(Block):
    """Wrist force/torque sensor: the wrench the end effector applies to the environment,
    low-pass filtered (the sensor and its conditioning electronics)::

        u = -w_ext                      (w_ext: the environment's wrench on the flange)
        u_s = R^T u  (frame 'flange'),  u_s = u  (frame 'base')
        dF/dt = 2 pi f_c (u_s + bias - F)

    The ``bias`` (an offset of the sensor's electronics) goes through the low-pass with the
    wrench: the reading starts at ``F(0) = 0`` and reaches the bias with the filter's time
    constant ``1 / (2 pi f_c)``.

    Force [N] first, then moment [N.m] about the flange origin. The output is a state:
    no direct feedthrough, so a force loop through the sensor has no algebraic loop.
    """

    category = "sensors"
    parameters = {"f_c": Param(100.0, "Hz", "bandwidth (first-order low-pass)", gt=0.0),
                  "frame": Param("base", kind="str", choices=("base", "flange"),
                                 doc="axes of the reading: base frame or flange frame"),
                  "bias": Param(0.0, "*", "offset added to the wrench before the low-pass "
                                "(N, N.m)", shape=6)}
    inputs = {"wrench": Port("*", size=6, doc="environment's wrench on the flange (Arm.f_ext)"),
              "rot": Port("1", size=9, optional=lambda p: p["frame"] == "base",
                          doc="flange rotation, row-major (needed for frame 'flange')")}
    outputs = {"F": Port("*", size=6, doc="measured wrench: force [N], moment [N.m]")}
    states = {"F": State("*", size=6, doc="filtered reading")}

    @classmethod
    def derive(cls, params):
        return {"flange": 1.0 if params["frame"] == "flange" else 0.0}

    @staticmethod
    def derivative(t, F, wrench, rot, f_c, bias, flange, der_F):
        a = 2.0 * math.pi * f_c
        for h in range(2):                     # force, then moment
            for r in range(3):
                if flange > 0.5:
                    u = 0.0
                    for c in range(3):
                        u -= rot[3 * c + r] * wrench[3 * h + c]
                else:
                    u = -wrench[3 * h + r]
                k = 3 * h + r
                der_F[k] = a * (u + bias[k] - F[k])


class RDC(Block):
    """Resolver-to-digital converter: a type-II tracking loop on the resolver's analog angle,
    with a digital angle output at ``bits`` resolution::

        e           = sin(theta - theta_r)         (theta: the resolver's angle, continuous)
        dtheta_r/dt = w_r + 2 zeta w_n e
        dw_r/dt     = w_n^2 e,                      w_n = 2 pi f_n
        theta_d     = q round(theta_r / q),         q = 2 pi / 2^bits   (theta_d = theta_r
                                                                          for bits = 0)
        w_d         = lsb sat(round(w_r / lsb)),    lsb = w_max / 2^(w_bits - 1)
                                                    (w_d = w_r for w_bits = 0)

    For small errors the tracked angle follows the true one through
    ``(2 zeta w_n s + w_n^2) / (s^2 + 2 zeta w_n s + w_n^2)``: zero steady error at constant
    speed, ``a / w_n^2`` at constant acceleration ``a``; a speed step ``w0`` from rest gives
    ``e(t) = w0 / w_d exp(-zeta w_n t) sin(w_d t)``, ``w_d = w_n sqrt(1 - zeta^2)``. The
    speed output is the loop's integrator ``w_r`` (what the converter's velocity output
    provides instead of a differentiated angle). ``sin`` of the error makes the loop track
    through angle wrap-around.

    Quantization as built: the converter compares the resolver's analog signals with its
    angle counter, and what has ``bits`` bits is the counter, i.e. the digital output
    ``theta_d``. The loop here tracks with the continuous ``theta_r`` and quantizes only
    the output, so no discontinuity enters the tracking loop (the counter's own error of at
    most half an LSB inside the loop is neglected: it is a bounded +-q/2 dither on ``e``
    that the loop filters at ``f_n``). ``|theta_d - theta| <= q/2 + |theta - theta_r|``.
    ``theta_d`` is a staircase: read it from sampled blocks (a sampled controller), whose
    samples are time events, not from continuous dynamics. Outputs ``theta_r`` and ``w_r``
    are states and ``theta_d`` depends on a state only: no direct feedthrough.

    The velocity output as built is a digital word too: ``w_bits`` bits, two's complement,
    full scale ``+-w_max`` (the converter's maximum tracking rate), so one count is
    ``lsb = w_max / 2^(w_bits - 1)`` and the word saturates at ``-2^(w_bits-1)`` and
    ``2^(w_bits-1) - 1`` counts. ``w_d`` is that word times ``lsb`` (rad/s), a staircase of
    ``w_r`` to be read by sampled blocks like ``theta_d``. The default ``w_bits = 0`` gives
    ``w_d = w_r``; with 16 bits, the default ``w_max = 2 pi 125`` rad/s (0.024 rad/s a
    count) is the 16-bit maximum tracking rate of a converter of the AD2S1210 kind at an
    8.192 MHz clock (125 rev/s), an assumption for SPIDER's converters.
    """

    category = "sensors"
    parameters = {
        "f_n": Param(500.0, "Hz", "natural frequency of the tracking loop", gt=0.0),
        "zeta": Param(0.7, "1", "damping ratio of the tracking loop", gt=0.0),
        "bits": Param(0, "1", "resolution of the digital angle output theta_d in bits per "
                      "revolution (0: theta_d = theta_r)", kind="int", ge=0, le=40),
        "w_bits": Param(0, "1", "bits of the digital velocity word w_d, two's complement "
                        "(0: w_d = w_r)", kind="int", ge=0, le=40),
        "w_max": Param(2.0 * math.pi * 125.0, "rad/s", "full scale of the velocity word "
                       "(the converter's maximum tracking rate)", gt=0.0),
        "theta0": Param(0.0, "rad", "initial tracked angle"),
        "w0": Param(0.0, "rad/s", "initial tracked speed"),
    }
    inputs = {"theta": Port("rad", doc="resolver angle (analog, continuous)")}
    outputs = {"theta_r": Port("rad", doc="tracked angle (continuous)"),
               "w_r": Port("rad/s", doc="tracked speed (the loop integrator, continuous)"),
               "theta_d": Port("rad", feedthrough=(),
                               doc="digital angle: theta_r on the 2 pi / 2^bits grid"),
               "w_d": Port("rad/s", feedthrough=(),
                           doc="digital velocity: w_r as a w_bits word of full scale w_max")}
    states = {"theta_r": State("rad", initial="theta0", doc="tracked angle"),
              "w_r": State("rad/s", initial="w0", doc="loop integrator: the speed")}
    quantizer = {"bits": 0, "w_bits": 0}    # linearized as theta_d = theta_r, w_d = w_r

    @classmethod
    def check(cls, params):
        if params["w_bits"] == 1:
            raise ValueError(f"w_bits = 1 is a sign bit only: the word's counts are -1 and 0, "
                             f"so w_d reads 0 for every speed >= -w_max/2 and -w_max "
                             f"({-params['w_max']:g} rad/s) below; use 0 (w_d = w_r) or at "
                             f"least 2 bits")

    @staticmethod
    def output(t, theta_r, w_r, bits, w_bits, w_max, theta_d, w_d):
        theta_d[0] = quantize_jit(theta_r[0], bits)
        w_d[0] = quantize_speed_jit(w_r[0], w_bits, w_max)

    @staticmethod
    def derivative(t, theta, theta_r, w_r, f_n, zeta, der_theta_r, der_w_r):
        wn = 2.0 * math.pi * f_n
        e = math.sin(theta[0] - theta_r[0])
        der_theta_r[0] = w_r[0] + 2.0 * zeta * wn * e
        der_w_r[0] = wn * wn * e

    @staticmethod
    def partials(t, theta, theta_r, f_n, zeta, bits, w_bits, dfdx, dfdu, dydx):
        """States ``(theta_r, w_r)``, input ``theta``, outputs that are not states
        ``(theta_d, w_d)``; with ``c = cos(theta - theta_r)``::

            d(dtheta_r/dt)/d(theta_r, w_r, theta) = (-2 zeta w_n c, 1, 2 zeta w_n c)
            d(dw_r/dt)/d(theta_r, theta) = (-w_n^2 c, w_n^2 c)
            d theta_d/d theta_r = 1 for bits = 0 (else the staircase: 0), w_d alike
        """
        wn = 2.0 * math.pi * f_n
        c = math.cos(theta[0] - theta_r[0])
        dfdx[0, 0] = -2.0 * zeta * wn * c
        dfdx[0, 1] = 1.0
        dfdx[1, 0] = -wn * wn * c
        dfdu[0, 0] = 2.0 * zeta * wn * c
        dfdu[1, 0] = wn * wn * c
        if bits <= 0:
            dydx[0, 0] = 1.0
        if w_bits <= 0:
            dydx[1, 1] = 1.0
