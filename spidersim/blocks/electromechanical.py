"""Electromechanical actuators: the brushed DC motor, the two-phase brushless motor and its
NRPI current driver.

Sign convention: positive voltage drives positive current, torque and speed; ``tau_load`` is
the torque the load applies *against* the rotor (positive load torque decelerates a rotor
turning forward).
"""
import math

from .base import Block, Dim, Param, Port, State


class DCMotor(Block):
    """Brushed DC motor with armature inductance::

        L di/dt = v - R i - K_t w
        J dw/dt = K_t i - b w - tau_load
        dphi/dt = w

    with ``K_t`` both torque constant [N.m/A] and back-EMF constant [V.s/rad] (``K`` before
    spidersim 0.1, still accepted with a warning). With ``L = 0`` the current is algebraic,
    ``i = (v - K_t w) / R``: the outputs ``i`` and
    ``tau`` are then direct feedthrough of ``v`` (a current loop around it becomes an
    algebraic loop, solved by Newton). ``L`` is structural: changing it recompiles.
    """

    category = "electromechanical"
    parameters = {
        "R": Param(1.0, "Ohm", "armature resistance", gt=0.0),
        "L": Param(1e-3, "H", "armature inductance (0: algebraic current)", ge=0.0,
                   structural=True),
        "K_t": Param(0.05, "N.m/A", "torque and back-EMF constant", gt=0.0),
        "J": Param(1e-4, "kg.m2", "rotor inertia", gt=0.0),
        "b": Param(1e-5, "N.m.s/rad", "viscous friction", ge=0.0),
        "i0": Param(0.0, "A", "initial current"),
        "w0": Param(0.0, "rad/s", "initial speed"),
        "phi0": Param(0.0, "rad", "initial angle"),
    }
    renamed = {"K": "K_t"}
    inputs = {"v": Port("V", doc="armature voltage"),
              "tau_load": Port("N.m", optional=True, doc="load torque opposing the rotor")}
    outputs = {"i": Port("A", doc="armature current",
                         feedthrough=lambda p: ("v",) if p["L"] == 0 else ()),
               "w": Port("rad/s", doc="rotor speed"),
               "phi": Port("rad", doc="rotor angle"),
               "tau": Port("N.m", doc="electromagnetic torque K_t i",
                           feedthrough=lambda p: ("v",) if p["L"] == 0 else ())}
    states = {"i": State("A", size=Dim("1 if L > 0 else 0", lambda p: 1 if p["L"] > 0 else 0),
                         initial="i0", doc="armature current (absent when L = 0)"),
              "w": State("rad/s", initial="w0", doc="rotor speed"),
              "phi": State("rad", initial="phi0", doc="rotor angle")}

    @staticmethod
    def output(t, i, w, v, R, L, K_t, tau):
        if L == 0.0:
            i[0] = (v[0] - K_t * w[0]) / R
        tau[0] = K_t * i[0]

    @staticmethod
    def derivative(t, i, w, v, tau_load, R, L, K_t, J, b, der_i, der_w, der_phi):
        if L > 0.0:
            der_i[0] = (v[0] - R * i[0] - K_t * w[0]) / L
        der_w[0] = (K_t * i[0] - b * w[0] - tau_load[0]) / J
        der_phi[0] = w[0]

    @staticmethod
    def partials(t, R, L, K_t, J, b, dfdx, dfdu, dydx, dydu):
        """States ``(i, w, phi)`` (``(w, phi)`` when ``L = 0``), inputs ``(v, tau_load)``,
        outputs that are not states ``tau`` (``(i, tau)`` when ``L = 0``)::

            L > 0:  d(di/dt)/d(i, w) = (-R/L, -K_t/L),  d(di/dt)/dv = 1/L
                    d(dw/dt)/d(i, w) = (K_t/J, -b/J),   d(dw/dt)/dtau_load = -1/J
                    d(dphi/dt)/dw = 1,                   dtau/di = K_t
            L = 0:  i = (v - K_t w)/R:  di/dw = -K_t/R, di/dv = 1/R (tau = K_t i alike)
                    d(dw/dt)/dw = -(K_t^2/R + b)/J, d(dw/dt)/dv = K_t/(R J)
        """
        if L > 0.0:
            dfdx[0, 0] = -R / L
            dfdx[0, 1] = -K_t / L
            dfdu[0, 0] = 1.0 / L
            dfdx[1, 0] = K_t / J
            dfdx[1, 1] = -b / J
            dfdu[1, 1] = -1.0 / J
            dfdx[2, 1] = 1.0
            dydx[0, 0] = K_t
        else:
            dfdx[0, 0] = -(K_t * K_t / R + b) / J
            dfdu[0, 0] = K_t / (R * J)
            dfdu[0, 1] = -1.0 / J
            dfdx[1, 0] = 1.0
            dydx[0, 0] = -K_t / R
            dydu[0, 0] = 1.0 / R
            dydx[1, 0] = -K_t * K_t / R
            dydu[1, 0] = K_t / R


class BrushlessMotor(Block):
    """Two-phase permanent-magnet brushless motor (SPIDER's actuator)::

        theta_e = p theta
        f_a = -sin(theta_e) - h3 sin(3 theta_e),   f_b = cos(theta_e) - h3 cos(3 theta_e)
        K_a = K_t (1 + unbalance / 2),             K_b = K_t (1 - unbalance / 2)
        L di_a/dt = v_a - R i_a - K_a w f_a        (phase b alike)
        tau = K_a f_a i_a + K_b f_b i_b + tau_cog sin(2 theta_e)
        J dw/dt = tau - b w - tau_load,   dtheta/dt = w

    Imperfections, each a fraction: ``h3`` is the amplitude of the third BEMF harmonic
    relative to the fundamental (0.008 in the paper); ``unbalance`` is the relative
    difference of the two phases' torque (and BEMF) constants, ``(K_a - K_b) / K_t``
    (0.015); ``tau_cog`` the amplitude of a cogging torque at twice the electrical
    frequency [N.m]. With the commutated currents ``i_a = -I sin theta_e``,
    ``i_b = I cos theta_e`` and no imperfections, ``tau = K_t I``; ``h3`` adds
    ``-K_t I h3 cos(4 theta_e)`` (a line at 4 f_e); ``unbalance`` adds
    ``-K_t I (unbalance / 2) cos(2 theta_e)`` (2 f_e). The per-phase constant appears in
    both the torque and the BEMF, so electrical power balances mechanical power:
    ``v.i = R |i|^2 + d/dt(L |i|^2 / 2) + (tau - cogging) w``.

    Sign convention: positive torque accelerates positively; ``tau_load`` opposes. The
    viscous friction ``b`` was ``B`` before spidersim 0.1 (still accepted with a warning).

    ``dw`` is the rotor's acceleration ``dw/dt`` [rad/s2] (direct feedthrough of
    ``tau_load`` only, so it closes no loop through a gearbox fed by the motor's states):
    ``-J dw/dt`` is the reaction torque a drive mounted on a moving body applies to it
    beyond its output torque (see :class:`spidersim.blocks.arm.Arm`).
    """

    category = "electromechanical"
    parameters = {
        "p": Param(7, "1", "pole pairs", kind="int", ge=1),
        "R": Param(1.5, "Ohm", "phase resistance", gt=0.0),
        "L": Param(1.5e-3, "H", "phase inductance", gt=0.0),
        "K_t": Param(0.15, "N.m/A", "torque constant = BEMF constant [V.s/rad], phase "
                                    "amplitude convention", gt=0.0),
        "J": Param(1.0e-4, "kg.m2", "rotor inertia (with the wave generator)", gt=0.0),
        "b": Param(0.0, "N.m.s/rad", "viscous friction", ge=0.0),
        "h3": Param(0.0, "1", "third BEMF harmonic relative to the fundamental"),
        "unbalance": Param(0.0, "1", "(K_a - K_b) / K_t, phase torque-constant unbalance",
                           gt=-2.0, lt=2.0),
        "tau_cog": Param(0.0, "N.m", "cogging torque amplitude at 2 theta_e"),
        "w0": Param(0.0, "rad/s", "initial speed"),
        "theta0": Param(0.0, "rad", "initial rotor angle"),
    }
    renamed = {"B": "b"}
    inputs = {"v_a": Port("V", doc="phase a voltage"), "v_b": Port("V", doc="phase b voltage"),
              "tau_load": Port("N.m", optional=True, doc="load torque opposing the rotor")}
    outputs = {"i_a": Port("A", doc="phase a current"), "i_b": Port("A", doc="phase b current"),
               "w": Port("rad/s", doc="rotor speed"), "theta": Port("rad", doc="rotor angle"),
               "theta_e": Port("rad", doc="electrical angle p theta"),
               "tau": Port("N.m", doc="electromagnetic torque (with cogging)"),
               "bemf_a": Port("V", doc="phase a back EMF K_a w f_a"),
               "bemf_b": Port("V", doc="phase b back EMF K_b w f_b"),
               "dw": Port("rad/s2", feedthrough=("tau_load",),
                          doc="rotor acceleration (tau - b w - tau_load) / J")}
    states = {"i_a": State("A", doc="phase a current"), "i_b": State("A", doc="phase b current"),
              "w": State("rad/s", initial="w0", doc="rotor speed"),
              "theta": State("rad", initial="theta0", doc="rotor angle")}

    @staticmethod
    def output(t, i_a, i_b, w, theta, tau_load, p, K_t, J, b, h3, unbalance, tau_cog,
               theta_e, tau, bemf_a, bemf_b, dw):
        """The harmonics from one sine and cosine: ``sin 2x = 2 s c``,
        ``sin 3x = s (3 - 4 s^2)``, ``cos 3x = c (4 c^2 - 3)``."""
        te = p * theta[0]
        s1, c1 = math.sin(te), math.cos(te)
        fa = -s1 - h3 * (s1 * (3.0 - 4.0 * s1 * s1))
        fb = c1 - h3 * (c1 * (4.0 * c1 * c1 - 3.0))
        ka = K_t * (1.0 + 0.5 * unbalance)
        kb = K_t * (1.0 - 0.5 * unbalance)
        theta_e[0] = te
        tau[0] = ka * fa * i_a[0] + kb * fb * i_b[0] + tau_cog * (2.0 * s1 * c1)
        bemf_a[0] = ka * w[0] * fa
        bemf_b[0] = kb * w[0] * fb
        dw[0] = (tau[0] - b * w[0] - tau_load[0]) / J

    @staticmethod
    def derivative(t, i_a, i_b, w, v_a, v_b, R, L, bemf_a, bemf_b, dw, der_i_a, der_i_b,
                   der_w, der_theta):
        """From the outputs of the same evaluation: the back EMF and ``dw``."""
        der_i_a[0] = (v_a[0] - R * i_a[0] - bemf_a[0]) / L
        der_i_b[0] = (v_b[0] - R * i_b[0] - bemf_b[0]) / L
        der_w[0] = dw[0]
        der_theta[0] = w[0]

    @staticmethod
    def partials(t, i_a, i_b, w, theta, p, R, L, K_t, J, b, h3, unbalance, tau_cog,
                 dfdx, dfdu, dydx, dydu):
        """States ``(i_a, i_b, w, theta)``, inputs ``(v_a, v_b, tau_load)``, outputs that
        are not states ``(theta_e, tau, bemf_a, bemf_b, dw)``. With ``f_a' = df_a/dtheta =
        p (-cos theta_e - 3 h3 cos 3 theta_e)``, ``f_b' = p (-sin theta_e + 3 h3 sin 3
        theta_e)``::

            dtau/d(i_a, i_b) = (K_a f_a, K_b f_b)
            dtau/dtheta = K_a i_a f_a' + K_b i_b f_b' + 2 p tau_cog cos 2 theta_e
            dbemf_a/d(w, theta) = (K_a f_a, K_a w f_a')      (b alike)
            d(dw)/dx = (dtau/dx - b e_w) / J,  d(dw)/dtau_load = -1/J
            L di_a/dt = v_a - R i_a - bemf_a                  (b alike)
        """
        te = p * theta[0]
        s1, c1 = math.sin(te), math.cos(te)
        fa = -s1 - h3 * (s1 * (3.0 - 4.0 * s1 * s1))
        fb = c1 - h3 * (c1 * (4.0 * c1 * c1 - 3.0))
        dfa = p * (-c1 - 3.0 * h3 * (c1 * (4.0 * c1 * c1 - 3.0)))
        dfb = p * (-s1 + 3.0 * h3 * (s1 * (3.0 - 4.0 * s1 * s1)))
        ka = K_t * (1.0 + 0.5 * unbalance)
        kb = K_t * (1.0 - 0.5 * unbalance)
        # outputs: theta_e, tau, bemf_a, bemf_b, dw
        dydx[0, 3] = p
        dydx[1, 0] = ka * fa
        dydx[1, 1] = kb * fb
        dydx[1, 3] = ka * i_a[0] * dfa + kb * i_b[0] * dfb \
            + tau_cog * 2.0 * p * (c1 * c1 - s1 * s1)
        dydx[2, 2] = ka * fa
        dydx[2, 3] = ka * w[0] * dfa
        dydx[3, 2] = kb * fb
        dydx[3, 3] = kb * w[0] * dfb
        for j in range(4):
            dydx[4, j] = dydx[1, j] / J
        dydx[4, 2] -= b / J
        dydu[4, 2] = -1.0 / J
        # derivatives: i_a, i_b, w, theta
        dfdx[0, 0] = -R / L
        dfdx[0, 2] = -dydx[2, 2] / L
        dfdx[0, 3] = -dydx[2, 3] / L
        dfdu[0, 0] = 1.0 / L
        dfdx[1, 1] = -R / L
        dfdx[1, 2] = -dydx[3, 2] / L
        dfdx[1, 3] = -dydx[3, 3] / L
        dfdu[1, 1] = 1.0 / L
        for j in range(4):
            dfdx[2, j] = dydx[4, j]
        dfdu[2, 2] = -1.0 / J
        dfdx[3, 2] = 1.0


class NRPIDriver(Block):
    """Analog current driver of SPIDER ("NRPI"): sinusoidal current references commutated
    from the electrical angle, two independent PI current loops, linear amplifier::

        I = min(max(i_cmd, -I_max), I_max)
        i_a* = -I sin(theta_e),  i_b* = I cos(theta_e)
        i_x,meas = (1 + gain_x) i_x + offset_x                  (current sensors)
        e_x = i_x* - i_x,meas,   v_x = sat(kp e_x + I_x, +-V_supply)
        dI_x/dt = ki e_x + kb (v_x - (kp e_x + I_x))            (back-calculation)

    A sensor ``offset_a`` [A] makes the loop regulate ``i_a = i_a* - offset_a``: a torque
    line at the electrical frequency of amplitude ``K_t offset``. The paper's 1.5 % offset
    is of the rated current (2 A): 0.03 A. No PWM: the amplifier is linear.
    """

    category = "electromechanical"
    parameters = {
        "kp": Param(18.85, "V/A", "current PI proportional gain (L w_c)", ge=0.0),
        "ki": Param(18850.0, "V/(A.s)", "current PI integral gain (R w_c)", ge=0.0),
        "kb": Param(1000.0, "1/s", "anti-windup back-calculation gain", ge=0.0),
        "V_supply": Param(28.0, "V", "supply voltage: output limit", gt=0.0),
        "I_max": Param(4.0, "A", "current command limit", gt=0.0),
        "gain_a": Param(0.0, "1", "phase a current-sensor gain error"),
        "gain_b": Param(0.0, "1", "phase b current-sensor gain error"),
        "offset_a": Param(0.0, "A", "phase a current-sensor offset"),
        "offset_b": Param(0.0, "A", "phase b current-sensor offset"),
    }
    inputs = {"i_cmd": Port("A", doc="current amplitude command (torque / K_t)"),
              "theta_e": Port("rad", doc="electrical angle for commutation"),
              "i_a": Port("A", doc="phase a current"), "i_b": Port("A", doc="phase b current")}
    outputs = {"v_a": Port("V", feedthrough=("i_cmd", "theta_e", "i_a"), doc="phase a voltage"),
               "v_b": Port("V", feedthrough=("i_cmd", "theta_e", "i_b"), doc="phase b voltage"),
               "i_a_ref": Port("A", feedthrough=("i_cmd", "theta_e"),
                               doc="phase a current reference"),
               "i_b_ref": Port("A", feedthrough=("i_cmd", "theta_e"),
                               doc="phase b current reference")}
    states = {"I_a": State("V", doc="phase a integral term"),
              "I_b": State("V", doc="phase b integral term")}

    @staticmethod
    def output(t, I_a, I_b, i_cmd, theta_e, i_a, i_b, kp, V_supply, I_max, gain_a, gain_b,
               offset_a, offset_b, v_a, v_b, i_a_ref, i_b_ref):
        amp = min(max(i_cmd[0], -I_max), I_max)
        ra = -amp * math.sin(theta_e[0])
        rb = amp * math.cos(theta_e[0])
        ea = ra - ((1.0 + gain_a) * i_a[0] + offset_a)
        eb = rb - ((1.0 + gain_b) * i_b[0] + offset_b)
        v_a[0] = min(max(kp * ea + I_a[0], -V_supply), V_supply)
        v_b[0] = min(max(kp * eb + I_b[0], -V_supply), V_supply)
        i_a_ref[0] = ra
        i_b_ref[0] = rb

    @staticmethod
    def derivative(t, I_a, I_b, i_a, i_b, kp, ki, kb, V_supply, gain_a, gain_b, offset_a,
                   offset_b, i_a_ref, i_b_ref, der_I_a, der_I_b):
        """The references from the outputs of the same evaluation."""
        ea = i_a_ref[0] - ((1.0 + gain_a) * i_a[0] + offset_a)
        eb = i_b_ref[0] - ((1.0 + gain_b) * i_b[0] + offset_b)
        va = kp * ea + I_a[0]
        vb = kp * eb + I_b[0]
        der_I_a[0] = ki * ea + kb * (min(max(va, -V_supply), V_supply) - va)
        der_I_b[0] = ki * eb + kb * (min(max(vb, -V_supply), V_supply) - vb)

    @staticmethod
    def partials(t, I_a, I_b, i_cmd, theta_e, i_a, i_b, kp, ki, kb, V_supply, I_max, gain_a,
                 gain_b, offset_a, offset_b, dfdx, dfdu, dydx, dydu):
        """States ``(I_a, I_b)``, inputs ``(i_cmd, theta_e, i_a, i_b)``, outputs ``(v_a,
        v_b, i_a_ref, i_b_ref)``. With ``s_I = 1`` strictly inside the command limit (else
        0), ``s_x = 1`` when ``kp e_x + I_x`` is strictly inside the supply (else 0, the
        output clipped)::

            d i_a*/d(i_cmd, theta_e) = (-s_I sin theta_e, -I cos theta_e)
            d i_b*/d(i_cmd, theta_e) = ( s_I cos theta_e, -I sin theta_e)
            d e_x/d u = d i_x*/d u - (1 + gain_x) [u = i_x]
            d v_x/d I_x = s_x,  d v_x/d u = s_x kp d e_x/d u
            d(dI_x/dt)/d I_x = kb (s_x - 1),  d(dI_x/dt)/d u = (ki + kb (s_x - 1) kp) d e_x/d u
        """
        c = i_cmd[0]
        s_i = 1.0 if -I_max < c < I_max else 0.0
        amp = min(max(c, -I_max), I_max)
        sn, cs = math.sin(theta_e[0]), math.cos(theta_e[0])
        d_ref = ((-s_i * sn, -amp * cs), (s_i * cs, -amp * sn))     # d(i_x*)/d(i_cmd, th)
        refs = (-amp * sn, amp * cs)
        states = (I_a[0], I_b[0])
        meas = ((1.0 + gain_a) * i_a[0] + offset_a, (1.0 + gain_b) * i_b[0] + offset_b)
        gains = (1.0 + gain_a, 1.0 + gain_b)
        for x in range(2):
            vu = kp * (refs[x] - meas[x]) + states[x]
            s_v = 1.0 if -V_supply < vu < V_supply else 0.0
            g_f = ki + kb * (s_v - 1.0) * kp
            dfdx[x, x] = kb * (s_v - 1.0)
            dydx[x, x] = s_v
            for j in range(2):
                dfdu[x, j] = g_f * d_ref[x][j]
                dydu[x, j] = s_v * kp * d_ref[x][j]
                dydu[2 + x, j] = d_ref[x][j]
            dfdu[x, 2 + x] = -g_f * gains[x]
            dydu[x, 2 + x] = -s_v * kp * gains[x]
