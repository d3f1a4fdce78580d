"""Harmonic Drive gearbox: ratio, torsional compliance (linear or the catalogue's
three-slope law) with damping, backlash with contact events, LuGre friction on the motor side.

Angles: ``phi_m`` motor (wave generator) side, ``phi_l`` load (output) side; the motor turns
``ratio`` times the output (``N`` before spidersim 0.1, still accepted with a warning).
Deflection at the output ``delta = phi_m / ratio - phi_l``. With total
backlash ``b`` the teeth are in contact when ``|delta| >= b/2``; the transmitted torque::

    tau_s = k(delta_e) + d d(delta)/dt     in contact (delta_e = delta -+ b/2), 0 in the gap

where ``k`` is ``K1 delta_e`` (linear) or the three-slope law inverted from PHYSICS.md::

    phi(T) = T/K1                 |T| <= T1
           = T1/K1 + (T-T1)/K2    T1 < |T| <= T2
           = T1/K1 + (T2-T1)/K2 + (T-T2)/K3 above   (odd in T)

Contact starts when ``|delta|`` is past ``b/2`` and the contact torque there would push
(the guard ``min(K1 (delta - b/2), tau_s)``, mirrored on the negative side: closing teeth
touch at ``b/2``; teeth parted by the damper, still past ``b/2``, touch again when the
torque turns back) and ends when the contact torque would pull (``tau_s`` changes sign):
both are events. Outputs: ``tau_l`` drives the load,
``tau_m`` is the torque the gearbox applies against the motor (connect it to the motor's
``tau_load``), ``tau_f`` is the LuGre friction (zero with ``friction: false``)::

    friction_side = motor:  tau_l = tau_s,        tau_m = tau_s / (ratio e) + tau_f(w_m)
    friction_side = load:   tau_l = tau_s - tau_f(w_l),  tau_m = tau_s / (ratio e)

with the mesh efficiency ``e = efficiency`` while the motor drives the load
(``tau_s w_l >= 0``) and ``e = 1 / efficiency`` while the load back-drives the motor: the
losses are always taken from the power flow. With ``efficiency < 1`` the switch at
``tau_s w_l = 0`` is a discontinuity without an event; the default is 1 (lossless mesh,
friction through LuGre).
"""

from .base import Block, Event, Mode, Param, Port, State
from .friction import LUGRE_PARAMS, check_levels, lugre_rates_jit, lugre_slopes_jit


def three_slope(phi, K1, K2, K3, T1, T2):
    """Torque of the three-slope stiffness at deflection ``phi`` (odd)."""
    a = abs(phi)
    p1 = T1 / K1
    p2 = p1 + (T2 - T1) / K2
    if a <= p1:
        t = K1 * a
    elif a <= p2:
        t = T1 + K2 * (a - p1)
    else:
        t = T2 + K3 * (a - p2)
    return t if phi >= 0.0 else -t



def three_slope_stiffness(phi, K1, K2, T1, T2, K3):
    """``d three_slope / d phi`` at ``phi``: ``K1``, ``K2`` or ``K3`` by the segment of
    ``|phi|`` (the corners belong to the lower segment, as in :func:`three_slope`)."""
    a = abs(phi)
    p1 = T1 / K1
    if a <= p1:
        return K1
    if a <= p1 + (T2 - T1) / K2:
        return K2
    return K3


def _spring(delta, w_rel, contact, half, linear, K1, K2, K3, T1, T2, d):
    """Transmitted torque for the contact mode (see the module docstring)."""
    if half > 0.0 and contact == 0.0:
        return 0.0
    de = delta - half * contact if half > 0.0 else delta
    k = K1 * de if linear else three_slope_jit(de, K1, K2, K3, T1, T2)
    return k + d * w_rel


def _jit(fn):
    import numba
    return numba.njit(cache=True, inline="always", error_model="numpy")(fn)


three_slope_jit = _jit(three_slope)
three_slope_stiffness_jit = _jit(three_slope_stiffness)
spring_jit = _jit(_spring)


class HarmonicDrive(Block):
    """Harmonic Drive gearbox (see the module docstring for equations and conventions)."""

    category = "mechanics"
    parameters = dict({
        "ratio": Param(160.0, "1", "ratio: motor angle / output angle", gt=0.0),
        "stiffness": Param("linear", kind="str", choices=("linear", "three_slope"),
                           doc="linear K1 spring or the catalogue's three-slope law"),
        "K1": Param(5.4e4, "N.m/rad", "stiffness below T1 (the linear spring)", gt=0.0),
        "K2": Param(7.8e4, "N.m/rad", "stiffness between T1 and T2", gt=0.0),
        "K3": Param(1.1e5, "N.m/rad", "stiffness above T2", gt=0.0),
        "T1": Param(29.0, "N.m", "first corner torque", gt=0.0),
        "T2": Param(108.0, "N.m", "second corner torque", gt=0.0),
        "d": Param(20.0, "N.m.s/rad", "torsional damping at the output", ge=0.0),
        "backlash": Param(0.0, "rad", "total backlash at the output (about 2.9e-4)", ge=0.0),
        "friction": Param(True, kind="bool", doc="LuGre friction"),
        "friction_side": Param("motor", kind="str", choices=("motor", "load"),
                               doc="where the LuGre friction acts (speed it sees)"),
        "efficiency": Param(1.0, "1", "mesh efficiency", gt=0.0, le=1.0),
    }, **LUGRE_PARAMS)
    renamed = {"N": "ratio"}
    inputs = {"phi_m": Port("rad", doc="motor-side angle"),
              "w_m": Port("rad/s", doc="motor-side speed"),
              "phi_l": Port("rad", doc="output (load) angle"),
              "w_l": Port("rad/s", doc="output speed")}
    outputs = {"tau_l": Port("N.m", feedthrough="all", doc="torque driving the load"),
               "tau_m": Port("N.m", feedthrough="all", doc="torque against the motor"),
               "tau_f": Port("N.m", doc="LuGre friction", feedthrough=lambda p: (
                   "w_l",) if p["friction_side"] == "load" else ("w_m",)),
               "deflection": Port("rad", feedthrough=("phi_m", "phi_l"),
                                  doc="phi_m / ratio - phi_l")}
    states = {"z": State("rad", doc="LuGre bristle deflection")}
    modes = {"contact": Mode(doc="-1 / +1 teeth in contact on either side, 0 in the gap")}
    events = {"contact_pos": Event(1, "deflection past +b/2 with a pushing contact torque"),
              "contact_neg": Event(-1, "deflection past -b/2 with a pushing contact torque"),
              "separate": Event(-1, "the contact torque would pull")}

    @classmethod
    def check(cls, params):
        if params["T2"] <= params["T1"]:
            raise ValueError(f"T2 ({params['T2']}) must exceed T1 ({params['T1']})")
        if params["friction"]:
            check_levels(params)

    @classmethod
    def derive(cls, params):
        return {"half": params["backlash"] / 2.0,
                "linear": float(params["stiffness"] == "linear"),
                "load_side": float(params["friction_side"] == "load")}

    @staticmethod
    def output(t, z, phi_m, w_m, phi_l, w_l, ratio, K1, K2, K3, T1, T2, d, half, linear,
               friction, load_side, efficiency, T_c, T_s, v_s, delta, sigma0, sigma1, D,
               contact, tau_l, tau_m, tau_f, deflection):
        de = phi_m[0] / ratio - phi_l[0]
        ts = spring_jit(de, w_m[0] / ratio - w_l[0], contact[0], half, linear > 0.5, K1, K2, K3,
                        T1, T2, d)
        f = 0.0
        if friction:
            v = w_l[0] if load_side > 0.5 else w_m[0]
            dz, f = lugre_rates_jit(v, z[0], T_c, T_s, v_s, delta, sigma0, sigma1, D)
        e = efficiency if ts * w_l[0] >= 0.0 else 1.0 / efficiency
        if load_side > 0.5:
            tau_l[0] = ts - f
            tau_m[0] = ts / (ratio * e)
        else:
            tau_l[0] = ts
            tau_m[0] = ts / (ratio * e) + f
        tau_f[0] = f
        deflection[0] = de

    @staticmethod
    def derivative(t, z, w_m, w_l, friction, load_side, T_c, T_s, v_s, delta, sigma0, sigma1,
                   D, der_z):
        if friction:
            v = w_l[0] if load_side > 0.5 else w_m[0]
            dz, f = lugre_rates_jit(v, z[0], T_c, T_s, v_s, delta, sigma0, sigma1, D)
            der_z[0] = dz
        else:
            der_z[0] = 0.0

    @staticmethod
    def partials(t, z, phi_m, w_m, phi_l, w_l, ratio, K1, K2, K3, T1, T2, d, half, linear,
                 friction, load_side, efficiency, T_c, T_s, v_s, delta, sigma0, sigma1, D,
                 contact, dfdx, dfdu, dydx, dydu):
        """State ``z``, inputs ``(phi_m, w_m, phi_l, w_l)``, outputs ``(tau_l, tau_m, tau_f,
        deflection)``, in the contact mode (the mesh efficiency's factor ``e`` held, as
        between events). With ``k'`` the spring's slope at the deflection (``K1``, or the
        three-slope segment's; 0 in the gap) and ``(a, b)`` the LuGre slopes
        ``d(dz/dt)/d(z, v)`` at the friction's speed ``v`` (``w_m``, or ``w_l`` on the load
        side)::

            d tau_s/d(phi_m, w_m, phi_l, w_l) = (k'/ratio, d/ratio, -k', -d)  (0 in the gap)
            d tau_f/dz = sigma0 + sigma1 a,     d tau_f/dv = sigma1 b + D
            tau_l = tau_s (- tau_f on the load side),  tau_m = tau_s / (ratio e) (+ tau_f
            on the motor side),  deflection = phi_m / ratio - phi_l,  dz/dt: (a, b)
        """
        gap = half > 0.0 and contact[0] == 0.0
        kp = 0.0
        dd = 0.0
        if not gap:
            de = phi_m[0] / ratio - phi_l[0] - (half * contact[0] if half > 0.0 else 0.0)
            kp = K1 if linear > 0.5 else three_slope_stiffness_jit(de, K1, K2, T1, T2, K3)
            dd = d
        ts = spring_jit(phi_m[0] / ratio - phi_l[0], w_m[0] / ratio - w_l[0], contact[0],
                        half, linear > 0.5, K1, K2, K3, T1, T2, d)
        e = efficiency if ts * w_l[0] >= 0.0 else 1.0 / efficiency
        dts = (kp / ratio, dd / ratio, -kp, -dd)
        for j in range(4):
            dydu[0, j] = dts[j]
            dydu[1, j] = dts[j] / (ratio * e)
        dydu[3, 0] = 1.0 / ratio
        dydu[3, 2] = -1.0
        if friction:
            iv = 3 if load_side > 0.5 else 1
            v = w_l[0] if load_side > 0.5 else w_m[0]
            a, b = lugre_slopes_jit(v, z[0], T_c, T_s, v_s, delta, sigma0)
            fz = sigma0 + sigma1 * a
            fv = sigma1 * b + D
            dfdx[0, 0] = a
            dfdu[0, iv] = b
            dydx[2, 0] = fz
            dydu[2, iv] = fv
            row = 0 if load_side > 0.5 else 1
            sgn = -1.0 if load_side > 0.5 else 1.0
            dydx[row, 0] = sgn * fz
            dydu[row, iv] += sgn * fv

    @staticmethod
    def initialize(t, phi_m, w_m, phi_l, w_l, ratio, K1, K2, K3, T1, T2, d, half, linear,
                   contact):
        # in contact only where the contact torque would push: just after a separation the
        # deflection is still beyond b/2 (by d |d delta/dt| / K1) while the teeth part
        if half > 0.0 and contact[0] == 0.0:
            de = phi_m[0] / ratio - phi_l[0]
            wr = w_m[0] / ratio - w_l[0]
            if de > half and spring_jit(de, wr, 1.0, half, linear > 0.5, K1, K2, K3, T1, T2,
                                        d) > 0.0:
                contact[0] = 1.0
            elif de < -half and spring_jit(de, wr, -1.0, half, linear > 0.5, K1, K2, K3, T1,
                                           T2, d) < 0.0:
                contact[0] = -1.0

    @staticmethod
    def guard(t, phi_m, w_m, phi_l, w_l, ratio, K1, K2, K3, T1, T2, d, half, linear, contact, zc):
        zc[0] = -1.0
        zc[1] = 1.0
        zc[2] = 1.0
        if half > 0.0:
            de = phi_m[0] / ratio - phi_l[0]
            wr = w_m[0] / ratio - w_l[0]
            if contact[0] == 0.0:
                # in the gap: a side touches when its deflection is past b/2 and the contact
                # torque there would push (a separation by damping leaves |delta| > b/2 with
                # the torque just turned: the teeth close again when it turns back)
                zc[0] = min(K1 * (de - half), spring_jit(de, wr, 1.0, half, linear > 0.5,
                                                          K1, K2, K3, T1, T2, d))
                zc[1] = max(K1 * (de + half), spring_jit(de, wr, -1.0, half, linear > 0.5,
                                                          K1, K2, K3, T1, T2, d))
            else:
                zc[2] = contact[0] * spring_jit(de, wr, contact[0], half, linear > 0.5, K1,
                                                K2, K3, T1, T2, d)

    @staticmethod
    def on_event(t, which, direction, contact):
        if which == 0:
            contact[0] = 1.0
        elif which == 1:
            contact[0] = -1.0
        else:
            contact[0] = 0.0
