"""What a mechanism is: the scene dataclasses, motions, the TOML reader, the variable table."""

from .reader import load_scene, scene_from_dict
from .scene import Scene, rod_inertia
from .variables import parameters, with_parameters

__all__ = ["Scene", "load_scene", "scene_from_dict", "rod_inertia", "parameters",
           "with_parameters"]
