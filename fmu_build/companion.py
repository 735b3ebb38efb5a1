"""Build a companion FMU (a DC motor, a hydraulic cylinder, ...) from its Python source.

A companion source imports its base as

    from mbdfmu.fmu_build.runtime import companion as base

so it runs and can be tested in Python as it is. In the FMU it becomes the model module
(``resources/model_<hash>.py``, a submodule of the runtime package, so the import line is
rewritten to ``from . import companion as base``) with a ``Model`` class appended that runs
its ``CompanionSlave`` subclass. Module names carry a hash of their content, so two
companions (or two versions of one) never share a module in a host, and neither depends
on an mbdfmu installed there (docs/fmu.md).

The variable table comes from the class's ``VARIABLES``. Output dependencies (FMI 2.0
section 2.2.8) are the inputs that ``outputs()`` reads, traced here with the start values:
an output that reads no input is declared without direct feedthrough (``dependencies=""``),
so masters do not see algebraic loops that are not there. A companion whose outputs read
an input only on some branches sets ``DEPENDENCIES = {output: (inputs...)}`` itself.
"""

from __future__ import annotations

import importlib.util
import re
import sys
from pathlib import Path

from .. import __version__
from . import osp
from .common import BuildError, digest, write_checked
from .model_description import Capabilities, ModelInfo
from .package import per_second
from .runtime import companion as base
from .runtime.companion_states import derivative_name
from .runtime.variables import Variable

# The import line a companion source uses for its base (rewritten in the FMU).
BASE_IMPORT = re.compile(
    r"^from mbdfmu\.fmu_build\.runtime import companion as base[ \t]*$", re.M)
FMU_IMPORT = "from . import companion as base"
MODEL_CLASS = ("\n\nclass Model(base.CompanionModel):\n"
               "    COMPANION = {name}\n    OUTPUTS = {outputs!r}\n"
               "    STATE_VARIABLES = {states!r}\n")


class _Tracer(dict):
    """Values that remember which of ``watched`` were read."""

    def __init__(self, values: dict, watched: set[str]):
        super().__init__(values)
        self.watched, self.read = watched, set()

    def __getitem__(self, key):
        if key in self.watched:
            self.read.add(key)
        return super().__getitem__(key)


class _Host:
    """Stands in for the FMU while the builder runs a companion once."""

    def __init__(self, values: dict):
        self.values, self.time = values, 0.0

    def log(self, text: str) -> None:
        pass

    def input_at(self, name: str, t: float) -> float:
        return self.values[name]

    def taylor_at(self, name: str, t: float) -> list[float]:
        return [self.values[name]]


def _load(source: Path, text: str) -> type[base.CompanionSlave]:
    """The one ``CompanionSlave`` subclass the source defines (imported under a throwaway name)."""
    name = f"_mbdfmu_companion_probe_{digest(text.encode())}"
    spec = importlib.util.spec_from_file_location(name, source)
    module = importlib.util.module_from_spec(spec)
    sys.modules[name] = module
    try:
        spec.loader.exec_module(module)
    except Exception as exc:  # noqa: BLE001 - any error of the source is a build error
        raise BuildError(f"{source}: {type(exc).__name__}: {exc}") from None
    finally:
        sys.modules.pop(name, None)
    classes = [c for c in vars(module).values() if isinstance(c, type)
               and issubclass(c, base.CompanionSlave) and c.__module__ == name]
    if len(classes) != 1:
        raise BuildError(f"{source}: defines {len(classes)} subclasses of "
                         "companion.CompanionSlave; a companion source defines one")
    return classes[0]


def _probe(cls: type[base.CompanionSlave]):
    """Run the companion once at its start values: (its state, the inputs
    ``initial_state`` reads, the inputs and state keys ``outputs`` reads, those ``rates``
    reads (None without rates)); None when it cannot run."""
    inputs = {v.name for v in cls.VARIABLES if v.kind == "input"}
    values = _Tracer({v.name: float(v.start) for v in cls.VARIABLES}, inputs)
    companion = cls(_Host(values))
    try:
        state = companion.initial_state()
        at_start = set(values.read)
        traced = []
        for function in ("outputs", "rates"):
            if function == "rates" and not hasattr(cls, "rates"):
                traced.append(None)
                continue
            values.read.clear()
            keys = _Tracer(state, set(state))
            getattr(companion, function)(keys)
            traced.append((set(values.read), keys.read))
    except Exception:  # noqa: BLE001 - cannot tell: the caller declares every known
        return None
    return state, at_start, traced[0], traced[1]


def exposed_states(cls: type[base.CompanionSlave], probe) -> dict[str, str]:
    """State key -> its variable: the output of that name, else a local of that name (a
    companion with ``rates`` only)."""
    if not hasattr(cls, "rates") or probe is None:
        return {}
    return {key: key for key in probe[0]}


def dependencies(cls: type[base.CompanionSlave], probe, states: dict) -> dict[str, tuple]:
    """Output -> (its knowns within a communication point, its knowns at initialization):
    ``DEPENDENCIES`` if the class gives it (and every exposed state), else the inputs and
    exposed states ``outputs()`` reads at the start values (every known if it cannot run);
    at initialization also the inputs ``initial_state()`` reads, and every parameter.
    A state derivative (``der(<state>)``) depends on what ``rates()`` reads."""
    inputs = [v.name for v in cls.VARIABLES if v.kind == "input"]
    parameters = tuple(v.name for v in cls.VARIABLES if v.kind == "parameter")
    names = [v.name for v in cls.VARIABLES if v.kind == "output"]
    declared = getattr(cls, "DEPENDENCIES", None)
    out: dict[str, tuple] = {}
    if probe is not None and states:
        read_inputs, read_keys = probe[3]
        for key, variable in states.items():
            out[derivative_name(variable)] = (tuple(i for i in inputs if i in read_inputs)
                                              + tuple(states[k] for k in states if k in read_keys),
                                              None)
    if declared is not None:
        out.update({n: (tuple(declared.get(n, ())) + tuple(states.values()), None) for n in names})
        return out
    if probe is None:
        return {**out, **{n: (None, None) for n in names}}
    _, at_start, (read_inputs, read_keys), _ = probe
    step = tuple(i for i in inputs if i in read_inputs) + \
        tuple(states[k] for k in states if k in read_keys)
    initial = parameters + tuple(i for i in inputs if i in read_inputs | at_start)
    out.update({n: (step, initial) for n in names})
    return out


def variable_table(cls: type[base.CompanionSlave], source: Path,
                   states: dict | None = None, probe=None) -> list[Variable]:
    kinds = {v.kind for v in cls.VARIABLES} - set(base.KINDS)
    if kinds or not cls.VARIABLES:
        raise BuildError(f"{source}: {cls.__name__}.VARIABLES must list Var(name, kind, ...) "
                         f"with kind parameter, input or output (got {sorted(kinds) or 'none'})")
    states = states or {}
    depends = dependencies(cls, probe, states)
    info = getattr(cls, "STATE_INFO", {})
    derivative_of = {v: k for k, v in states.items()}
    table = []
    for k, v in enumerate(cls.VARIABLES):
        extra = (dict(initial="calculated", dependencies=depends[v.name][0],
                      initial_dependencies=depends[v.name][1]) if v.kind == "output"
                 else dict(start=float(v.start)))
        table.append(Variable(v.name, k, causality=v.kind, unit=v.unit or None,
                              description=v.description, **extra))
    units = {v.name: v.unit for v in table}
    for key, variable in states.items():
        if variable not in units:
            unit, text = info.get(key, (None, f"internal state {key}"))
            table.append(Variable(variable, len(table), causality="local", initial="calculated",
                                  unit=unit or None, description=text))
            units[variable] = unit or None
    for variable in derivative_of:
        name = derivative_name(variable)
        table.append(Variable(name, len(table), causality="local", initial="calculated",
                              unit=per_second(units[variable], 1), derivative=variable,
                              dependencies=depends[name][0],
                              description=f"time derivative of {variable}"))
    return table


def build_companion(source, output=None, fmi_version: int = 2) -> Path:
    """Build the FMU (FMI ``fmi_version``.0) of a companion source; returns its path
    (default ``<Class>.fmu`` in the cwd, the class name being the model identifier)."""
    source = Path(source)
    if not source.is_file():
        raise BuildError(f"{source}: no such file")
    text = source.read_text(encoding="utf-8")
    fmu_text, uses_base = BASE_IMPORT.subn(FMU_IMPORT, text)
    if uses_base != 1:
        raise BuildError(f"{source}: a companion source imports its base with the line "
                         f'"from mbdfmu.fmu_build.runtime import companion as base"')
    cls = _load(source, text)
    probe = _probe(cls)
    states = exposed_states(cls, probe)
    table = variable_table(cls, source, states, probe)
    outputs = tuple(v.name for v in table if v.causality == "output")
    model = fmu_text + MODEL_CLASS.format(name=cls.__name__, outputs=outputs, states=states)
    info = ModelInfo(description=cls.DESCRIPTION, author=cls.AUTHOR, version=cls.VERSION,
                     generation_tool=f"mbdfmu {__version__} companion (native FMI "
                                     f"{fmi_version}.0 runtime)")
    capabilities = Capabilities(can_interpolate_inputs=bool(cls.INTERPOLATES_INPUTS),
                                max_output_derivative_order=2,
                                provides_directional_derivative=bool(states))
    declared = getattr(cls, "POWER_PORTS", {})
    try:
        ports = osp.checked_ports([osp.Port(name, *pair) for name, pair in declared.items()],
                                  {v.name: v.unit for v in table}, f"{source}: POWER_PORTS")
    except (osp.PortError, TypeError) as exc:
        raise BuildError(str(exc) if isinstance(exc, osp.PortError) else
                         f"{source}: POWER_PORTS must map a port name to (effort, flow) "
                         "variable names") from None
    return write_checked(output, cls.__name__, table, model, info=info, default_experiment=None,
                         capabilities=capabilities, fmi_version=fmi_version,
                         extra_files=osp.extra_files(ports))
