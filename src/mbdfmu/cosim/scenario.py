"""A co-simulation scenario: which FMUs, how they connect, and how the run is set up.

A scenario is a folder under ``scenarios/`` holding a connections file (TOML):

```toml
name = "dc_motor_slider_crank"
description = "A DC motor drives a slider-crank through its crank torque"
t_end = 0.5                      # s
step = 1e-3                      # communication step (s)
algorithm = "gauss-seidel"       # jacobi | gauss-seidel (the default of `mbdfmu cosim`)
order = ["mechanism", "motor"]   # Gauss-Seidel order (default: the instances as listed)
record = ["mechanism.slider.x"]  # outputs written besides the connected ones
plot = ["mechanism.crank.omega", "motor.torque"]
compare = ["mechanism.crank.omega"]   # coupling error: these against the reference
reference = "reference.py"       # optional: reference(scenario, times) -> {name: values}

[instances]
mechanism = "slider_crank.toml"  # a scene: built by fmu_build
motor = "dc_motor.py"            # a companion source: built by mbdfmu.cosim.companion

[[connections]]
from = "motor.torque"            # <instance>.<output>
to = "mechanism.drive.torque"    # <instance>.<input>

[parameters]                     # start values set before initialization (numbers only)
"motor.R" = 0.5
"motor.voltage" = 12.0           # an input nobody drives holds this value

[power_bonds]                    # optional: ECCO takes the bond from the FMUs' power ports
mechanism = ["drive.torque", "crank.omega"]
motor = ["speed", "torque"]

[variable_step]                  # the error-controlled master (all optional)
rtol = 1e-2                      # allowed change of a coupled variable over one step
atol = 1e-6
h_min = 1e-6
h_max = 1e-2
nominal = { "motor.torque" = 1.0 }   # typical magnitudes of connected outputs
```

Names are ``<instance>.<variable>``: instance names are identifiers (no dots), so the first
dot separates them. ``load_scenario`` checks everything it can without the FMUs and raises
one ``ScenarioError`` listing every problem; ``check_variables`` checks names, causalities
and units once the model descriptions are known.
"""

from __future__ import annotations

import re
from dataclasses import dataclass, field
from pathlib import Path

from ..errors import ReadError, suggest

def _scenarios_folder() -> Path:
    """Where ``mbdfmu cosim NAME`` looks: $MBDFMU_SCENARIOS, scenarios/ of the source tree,
    the installed ``mbdfmu.scenarios``, or ./scenarios."""
    import os

    if os.environ.get("MBDFMU_SCENARIOS"):
        return Path(os.environ["MBDFMU_SCENARIOS"])
    source = Path(__file__).resolve().parents[3] / "scenarios"
    if source.is_dir():
        return source
    try:
        from importlib import resources

        installed = Path(str(resources.files("mbdfmu.scenarios")))
        if installed.is_dir():
            return installed
    except (ImportError, TypeError):
        pass
    return Path.cwd() / "scenarios"


SCENARIOS = _scenarios_folder()
CONNECTIONS_FILE = "connections.toml"
ALGORITHMS = ("jacobi", "gauss-seidel")
IDENTIFIER = re.compile(r"[A-Za-z_][A-Za-z0-9_]*")
REAL = ("Real", "Float64")        # FMI 2.0's and FMI 3.0's type of the connected variables
TOP_KEYS = {"name", "description", "t_end", "step", "algorithm", "order", "record", "plot",
            "compare", "reference", "instances", "connections", "parameters", "variable_step",
            "power_bonds"}
VARIABLE_STEP_KEYS = {"rtol", "atol", "h_min", "h_max", "h_initial", "nominal"}


class ScenarioError(ReadError):
    """A connections file that cannot be read or does not fit its FMUs (every problem)."""


@dataclass(frozen=True)
class Instance:
    """One FMU of the scenario: ``source`` is a scene (.toml) or a companion source (.py)."""

    name: str
    source: Path


def _part(end: str, index: int) -> property:
    """The instance (index 0) or the variable (1) of a connection's ``end``."""
    return property(lambda self: getattr(self, end).split(".", 1)[index])


@dataclass(frozen=True)
class Connection:
    """An output of one instance feeding an input of another (``instance.variable``)."""

    source: str
    target: str
    source_instance = _part("source", 0)
    source_variable = _part("source", 1)
    target_instance = _part("target", 0)
    target_variable = _part("target", 1)


@dataclass(frozen=True)
class VariableStepSettings:
    """The error-controlled master's settings (see ``master.VariableStep``)."""

    rtol: float = 1e-2
    atol: float = 1e-6
    h_min: float = 1e-7
    h_max: float | None = None      # default: 10 times the scenario's step
    h_initial: float | None = None  # default: the scenario's step
    nominal: dict = field(default_factory=dict)  # "instance.output" -> typical magnitude


@dataclass(frozen=True)
class Scenario:
    """A parsed connections file; paths are absolute."""

    name: str
    description: str
    path: Path
    instances: tuple[Instance, ...]
    connections: tuple[Connection, ...]
    parameters: dict[str, float]
    t_end: float
    step: float
    algorithm: str = "jacobi"
    order: tuple[str, ...] = ()
    record: tuple[str, ...] = ()
    plot: tuple[str, ...] = ()
    compare: tuple[str, ...] = ()
    reference: Path | None = None
    variable_step: VariableStepSettings = field(default_factory=VariableStepSettings)
    # instance -> (effort input, flow output) of the scenario's power bond (ECCO)
    power_bonds: dict = field(default_factory=dict)

    @property
    def folder(self) -> Path:
        return self.path.parent

    def instance(self, name: str) -> Instance:
        for i in self.instances:
            if i.name == name:
                return i
        raise KeyError(name)

    def instance_parameters(self, instance: str) -> dict[str, float]:
        """``{variable: value}`` of one instance's start values."""
        prefix = instance + "."
        return {k[len(prefix):]: v for k, v in self.parameters.items() if k.startswith(prefix)}

    def recorded(self) -> list[str]:
        """The outputs a run records: every connected output, then ``record``, then
        ``compare`` and ``plot`` (each once, in that order)."""
        names = [c.source for c in self.connections] + list(self.record) + list(self.compare) \
            + list(self.plot)
        return list(dict.fromkeys(names))


def resolve(name_or_path: str | Path) -> Path:
    """A connections file from ``NAME`` (scenarios/NAME/connections.toml), ``NAME:VARIANT``
    (scenarios/NAME/connections_VARIANT.toml), a folder or a file."""
    text = str(name_or_path)
    path = Path(text)
    if path.is_file():
        return path.resolve()
    if path.is_dir():
        return (path / CONNECTIONS_FILE).resolve()
    name, _, variant = text.partition(":")
    folder = SCENARIOS / name
    file = folder / (f"connections_{variant}.toml" if variant else CONNECTIONS_FILE)
    if file.is_file():
        return file
    known = sorted(p.parent.name for p in SCENARIOS.glob(f"*/{CONNECTIONS_FILE}"))
    variants = sorted(f"{p.parent.name}:{p.stem.removeprefix('connections_')}"
                      for p in SCENARIOS.glob("*/connections_*.toml"))
    raise ScenarioError(f'no scenario "{text}"{suggest(text, known + variants)}; scenarios: '
                        f"{', '.join(known + variants) or 'none'} "
                        "(or give a folder or a connections file)")


def check_variables(scenario: Scenario, descriptions: dict) -> None:
    """Check names and causalities against the FMUs' model descriptions (fmpy's
    ``ModelDescription`` per instance); raise one ``ScenarioError`` with every problem."""
    where = scenario.path.name
    problems: list[str] = []
    variables = {inst: {v.name: v for v in md.modelVariables} for inst, md in descriptions.items()}

    def lookup(ref: str, causalities: tuple[str, ...], what: str):
        inst, var = ref.split(".", 1)
        table = variables[inst]
        if var not in table:
            hint = suggest(var, list(table)).replace('"', f'"{inst}.', 1)
            problems.append(f'{where}: {what} "{ref}": {inst} has no variable "{var}"{hint}')
            return None
        v = table[var]
        if v.causality not in causalities:
            problems.append(f'{where}: {what} "{ref}" has causality {v.causality}, not '
                            f"{' or '.join(causalities)}")
        return v

    for c in scenario.connections:
        a = lookup(c.source, ("output",), "connection from")
        b = lookup(c.target, ("input",), "connection to")
        if a is not None and b is not None:
            if a.type not in REAL or b.type not in REAL:
                problems.append(f'{where}: connection "{c.source}" -> "{c.target}": only Real '
                                "variables are connected")
            elif (a.unit or "") != (b.unit or "") and a.unit and b.unit:
                problems.append(f'{where}: connection "{c.source}" ({a.unit}) -> "{c.target}" '
                                f"({b.unit}): units differ")
    for key in scenario.parameters:
        v = lookup(key, ("parameter", "input"), "parameter")
        if v is not None and v.type not in REAL:
            problems.append(f'{where}: parameter "{key}" is a {v.type}; set it in the scene file')
    for key in ("record", "plot", "compare"):
        for ref in getattr(scenario, key):
            lookup(ref, ("output",), key)
    if problems:
        raise ScenarioError(problems)


def reference_function(scenario: Scenario):
    """The scenario's reference as ``f(times) -> {name: values}`` (None without one): its
    ``reference`` file's ``reference(scenario, times)``."""
    if scenario.reference is None:
        return None
    import importlib.util

    module_name = f"_mbdfmu_reference_{scenario.name}"
    spec = importlib.util.spec_from_file_location(module_name, scenario.reference)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    if not hasattr(module, "reference"):
        raise ScenarioError(f"{scenario.reference}: no function reference(scenario, times)")
    return lambda times: module.reference(scenario, times)
