"""Rigid-body algorithms for serial chains (kinematics, RNEA, mass matrix, forward dynamics,
base wrench), compiled with numba; used by the arm block and usable on their own.

    from spidersim.multibody import Chain
    arm = Chain.from_yaml()       # SPIDER-like data shipped with spidersim
"""
from .chain import SPIDER, Chain

__all__ = ["Chain", "SPIDER"]
