"""What a mechanism is: bodies, joints, drivers and forces, as frozen dataclasses.

Conventions (SI units, radians): body positions are those of the centre of mass in the
ground frame; ``point_*`` are body-fixed coordinates relative to the centre of mass (for
``ground``: relative to the origin); ``inertia`` is about the centre of mass.

Each class declares its scene keys once, as its fields (``key(kind, default, ...)``); the
reader (``reader.py``) reads any of them from that declaration, and the variable table
(``variables.py``) names what each item type offers as parameters, inputs and outputs.
Joint coordinates: a revolute joint's is ``phi_j - phi_i`` (rad); a translational joint's
is ``(r_Pj - r_Pi) . u_i`` (m), ``u_i`` its unit axis in the ground frame.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass, field

from .motion import InputMotion, Motion
from .toml_table import key

GROUND = "ground"
RESERVED_NAMES = {GROUND, "energy", "constraint", "time", "gravity", "solver"}
IDENTIFIER = re.compile(r"^[A-Za-z_][A-Za-z0-9_]*$")
COORDINATES = ("angle", "x", "y")
# How far (relative to its radius) a rolling disc's centre may start from its radius.
PLACEMENT_TOLERANCE = 1e-6

Vec2 = tuple[float, float]


@dataclass(frozen=True)
class Body:
    """A rigid body: mass (kg), inertia about its centre of mass (kg m^2), initial state."""

    name: str = key("str")
    mass: float = key("float", positive=True)
    inertia: float = key("float", positive=True)
    position: Vec2 = key("vec2")
    angle: float = key("float", 0.0)
    velocity: Vec2 = key("vec2", (0.0, 0.0))
    angular_velocity: float = key("float", 0.0)
    # The keys the scene file gave (None: every field, as for a body made in Python);
    # assembly reports a change only of what was given (``projection.assembly_changes``).
    given: frozenset[str] | None = field(default=None, compare=False, repr=False)

    def gave(self, name: str) -> bool:
        return self.given is None or name in self.given


@dataclass(frozen=True, kw_only=True)
class BodyPair:
    """What every joint between two bodies has: its name and the two bodies."""

    name: str = key("str")
    body_i: str = key("str", ref="body")
    body_j: str = key("str", ref="body")

    def problems(self) -> list[str]:
        return [f'joins body "{self.body_i}" to itself'] if self.body_i == self.body_j else []

    def summary(self) -> str:
        """What it joins, in a line (``mbdfmu check``)."""
        return f"{self.body_i} - {self.body_j}"


@dataclass(frozen=True, kw_only=True)
class TwoBodyJoint(BodyPair):
    """A joint with a point on each body (body-fixed, m) and the angle of the frame its
    reactions are reported in (rad)."""

    point_i: Vec2 = key("vec2", (0.0, 0.0))
    point_j: Vec2 = key("vec2", (0.0, 0.0))
    frame_angle: float = key("float", 0.0)


@dataclass(frozen=True)
class Friction:
    """Coulomb friction on a joint's coordinate: magnitude ``coulomb + coefficient * radius
    * |F|`` (revolute, |F| its reaction's magnitude; N.m) or ``coulomb + coefficient * |Fy|``
    (translational, Fy its normal reaction; N), opposing the coordinate's rate; it sticks
    while the force needed to hold is below that magnitude."""

    coulomb: float = key("float", 0.0, nonnegative=True)
    coefficient: float = key("float", 0.0, nonnegative=True)
    radius: float = key("float", 0.0, nonnegative=True)


@dataclass(frozen=True, kw_only=True)
class LimitedJoint(TwoBodyJoint):
    """A joint with a coordinate, which may have end stops and Coulomb friction:
    ``limits = [lower, upper]`` (rad or m) with Newton's ``restitution`` (0 to 1) at an
    impact, and ``friction`` (``Friction``)."""

    limits: Vec2 | None = key("vec2", None)
    restitution: float = key("float", 0.0)
    friction: Friction | None = key("table", None)

    def problems(self) -> list[str]:
        out = super().problems()
        if self.limits is not None and not self.limits[0] < self.limits[1]:
            out.append(f"limits: lower {self.limits[0]:g} is not below upper "
                       f"{self.limits[1]:g}")
        if not 0.0 <= self.restitution <= 1.0:
            out.append(f"restitution must be between 0 and 1, got {self.restitution:g}")
        elif self.restitution and self.limits is None:
            out.append("restitution needs limits = [lower, upper]")
        return out

    def summary(self) -> str:
        text = super().summary()
        if self.limits is not None:
            text += (f", limits [{self.limits[0]:g}, {self.limits[1]:g}] restitution "
                     f"{self.restitution:g}")
        if self.friction is not None:
            f = self.friction
            text += f", friction coulomb {f.coulomb:g} coefficient {f.coefficient:g}"
            text += f" radius {f.radius:g}" if f.radius else ""
        return text


@dataclass(frozen=True, kw_only=True)
class RevoluteJoint(LimitedJoint):
    """point_i of body_i and point_j of body_j coincide; rotation is free.

    Reactions are reported on body_j in the joint frame: body_j's frame turned by
    ``frame_angle``."""

    TYPE = "revolute"


@dataclass(frozen=True, kw_only=True)
class TranslationalJoint(LimitedJoint):
    """point_j stays on the line through point_i along ``axis_i`` (body_i's frame); the
    relative rotation stays at its initial value.

    Reactions are reported on body_j in the joint frame: the sliding axis turned by
    ``frame_angle`` (x along the axis: no force there)."""

    TYPE = "translational"
    axis_i: Vec2 = key("vec2", nonzero=True)

    def problems(self) -> list[str]:
        out = super().problems()
        if self.friction is not None and self.friction.radius:
            out.append("friction.radius is for revolute joints only (a translational "
                       "joint's friction grows with its normal reaction)")
        return out


@dataclass(frozen=True, kw_only=True)
class SlotJoint(TwoBodyJoint):
    """A pin in a straight slot: point_j (the pin) stays on the line through point_i along
    ``axis_i`` (body_i's frame); the relative rotation is free.

    Reactions are reported on body_j in the slot's frame (x along the axis, turned by
    ``frame_angle``): Fx = 0 (no friction), Fy the normal force."""

    TYPE = "slot"
    axis_i: Vec2 = key("vec2", nonzero=True)


@dataclass(frozen=True, kw_only=True)
class RollingJoint(BodyPair):
    """A disc (body_j, centred at its centre of mass) rolling without slipping on the line
    through point_i along ``axis_i`` (body_i's frame), on its left: the disc's centre stays at
    ``radius`` from the line along the axis turned by +90 degrees.

    Reactions are the contact force on the disc in the line's frame: Fx tangential (along
    the axis), Fy normal."""

    TYPE = "rolling"
    point_i: Vec2 = key("vec2", (0.0, 0.0))
    axis_i: Vec2 = key("vec2", nonzero=True)
    body_j: str = key("str", ref="moving body")
    radius: float = key("float", positive=True)

    def placement_problems(self, poses: dict) -> list[str]:
        """The disc's centre must start at ``radius`` on the left of the line (``poses``:
        body name -> (x, y, angle), the ground included)."""
        xi, yi, ai = poses[self.body_i]
        xj, yj, _ = poses[self.body_j]
        c, s = math.cos(ai), math.sin(ai)
        (sx, sy), (ux, uy) = self.point_i, self.axis_i
        px, py = xi + c * sx - s * sy, yi + s * sx + c * sy        # r_i + A_i s_i
        nx, ny = -(s * ux + c * uy), c * ux - s * uy               # A_i axis_i turned by +90
        distance = (nx * (xj - px) + ny * (yj - py)) / math.hypot(ux, uy)
        if abs(distance - self.radius) <= PLACEMENT_TOLERANCE * self.radius:
            return []
        return [f'the centre of body "{self.body_j}" starts {distance:.9g} m from the line '
                f'(positive on its left, axis_i turned by +90 degrees), not at the radius '
                f'{self.radius:g} m']


@dataclass(frozen=True)
class CouplerJoint:
    """Couples two joints' coordinates (gears, rack and pinion, belts):
    ``q_j - q_j0 = ratio (q_i - q_i0)``, from their values at the scene's initial positions.

    Its output is the effort: the generalized force it applies on joint_j's coordinate (the
    reaction to it, ``-ratio`` times it, acts on joint_i's)."""

    TYPE = "coupler"
    name: str = key("str")
    joint_i: str = key("str", ref="coordinate joint")
    joint_j: str = key("str", ref="coordinate joint")
    ratio: float = key("float", nonzero=True)

    def problems(self) -> list[str]:
        return [f'couples joint "{self.joint_i}" to itself'] if self.joint_i == self.joint_j else []

    def summary(self) -> str:
        return f"joint {self.joint_j} = {self.ratio:g} x joint {self.joint_i}"


@dataclass(frozen=True)
class Driver:
    """A prescribed motion of a joint's coordinate, or of a body's x, y or angle."""

    name: str = key("str")
    motion: Motion = key("table")
    joint: str | None = key("str", None, ref="coordinate joint")
    body: str | None = key("str", None, ref="moving body")
    coordinate: str | None = key("str", None)

    def problems(self) -> list[str]:
        out = []
        if (self.joint is None) == (self.body is None):
            out.append('needs exactly one of "joint" or "body" (with "coordinate")')
        if self.body is not None and self.coordinate not in COORDINATES:
            out.append(f'"coordinate" must be one of {", ".join(COORDINATES)}, '
                       f"got {self.coordinate!r}")
        if self.joint is not None and self.coordinate is not None:
            out.append('"coordinate" goes with "body", not with "joint"')
        return out

    @property
    def is_input(self) -> bool:
        return isinstance(self.motion, InputMotion)


@dataclass(frozen=True)
class PointForce:
    """A force at a body point, components in the ground frame (N)."""

    TYPE = "force"
    name: str = key("str")
    body: str = key("str", ref="moving body")
    point: Vec2 = key("vec2", (0.0, 0.0))
    value: Vec2 = key("vec2", (0.0, 0.0), required_unless="input")
    input: bool = key("bool", False)


@dataclass(frozen=True)
class Torque:
    """A torque on a body (N m, counter-clockwise positive)."""

    TYPE = "torque"
    name: str = key("str")
    body: str = key("str", ref="moving body")
    value: float = key("float", 0.0, required_unless="input")
    input: bool = key("bool", False)


@dataclass(frozen=True)
class SpringDamper:
    """A linear spring-damper between two points; tension k (L - L0) + c L'.

    With ``actuator_input`` an input force along the line is added, positive pushing the
    points apart."""

    TYPE = "spring_damper"
    name: str = key("str")
    body_i: str = key("str", ref="body")
    body_j: str = key("str", ref="body")
    stiffness: float = key("float", nonnegative=True)
    point_i: Vec2 = key("vec2", (0.0, 0.0))
    point_j: Vec2 = key("vec2", (0.0, 0.0))
    damping: float = key("float", 0.0, nonnegative=True)
    rest_length: float = key("float", 0.0, nonnegative=True)
    actuator_input: bool = key("bool", False)


@dataclass(frozen=True)
class RotationalSpringDamper:
    """A torsional spring-damper on a revolute joint: torque on body_j
    -k (theta - theta0) - c theta', theta = phi_j - phi_i."""

    TYPE = "rotational_spring_damper"
    name: str = key("str")
    joint: str = key("str", ref="revolute joint")
    stiffness: float = key("float", nonnegative=True)
    damping: float = key("float", 0.0, nonnegative=True)
    rest_angle: float = key("float", 0.0)


Joint = RevoluteJoint | TranslationalJoint | SlotJoint | RollingJoint | CouplerJoint
# Joints with a coordinate (what drivers, couplers and rotational springs act on).
COORDINATE_JOINTS = (RevoluteJoint, TranslationalJoint)


def has_events(scene: "Scene") -> bool:
    """The scene has end stops or Coulomb friction: its run locates events."""
    return any(isinstance(j, LimitedJoint) and (j.limits is not None or j.friction is not None)
               for j in scene.joints)
Force = PointForce | Torque | SpringDamper | RotationalSpringDamper
JOINT_TYPES: dict[str, type] = {cls.TYPE: cls for cls in (RevoluteJoint, TranslationalJoint,
                                                          SlotJoint, RollingJoint, CouplerJoint)}
FORCE_TYPES: dict[str, type] = {cls.TYPE: cls for cls in (PointForce, Torque, SpringDamper,
                                                          RotationalSpringDamper)}


@dataclass(frozen=True)
class SimulationSettings:
    """The scene's ``[simulation]`` table: defaults of a run (and of the FMU). Solver values
    are checked when a run builds its ``SolverSettings`` from them."""

    t_end: float = key("float", 1.0, positive=True)
    output_interval: float | None = key("float", None, positive=True)
    method: str | None = key("str", None)
    step: float | None = key("float", None, positive=True)
    rtol: float | None = key("float", None, positive=True)
    atol: float | None = key("float", None, positive=True)
    options: dict = key("table", {})


@dataclass(frozen=True)
class Scene:
    """A planar mechanism: bodies, joints, drivers and forces, in the ground frame."""

    name: str
    bodies: tuple[Body, ...]
    joints: tuple[Joint, ...] = ()
    drivers: tuple[Driver, ...] = ()
    forces: tuple[Force, ...] = ()
    gravity: Vec2 = (0.0, -9.81)
    description: str = ""
    version: str = "0.1.0"
    author: str = ""
    outputs: tuple[str, ...] | None = None
    simulation: SimulationSettings = field(default_factory=SimulationSettings)
    source: str = "<scene>"

    def joint(self, name: str) -> Joint:
        return next(j for j in self.joints if j.name == name)

    def body(self, name: str) -> Body:
        return next(b for b in self.bodies if b.name == name)


def driver_is_angular(scene: Scene, driver: Driver) -> bool:
    """A driver of an angle (revolute joint or body angle) rather than a length."""
    if driver.joint is not None:
        return isinstance(scene.joint(driver.joint), RevoluteJoint)
    return driver.coordinate == "angle"


def driven_body(scene: Scene, driver: Driver) -> str:
    """The body a driver's effort acts on: its body, or its joint's body_j."""
    return driver.body if driver.body is not None else scene.joint(driver.joint).body_j


def rod_inertia(mass: float, length: float) -> float:
    """Moment of inertia of a uniform slender rod about its centre: m L^2 / 12."""
    return mass * length * length / 12.0
