"""Contact modes of a scene with end stops and Coulomb friction, as scenes.

Each joint with ``limits`` or ``friction`` is, at any time, in one state (``JointMode``):
free, resting against its lower or upper stop, sticking, or sliding up or down. A joint
resting or sticking has its coordinate held: ``mode_scene`` adds a constant driver of that
coordinate after the scene's own drivers, so its row comes last and its effort is the
generalized force of the stop or of static friction (formulation.md eq. 29).
"""

from __future__ import annotations

import dataclasses
import itertools
from typing import Iterator, NamedTuple

from .motion import ConstantMotion
from .scene import Driver, LimitedJoint, Scene

FREE, LOWER, UPPER, STICK, SLIDE_UP, SLIDE_DOWN = ("free", "lower", "upper", "stick",
                                                    "slide up", "slide down")
HELD = (LOWER, UPPER, STICK)


class JointMode(NamedTuple):
    """One event joint's state; ``held`` the coordinate value its driver row holds."""

    state: str
    held: float = 0.0


def event_joints(scene: Scene) -> list[int]:
    """Indices of the joints with end stops or friction, in scene order."""
    return [k for k, j in enumerate(scene.joints)
            if isinstance(j, LimitedJoint) and (j.limits is not None or j.friction is not None)]


def joint_states(joint: LimitedJoint) -> tuple[str, ...]:
    """The states an event joint can be in: free, or with friction sticking or sliding
    either way; with limits, resting on either stop too."""
    moving = (FREE,) if joint.friction is None else (STICK, SLIDE_UP, SLIDE_DOWN)
    return moving + ((LOWER, UPPER) if joint.limits is not None else ())


def every_mode(scene: Scene) -> Iterator[dict[int, JointMode]]:
    """Every combination of the event joints' states, each a contact mode (a resting
    joint held at its stop, a sticking one at 0: where it sticks changes no structure)."""
    joints = event_joints(scene)
    for states in itertools.product(*(joint_states(scene.joints[k]) for k in joints)):
        yield {k: JointMode(s, _held_at(scene.joints[k], s)) for k, s in zip(joints, states)}


def _held_at(joint: LimitedJoint, state: str) -> float:
    return joint.limits[0] if state == LOWER else joint.limits[1] if state == UPPER else 0.0


def hold_driver_name(joint_name: str) -> str:
    return f"{joint_name}__held"


def mode_scene(scene: Scene, mode: dict[int, JointMode]) -> Scene:
    """The scene with a constant driver holding each resting or sticking joint's coordinate."""
    extra = tuple(Driver(name=hold_driver_name(scene.joints[k].name),
                         motion=ConstantMotion(m.held), joint=scene.joints[k].name)
                  for k, m in mode.items() if m.state in HELD)
    return dataclasses.replace(scene, drivers=scene.drivers + extra) if extra else scene


def slip_text(state: str) -> str:
    """A sliding state in a log line."""
    return "its coordinate rising" if state == SLIDE_UP else "its coordinate falling"


def sliding(mode: dict[int, JointMode]) -> dict[int, int]:
    """{joint index: +1 or -1} of the sliding joints that have friction."""
    return {k: (1 if m.state == SLIDE_UP else -1) for k, m in mode.items()
            if m.state in (SLIDE_UP, SLIDE_DOWN)}
