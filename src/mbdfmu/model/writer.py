"""Scene files with values changed: parameters (names as the FMU's) and body positions.

``set_parameters`` writes parameter values into a scene's parsed TOML (a dict, or a
``tomlkit`` document, which keeps the file's comments and layout), at the key the variable
table says each parameter comes from; ``write_scene`` writes a scene file with new
parameters and body positions (``mbdfmu equilibrium -o``).
"""

from __future__ import annotations

from pathlib import Path

from ..errors import SceneError
from .scene import Body, Driver, Scene
from .variables import parameter_specs, with_parameters


def _kind(item) -> str:
    if isinstance(item, Body):
        return "body"
    return "driver" if isinstance(item, Driver) else "force"


def _item_table(data, kind: str, name: str):
    for table in data.get(kind, []):
        if table.get("name") == name:
            return table
    raise SceneError(f'no [[{kind}]] named "{name}" in the scene file')


def _set(table, key: str, index, value: float, default) -> None:
    if index is None:
        table[key] = value
        return
    current = [float(v) for v in table.get(key, default)]
    current[index] = value
    table[key] = current


def set_parameters(data, scene: Scene, values: dict[str, float]) -> None:
    """Write ``values`` (parameter name -> value, checked as ``with_parameters`` checks
    them) into ``data``, the parsed TOML of ``scene``'s file."""
    with_parameters(scene, values)          # unknown names, ranges: one SceneError
    specs = parameter_specs(scene)
    for name, value in values.items():
        owner, item, spec = specs[name]
        if item is None:                    # gravity
            _set(data, "gravity", spec.index, float(value), scene.gravity)
            continue
        table = _item_table(data, _kind(item), item.name)
        if owner is not item:               # a driver's motion constant
            table = table["motion"]
        _set(table, spec.field, spec.index, float(value), getattr(owner, spec.field))


def set_positions(data, positions: dict[str, tuple[float, float, float]]) -> None:
    """Body positions (x, y, phi) into ``data``'s ``position`` and ``angle`` keys."""
    for name, (x, y, phi) in positions.items():
        table = _item_table(data, "body", name)
        table["position"] = [float(x), float(y)]
        table["angle"] = float(phi)


def write_scene(source: str | Path, target: str | Path, scene: Scene,
                positions: dict[str, tuple[float, float, float]] | None = None,
                parameters: dict[str, float] | None = None) -> Path:
    """The scene file ``source`` written to ``target`` with ``parameters`` and body
    ``positions`` changed; comments and layout kept."""
    import tomlkit

    try:
        doc = tomlkit.parse(Path(source).read_text(encoding="utf-8"))
    except (OSError, tomlkit.exceptions.TOMLKitError) as exc:
        raise SceneError(f"{source}: cannot read: {exc}") from None
    set_parameters(doc, scene, parameters or {})
    set_positions(doc, positions or {})
    target = Path(target)
    try:
        target.write_text(tomlkit.dumps(doc), encoding="utf-8")
    except OSError as exc:
        raise SceneError(f"{target}: cannot write: {exc.strerror or exc}") from None
    return target
