"""Analysis of a scene beyond a run: static equilibrium, linearization, parameter sweeps.

Above the simulation layer: these use the equations, the projections and ``Simulation``;
nothing below imports them.
"""

from .equilibrium import Equilibrium, equilibrium
from .linearize import Linearization, linearize

__all__ = ["Equilibrium", "equilibrium", "Linearization", "linearize"]
