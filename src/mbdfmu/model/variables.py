"""The one variable table: what each item type offers as parameters, inputs and outputs.

Every name a user, a CSV column or an FMU sees is made here, from ``TABLES`` (one entry per
item class, like the one ``config.h`` of each Reference-FMUs model): ``parameters(scene)``
(constants that may change before a run), ``inputs(scene)`` (run-time signals),
``outputs(scene)`` (what a run reports, in the order the equations compute it),
``with_parameters`` (a scene with parameters changed) and ``input_layout`` (where each
input sits in the ``InputValues`` passed to the equations). Units: SI, with ``{pos}`` and
``{effort}`` standing for a driver's own (rad and N.m, or m and N) or a coupler's joint_j's,
and ``{ratio}`` for a coupler's ratio (1, m/rad or rad/m).
"""

from __future__ import annotations

import dataclasses
import fnmatch
import math
from dataclasses import dataclass

import numpy as np

from ..errors import Problems, SceneError, suggest
from .motion import ConstantMotion, HarmonicMotion, LinearMotion, PolynomialMotion
from .scene import (Body, CouplerJoint, Driver, PointForce, RevoluteJoint, RollingJoint,
                    RotationalSpringDamper, Scene, SlotJoint, SpringDamper, Torque,
                    TranslationalJoint, driver_is_angular, driven_body)


@dataclass(frozen=True)
class Variable:
    """A named scalar of a scene: a parameter, an input or an output."""

    name: str
    unit: str
    description: str


@dataclass(frozen=True)
class Parameter(Variable):
    """A scene constant that a user (or an FMU's importer) may change before a run."""

    value: float = 0.0


@dataclass(frozen=True)
class Spec:
    """One scalar an item type declares: ``<item>.<suffix>``.

    Parameters name the item ``field`` (and ``index`` in a vector) they set; ``when`` is an
    item attribute that must be true for the variable to exist (``"!input"``: false).
    """

    suffix: str
    unit: str
    description: str
    field: str | None = None
    index: int | None = None
    positive: bool = False
    nonnegative: bool = False
    nonzero: bool = False
    when: str | None = None

    @property
    def condition(self) -> tuple[str, bool] | None:
        """(the item attribute ``applies`` reads, whether negated); None: it always applies."""
        return None if self.when is None else (self.when.lstrip("!"), self.when.startswith("!"))

    def applies(self, item) -> bool:
        if self.when is None:
            return True
        attribute, negate = self.condition
        return bool(getattr(item, attribute)) != negate


@dataclass(frozen=True)
class ItemVariables:
    parameters: tuple[Spec, ...] = ()
    inputs: tuple[Spec, ...] = ()
    outputs: tuple[Spec, ...] = ()


_REACTIONS = (
    Spec("Fx", "N", "force of joint {name} on {item.body_j}, x in its joint frame"),
    Spec("Fy", "N", "force of joint {name} on {item.body_j}, y in its joint frame"),
    Spec("Tz", "N.m", "torque of joint {name} on {item.body_j}"))

TABLES: dict[type, ItemVariables] = {
    Body: ItemVariables(
        parameters=(Spec("mass", "kg", "mass of {name}", "mass", positive=True),
                    Spec("inertia", "kg.m2", "moment of inertia of {name} about its centre "
                         "of mass", "inertia", positive=True)),
        outputs=(Spec("x", "m", "x of {name}'s centre of mass, ground frame"),
                 Spec("y", "m", "y of {name}'s centre of mass, ground frame"),
                 Spec("phi", "rad", "rotation angle of {name}"),
                 Spec("vx", "m/s", "x velocity of {name}'s centre of mass"),
                 Spec("vy", "m/s", "y velocity of {name}'s centre of mass"),
                 Spec("omega", "rad/s", "angular velocity of {name}"))),
    RevoluteJoint: ItemVariables(outputs=_REACTIONS + (
        Spec("limit", "N.m", "torque the end stops of {name} apply on its coordinate, "
             "positive pushing it up (0: not in contact)", when="limits"),
        Spec("friction", "N.m", "Coulomb friction torque of {name} on its coordinate",
             when="friction"))),
    TranslationalJoint: ItemVariables(outputs=_REACTIONS + (
        Spec("limit", "N", "force the end stops of {name} apply on its coordinate, positive "
             "pushing it up (0: not in contact)", when="limits"),
        Spec("friction", "N", "Coulomb friction force of {name} on its coordinate",
             when="friction"))),
    SlotJoint: ItemVariables(outputs=(
        Spec("Fx", "N", "force of slot {name} on the pin ({item.body_j}) along the slot's axis "
             "(0: no friction)"),
        Spec("Fy", "N", "force of slot {name} on the pin ({item.body_j}) normal to the slot"))),
    RollingJoint: ItemVariables(outputs=(
        Spec("Fx", "N", "contact force of {name} on the disc ({item.body_j}), tangential: "
             "along the line's axis"),
        Spec("Fy", "N", "contact force of {name} on the disc ({item.body_j}), normal: the "
             "axis turned by +90 degrees"))),
    CouplerJoint: ItemVariables(
        parameters=(Spec("ratio", "{ratio}", "ratio of {name}: {item.joint_j}'s coordinate "
                         "change per unit of {item.joint_i}'s", "ratio", nonzero=True),),
        outputs=(Spec("effort", "{effort}", "generalized force coupler {name} applies on "
                      "joint {item.joint_j}'s coordinate"),)),
    Driver: ItemVariables(
        inputs=(Spec("position", "{pos}", "prescribed position of {name}", when="is_input"),
                Spec("velocity", "{pos}/s", "its rate (optional)", when="is_input"),
                Spec("acceleration", "{pos}/s2", "its second rate (optional)", when="is_input")),
        outputs=(Spec("effort", "{effort}", "generalized force driver {name} applies to "
                      "{body}"),)),
    PointForce: ItemVariables(
        parameters=(Spec("fx", "N", "{name}, x component", "value", 0, when="!input"),
                    Spec("fy", "N", "{name}, y component", "value", 1, when="!input")),
        inputs=(Spec("fx", "N", "{name}, x component, ground frame", when="input"),
                Spec("fy", "N", "{name}, y component, ground frame", when="input"))),
    Torque: ItemVariables(
        parameters=(Spec("torque", "N.m", "{name}", "value", when="!input"),),
        inputs=(Spec("torque", "N.m", "torque {name} on {item.body}", when="input"),)),
    SpringDamper: ItemVariables(
        parameters=(Spec("stiffness", "N/m", "spring stiffness", "stiffness", nonnegative=True),
                    Spec("damping", "N.s/m", "damping coefficient", "damping", nonnegative=True),
                    Spec("rest_length", "m", "spring rest length", "rest_length",
                         nonnegative=True)),
        inputs=(Spec("actuator", "N", "actuator force along {name}, positive pushing apart",
                     when="actuator_input"),),
        outputs=(Spec("length", "m", "distance between {name}'s points"),
                 Spec("velocity", "m/s", "rate of {name}'s length"),
                 Spec("tension", "N", "force of {name} along its line, positive pulling "
                      "together"))),
    RotationalSpringDamper: ItemVariables(
        parameters=(Spec("stiffness", "N.m/rad", "torsional stiffness", "stiffness",
                         nonnegative=True),
                    Spec("damping", "N.m.s/rad", "torsional damping", "damping",
                         nonnegative=True),
                    Spec("rest_angle", "rad", "spring rest angle", "rest_angle"))),
}

# A driver's motion constants are parameters of the driver.
MOTION_PARAMETERS: dict[type, tuple[Spec, ...]] = {
    ConstantMotion: (Spec("value", "{pos}", "value of {name}'s constant motion", "value"),),
    LinearMotion: (Spec("start", "{pos}", "start of {name}'s linear motion", "start"),
                   Spec("rate", "{pos}/s", "rate of {name}'s linear motion", "rate")),
    HarmonicMotion: (Spec("offset", "{pos}", "offset of {name}'s harmonic motion", "offset"),
                     Spec("amplitude", "{pos}", "amplitude of {name}'s harmonic motion",
                          "amplitude"),
                     Spec("frequency", "Hz", "frequency of {name}'s harmonic motion",
                          "frequency", nonnegative=True),
                     Spec("phase", "rad", "phase of {name}'s harmonic motion", "phase")),
}

GRAVITY = (Spec("x", "m/s2", "gravity, x component", "gravity", 0),
           Spec("y", "m/s2", "gravity, y component", "gravity", 1))
GLOBAL_OUTPUTS = (Variable("energy.kinetic", "J", "kinetic energy"),
                  Variable("energy.potential", "J", "potential energy of gravity and springs"),
                  Variable("constraint.position_error", "1", "norm of Psi(q, t)"),
                  Variable("constraint.velocity_error", "1", "norm of Psi_q q' - nu"))


def _units(scene: Scene, item) -> dict[str, str]:
    if isinstance(item, Driver):
        angular = driver_is_angular(scene, item)
        return {"pos": "rad" if angular else "m", "effort": "N.m" if angular else "N",
                "body": driven_body(scene, item), "ratio": ""}
    if isinstance(item, CouplerJoint):
        pos_i, pos_j = (coordinate_unit(scene.joint(name)) for name in (item.joint_i, item.joint_j))
        return {"pos": pos_j, "effort": "N.m" if pos_j == "rad" else "N", "body": "",
                "ratio": "1" if pos_i == pos_j else f"{pos_j}/{pos_i}"}
    return {"pos": "m", "effort": "N", "body": "", "ratio": ""}


def coordinate_unit(joint) -> str:
    """The unit of a joint's coordinate: rad (revolute) or m (translational)."""
    return "rad" if isinstance(joint, RevoluteJoint) else "m"


def _make(scene, item, spec: Spec, value=None) -> Variable:
    context = _units(scene, item)
    unit = spec.unit.format(**context)
    text = spec.description.format(name=item.name, item=item, **context)
    name = f"{item.name}.{spec.suffix}"
    if value is None:
        return Variable(name, unit, text)
    return Parameter(name, unit, text, float(value))


def _field_value(owner, spec: Spec):
    value = getattr(owner, spec.field)
    return value if spec.index is None else value[spec.index]


def _items(scene: Scene):
    return (*scene.bodies, *scene.joints, *scene.drivers, *scene.forces)


def _motion_specs(driver: Driver) -> tuple[Spec, ...]:
    motion = driver.motion
    if isinstance(motion, PolynomialMotion):
        return tuple(Spec(f"c{k}", "{pos}" + ("" if k == 0 else "/s" if k == 1 else f"/s{k}"),
                          f"coefficient of t^{k} in {{name}}'s motion", "coefficients", k)
                     for k in range(len(motion.coefficients)))
    return MOTION_PARAMETERS.get(type(motion), ())


def _parameter_specs(scene: Scene):
    """(owner of the field, item naming it, spec) for every parameter, in table order."""
    out = []
    for item in _items(scene):
        out += [(item, item, s) for s in TABLES[type(item)].parameters if s.applies(item)]
        if isinstance(item, Driver):
            out += [(item.motion, item, s) for s in _motion_specs(item)]
    return out


def parameters(scene: Scene) -> list[Parameter]:
    """Every constant of the scene that may be changed before a run, with unit."""
    gravity = [Parameter(f"gravity.{s.suffix}", s.unit, s.description, scene.gravity[s.index])
               for s in GRAVITY]
    return gravity + [_make(scene, item, spec, _field_value(owner, spec))
                      for owner, item, spec in _parameter_specs(scene)]


def inputs(scene: Scene) -> list[Variable]:
    """Every run-time input of the scene, drivers first, then forces (scene order)."""
    return [_make(scene, item, s) for item in (*scene.drivers, *scene.forces)
            for s in TABLES[type(item)].inputs if s.applies(item)]


def outputs(scene: Scene) -> list[Variable]:
    """Every output, in the order ``equations.dynamics.output_values`` computes them:
    bodies, joints, drivers, forces, then energies and constraint errors."""
    items = [_make(scene, item, s) for item in _items(scene)
             for s in TABLES[type(item)].outputs if s.applies(item)]
    return items + list(GLOBAL_OUTPUTS)


def selected_outputs(scene: Scene) -> list[Variable]:
    """The outputs a scene reports by default (its FMU's outputs): those its ``outputs``
    globs match, else every body state, joint reaction and driver effort. SceneError when a
    glob matches nothing."""
    variables = outputs(scene)
    names = [v.name for v in variables]
    if scene.outputs is not None:
        patterns = list(scene.outputs)
        unmatched = [p for p in patterns if not fnmatch.filter(names, p)]
        if unmatched:
            raise SceneError(f"{scene.source}: outputs {unmatched} match no variable; "
                             f"this scene's outputs: {', '.join(names)}")
    else:
        patterns = ([f"{b.name}.*" for b in scene.bodies] + [f"{j.name}.*" for j in scene.joints]
                    + [f"{d.name}.effort" for d in scene.drivers])
    return [v for v in variables if any(fnmatch.fnmatchcase(v.name, p) for p in patterns)]


def _check_value(spec: Spec, name: str, value: float) -> str | None:
    if not math.isfinite(value):
        return f'"{name}" must be finite, got {value}'
    if spec.positive and value <= 0:
        return f'"{name}" must be positive, got {value:g}'
    if spec.nonnegative and value < 0:
        return f'"{name}" must not be negative, got {value:g}'
    if spec.nonzero and value == 0:
        return f'"{name}" must not be zero'
    return None


def _replaced(owner, specs_values):
    """``owner`` with each (spec, value) set: vectors and tuples rebuilt element-wise."""
    changes = {}
    for spec, value in specs_values:
        current = changes.get(spec.field, getattr(owner, spec.field))
        if spec.index is None:
            changes[spec.field] = value
        else:
            current = list(current)
            current[spec.index] = value
            changes[spec.field] = tuple(current)
    return dataclasses.replace(owner, **changes) if changes else owner


def parameter_specs(scene: Scene) -> dict[str, tuple]:
    """Each parameter's name -> (owner of its field, item naming it (None: the scene),
    spec): where ``with_parameters`` sets it, and where a scene file keeps it."""
    specs = {f"gravity.{s.suffix}": (scene, None, s) for s in GRAVITY}
    return specs | {f"{item.name}.{s.suffix}": (owner, item, s)
                    for owner, item, s in _parameter_specs(scene)}


def with_parameters(scene: Scene, values: dict[str, float]) -> Scene:
    """A copy of ``scene`` with the named parameters (see ``parameters``) changed; raises
    SceneError naming every unknown or out-of-range value."""
    specs = parameter_specs(scene)
    problems = Problems(scene.source)
    for name, value in values.items():
        if name not in specs:
            problems.add("parameters", f'unknown parameter "{name}"{suggest(name, specs)}')
        else:
            problem = _check_value(specs[name][2], name, float(value))
            if problem:
                problems.add("parameters", problem)
    problems.raise_if_any()
    by_owner: dict[int, list] = {}
    for name, value in values.items():
        owner, _, spec = specs[name]
        by_owner.setdefault(id(owner), []).append((spec, float(value)))

    def new(owner):
        return _replaced(owner, by_owner.get(id(owner), []))

    def new_item(item):
        item = new(item)
        if isinstance(item, Driver):
            original = next(d for d in scene.drivers if d.name == item.name)
            item = dataclasses.replace(item, motion=new(original.motion))
        return item

    scene_changes = new(scene)
    return dataclasses.replace(
        scene, gravity=scene_changes.gravity,
        bodies=tuple(map(new_item, scene.bodies)), joints=tuple(map(new_item, scene.joints)),
        drivers=tuple(map(new_item, scene.drivers)), forces=tuple(map(new_item, scene.forces)))


# ----------------------------------------------------------------------------- input values

@dataclass(frozen=True)
class InputValues:
    """The inputs at one instant, as the equations take them.

    ``motions`` (k, 3): f, f', f'' of each input-driven driver (``InputLayout.drivers``
    order); ``forces`` (l,): the force inputs, each item's components at its
    ``InputLayout.forces`` slice (N or N.m).
    """

    motions: np.ndarray
    forces: np.ndarray


@dataclass(frozen=True)
class InputLayout:
    """Where each input item sits in ``InputValues``."""

    drivers: tuple[str, ...]                    # input-driven drivers, scene order
    driver_initial: tuple[float, ...]           # their positions before any input arrives
    forces: dict[str, slice]                    # force item -> its slice of ``forces``
    fields: dict[str, tuple[str, ...]]          # force item -> its input suffixes

    @property
    def size(self) -> int:
        return sum(s.stop - s.start for s in self.forces.values())

    def initial(self) -> InputValues:
        """Inputs before anything is set: drivers at rest at their initial value, forces 0."""
        motions = np.zeros((len(self.drivers), 3))
        motions[:, 0] = self.driver_initial
        return InputValues(motions, np.zeros(self.size))


def input_layout(scene: Scene) -> InputLayout:
    drivers = [d for d in scene.drivers if d.is_input]
    forces, fields, k = {}, {}, 0
    for f in scene.forces:
        suffixes = tuple(s.suffix for s in TABLES[type(f)].inputs if s.applies(f))
        if suffixes:
            forces[f.name], fields[f.name] = slice(k, k + len(suffixes)), suffixes
            k += len(suffixes)
    return InputLayout(tuple(d.name for d in drivers), tuple(d.motion.initial for d in drivers),
                       forces, fields)


def input_slots(layout) -> dict:
    """Input name -> ("motion", index in the flattened (drivers, 3) motions) or ("force",
    index in the forces vector)."""
    slots = {f"{d}.{field}": ("motion", 3 * k + j) for k, d in enumerate(layout.drivers)
             for j, field in enumerate(("position", "velocity", "acceleration"))}
    for item, where in layout.forces.items():
        for j, field in enumerate(layout.fields[item]):
            slots[f"{item}.{field}"] = ("force", where.start + j)
    return slots
