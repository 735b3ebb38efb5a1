"""TOML -> Scene: ``load_scene`` and ``scene_from_dict``, every problem reported at once.

The reader knows no item type by heart: each class in ``scene.py`` declares its keys as
fields, and the type registries (``JOINT_TYPES``, ``FORCE_TYPES``, ``MOTION_TYPES``) say
which class a ``type`` names. Nothing in a scene is ever evaluated as code.
"""

from __future__ import annotations

from importlib import resources
from pathlib import Path
from typing import Any

from ..errors import Problems, SceneError, suggest
from .motion import MOTION_TYPES
from .scene import (COORDINATE_JOINTS, FORCE_TYPES, GROUND, IDENTIFIER, JOINT_TYPES,
                    RESERVED_NAMES, Body, Driver, Friction, LimitedJoint, RevoluteJoint, Scene,
                    SimulationSettings)
from .toml_table import Table, load_toml, read_fields

# [[kind]] arrays of a scene and the class (or type registry) of their items.
ITEM_KINDS: dict[str, Any] = {"body": Body, "joint": JOINT_TYPES, "driver": Driver,
                              "force": FORCE_TYPES}
TOP_KEYS = ("name", "description", "version", "author", "gravity", "outputs", "simulation",
            *ITEM_KINDS)


def _label(kind: str, raw: Any, index: int) -> str:
    name = raw.get("name") if isinstance(raw, dict) else None
    return f'{kind} "{name}"' if isinstance(name, str) else f"{kind} #{index + 1}"


def _choose_class(table: Table, registry, what: str) -> type | None:
    """The class of an item: fixed, or the one its ``type`` key names in ``registry``."""
    if isinstance(registry, type):
        return registry
    kind = table.get("type", "str")
    if kind is None:
        return None
    if kind not in registry:
        table.fail(f'unknown {what} type "{kind}"{suggest(kind, registry)}; '
                   f"expected one of {', '.join(registry)}")
        return None
    return registry[kind]


def _read_motion(table: Table):
    raw = table.data.get("motion")
    if raw is None:
        return None          # read_fields reports the missing key
    t = Table(raw, table.where + ": motion", table.problems)
    cls = _choose_class(t, MOTION_TYPES, "motion")
    values = read_fields(cls, t) if cls is not None else {}
    t.finish()
    if not t.ok or cls is None:
        table.ok = False
        return None
    return cls(**values)


def _read_friction(table: Table):
    """A joint's ``friction`` table (None when absent); its keys checked as any item's."""
    table.known.add("friction")
    raw = table.data.get("friction")
    if raw is None:
        return None
    t = Table(raw, table.where + ": friction", table.problems)   # reports a non-table
    values = read_fields(Friction, t)
    t.finish()
    if not t.ok:
        table.ok = False
        return None
    return Friction(**values)


def read_item(kind: str, raw: Any, where: str, problems: Problems):
    """One ``[[kind]]`` item, or None when it has problems (all of them reported)."""
    t = Table(raw, where, problems)
    cls = _choose_class(t, ITEM_KINDS[kind], kind)
    if cls is None:
        return None
    values = {}
    if cls is Driver:
        t.known.add("motion")
        values["motion"] = _read_motion(t)
        if "motion" not in t.data:
            t.fail('missing required key "motion"')
    if issubclass(cls, LimitedJoint):
        values["friction"] = _read_friction(t)
    values = read_fields(cls, t, values)
    t.finish()
    if not t.ok:
        return None
    if cls is Body:
        values["given"] = frozenset(t.data)
    item = cls(**values)
    for problem in getattr(item, "problems", lambda: [])():
        problems.add(where, problem)
    return item


def _check_names(items: dict[str, list], problems: Problems) -> None:
    seen: dict[str, str] = {}
    for kind, group in items.items():
        for item in group:
            where = f'{kind} "{item.name}"'
            if not IDENTIFIER.match(item.name):
                problems.add(where, "name must be an identifier (letters, digits, _)")
            elif item.name in RESERVED_NAMES:
                problems.add(where, f'"{item.name}" is a reserved name')
            if item.name in seen:
                problems.add(where, f"duplicate name (also a {seen[item.name]})")
            seen.setdefault(item.name, kind)


def _check_references(items: dict[str, list], problems: Problems) -> None:
    """Every ``ref`` key names an existing item of the right kind."""
    bodies = {b.name for b in items["body"]}
    joints = {j.name: j for j in items["joint"]}
    for kind, group in items.items():
        for item in group:
            for name, refkind in _references(item):
                value = getattr(item, name)
                if value is None:
                    continue
                problem = _reference_problem(refkind, value, bodies, joints)
                if problem:
                    problems.add(f'{kind} "{item.name}"', f"{name}: {problem}")


def _references(item) -> list[tuple[str, str]]:
    fields = getattr(type(item), "__dataclass_fields__", {})
    return [(n, f.metadata["ref"]) for n, f in fields.items() if f.metadata.get("ref")]


def _reference_problem(refkind: str, value: str, bodies: set, joints: dict) -> str:
    if refkind in ("body", "moving body"):
        if value == GROUND:
            return ("acts on the ground, which is fixed: name a moving body"
                    if refkind == "moving body" else "")
        return "" if value in bodies else (f'unknown body "{value}"'
                                           f"{suggest(value, bodies | {GROUND})}")
    if value not in joints:
        return f'unknown joint "{value}"{suggest(value, joints)}'
    if refkind == "revolute joint" and not isinstance(joints[value], RevoluteJoint):
        return f'joint "{value}" is {joints[value].TYPE}, not revolute'
    if refkind == "coordinate joint" and not isinstance(joints[value], COORDINATE_JOINTS):
        return (f'joint "{value}" is {joints[value].TYPE}, which has no coordinate '
                f"(revolute or translational joints have)")
    return ""


def _check_placement(items: dict[str, list], problems: Problems) -> None:
    """Items whose initial placement is part of their definition (a rolling disc's centre at
    its radius from its line) check it against the bodies' initial positions."""
    poses = {b.name: (*b.position, b.angle) for b in items["body"]} | {GROUND: (0.0, 0.0, 0.0)}
    for item in items["joint"]:
        check = getattr(item, "placement_problems", None)
        if check is not None and item.body_i in poses and item.body_j in poses:
            for problem in check(poses):
                problems.add(f'joint "{item.name}"', problem)


def _read_top(data: dict, problems: Problems) -> tuple[Table, dict]:
    top = Table(data, "", problems)
    values = {k: top.get(k, "str", d) for k, d in
              (("description", ""), ("version", "0.1.0"), ("author", ""))}
    values["name"] = top.get("name", "str")
    if values["name"] is not None and not IDENTIFIER.match(values["name"]):
        problems.add("name", f'"{values["name"]}" must be a valid identifier (it names the FMU)')
    values["gravity"] = top.get("gravity", "vec2", (0.0, -9.81))
    values["outputs"] = None
    if "outputs" in data:
        top.known.add("outputs")
        raw = data["outputs"]
        if not isinstance(raw, list) or not all(isinstance(p, str) for p in raw):
            problems.add("outputs", "must be a list of glob patterns (strings)")
        else:
            values["outputs"] = tuple(raw)
    values["simulation"] = SimulationSettings()
    if "simulation" in data:
        top.known.add("simulation")
        s = Table(data["simulation"], "simulation", problems)
        fields = read_fields(SimulationSettings, s)
        fields["options"] = s.get("options", "table", {})
        s.finish()
        if s.ok:
            values["simulation"] = SimulationSettings(**fields)
    return top, values


def scene_from_dict(data: dict, source: str = "<scene>") -> Scene:
    """Build and check a Scene from parsed TOML; raises SceneError listing every problem."""
    problems = Problems(source)
    if not isinstance(data, dict):
        raise SceneError(f"{source}: a scene must be a table")
    top, values = _read_top(data, problems)
    items: dict[str, list] = {kind: [] for kind in ITEM_KINDS}
    for kind in ITEM_KINDS:
        top.known.add(kind)
        raw_list = data.get(kind, [])
        if not isinstance(raw_list, list):
            problems.add(kind, f"must be an array of tables ([[{kind}]])")
            continue
        for k, raw in enumerate(raw_list):
            item = read_item(kind, raw, _label(kind, raw, k), problems)
            if item is not None:
                items[kind].append(item)
    top.finish()
    if not data.get("body"):
        problems.add("", "a scene needs at least one [[body]]")
    _check_names(items, problems)
    _check_references(items, problems)
    _check_placement(items, problems)
    problems.raise_if_any()
    return Scene(source=source, bodies=tuple(items["body"]), joints=tuple(items["joint"]),
                 drivers=tuple(items["driver"]), forces=tuple(items["force"]), **values)


def bundled_scene(name: str) -> Path:
    """The path of a scene shipped with mbdfmu (``scenes/<name>.toml``)."""
    return Path(str(resources.files("mbdfmu.scenes").joinpath(f"{name}.toml")))


def shipped_scene_names() -> list[str]:
    folder = resources.files("mbdfmu.scenes")
    return sorted(p.name[:-5] for p in folder.iterdir() if p.name.endswith(".toml"))


def resolve_scene_path(name_or_path: str | Path) -> Path:
    """A scene file from a path, or from the name of a shipped scene (``slider_crank``)."""
    path = Path(name_or_path)
    if path.suffix == ".toml" or path.exists() or any(c in str(name_or_path) for c in "/\\"):
        return path
    shipped = shipped_scene_names()
    if str(name_or_path) in shipped:
        return bundled_scene(str(name_or_path))
    raise SceneError(f'{name_or_path}: no such file, and no shipped scene of that name'
                     f'{suggest(str(name_or_path), shipped)}; shipped: {", ".join(shipped)}')


def load_scene(path: str | Path) -> Scene:
    """Read and check a scene file (TOML), or a shipped scene by name. Raises SceneError
    naming file, item and problem."""
    path = resolve_scene_path(path)
    return scene_from_dict(load_toml(path, SceneError), source=path.name)
