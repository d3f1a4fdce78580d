"""Electromechanical actuators: the brushed DC motor.

Sign convention: positive voltage drives positive current, torque and speed; ``tau_load`` is
the torque the load applies *against* the rotor (positive load torque decelerates a rotor
turning forward).
"""
from .base import Block, Dim, Param, Port, State


class DCMotor(Block):
    """Brushed DC motor with armature inductance::

        L di/dt = v - R i - K w
        J dw/dt = K i - b w - tau_load
        dphi/dt = w

    with ``K`` both torque constant [N.m/A] and back-EMF constant [V.s/rad].
    With ``L = 0`` the current is algebraic, ``i = (v - K w) / R``: the outputs ``i`` and
    ``tau`` are then direct feedthrough of ``v`` (a current loop around it becomes an
    algebraic loop, solved by Newton). ``L`` is structural: changing it recompiles.
    """

    category = "electromechanical"
    parameters = {
        "R": Param(1.0, "Ohm", "armature resistance", gt=0.0),
        "L": Param(1e-3, "H", "armature inductance (0: algebraic current)", ge=0.0,
                   structural=True),
        "K": Param(0.05, "N.m/A", "torque and back-EMF constant", gt=0.0),
        "J": Param(1e-4, "kg.m2", "rotor inertia", gt=0.0),
        "b": Param(1e-5, "N.m.s/rad", "viscous friction", ge=0.0),
        "i0": Param(0.0, "A", "initial current"),
        "w0": Param(0.0, "rad/s", "initial speed"),
        "phi0": Param(0.0, "rad", "initial angle"),
    }
    inputs = {"v": Port("V", doc="armature voltage"),
              "tau_load": Port("N.m", optional=True, doc="load torque opposing the rotor")}
    outputs = {"i": Port("A", doc="armature current",
                         feedthrough=lambda p: ("v",) if p["L"] == 0 else ()),
               "w": Port("rad/s", doc="rotor speed"),
               "phi": Port("rad", doc="rotor angle"),
               "tau": Port("N.m", doc="electromagnetic torque K i",
                           feedthrough=lambda p: ("v",) if p["L"] == 0 else ())}
    states = {"i": State("A", size=Dim("1 if L > 0 else 0", lambda p: 1 if p["L"] > 0 else 0),
                         initial="i0", doc="armature current (absent when L = 0)"),
              "w": State("rad/s", initial="w0", doc="rotor speed"),
              "phi": State("rad", initial="phi0", doc="rotor angle")}

    @staticmethod
    def output(t, i, w, v, R, L, K, tau):
        if L == 0.0:
            i[0] = (v[0] - K * w[0]) / R
        tau[0] = K * i[0]

    @staticmethod
    def derivative(t, i, w, v, tau_load, R, L, K, J, b, der_i, der_w, der_phi):
        if L > 0.0:
            der_i[0] = (v[0] - R * i[0] - K * w[0]) / L
        der_w[0] = (K * i[0] - b * w[0] - tau_load[0]) / J
        der_phi[0] = w[0]
