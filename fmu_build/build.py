"""Turn a scene into an FMI 2.0 co-simulation FMU: ``build_fmu(scene_path, output=None)``.

The FMU holds, under ``resources/``:

* ``<module>.py``: ``slave.py`` with its generated block filled in (model identity, the
  variable table, units) and its class renamed; ``<module>`` is
  ``mbdfmu_<Model>_<hash>``, unique to the model and to everything shipped, so two
  different mbdfmu FMUs never share a module in one process;
* ``_mbdfmu_<hash>/``: a copy of the mbdfmu package (without ``cli``, ``plotting``, ``cosim``),
  imported under that name, so the FMU never uses (and is never shadowed by) an mbdfmu
  installed in the host;
* ``scene.json`` (the scene as read, what the FMU loads: no TOML reader needed at run
  time) and ``scene.toml`` (the source, for people);
* ``pythonfmu/`` (pythonfmu adds it).

pythonfmu cannot express units, unit definitions or a generation tool of our own: the slave's
``to_xml`` adds them, so the model description comes out complete from pythonfmu's builder.
"""

from __future__ import annotations

import fnmatch
import hashlib
import json
import re
import shutil
import sys
import tempfile
from pathlib import Path

import mbdfmu
from mbdfmu import integrators
from mbdfmu.errors import MbdfmuError
from mbdfmu.scene import parameters

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover - Python 3.10
    import tomli as tomllib

HERE = Path(__file__).resolve().parent
TEMPLATE = HERE / "slave.py"
TEMPLATE_CLASS = "MbdfmuSlave"
GENERATED = re.compile(r"# >>> GENERATED.*?\n(.*?)# <<< GENERATED\n", re.S)
# Modules of mbdfmu an FMU does not need (they would pull in matplotlib).
NOT_SHIPPED = {"cli.py", "plotting.py", "__main__.py"}
# Subpackages an FMU does not need: the co-simulation masters (they import fmpy, libcosimpy).
NOT_SHIPPED_PACKAGES = {"cosim"}
# Output points of the DefaultExperiment when the scene gives no output interval.
DEFAULT_OUTPUT_POINTS = 500

# SI base-unit exponents of each unit symbol that may appear in a unit name.
_SYMBOLS = {
    "1": {}, "kg": {"kg": 1}, "m": {"m": 1}, "s": {"s": 1}, "rad": {"rad": 1},
    "N": {"kg": 1, "m": 1, "s": -2}, "J": {"kg": 1, "m": 2, "s": -2},
    "Hz": {"s": -1}, "W": {"kg": 1, "m": 2, "s": -3},
}


class BuildError(MbdfmuError):
    """A scene that cannot be turned into an FMU (the message says why)."""


def base_units(unit: str) -> dict[str, int]:
    """SI exponents of a unit name such as ``N.m.s/rad`` or ``kg.m2``."""
    exponents: dict[str, int] = {}
    numerator, _, denominator = unit.partition("/")
    for part, sign in ((numerator, 1), (denominator, -1)):
        for token in filter(None, part.split(".")):
            symbol, power = re.fullmatch(r"([A-Za-z]+|1)(-?\d*)", token).groups()
            if symbol not in _SYMBOLS:
                raise BuildError(f'unit "{unit}": unknown symbol "{symbol}"')
            for base, e in _SYMBOLS[symbol].items():
                exponents[base] = exponents.get(base, 0) + sign * e * int(power or 1)
    return {k: v for k, v in exponents.items() if v}


def select_outputs(scene, variables) -> list:
    """The scene's ``outputs`` globs, or every body state, joint reaction, driver effort."""
    names = [v.name for v in variables]
    if scene.outputs is not None:
        patterns = list(scene.outputs)
        unmatched = [p for p in patterns if not fnmatch.filter(names, p)]
        if unmatched:
            raise BuildError(f"{scene.source}: outputs {unmatched} match no variable; "
                             f"this scene's outputs: {', '.join(names)}")
    else:
        patterns = ([f"{b.name}.*" for b in scene.bodies] + [f"{j.name}.*" for j in scene.joints]
                    + [f"{d.name}.effort" for d in scene.drivers])
    return [v for v in variables if any(fnmatch.fnmatchcase(v.name, p) for p in patterns)]


def solver_variables(scene) -> tuple[list[tuple], dict]:
    """The solver parameters (table rows) and their start values, as ``simulate`` defaults them."""
    settings = scene.simulation
    method = integrators.method_class(settings.method)
    step = settings.step if settings.step is not None else (
        0.0 if method.adaptive else method.default_step)
    rows = [
        ("solver.method", "solver", "String", "",
         f"integration method: {', '.join(integrators.METHODS)}"),
        ("solver.step", "solver", "Real", "s",
         "internal step of fixed-step methods; largest step of adaptive ones "
         "(0: the method's default, no limit for adaptive methods)"),
        ("solver.rtol", "solver", "Real", "1", "relative tolerance of adaptive methods"),
        ("solver.atol", "solver", "Real", "1", "absolute tolerance of adaptive methods"),
    ]
    values = {"solver.method": method.name, "solver.step": float(step),
              "solver.rtol": float(settings.rtol if settings.rtol is not None else method.default_rtol),
              "solver.atol": float(settings.atol if settings.atol is not None else method.default_atol)}
    return rows, values


def variable_table(scene) -> tuple[list[tuple], dict]:
    """Every variable of the scene's FMU in value-reference order, and the solver starts."""
    sim = mbdfmu.Simulation(scene)  # also proves that the scene assembles
    rows = [(p.name, "parameter", "Real", p.unit, p.description) for p in parameters(scene)]
    solver_rows, solver_values = solver_variables(scene)
    rows += solver_rows
    rows += [(v.name, "input", "Real", v.unit, v.description) for v in sim.system.inputs]
    rows += [(v.name, "output", "Real", v.unit, v.description)
             for v in select_outputs(scene, sim.system.outputs)]
    return rows, solver_values


def _package_files(package_dir: Path) -> list[Path]:
    return sorted(p for p in package_dir.rglob("*.py")
                  if "__pycache__" not in p.parts and p.relative_to(package_dir).as_posix()
                  not in NOT_SHIPPED and p.relative_to(package_dir).parts[0]
                  not in NOT_SHIPPED_PACKAGES)


def build_isolated(script: Path, dest: Path, own_modules: set[str], **options) -> Path:
    """pythonfmu's ``build_FMU``, leaving this process as it found it.

    pythonfmu imports the script (and what it ships) in this process and leaves its folder
    on ``sys.path``: both are undone (for the FMU's own modules only; third-party modules
    imported on the way stay), so this process later loads the FMU's own copy.
    """
    from pythonfmu.builder import FmuBuilder

    saved_path, saved_modules = list(sys.path), set(sys.modules)
    try:
        return Path(FmuBuilder.build_FMU(script, dest=dest, **options))
    finally:
        sys.path[:] = saved_path
        for m in set(sys.modules) - saved_modules:
            if m.split(".")[0] in own_modules:
                del sys.modules[m]


def digest(*chunks: bytes) -> str:
    """A short content hash that tells FMU modules apart (length-prefixed chunks)."""
    h = hashlib.sha256()
    for c in chunks:
        h.update(len(c).to_bytes(8, "little"))
        h.update(c)
    return h.hexdigest()[:12]


def render_slave(model: dict, variables: list[tuple], class_name: str) -> str:
    """The template with its generated block filled in and its class renamed."""
    units = {row[3]: base_units(row[3]) for row in variables if row[3]}
    block = (f"CORE_PACKAGE = {model['core_package']!r}\n"
             f"MODEL = {model!r}\n"
             f"VARIABLES = (\n" + "".join(f"    {row!r},\n" for row in variables) + ")\n"
             f"UNITS = {units!r}\n")
    text = TEMPLATE.read_text(encoding="utf-8")
    text, n = GENERATED.subn(lambda m: m.group(0).replace(m.group(1), block), text)
    if n != 1:
        raise BuildError(f"{TEMPLATE}: the GENERATED block is missing")
    return text.replace(TEMPLATE_CLASS, class_name)


def build_fmu(scene_path, output=None) -> Path:
    """Build the FMU of a scene file; returns its path (default ``<Model>.fmu`` in the cwd)."""
    from pythonfmu import __version__ as pythonfmu_version
    scene_path = Path(scene_path)
    scene = mbdfmu.load_scene(scene_path)
    name = scene.name
    if not re.fullmatch(r"[A-Za-z_][A-Za-z0-9_]*", name):
        raise BuildError(f'{scene_path.name}: name "{name}" is not a valid identifier '
                         "(it becomes the FMU's model identifier)")
    variables, solver_values = variable_table(scene)
    scene_data = tomllib.loads(scene_path.read_text(encoding="utf-8"))
    scene_json = json.dumps(scene_data, indent=1, sort_keys=True).encode()

    package_dir = Path(mbdfmu.__file__).resolve().parent
    files = _package_files(package_dir)
    package_tag = digest(*(f.relative_to(package_dir).as_posix().encode() + b"\0" + f.read_bytes()
                            for f in files))
    settings = scene.simulation
    interval = settings.output_interval or settings.t_end / DEFAULT_OUTPUT_POINTS
    experiment = {"start": 0.0, "stop": settings.t_end, "step": interval}
    if settings.rtol is not None:
        experiment["tolerance"] = settings.rtol
    model = {
        "name": name,
        "description": scene.description,
        "version": scene.version,
        "author": scene.author or "mbdfmu",
        "generation_tool": f"mbdfmu {mbdfmu.__version__} (pythonfmu {pythonfmu_version})",
        "default_experiment": experiment,
        "scene_file": "scene.json",
        "solver": solver_values,
        "core_package": f"_mbdfmu_{package_tag}",
    }
    tag = digest(package_tag.encode(), scene_json, TEMPLATE.read_bytes(),
                  repr(variables).encode(), repr(model).encode())
    module = f"mbdfmu_{name}_{tag}"
    source = render_slave(model, variables, class_name=f"{name}_{tag}")

    output = Path(output) if output is not None else Path.cwd() / f"{name}.fmu"
    if output.suffix != ".fmu":
        raise BuildError(f"{output}: an FMU file name must end in .fmu")
    output.parent.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory(prefix="mbdfmu_build_") as tmp:
        stage = Path(tmp)
        script = stage / f"{module}.py"
        script.write_text(source, encoding="utf-8")
        core = stage / model["core_package"]
        for f in files:
            target = core / f.relative_to(package_dir)
            target.parent.mkdir(parents=True, exist_ok=True)
            shutil.copyfile(f, target)
        (stage / "scene.json").write_bytes(scene_json)
        shutil.copyfile(scene_path, stage / "scene.toml")
        fmu = build_isolated(
            script, dest=output, own_modules={module, model["core_package"]},
            project_files=[core, stage / "scene.json", stage / "scene.toml"],
            needsExecutionTool=True, canHandleVariableCommunicationStepSize=True,
            canGetAndSetFMUstate=True, canSerializeFMUstate=True,
            canInterpolateInputs=False, canBeInstantiatedOnlyOncePerProcess=False)
    return Path(fmu)
