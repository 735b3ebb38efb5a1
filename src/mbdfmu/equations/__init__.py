"""The equations of motion of a scene: constraints, forces, eq. (14), reactions.

Pure functions of (t, q, q') and the inputs; see ``docs/formulation.md`` for the equations
and their numbers.
"""

from .dynamics import Equations

__all__ = ["Equations"]
