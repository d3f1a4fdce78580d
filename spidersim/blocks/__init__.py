"""The block library. Importing this package registers every block type.

See :mod:`spidersim.blocks.base` for the contract a block implements.
"""
from . import (arm, contact, continuous, controllers, discrete, electromechanical,
               force_control, friction, gearbox, mathops, mechanics, nonlinear, routing,
               sensors, sources, trajectory)
from .base import REGISTRY, Block, Dim, Event, FromInputs, Mode, Param, Port, State, lookup

__all__ = ["REGISTRY", "Block", "Dim", "Event", "FromInputs", "Mode", "Param", "Port", "State",
           "lookup", "arm", "contact", "continuous", "controllers", "discrete",
           "electromechanical", "force_control", "friction", "gearbox", "mathops",
           "mechanics", "nonlinear", "routing", "sensors", "sources", "trajectory"]
