"""spidersim: a causal block-diagram simulator for servomechanisms and robot arms.

Quick use::

    import spidersim
    d = spidersim.load("diagrams/servo.yaml", set={"motor.R": 1.2})
    r = d.simulate(t_end=0.5)
    r.t, r["motor.w"], r.stats
"""
from .solver.compiled import refresh_kernel_caches

refresh_kernel_caches()  # before any kernel loads machine code that a source edit outdated
from . import blocks  # noqa: E402,F401  (registers the block library)
from .diagram.analysis import AnalysisError, OperatingPoint, linearize, loop_transfer, trim
from .diagram.model import Diagram, load, loads
from .errors import (AlgebraicLoopError, BlockTypeError, DiagramError, IntegrationError,
                     ParameterError, ResultError, SignalError, SpidersimError, WiringError)
from .solver.result import Result

__version__ = "0.1.0"
__all__ = ["Diagram", "load", "loads", "Result", "linearize", "loop_transfer", "trim",
           "OperatingPoint", "AnalysisError", "SpidersimError", "DiagramError",
           "BlockTypeError", "ParameterError", "WiringError", "AlgebraicLoopError",
           "IntegrationError", "ResultError", "SignalError"]
