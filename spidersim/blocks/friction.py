"""Friction: the LuGre model (Canudas de Wit, Olsson, Astrom, Lischinsky, IEEE TAC 1995)::

    dz/dt = v - sigma0 |v| z / g(v)
    g(v)  = T_c + (T_s - T_c) exp(-|v / v_s|^delta)
    tau_f = sigma0 z + sigma1 dz/dt + D v

``z`` is the mean bristle deflection [rad]; ``tau_f`` opposes the motion (positive for
positive ``v``). In steady sliding ``z = g(v) sgn(v) / sigma0`` and ``tau_f = g(v) sgn(v) +
D v``; below break-away the bristles act as a spring of stiffness ``sigma0``. The ``z``
equation is stiff (eigenvalue ``-sigma0 |v| / g(v)``): use an implicit method or LSODA.
Defaults are PHYSICS.md's motor-side values.
"""
import math

from .base import Block, Param, Port, State

LUGRE_PARAMS = {
    "T_c": Param(0.05, "N.m", "Coulomb friction level", ge=0.0),
    "T_s": Param(0.07, "N.m", "static (break-away) friction level", ge=0.0),
    "v_s": Param(1.0, "rad/s", "Stribeck velocity", gt=0.0),
    "delta": Param(2.0, "1", "Stribeck exponent", gt=0.0),
    "sigma0": Param(80.0, "N.m/rad", "bristle stiffness", gt=0.0),
    "sigma1": Param(0.1, "N.m.s/rad", "bristle damping", ge=0.0),
    "D": Param(2e-4, "N.m.s/rad", "viscous friction", ge=0.0),
}


def check_levels(params, z0=0.0):
    """The friction levels of a LuGre model (raise ``ValueError``): ``T_s >= T_c``, and
    ``T_c > 0`` unless both are 0. With ``T_c = 0 < T_s`` the level ``g(v)`` falls to 0 at
    speed (it underflows: 0.07 exp(-900) at v = 30 v_s), where the bristle equation
    ``dz/dt = v - sigma0 |v| z / g`` has no finite solution (it was taken as ``dz/dt = v``:
    the bristles became a spring winding up without bound, 2,403 N.m instead of D v). Both
    0: no Coulomb and Stribeck friction, the bristles stay at ``z = 0`` (``z0`` must be 0)
    and only the viscous ``D v`` remains."""
    T_c, T_s = params["T_c"], params["T_s"]
    if T_s < T_c:
        raise ValueError(f"T_s ({T_s}) must not be below T_c ({T_c})")
    if T_c == 0.0 and T_s > 0.0:
        raise ValueError(f"T_c = 0 with T_s = {T_s}: the friction level g(v) falls to 0 at "
                         f"speed, where the LuGre bristle equation has no solution; give "
                         f"T_c > 0 (a small Coulomb level), or T_c = T_s = 0 for viscous "
                         f"friction D only")
    if T_c == 0.0 and z0 != 0.0:
        raise ValueError(f"z0 = {z0} with T_c = T_s = 0: without Coulomb and Stribeck "
                         f"friction the bristles carry nothing (z0 must be 0)")


def lugre_rates(v, z, T_c, T_s, v_s, delta, sigma0, sigma1, D):
    """``(dz/dt, tau_f)`` of the LuGre model (``delta = 2``, the usual Gaussian
    Stribeck curve, as ``r * r``: correctly rounded, where ``pow`` is within 0.52 ulp;
    cheaper)."""
    r = abs(v / v_s)
    g = T_c + (T_s - T_c) * math.exp(-(r * r if delta == 2.0 else r ** delta))
    # g = 0 only with T_c = T_s = 0 (check_levels): no bristle friction, z stays 0
    dz = v - sigma0 * abs(v) * z / g if g > 0.0 else 0.0
    return dz, sigma0 * z + sigma1 * dz + D * v


def _jit(fn):
    import numba
    return numba.njit(cache=True, inline="always", error_model="numpy")(fn)


lugre_rates_jit = _jit(lugre_rates)


def lugre_slopes(v, z, T_c, T_s, v_s, delta, sigma0):
    """``(d(dz/dt)/dz, d(dz/dt)/dv)`` of the LuGre model at ``(v, z)`` (see
    :meth:`LuGre.partials` for the equations; ``sgn(0) = 0`` at the kink of ``|v|``)."""
    r = abs(v / v_s)
    e = math.exp(-(r * r if delta == 2.0 else r ** delta))
    g = T_c + (T_s - T_c) * e
    if not g > 0.0:
        return 0.0, 0.0
    sg = 1.0 if v > 0.0 else (-1.0 if v < 0.0 else 0.0)
    dg = 0.0
    if v != 0.0:
        dg = -(T_s - T_c) * e * delta * (r if delta == 2.0 else r ** (delta - 1.0)) * sg / v_s
    return -sigma0 * abs(v) / g, 1.0 - sigma0 * z * (sg * g - abs(v) * dg) / (g * g)


lugre_slopes_jit = _jit(lugre_slopes)


class LuGre(Block):
    """LuGre friction (see the module docstring): relative velocity in, friction out."""

    category = "friction"
    parameters = dict(LUGRE_PARAMS, z0=Param(0.0, "rad", "initial bristle deflection"))
    inputs = {"v": Port("rad/s", doc="relative velocity")}
    outputs = {"tau": Port("N.m", feedthrough=("v",), doc="friction, opposing v"),
               "z": Port("rad", doc="bristle deflection")}
    states = {"z": State("rad", initial="z0", doc="bristle deflection")}

    @classmethod
    def check(cls, params):
        check_levels(params, params["z0"])

    @staticmethod
    def output(t, z, v, T_c, T_s, v_s, delta, sigma0, sigma1, D, tau):
        dz, f = lugre_rates_jit(v[0], z[0], T_c, T_s, v_s, delta, sigma0, sigma1, D)
        tau[0] = f

    @staticmethod
    def derivative(t, z, v, T_c, T_s, v_s, delta, sigma0, sigma1, D, der_z):
        dz, f = lugre_rates_jit(v[0], z[0], T_c, T_s, v_s, delta, sigma0, sigma1, D)
        der_z[0] = dz

    @staticmethod
    def partials(t, z, v, T_c, T_s, v_s, delta, sigma0, sigma1, D, dfdx, dfdu, dydx,
                 dydu):
        """State ``z``, input ``v``, output ``tau``::

            d(dz/dt)/dz = -sigma0 |v| / g
            d(dz/dt)/dv = 1 - sigma0 z (sgn(v) g - |v| g') / g^2,
                          g' = -(T_s - T_c) exp(-r^delta) delta r^(delta-1) sgn(v) / v_s
            dtau/dz = sigma0 + sigma1 d(dz/dt)/dz,  dtau/dv = sigma1 d(dz/dt)/dv + D

        (``r = |v / v_s|``; at ``v = 0`` the kink of ``|v|`` is taken with ``sgn(0) = 0``;
        with ``g = 0`` (``T_c = T_s = 0``), ``dz/dt = 0``).
        """
        a, b = lugre_slopes_jit(v[0], z[0], T_c, T_s, v_s, delta, sigma0)
        dfdx[0, 0] = a
        dfdu[0, 0] = b
        dydx[0, 0] = sigma0 + sigma1 * a
        dydu[0, 0] = sigma1 * b + D
