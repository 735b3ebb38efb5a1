"""Reading a scenario's connections file (format: ``scenario.py``'s docstring) into a
``Scenario``, every problem located and reported at once."""

from __future__ import annotations

import math
from pathlib import Path

from ..errors import Problems, suggest
from ..model.toml_table import load_toml
from .scenario import (ALGORITHMS, IDENTIFIER, TOP_KEYS, VARIABLE_STEP_KEYS, Connection,
                       Instance, Scenario, ScenarioError, VariableStepSettings, resolve)


def _positive(value, name: str, problems: Problems) -> float | None:
    if isinstance(value, bool) or not isinstance(value, (int, float)) or \
            not (math.isfinite(value) and value > 0):
        problems.add("", f"{name} must be a positive number, got {value!r}")
        return None
    return float(value)


def _names(value, name: str, problems: Problems) -> tuple[str, ...]:
    if value is None:
        return ()
    if not isinstance(value, list) or not all(isinstance(v, str) for v in value):
        problems.add("", f"{name} must be a list of names, got {value!r}")
        return ()
    return tuple(value)


def _read_instances(data: dict, path: Path, problems: Problems) -> list[Instance]:
    raw = data.get("instances")
    if not isinstance(raw, dict) or not raw:
        problems.add("", "[instances] must map instance names to FMU sources (scene .toml or "
                     "companion .py)")
        raw = {}
    instances = []
    for name, source in raw.items():
        where = f'instance "{name}"'
        if not IDENTIFIER.fullmatch(name):
            problems.add(where, "a name must be an identifier (no dots)")
        if not isinstance(source, str):
            problems.add(where, f"the source must be a file name, got {source!r}")
            continue
        file = (path.parent / source).resolve()
        if file.suffix not in (".toml", ".py"):
            problems.add(where, f'"{source}" is neither a scene (.toml) nor a companion '
                         "source (.py)")
        elif not file.is_file():
            problems.add(where, f'no file "{source}" next to {path.name}')
        instances.append(Instance(name, file))
    names = [i.name for i in instances]
    for a in names:
        for b in names:
            if a != b and b.startswith(a):
                problems.add(f'instance "{a}"', f'is a prefix of instance "{b}": fmpy\'s SSP '
                             "runner would give one's parameters to the other; rename one")
    return instances


def _variable(ref, where: str, names: list[str], problems: Problems) -> str | None:
    """``ref`` if it is ``<instance>.<variable>`` of a known instance, else None (reported)."""
    if not isinstance(ref, str) or "." not in ref:
        problems.add(where, f"{ref!r} is not <instance>.<variable>")
        return None
    instance = ref.split(".", 1)[0]
    if instance not in names:
        problems.add(where, f'unknown instance "{instance}" in "{ref}"{suggest(instance, names)}')
        return None
    return ref


def _read_connections(raw, names: list[str], problems: Problems) -> list[Connection]:
    if not isinstance(raw, list):
        problems.add("", "[[connections]] must be an array of tables")
        return []
    connections, targets = [], {}
    for k, c in enumerate(raw):
        label = f"connection {k + 1}"
        if not isinstance(c, dict) or set(c) != {"from", "to"}:
            problems.add(label, f"needs exactly the keys from and to, got {c!r}")
            continue
        src, dst = _variable(c["from"], label, names, problems), \
            _variable(c["to"], label, names, problems)
        if src is None or dst is None:
            continue
        if src.split(".", 1)[0] == dst.split(".", 1)[0]:
            problems.add(label, f'"{src}" -> "{dst}" connects an instance to itself')
        if dst in targets:
            problems.add(label, f'input "{dst}" is already driven by "{targets[dst]}"')
        targets[dst] = src
        connections.append(Connection(src, dst))
    return connections


def _read_parameters(raw, names, connections, problems: Problems) -> dict[str, float]:
    if not isinstance(raw, dict):
        problems.add("", "[parameters] must be a table")
        return {}
    driven = {c.target: c.source for c in connections}
    out = {}
    for key, value in raw.items():
        if _variable(key, "parameters", names, problems) is None:
            continue
        if isinstance(value, bool) or not isinstance(value, (int, float)) or \
                not math.isfinite(value):
            problems.add("", f'parameter "{key}" = {value!r}: only finite numbers (set strings '
                         "such as solver.method in the scene file: fmpy's SSP runner sets "
                         "Reals only)")
            continue
        if key in driven:
            problems.add("", f'parameter "{key}" is an input driven by "{driven[key]}"')
        out[key] = float(value)
    return out


def _read_variable_step(raw, connections_raw, problems: Problems) -> VariableStepSettings:
    if not isinstance(raw, dict):
        problems.add("", "[variable_step] must be a table")
        return VariableStepSettings()
    for key in sorted(set(raw) - VARIABLE_STEP_KEYS):
        problems.add("[variable_step]", f'unknown key "{key}" (known: '
                     f'{", ".join(sorted(VARIABLE_STEP_KEYS))})')
    values = {k: _positive(v, f"variable_step.{k}", problems)
              for k, v in raw.items() if k in VARIABLE_STEP_KEYS - {"nominal"}}
    nominal = raw.get("nominal", {})
    if not isinstance(nominal, dict):
        problems.add("[variable_step]", "nominal must be a table of output magnitudes")
        nominal = {}
    # (every declared source, valid or not: a broken connection is reported once)
    sources = {c.get("from") for c in connections_raw if isinstance(c, dict)} \
        if isinstance(connections_raw, list) else set()
    for key, value in nominal.items():
        if key not in sources:
            problems.add("[variable_step] nominal", f'"{key}" is not a connected output')
        _positive(value, f'variable_step.nominal "{key}"', problems)
    return VariableStepSettings(nominal={k: float(v) for k, v in nominal.items()
                                         if isinstance(v, (int, float))},
                                **{k: v for k, v in values.items() if v is not None})


def _read_power_bonds(raw, names, connections, problems: Problems) -> dict:
    """``{instance: [effort input, flow output]}`` of two instances whose effort and flow
    are connected to each other's flow and effort."""
    if not isinstance(raw, dict) or not all(
            isinstance(v, list) and len(v) == 2 and all(isinstance(x, str) for x in v)
            for v in raw.values()):
        problems.add("[power_bonds]", "must map each of two instances to [effort input, "
                     "flow output]")
        return {}
    if not raw:
        return {}
    unknown = [k for k in raw if k not in names]
    if unknown or len(raw) != 2:
        problems.add("[power_bonds]", f"needs two of the instances {names}, got {list(raw)}")
        return {}
    (a, (ea, fa)), (b, (eb, fb)) = raw.items()
    linked = {(c.source, c.target) for c in connections}
    for src, dst in ((f"{b}.{fb}", f"{a}.{ea}"), (f"{a}.{fa}", f"{b}.{eb}")):
        if (src, dst) not in linked:
            problems.add("[power_bonds]", f'"{src}" -> "{dst}" is not a connection')
    return {k: tuple(v) for k, v in raw.items()}


def load_scenario(name_or_path: str | Path) -> Scenario:
    """Read and check a connections file (see the module docstring for the format); raises
    one ``ScenarioError`` listing every problem."""
    path = resolve(name_or_path)
    data = load_toml(path, ScenarioError)
    problems = Problems(path.name, ScenarioError)
    for key in sorted(set(data) - TOP_KEYS):
        problems.add("", f'unknown key "{key}"{suggest(key, TOP_KEYS)}')
    instances = _read_instances(data, path, problems)
    names = [i.name for i in instances]
    connections = _read_connections(data.get("connections", []), names, problems)
    parameters = _read_parameters(data.get("parameters", {}), names, connections, problems)
    t_end = _positive(data.get("t_end"), "t_end", problems)
    step = _positive(data.get("step"), "step", problems)
    algorithm = data.get("algorithm", "jacobi")
    if algorithm not in ALGORITHMS:
        problems.add("", f'algorithm "{algorithm}" is not one of {", ".join(ALGORITHMS)}')
    order = _names(data.get("order"), "order", problems) or tuple(names)
    if sorted(order) != sorted(names):
        problems.add("", f"order {list(order)} must list every instance once: {names}")
    lists = {key: _names(data.get(key), key, problems) for key in ("record", "plot", "compare")}
    for key, refs in lists.items():
        for ref in refs:
            _variable(ref, key, names, problems)
    reference = None
    if data.get("reference") is not None:
        reference = (path.parent / str(data["reference"])).resolve()
        if not reference.is_file():
            problems.add("", f'reference "{data["reference"]}": no such file next to {path.name}')
    variable_step = _read_variable_step(data.get("variable_step", {}),
                                        data.get("connections", []), problems)
    power_bonds = _read_power_bonds(data.get("power_bonds", {}), names, connections, problems)
    name = data.get("name", path.parent.name)
    if not isinstance(name, str) or not name:
        problems.add("", f"name must be a non-empty string, got {name!r}")
    problems.raise_if_any()
    return Scenario(name=name, description=str(data.get("description", "")), path=path,
                    instances=tuple(instances), connections=tuple(connections),
                    parameters=parameters, t_end=t_end, step=step, algorithm=algorithm,
                    order=tuple(order), variable_step=variable_step, reference=reference,
                    power_bonds=power_bonds,
                    **lists)
