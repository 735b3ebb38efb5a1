"""Turn a scene into an FMI 2.0 co-simulation FMU: ``build_fmu(scene_path, output=None)``.

The FMU holds, under ``resources/``:

* ``<module>.py``: ``slave.py`` with its generated block filled in (model identity, the
  variable table, units) and its class renamed; ``<module>`` is
  ``mbdfmu_<Model>_<hash>``, unique to the model and to everything shipped, so two
  different mbdfmu FMUs never share a module in one process;
* ``_mbdfmu_<hash>/``: a copy of the parts of mbdfmu a simulation needs (``SHIPPED``: the
  model, equations and integrators, the simulation; no CLI, plotting, benchmarks,
  co-simulation or FMU building), imported under that name, so the FMU never uses (and is
  never shadowed by) an mbdfmu installed in the host;
* ``scene.json`` (the scene as read, what the FMU loads: no TOML reader needed at run
  time) and ``scene.toml`` (the source, for people);
* ``pythonfmu/`` (pythonfmu adds it).

pythonfmu cannot express units, unit definitions or a generation tool of our own: the slave's
``to_xml`` adds them, so the model description comes out complete from pythonfmu's builder.
"""

from __future__ import annotations

import json
import re
import shutil
import tempfile
from pathlib import Path

from .. import __file__ as core_init
from .. import __version__
from ..equations import Equations
from ..equations.projection import assemble
from ..integrators import METHOD_NAMES
from ..integrators.settings import settings_from_scene
from ..model.reader import resolve_scene_path, scene_from_dict
from ..model.toml_table import load_toml, tomllib
from ..model.variables import inputs, parameters, selected_outputs
from ..errors import SceneError
from .common import CAPABILITIES, BuildError, build_isolated, digest

HERE = Path(__file__).resolve().parent
TEMPLATE = HERE / "slave.py"
TEMPLATE_CLASS = "MbdfmuSlave"
GENERATED = re.compile(r"# >>> GENERATED.*?\n(.*?)# <<< GENERATED\n", re.S)
# What of mbdfmu an FMU ships: the layers a simulation runs on (no CLI, plotting,
# benchmarks, co-simulation masters or FMU building: they would pull in matplotlib, dask,
# fmpy or libcosimpy, and change the host's process).
SHIPPED_PACKAGES = ("model", "equations", "integrators")
SHIPPED_MODULES = ("__init__.py", "errors.py", "plain.py", "result.py", "signals.py",
                   "simulation.py")

# SI base-unit exponents of each unit symbol that may appear in a unit name.
_SYMBOLS = {
    "1": {}, "kg": {"kg": 1}, "m": {"m": 1}, "s": {"s": 1}, "rad": {"rad": 1},
    "N": {"kg": 1, "m": 1, "s": -2}, "J": {"kg": 1, "m": 2, "s": -2},
    "Hz": {"s": -1}, "W": {"kg": 1, "m": 2, "s": -3},
}


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


def select_outputs(scene) -> list:
    """The scene's ``outputs`` globs, or every body state, joint reaction, driver effort
    (``model.variables.selected_outputs``, which linearize uses too)."""
    try:
        return selected_outputs(scene)
    except SceneError as exc:
        raise BuildError(str(exc)) from None


def solver_variables(scene) -> tuple[list[tuple], dict]:
    """The solver parameters (table rows) and their start values: the scene's settings as
    ``SolverSettings`` defaults and checks them (step 0: the method's default)."""
    settings = settings_from_scene(scene)
    rows = [
        ("solver.method", "solver", "String", "",
         f"integration method: {', '.join(METHOD_NAMES)}"),
        ("solver.step", "solver", "Real", "s",
         "internal step of fixed-step methods; largest step of adaptive ones "
         "(0: the method's default, no limit for adaptive methods)"),
        ("solver.rtol", "solver", "Real", "1", "relative tolerance of adaptive methods"),
        ("solver.atol", "solver", "Real", "1", "absolute tolerance of adaptive methods"),
    ]
    values = {"solver.method": settings.method_name, "solver.step": float(settings.step or 0.0),
              "solver.rtol": settings.rtol, "solver.atol": settings.atol}
    return rows, values


def variable_table(scene) -> tuple[list[tuple], dict]:
    """Every variable of the scene's FMU in value-reference order (from the variable table,
    ``model/variables.py``), and the solver starts."""
    rows = [(p.name, "parameter", "Real", p.unit, p.description) for p in parameters(scene)]
    solver_rows, solver_values = solver_variables(scene)
    rows += solver_rows
    rows += [(v.name, "input", "Real", v.unit, v.description) for v in inputs(scene)]
    rows += [(v.name, "output", "Real", v.unit, v.description)
             for v in select_outputs(scene)]
    return rows, solver_values


def shipped_files(package_dir: Path) -> list[Path]:
    """The files of mbdfmu an FMU carries (``SHIPPED_PACKAGES`` and ``SHIPPED_MODULES``)."""
    files = [package_dir / name for name in SHIPPED_MODULES]
    for package in SHIPPED_PACKAGES:
        files += [p for p in (package_dir / package).rglob("*.py") if "__pycache__" not in p.parts]
    return sorted(files)


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


def with_start_values(scene_path: Path, parameters: dict) -> tuple[dict, str]:
    """The scene's data and TOML text with ``parameters`` (names as the FMU's, solver.*
    included) as the values of the scene's keys, so that the FMU's start values are them
    (none: the file as it is)."""
    import tomlkit

    from ..model.writer import set_parameters
    data = load_toml(scene_path, SceneError)
    text = scene_path.read_text(encoding="utf-8")
    if not parameters:
        return data, text
    scene = scene_from_dict(data, source=scene_path.name)
    doc = tomlkit.parse(text)
    set_parameters(doc, scene, {k: v for k, v in parameters.items()
                                if not k.startswith("solver.")})
    for name, value in parameters.items():
        if name.startswith("solver."):
            if name not in {row[0] for row in solver_variables(scene)[0]}:
                raise BuildError(f"{scene_path.name}: unknown parameter {name!r}")
            doc.setdefault("simulation", tomlkit.table())[name[len("solver."):]] = value
    text = tomlkit.dumps(doc)
    return tomllib.loads(text), text


def build_fmu(scene_path, output=None, parameters=None) -> Path:
    """Build the FMU of a scene file (or a shipped scene's name); returns its path (default
    ``<Model>.fmu`` in the cwd). ``parameters``: start values of the FMU's parameters
    (names as in its model description), checked as the FMU checks them."""
    from pythonfmu import __version__ as pythonfmu_version
    scene_path = resolve_scene_path(scene_path)
    scene_data, scene_text = with_start_values(scene_path, parameters or {})
    scene = scene_from_dict(scene_data, source=scene_path.name)
    name = scene.name
    assemble(Equations(scene, kernel="numpy"))   # a scene that cannot start is no FMU
    variables, solver_values = variable_table(scene)
    scene_json = json.dumps(scene_data, indent=1, sort_keys=True).encode()

    package_dir = Path(core_init).resolve().parent
    files = shipped_files(package_dir)
    package_tag = digest(*(f.relative_to(package_dir).as_posix().encode() + b"\0" + f.read_bytes()
                            for f in files))
    run = scene.simulation
    interval = settings_from_scene(scene).output_interval_for(run.t_end)
    experiment = {"start": 0.0, "stop": run.t_end, "step": interval}
    if run.rtol is not None:
        experiment["tolerance"] = run.rtol
    model = {
        "name": name,
        "description": scene.description,
        "version": scene.version,
        "author": scene.author or "mbdfmu",
        "generation_tool": f"mbdfmu {__version__} (pythonfmu {pythonfmu_version})",
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
        (stage / "scene.toml").write_text(scene_text, encoding="utf-8")
        fmu = build_isolated(
            script, dest=output, own_modules={module, model["core_package"]},
            project_files=[core, stage / "scene.json", stage / "scene.toml"], **CAPABILITIES)
    return Path(fmu)
