"""mbdfmu: planar multibody dynamics in absolute coordinates, packaged as FMI 2.0 FMUs.

    >>> import mbdfmu
    >>> scene = mbdfmu.load_scene("scenes/slider_crank.toml")
    >>> result = mbdfmu.simulate(scene, t_end=0.1)
    >>> result["motor.effort"]
"""

from .errors import AssemblyError, InputError, MbdfmuError, SceneError, SolverError
from .integrators import METHODS
from .result import Result, read_csv
from .scene import Scene, load_scene, parameters, rod_inertia, with_parameters
from .simulation import Simulation, simulate

__version__ = "0.1.0"

__all__ = ["AssemblyError", "InputError", "MbdfmuError", "SceneError", "SolverError",
           "METHODS", "Result", "read_csv", "Scene", "load_scene", "parameters",
           "rod_inertia", "with_parameters", "Simulation", "simulate", "__version__"]
