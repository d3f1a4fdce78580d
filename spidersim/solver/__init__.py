"""Numerical core: compiled systems, integration with time events, results.

Never imports :mod:`spidersim.blocks` or :mod:`spidersim.diagram`: it sees the small
``System`` contract of :mod:`spidersim.solver.system`.
"""
from .integrate import METHODS, integrate
from .result import Result
from .system import CompiledSystem

__all__ = ["METHODS", "integrate", "Result", "CompiledSystem"]
