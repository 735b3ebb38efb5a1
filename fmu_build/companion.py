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
from .common import BuildError, digest, write_checked
from .model_description import Capabilities, ModelInfo
from .runtime import companion as base
from .runtime.variables import Variable

# The import line a companion source uses for its base (rewritten in the FMU).
BASE_IMPORT = re.compile(
    r"^from mbdfmu\.fmu_build\.runtime import companion as base[ \t]*$", re.M)
FMU_IMPORT = "from . import companion as base"
MODEL_CLASS = ("\n\nclass Model(base.CompanionModel):\n"
               "    COMPANION = {name}\n    OUTPUTS = {outputs!r}\n")


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


def dependencies(cls: type[base.CompanionSlave]) -> dict[str, tuple]:
    """Output -> (the inputs it depends on within a communication point, its knowns at
    initialization): ``DEPENDENCIES`` if the class gives it, else the inputs ``outputs()``
    reads at the start values (all inputs if it cannot run); at initialization also those
    ``initial_state()`` reads, and every parameter."""
    inputs = [v.name for v in cls.VARIABLES if v.kind == "input"]
    parameters = tuple(v.name for v in cls.VARIABLES if v.kind == "parameter")
    names = [v.name for v in cls.VARIABLES if v.kind == "output"]
    declared = getattr(cls, "DEPENDENCIES", None)
    if declared is not None:
        return {n: (tuple(declared.get(n, ())), None) for n in names}
    values = _Tracer({v.name: float(v.start) for v in cls.VARIABLES}, set(inputs))
    companion = cls(_Host(values))
    try:
        state = companion.initial_state()
        at_start = set(values.read)
        values.read.clear()
        companion.outputs(state)
    except Exception:  # noqa: BLE001 - cannot tell: declare every input
        return {n: (None, None) for n in names}
    step = tuple(i for i in inputs if i in values.read)
    initial = parameters + tuple(i for i in inputs if i in values.read | at_start)
    return {n: (step, initial) for n in names}


def variable_table(cls: type[base.CompanionSlave], source: Path) -> list[Variable]:
    kinds = {v.kind for v in cls.VARIABLES} - set(base.KINDS)
    if kinds or not cls.VARIABLES:
        raise BuildError(f"{source}: {cls.__name__}.VARIABLES must list Var(name, kind, ...) "
                         f"with kind parameter, input or output (got {sorted(kinds) or 'none'})")
    depends = dependencies(cls)
    table = []
    for k, v in enumerate(cls.VARIABLES):
        extra = (dict(initial="calculated", dependencies=depends[v.name][0],
                      initial_dependencies=depends[v.name][1]) if v.kind == "output"
                 else dict(start=float(v.start)))
        table.append(Variable(v.name, k, causality=v.kind, unit=v.unit or None,
                              description=v.description, **extra))
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
    table = variable_table(cls, source)
    outputs = tuple(v.name for v in table if v.causality == "output")
    model = fmu_text + MODEL_CLASS.format(name=cls.__name__, outputs=outputs)
    info = ModelInfo(description=cls.DESCRIPTION, author=cls.AUTHOR, version=cls.VERSION,
                     generation_tool=f"mbdfmu {__version__} companion (native FMI "
                                     f"{fmi_version}.0 runtime)")
    capabilities = Capabilities(can_interpolate_inputs=bool(cls.INTERPOLATES_INPUTS),
                                max_output_derivative_order=2)
    return write_checked(output, cls.__name__, table, model, info=info, default_experiment=None,
                         capabilities=capabilities, fmi_version=fmi_version)
