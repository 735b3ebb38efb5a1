"""mbdfmu: planar multibody dynamics in absolute coordinates, packaged as FMI 2.0 FMUs.

    >>> import mbdfmu
    >>> scene = mbdfmu.load_scene("slider_crank")          # a file, or a shipped scene
    >>> result = mbdfmu.simulate(scene, t_end=0.1)
    >>> result["motor.effort"]
    >>> mbdfmu.linearize("double_pendulum", equilibrium=True).frequencies_hz
"""

from .errors import (AccuracyError, AssemblyError, InputError, MbdfmuError, SceneError,
                     SettingError, SolverError)
from .integrators import METHOD_NAMES, METHODS, SolverSettings
from .model import Scene, load_scene, parameters, rod_inertia, with_parameters
from .result import Result, read_csv
from .simulation import Simulation, simulate

__version__ = "0.1.0"

# The analysis layer (linearize, equilibrium) sits above the simulation and is imported on
# first use: an FMU ships this file without it (fmu_build.scene_fmu.SHIPPED_PACKAGES).
_ANALYSIS = ("Equilibrium", "Linearization", "equilibrium", "linearize")


def __getattr__(name: str):
    if name in _ANALYSIS:
        from . import analysis
        return getattr(analysis, name)
    raise AttributeError(f"module 'mbdfmu' has no attribute {name!r}")

__all__ = ["AccuracyError", "AssemblyError", "InputError", "MbdfmuError", "SceneError",
           "SettingError", "SolverError", "METHODS", "METHOD_NAMES", "SolverSettings", "Result", "read_csv",
           "Scene", "load_scene", "parameters", "rod_inertia", "with_parameters",
           "Simulation", "simulate", "Equilibrium", "Linearization", "equilibrium", "linearize",
           "__version__"]
