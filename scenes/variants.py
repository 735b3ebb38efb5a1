"""Variants of the shipped scenes that tests and benchmarks share, as TOML text, so that
each is written once: the stiff spring (stiff_spring.toml) pushed across by a force the
master sets, and hung from a second body pinned off its centre; crane_stop with an
actuator force in its cylinder."""

from __future__ import annotations

# a force input on the bob, across the spring ("push.fx", "push.fy")
PUSH = """
[[force]]
name = "push"
type = "force"
body = "bob"
point = [0.0, 0.0]
input = true
"""
# a second body pinned to the ground 0.1 m off its centre (a revolute whose rows depend on
# the hook's angle, and a spring force Jacobian that couples two bodies)
HOOK = """
[[body]]
name = "hook"
mass = 1.0
inertia = 1.0
position = [-0.1, 0.0]
[[joint]]
name = "pin"
type = "revolute"
body_i = "ground"
point_i = [0.0, 0.0]
body_j = "hook"
point_j = [0.1, 0.0]
"""
GROUND_END = 'body_i = "ground"\npoint_i = [0.0, 0.0]'


def pushed(text: str) -> str:
    """The stiff spring's scene text with the push input on its bob."""
    return text + PUSH


def hooked(text: str) -> str:
    """The stiff spring's scene text with its ground end moved to the hook's pin, the
    hook added, and the push."""
    if GROUND_END not in text:
        raise ValueError("the stiff spring's text has no spring end at the ground's origin")
    return text.replace(GROUND_END, 'body_i = "hook"\npoint_i = [0.1, 0.0]') + HOOK + PUSH


# crane_stop.toml with an actuator force between its cylinder's barrel and rod, along the
# stroke (N, positive pushing them apart, as a hydraulic cylinder's): "cylinder.actuator"
CYLINDER = """
[[force]]
name = "cylinder"
type = "spring_damper"
body_i = "barrel"
point_i = [0.0, 0.0]
body_j = "rod"
point_j = [0.0, 0.0]
stiffness = 0.0
damping = 0.0
rest_length = 0.0
actuator_input = true
"""
