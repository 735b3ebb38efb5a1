"""What a mechanism is: the scene model and its TOML reader.

A scene is a set of frozen dataclasses. ``load_scene`` reads a TOML file with the standard
library's ``tomllib``, checks every item and raises one ``SceneError`` that lists every
problem, each located by file and item. Nothing in a scene is ever evaluated as code.

Conventions (SI units, radians): body positions are those of the centre of mass in the
ground frame; ``point_*`` are body-fixed coordinates relative to the centre of mass (for
``ground``: relative to the origin); ``inertia`` is about the centre of mass.
"""

from __future__ import annotations

import dataclasses
import difflib
import math
import re
import sys
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal

from .errors import SceneError
from .motion import MOTION_TYPES, InputMotion, Motion

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover - Python 3.10 (FMUs read their scene as JSON and need no TOML)
    try:
        import tomli as tomllib
    except ModuleNotFoundError:
        tomllib = None

GROUND = "ground"
RESERVED_NAMES = {GROUND, "energy", "constraint", "time", "gravity", "solver"}
NAME_PATTERN = re.compile(r"^[A-Za-z_][A-Za-z0-9_]*$")

Vec2 = tuple[float, float]


@dataclass(frozen=True)
class Body:
    """A rigid body: mass (kg), inertia about its centre of mass (kg m^2), initial state."""

    name: str
    mass: float
    inertia: float
    position: Vec2
    angle: float = 0.0
    velocity: Vec2 = (0.0, 0.0)
    angular_velocity: float = 0.0


@dataclass(frozen=True)
class Joint:
    """A revolute or translational joint between body_i and body_j.

    Revolute: point_i of body_i and point_j of body_j coincide.
    Translational: point_j stays on the line through point_i along axis_i (body_i frame),
    and the relative rotation stays at its initial value.
    Reactions are reported on body_j in the joint frame: body_j's frame rotated by
    ``frame_angle`` (revolute), or the sliding axis rotated by ``frame_angle`` (translational).
    """

    name: str
    type: Literal["revolute", "translational"]
    body_i: str
    point_i: Vec2
    body_j: str
    point_j: Vec2
    axis_i: Vec2 | None = None
    frame_angle: float = 0.0


@dataclass(frozen=True)
class Driver:
    """A prescribed motion of a joint's relative coordinate or of a body's coordinate."""

    name: str
    motion: Motion
    joint: str | None = None
    body: str | None = None
    coordinate: Literal["angle", "x", "y"] | None = None


@dataclass(frozen=True)
class PointForce:
    """A force at a body point, components in the ground frame (N)."""

    name: str
    body: str
    point: Vec2
    value: Vec2 = (0.0, 0.0)
    input: bool = False


@dataclass(frozen=True)
class Torque:
    """A torque on a body (N m, counter-clockwise positive)."""

    name: str
    body: str
    value: float = 0.0
    input: bool = False


@dataclass(frozen=True)
class SpringDamper:
    """A linear spring-damper between two points; tension k (L - L0) + c L'.

    With ``actuator_input`` an input force along the line is added, positive pushing the
    points apart.
    """

    name: str
    body_i: str
    point_i: Vec2
    body_j: str
    point_j: Vec2
    stiffness: float
    damping: float = 0.0
    rest_length: float = 0.0
    actuator_input: bool = False


@dataclass(frozen=True)
class RotationalSpringDamper:
    """A torsional spring-damper on a revolute joint: torque on body_j
    -k (theta - theta0) - c theta', theta = phi_j - phi_i."""

    name: str
    joint: str
    stiffness: float
    damping: float = 0.0
    rest_angle: float = 0.0


Force = PointForce | Torque | SpringDamper | RotationalSpringDamper


@dataclass(frozen=True)
class SimulationSettings:
    """Defaults for a run of this scene (and the FMU's DefaultExperiment)."""

    t_end: float = 1.0
    output_interval: float | None = None
    method: str | None = None
    step: float | None = None
    rtol: float | None = None
    atol: float | None = None


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

    def body_index(self, name: str) -> int:
        """Index of a body in ``bodies``; -1 for ground."""
        if name == GROUND:
            return -1
        for k, body in enumerate(self.bodies):
            if body.name == name:
                return k
        raise KeyError(name)

    def joint(self, name: str) -> Joint:
        return next(j for j in self.joints if j.name == name)


# --------------------------------------------------------------------------- reading


class _Problems:
    """Collects located problems; ``raise_if_any`` raises them all at once."""

    def __init__(self, source: str):
        self.source = source
        self.items: list[str] = []

    def add(self, where: str, what: str) -> None:
        self.items.append(f"{self.source}: {where}: {what}" if where else f"{self.source}: {what}")

    def raise_if_any(self) -> None:
        if self.items:
            raise SceneError(self.items)


def _suggest(word: str, choices) -> str:
    close = difflib.get_close_matches(word, list(choices), n=1)
    return f' (did you mean "{close[0]}"?)' if close else ""


class _Table:
    """Typed, located access to one TOML table; remembers which keys were read."""

    def __init__(self, data: Any, where: str, problems: _Problems):
        self.where, self.problems = where, problems
        self.data = data if isinstance(data, dict) else {}
        if not isinstance(data, dict):
            problems.add(where, "must be a table")
        self.known: set[str] = set()
        self.ok = True

    def _fail(self, what: str):
        self.ok = False
        self.problems.add(self.where, what)
        return None

    def get(self, key: str, kind: str, default: Any = ..., *, positive=False, nonnegative=False):
        """Read ``key`` as kind 'float' | 'vec2' | 'str' | 'bool' | 'floats'; ``...`` = required."""
        self.known.add(key)
        if key not in self.data:
            if default is ...:
                return self._fail(f'missing required key "{key}"')
            return default
        value = self.data[key]
        if kind == "float":
            if isinstance(value, bool) or not isinstance(value, (int, float)):
                return self._fail(f'"{key}" must be a number, got {value!r}')
            value = float(value)
            if not math.isfinite(value):
                return self._fail(f'"{key}" must be finite, got {value}')
            if positive and value <= 0:
                return self._fail(f'"{key}" must be positive, got {value:g}')
            if nonnegative and value < 0:
                return self._fail(f'"{key}" must not be negative, got {value:g}')
            return value
        if kind in ("vec2", "floats"):
            if not isinstance(value, list) or (kind == "vec2" and len(value) != 2) or not value:
                shape = "a list of two numbers" if kind == "vec2" else "a non-empty list of numbers"
                return self._fail(f'"{key}" must be {shape}, got {value!r}')
            out = []
            for v in value:
                if isinstance(v, bool) or not isinstance(v, (int, float)):
                    return self._fail(f'"{key}" must hold numbers, got {v!r}')
                if not math.isfinite(v):
                    return self._fail(f'"{key}" must be finite, got {v}')
                out.append(float(v))
            return tuple(out)
        if kind == "str":
            if not isinstance(value, str):
                return self._fail(f'"{key}" must be a string, got {value!r}')
            return value
        if kind == "bool":
            if not isinstance(value, bool):
                return self._fail(f'"{key}" must be true or false, got {value!r}')
            return value
        raise ValueError(kind)  # a programming error, not a user one

    def finish(self) -> None:
        for key in self.data:
            if key not in self.known:
                self.problems.add(self.where, f'unknown key "{key}"{_suggest(key, self.known)}')
                self.ok = False


def _label(kind: str, table: Any, index: int) -> str:
    name = table.get("name") if isinstance(table, dict) else None
    return f'{kind} "{name}"' if isinstance(name, str) else f"{kind} #{index + 1}"


JOINT_TYPES = ("revolute", "translational")
FORCE_TYPES = ("force", "torque", "spring_damper", "rotational_spring_damper")
COORDINATES = ("angle", "x", "y")


def _read_motion(t: _Table) -> Motion | None:
    raw = t.data.get("motion")
    t.known.add("motion")
    if raw is None:
        return t._fail('missing required key "motion"')
    m = _Table(raw, t.where + ": motion", t.problems)
    kind = m.get("type", "str")
    if kind is None:
        return None
    if kind not in MOTION_TYPES:
        return m._fail(f'unknown motion type "{kind}"{_suggest(kind, MOTION_TYPES)}; '
                       f"expected one of {', '.join(MOTION_TYPES)}")
    cls, required, optional = MOTION_TYPES[kind]
    args = {}
    for key in required:
        args[key] = m.get(key, "floats" if key == "coefficients" else "float")
    for key, default in optional.items():
        args[key] = m.get(key, "float", default)
    if kind == "harmonic" and args.get("frequency") is not None and args["frequency"] < 0:
        m._fail('"frequency" must not be negative')
    m.finish()
    if not m.ok:
        t.ok = False
        return None
    return cls(**args)


def _read_item(kind: str, raw: Any, where: str, problems: _Problems):
    t = _Table(raw, where, problems)
    name = t.get("name", "str")
    out = None
    if kind == "body":
        out = Body(
            name=name,
            mass=t.get("mass", "float", positive=True),
            inertia=t.get("inertia", "float", positive=True),
            position=t.get("position", "vec2"),
            angle=t.get("angle", "float", 0.0),
            velocity=t.get("velocity", "vec2", (0.0, 0.0)),
            angular_velocity=t.get("angular_velocity", "float", 0.0),
        )
    elif kind == "joint":
        jtype = t.get("type", "str")
        if jtype is not None and jtype not in JOINT_TYPES:
            t._fail(f'unknown joint type "{jtype}"{_suggest(jtype, JOINT_TYPES)}; '
                    f"expected one of {', '.join(JOINT_TYPES)}")
        axis = None
        if jtype == "translational":
            axis = t.get("axis_i", "vec2")
            if axis is not None and math.hypot(*axis) < 1e-12:
                t._fail('"axis_i" has zero length')
        out = Joint(
            name=name, type=jtype,
            body_i=t.get("body_i", "str"), point_i=t.get("point_i", "vec2", (0.0, 0.0)),
            body_j=t.get("body_j", "str"), point_j=t.get("point_j", "vec2", (0.0, 0.0)),
            axis_i=axis, frame_angle=t.get("frame_angle", "float", 0.0),
        )
    elif kind == "driver":
        joint = t.get("joint", "str", None)
        body = t.get("body", "str", None)
        coordinate = t.get("coordinate", "str", None)
        if (joint is None) == (body is None):
            t._fail('needs exactly one of "joint" or "body" (with "coordinate")')
        if body is not None and coordinate not in COORDINATES:
            t._fail(f'"coordinate" must be one of {", ".join(COORDINATES)}, got {coordinate!r}')
        if joint is not None and coordinate is not None:
            t._fail('"coordinate" goes with "body", not with "joint"')
        out = Driver(name=name, motion=_read_motion(t), joint=joint, body=body,
                     coordinate=coordinate)
    elif kind == "force":
        ftype = t.get("type", "str")
        if ftype == "force":
            is_input = t.get("input", "bool", False)
            value = t.get("value", "vec2", (0.0, 0.0) if is_input else ...)
            out = PointForce(name=name, body=t.get("body", "str"),
                             point=t.get("point", "vec2", (0.0, 0.0)), value=value,
                             input=is_input)
        elif ftype == "torque":
            is_input = t.get("input", "bool", False)
            value = t.get("value", "float", 0.0 if is_input else ...)
            out = Torque(name=name, body=t.get("body", "str"), value=value, input=is_input)
        elif ftype == "spring_damper":
            out = SpringDamper(
                name=name,
                body_i=t.get("body_i", "str"), point_i=t.get("point_i", "vec2", (0.0, 0.0)),
                body_j=t.get("body_j", "str"), point_j=t.get("point_j", "vec2", (0.0, 0.0)),
                stiffness=t.get("stiffness", "float", nonnegative=True),
                damping=t.get("damping", "float", 0.0, nonnegative=True),
                rest_length=t.get("rest_length", "float", 0.0, nonnegative=True),
                actuator_input=t.get("actuator_input", "bool", False),
            )
        elif ftype == "rotational_spring_damper":
            out = RotationalSpringDamper(
                name=name, joint=t.get("joint", "str"),
                stiffness=t.get("stiffness", "float", nonnegative=True),
                damping=t.get("damping", "float", 0.0, nonnegative=True),
                rest_angle=t.get("rest_angle", "float", 0.0),
            )
        elif ftype is not None:
            t._fail(f'unknown force type "{ftype}"{_suggest(ftype, FORCE_TYPES)}; '
                    f"expected one of {', '.join(FORCE_TYPES)}")
    t.finish()
    return out if t.ok else None


def _check_references(scene_items: dict[str, list], problems: _Problems) -> None:
    bodies = [b.name for b in scene_items["body"]]
    body_names = set(bodies) | {GROUND}
    joints = {j.name: j for j in scene_items["joint"]}

    def body_ref(where: str, key: str, value: str) -> None:
        if value not in body_names:
            problems.add(where, f'{key}: unknown body "{value}"{_suggest(value, body_names)}')

    for j in scene_items["joint"]:
        where = f'joint "{j.name}"'
        body_ref(where, "body_i", j.body_i)
        body_ref(where, "body_j", j.body_j)
        if j.body_i == j.body_j:
            problems.add(where, f'joins body "{j.body_i}" to itself')
    for d in scene_items["driver"]:
        where = f'driver "{d.name}"'
        if d.joint is not None and d.joint not in joints:
            problems.add(where, f'unknown joint "{d.joint}"{_suggest(d.joint, joints)}')
        if d.body is not None:
            if d.body == GROUND:
                problems.add(where, "cannot drive the ground")
            else:
                body_ref(where, "body", d.body)
    for f in scene_items["force"]:
        where = f'force "{f.name}"'
        if isinstance(f, (PointForce, Torque)):
            if f.body == GROUND:
                problems.add(where, "acts on the ground, which is fixed: name a moving body")
            else:
                body_ref(where, "body", f.body)
        elif isinstance(f, SpringDamper):
            body_ref(where, "body_i", f.body_i)
            body_ref(where, "body_j", f.body_j)
        elif isinstance(f, RotationalSpringDamper):
            if f.joint not in joints:
                problems.add(where, f'unknown joint "{f.joint}"{_suggest(f.joint, joints)}')
            elif joints[f.joint].type != "revolute":
                problems.add(where, f'joint "{f.joint}" is {joints[f.joint].type}, not revolute')


def _check_names(scene_items: dict[str, list], problems: _Problems) -> None:
    seen: dict[str, str] = {}
    for kind, items in scene_items.items():
        for item in items:
            where = f'{kind} "{item.name}"'
            if not NAME_PATTERN.match(item.name):
                problems.add(where, "name must be an identifier (letters, digits, _)")
            elif item.name in RESERVED_NAMES:
                problems.add(where, f'"{item.name}" is a reserved name')
            if item.name in seen:
                problems.add(where, f"duplicate name (also a {seen[item.name]})")
            seen.setdefault(item.name, kind)


def scene_from_dict(data: dict, source: str = "<scene>") -> Scene:
    """Build and check a Scene from parsed TOML; raises SceneError listing every problem."""
    problems = _Problems(source)
    top = _Table(data, "", problems)
    name = top.get("name", "str")
    if name is not None and not NAME_PATTERN.match(name):
        problems.add("name", f'"{name}" must be a valid identifier (it names the FMU)')
    description = top.get("description", "str", "")
    version = top.get("version", "str", "0.1.0")
    author = top.get("author", "str", "")
    gravity = top.get("gravity", "vec2", (0.0, -9.81))
    outputs = None
    if "outputs" in data:
        top.known.add("outputs")
        raw = data["outputs"]
        if not isinstance(raw, list) or not all(isinstance(p, str) for p in raw):
            problems.add("outputs", "must be a list of glob patterns (strings)")
        else:
            outputs = tuple(raw)

    settings = SimulationSettings()
    if "simulation" in data:
        top.known.add("simulation")
        s = _Table(data["simulation"], "simulation", problems)
        method = s.get("method", "str", None)
        settings = SimulationSettings(
            t_end=s.get("t_end", "float", 1.0, positive=True),
            output_interval=s.get("output_interval", "float", None, positive=True),
            method=method,
            step=s.get("step", "float", None, positive=True),
            rtol=s.get("rtol", "float", None, positive=True),
            atol=s.get("atol", "float", None, positive=True),
        )
        s.finish()

    items: dict[str, list] = {"body": [], "joint": [], "driver": [], "force": []}
    for kind in items:
        top.known.add(kind)
        raw_list = data.get(kind, [])
        if not isinstance(raw_list, list):
            problems.add(kind, f"must be an array of tables ([[{kind}]])")
            continue
        for k, raw in enumerate(raw_list):
            item = _read_item(kind, raw, _label(kind, raw, k), problems)
            if item is not None:
                items[kind].append(item)
    top.finish()
    if not data.get("body"):
        problems.add("", "a scene needs at least one [[body]]")
    _check_names(items, problems)
    _check_references(items, problems)
    problems.raise_if_any()
    return Scene(
        name=name, description=description, version=version, author=author,
        gravity=gravity, outputs=outputs, simulation=settings, source=source,
        bodies=tuple(items["body"]), joints=tuple(items["joint"]),
        drivers=tuple(items["driver"]), forces=tuple(items["force"]),
    )


def load_scene(path: str | Path) -> Scene:
    """Read and check a scene file (TOML). Raises SceneError naming file, item and problem."""
    path = Path(path)
    source = path.name
    if tomllib is None:  # pragma: no cover
        raise SceneError(f"{source}: reading TOML needs Python 3.11 or the tomli package")
    try:
        text = path.read_text(encoding="utf-8")
    except OSError as exc:
        raise SceneError(f"{path}: cannot read: {exc.strerror or exc}") from None
    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise SceneError(f"{source}: invalid TOML: {exc}") from None
    return scene_from_dict(data, source=source)


# --------------------------------------------------------------------------- parameters


@dataclass(frozen=True)
class Parameter:
    """A scene constant that a user (or an FMU's importer) may change before a run."""

    name: str
    value: float
    unit: str
    description: str


_MOTION_UNITS = {"frequency": "Hz", "phase": "rad"}


def _driver_unit(scene: Scene, driver: Driver) -> tuple[str, str]:
    """(position unit, effort unit) of a driver."""
    if driver.joint is not None:
        angular = scene.joint(driver.joint).type == "revolute"
    else:
        angular = driver.coordinate == "angle"
    return ("rad", "N.m") if angular else ("m", "N")


def parameters(scene: Scene) -> list[Parameter]:
    """Every constant of the scene that may be changed before a run, with unit."""
    out = [Parameter("gravity.x", scene.gravity[0], "m/s2", "gravity, x component"),
           Parameter("gravity.y", scene.gravity[1], "m/s2", "gravity, y component")]
    for b in scene.bodies:
        out.append(Parameter(f"{b.name}.mass", b.mass, "kg", f"mass of {b.name}"))
        out.append(Parameter(f"{b.name}.inertia", b.inertia, "kg.m2",
                             f"moment of inertia of {b.name} about its centre of mass"))
    for d in scene.drivers:
        pos_unit, _ = _driver_unit(scene, d)
        m = d.motion
        if isinstance(m, InputMotion):
            continue
        for f in dataclasses.fields(m):
            value = getattr(m, f.name)
            if f.name == "coefficients":
                for k, c in enumerate(value):
                    unit = pos_unit if k == 0 else f"{pos_unit}/s{k}" if k > 1 else f"{pos_unit}/s"
                    out.append(Parameter(f"{d.name}.c{k}", c, unit,
                                         f"coefficient of t^{k} in {d.name}'s motion"))
                continue
            unit = _MOTION_UNITS.get(f.name, f"{pos_unit}/s" if f.name == "rate" else pos_unit)
            out.append(Parameter(f"{d.name}.{f.name}", value, unit,
                                 f"{f.name} of {d.name}'s {type(m).__name__}"))
    for f in scene.forces:
        if isinstance(f, PointForce) and not f.input:
            out.append(Parameter(f"{f.name}.fx", f.value[0], "N", f"{f.name}, x component"))
            out.append(Parameter(f"{f.name}.fy", f.value[1], "N", f"{f.name}, y component"))
        elif isinstance(f, Torque) and not f.input:
            out.append(Parameter(f"{f.name}.torque", f.value, "N.m", f"{f.name}"))
        elif isinstance(f, SpringDamper):
            out += [Parameter(f"{f.name}.stiffness", f.stiffness, "N/m", "spring stiffness"),
                    Parameter(f"{f.name}.damping", f.damping, "N.s/m", "damping coefficient"),
                    Parameter(f"{f.name}.rest_length", f.rest_length, "m", "spring rest length")]
        elif isinstance(f, RotationalSpringDamper):
            out += [Parameter(f"{f.name}.stiffness", f.stiffness, "N.m/rad", "torsional stiffness"),
                    Parameter(f"{f.name}.damping", f.damping, "N.m.s/rad", "torsional damping"),
                    Parameter(f"{f.name}.rest_angle", f.rest_angle, "rad", "spring rest angle")]
    return out


def with_parameters(scene: Scene, values: dict[str, float]) -> Scene:
    """A copy of ``scene`` with the named parameters (see ``parameters``) changed."""
    known = {p.name for p in parameters(scene)}
    problems = _Problems(scene.source)
    for key, value in values.items():
        if key not in known:
            problems.add("parameters", f'unknown parameter "{key}"{_suggest(key, known)}')
        elif not math.isfinite(value):
            problems.add("parameters", f'"{key}" must be finite, got {value}')
        elif key.endswith((".mass", ".inertia")) and value <= 0:
            problems.add("parameters", f'"{key}" must be positive, got {value:g}')
    problems.raise_if_any()
    v = {k: float(x) for k, x in values.items()}

    def pick(prefix: str, attr: str, current):
        return v.get(f"{prefix}.{attr}", current)

    gravity = (pick("gravity", "x", scene.gravity[0]), pick("gravity", "y", scene.gravity[1]))
    bodies = tuple(dataclasses.replace(b, mass=pick(b.name, "mass", b.mass),
                                       inertia=pick(b.name, "inertia", b.inertia))
                   for b in scene.bodies)
    drivers = []
    for d in scene.drivers:
        m = d.motion
        if not isinstance(m, InputMotion):
            changes = {}
            for f in dataclasses.fields(m):
                if f.name == "coefficients":
                    changes[f.name] = tuple(pick(d.name, f"c{k}", c) for k, c in enumerate(m.coefficients))
                else:
                    changes[f.name] = pick(d.name, f.name, getattr(m, f.name))
            m = dataclasses.replace(m, **changes)
        drivers.append(dataclasses.replace(d, motion=m))
    forces = []
    for f in scene.forces:
        if isinstance(f, PointForce) and not f.input:
            f = dataclasses.replace(f, value=(pick(f.name, "fx", f.value[0]), pick(f.name, "fy", f.value[1])))
        elif isinstance(f, Torque) and not f.input:
            f = dataclasses.replace(f, value=pick(f.name, "torque", f.value))
        elif isinstance(f, SpringDamper):
            f = dataclasses.replace(f, stiffness=pick(f.name, "stiffness", f.stiffness),
                                    damping=pick(f.name, "damping", f.damping),
                                    rest_length=pick(f.name, "rest_length", f.rest_length))
        elif isinstance(f, RotationalSpringDamper):
            f = dataclasses.replace(f, stiffness=pick(f.name, "stiffness", f.stiffness),
                                    damping=pick(f.name, "damping", f.damping),
                                    rest_angle=pick(f.name, "rest_angle", f.rest_angle))
        forces.append(f)
    return dataclasses.replace(scene, gravity=gravity, bodies=bodies, drivers=tuple(drivers),
                               forces=tuple(forces))


def rod_inertia(mass: float, length: float) -> float:
    """Moment of inertia of a uniform slender rod about its centre: m L^2 / 12."""
    return mass * length * length / 12.0
