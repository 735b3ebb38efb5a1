"""Turn a scene into an FMI 2.0 (or 3.0) co-simulation FMU on the native runtime:
``build_fmu(scene_path, output=None, parameters=None, fmi_version=2)``.

The FMU (``package.write_fmu``) holds the native wrapper, the runtime package, and under
``resources/``:

* the model module: ``scene_model.py`` with its generated block filled in (the core
  package's name, the scene file, the outputs);
* ``_mbdfmu_<hash>/``: a copy of the parts of mbdfmu a simulation needs
  (``SHIPPED_PACKAGES``, ``SHIPPED_MODULES``: the model, equations and integrators, the
  simulation; no CLI, plotting, benchmarks, co-simulation or FMU building), imported under
  that name, so the FMU never uses (and is never shadowed by) an mbdfmu installed in the
  host, and two FMUs with different cores never share one;
* ``scene.json`` (the scene as read, what the FMU loads: no TOML reader needed at run
  time) and ``scene.toml`` (the source, for people).

The variable table comes from ``mbdfmu.model.variables`` (parameters, inputs, outputs)
and ``solver_variables`` (the ``solver.*`` parameters from ``SolverSettings``): there is
no second list of names.
"""

from __future__ import annotations

import itertools
import json
import os
import warnings
from pathlib import Path

from .. import __file__ as core_init
from .. import __version__
from ..equations import Equations
from ..equations.ckernel.build import KernelBuildError, compile_kernel
from ..equations.ckernel.scene_kernel import compile_scene_kernel, scene_header
from ..equations.projection import assemble
from ..errors import MbdfmuError, SceneError
from ..integrators import METHOD_NAMES
from ..integrators.settings import settings_from_scene
from ..model.limits import every_mode
from ..model.reader import resolve_scene_path, scene_from_dict
from ..model.scene import Body, SpringDamper
from ..model.toml_table import load_toml, tomllib
from ..model.variables import (GLOBAL_OUTPUTS, TABLES, input_layout, inputs, outputs,
                               parameters, selected_outputs)
from ..simulation import Simulation
from . import osp
from .common import BuildError, digest, fill_template, write_checked
from .model_description import Capabilities, DefaultExperiment, ModelInfo
from .runtime.kernels import MODE_KERNEL_FILE, SCENE_KERNEL_FILE
from .runtime.variables import Variable

HERE = Path(__file__).resolve().parent
TEMPLATE = HERE / "scene_model.py"
# What of mbdfmu an FMU ships: the layers a simulation runs on (no CLI, plotting,
# benchmarks, co-simulation masters or FMU building: they would pull in matplotlib, dask,
# fmpy or libcosimpy, and change the host's process).
SHIPPED_PACKAGES = ("model", "equations", "integrators")
SHIPPED_MODULES = ("__init__.py", "errors.py", "plain.py", "result.py", "signals.py",
                   "simulation.py", "simulation_inputs.py", "fast_steps.py")
# Work limits of one communication step (0: none): a step that needs more returns
# fmi2Discard with the reason, and the FMU stays at its last communication point.
MAX_STEPS_DEFAULT = 100_000
MAX_CPU_DEFAULT = 10.0
# The compiled C kernel's name in the FMU's resources (docs/performance.md): loaded at
# instantiation, so nothing is compiled when the FMU is loaded.
KERNEL_FILE = "mbdfmu_kernel.so"
# Whether a build ships the kernel built for its scene too (SCENE_KERNEL_FILE) when the
# caller does not say: "1" (the default) or "0" (a build some seconds shorter).
SCENE_KERNEL_ENV = "MBDFMU_SCENE_KERNEL"
# Kernels a build compiles for a scene with end stops or friction: its contact modes of
# distinct structures, fewest joints changed from the start first, this many at most
# (each is seconds of gcc at a build; a mode beyond them runs the generic kernel).
MAX_SCENE_KERNELS = 4
# Contact modes looked at for them (every combination of the event joints' states).
MAX_MODES_LOOKED_AT = 729


def select_outputs(scene) -> list:
    """The scene's ``outputs`` globs, or every body state, joint reaction, driver effort
    (``model.variables.selected_outputs``, which linearize uses too)."""
    try:
        return selected_outputs(scene)
    except SceneError as exc:
        raise BuildError(str(exc)) from None


def solver_variables(scene) -> list[tuple]:
    """The solver parameters as (name, type, unit, start, description): the scene's settings
    as ``SolverSettings`` defaults and checks them (step 0: the method's default), and the
    work limits of a communication step."""
    s = settings_from_scene(scene)
    return [
        ("solver.method", "String", None, s.method_name,
         f"integration method: {', '.join(METHOD_NAMES)}"),
        ("solver.step", "Real", "s", float(s.step or 0.0),
         "internal step of fixed-step methods; largest step of adaptive ones "
         "(0: the method's default, no limit for adaptive methods)"),
        ("solver.rtol", "Real", "1", s.rtol, "relative tolerance of adaptive methods "
         "(default: fmi2SetupExperiment's tolerance when the master gives one)"),
        ("solver.atol", "Real", "1", s.atol, "absolute tolerance of adaptive methods"),
        ("solver.max_steps_per_communication_step", "Integer", None, MAX_STEPS_DEFAULT,
         "most internal steps (accepted and rejected) of one fmi2DoStep, else fmi2Discard "
         "(0: no limit)"),
        ("solver.max_cpu_per_communication_step", "Real", "s", MAX_CPU_DEFAULT,
         "most CPU seconds of one fmi2DoStep, else fmi2Discard (0: no limit)"),
    ]


def kinematic_outputs(scene) -> set[str]:
    """Outputs of positions and velocities only (body states, spring lengths and rates,
    energies, constraint errors): at initialization they follow the driver inputs (the
    assembly) but no force input, unlike reactions, efforts and tensions."""
    names = {f"{b.name}.{s.suffix}" for b in scene.bodies for s in TABLES[Body].outputs}
    names |= {f"{f.name}.{suffix}" for f in scene.forces if isinstance(f, SpringDamper)
              for suffix in ("length", "velocity")}
    return names | {v.name for v in GLOBAL_OUTPUTS}


# A body's continuous states (its coordinates q, then velocities q'), each velocity the
# derivative of its coordinate, and the accelerations (derivatives of the velocities).
COORDINATES, VELOCITIES = ("x", "y", "phi"), ("vx", "vy", "omega")
ACCELERATIONS = (("ax", "m/s2", "x acceleration of {b}'s centre of mass"),
                 ("ay", "m/s2", "y acceleration of {b}'s centre of mass"),
                 ("alpha", "rad/s2", "angular acceleration of {b}"))


def state_names(scene) -> tuple[list[str], list[str]]:
    """(states, their derivatives) in FMI's order: per body x, y, phi, vx, vy, omega with
    derivatives vx, vy, omega, ax, ay, alpha (``ModelStructure/Derivatives``)."""
    states, derivatives = [], []
    for b in scene.bodies:
        states += [f"{b.name}.{c}" for c in COORDINATES + VELOCITIES]
        derivatives += [f"{b.name}.{c}" for c in VELOCITIES + tuple(a[0] for a in ACCELERATIONS)]
    return states, derivatives


def _with_states(scene, rows: list[dict]) -> list[dict]:
    """``rows`` with the continuous states exposed for directional derivatives (docs/fmu.md):
    the body state outputs become states (``derivative`` attributes), states the scene does
    not output and the accelerations are calculated locals (depending on every known);
    outputs that are not states depend on every state and on no input (no direct
    feedthrough)."""
    states, derivatives = state_names(scene)
    of = dict(zip(derivatives, states))
    named = {r["name"]: r for r in rows}
    body = {v.name: v for v in outputs(scene) if v.name in set(states)}
    rows = rows + [dict(name=n, unit=body[n].unit, description=body[n].description,
                        causality="local", initial="calculated") for n in states if n not in named]
    rows += [dict(name=f"{b.name}.{a}", unit=unit, description=text.format(b=b.name),
                  causality="local", initial="calculated")
             for b in scene.bodies for a, unit, text in ACCELERATIONS]
    accelerations = {f"{b.name}.{a[0]}" for b in scene.bodies for a in ACCELERATIONS}
    for r in rows:
        if r["name"] in of:        # a velocity (depends on itself) or an acceleration
            r["derivative"] = of[r["name"]]
            r["dependencies"] = None if r["name"] in accelerations else ()   # None: every known
        elif r["causality"] == "output" and r["name"] not in states:
            r["dependencies"] = tuple(states)
    return rows


def variable_table(scene) -> list[Variable]:
    """Every variable of the scene's FMU in value-reference order: parameters (start values
    as in ``scene``), solver parameters, inputs, outputs (``initial="calculated"``; no
    direct feedthrough: inputs reach the outputs at the next fmi2DoStep; in Initialization
    Mode kinematic outputs depend on the parameters and driver inputs, the others on every
    known), then the states the scene does not output and the accelerations
    (``_with_states``)."""
    rows = [dict(name=p.name, start=p.value, unit=p.unit, description=p.description,
                 causality="parameter") for p in parameters(scene)]
    rows += [dict(name=n, type=t, unit=u, start=start, description=d, causality="parameter")
             for n, t, u, start, d in solver_variables(scene)]
    layout = input_layout(scene)
    starts = {f"{d}.position": x0 for d, x0 in zip(layout.drivers, layout.driver_initial)}
    rows += [dict(name=v.name, start=float(starts.get(v.name, 0.0)), unit=v.unit,
                  description=v.description, causality="input") for v in inputs(scene)]
    # knowns of the kinematic outputs at initialization: parameters and driver inputs
    assembly = tuple(r["name"] for r in rows if r["causality"] == "parameter"
                     or r["name"].split(".")[0] in layout.drivers)
    kinematic = kinematic_outputs(scene)
    rows += [dict(name=v.name, unit=v.unit, description=v.description, causality="output",
                  initial="calculated", dependencies=(),
                  initial_dependencies=assembly if v.name in kinematic else None)
             for v in select_outputs(scene)]
    return [Variable(value_reference=k, **row) for k, row in enumerate(_with_states(scene, rows))]


def shipped_files(package_dir: Path) -> list[Path]:
    """The files of mbdfmu an FMU carries (``SHIPPED_PACKAGES`` and ``SHIPPED_MODULES``)."""
    files = [package_dir / name for name in SHIPPED_MODULES]
    for package in SHIPPED_PACKAGES:
        files += [p for p in (package_dir / package).rglob("*.py") if "__pycache__" not in p.parts]
    return sorted(files)


def _core_files() -> tuple[str, dict[str, bytes]]:
    """The core package's name (unique to its content) and its files by resource path."""
    package_dir = Path(core_init).resolve().parent
    files = {f.relative_to(package_dir).as_posix(): f.read_bytes()
             for f in shipped_files(package_dir)}
    name = "_mbdfmu_" + digest(*(k.encode() + b"\0" + v for k, v in files.items()))
    return name, {f"{name}/{k}": v for k, v in files.items()}


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
    solver_names = {row[0] for row in solver_variables(scene)}
    for name, value in parameters.items():
        if name.startswith("solver."):
            if name not in solver_names:
                raise BuildError(f"{scene_path.name}: unknown parameter {name!r}")
            doc.setdefault("simulation", tomlkit.table())[name[len("solver."):]] = value
    text = tomlkit.dumps(doc)
    return tomllib.loads(text), text


def wants_scene_kernel(scene_kernel: bool | None) -> bool:
    """``scene_kernel`` as given, else ``$MBDFMU_SCENE_KERNEL`` (default 1), checked."""
    if scene_kernel is not None:
        return bool(scene_kernel)
    value = os.environ.get(SCENE_KERNEL_ENV, "1")
    if value not in ("0", "1"):
        raise BuildError(f"{SCENE_KERNEL_ENV}={value!r}: use 1 (ship the C kernel built for "
                         "the scene, the default) or 0 (the generic C kernel only)")
    return value == "1"


def shipped_kernel(scene, scene_kernel: bool) -> dict[str, bytes]:
    """The compiled C kernel as a resource (compiled once per content into the cache), with
    the kernels built for ``scene`` (ckernel/scene_kernel.py) when ``scene_kernel`` and the
    scene is not too large for them: for the equations it starts on (SCENE_KERNEL_FILE)
    and, with end stops or friction, for its other contact modes (``kernel_equations``;
    MODE_KERNEL_FILE); nothing when no kernel can be compiled here: the FMU then runs the
    numpy kernel and logs so."""
    try:
        files = {KERNEL_FILE: compile_kernel().read_bytes()}
    except KernelBuildError:
        return {}
    try:
        paths = [compile_scene_kernel(eq) for eq in kernel_equations(scene)] \
            if scene_kernel else []
    except KernelBuildError as exc:     # the generic kernel runs, as fast as before
        warnings.warn(f"{scene.name}: the C kernel built for the scene was not compiled "
                      f"({exc}): the FMU ships the generic C kernel only", stacklevel=3)
        paths = []
    names = [SCENE_KERNEL_FILE] + [MODE_KERNEL_FILE.format(k) for k in range(1, len(paths))]
    return {**files, **{name: path.read_bytes() for name, path in zip(names, paths)
                        if path is not None}}


def kernel_equations(scene) -> list[Equations]:
    """The equations the FMU's scene kernels are built for: those a simulation of
    ``scene`` starts on (with end stops or friction, its first contact mode's; the scene's
    own where its settings do not start: a method the master must change first), then
    those of its other contact modes, one per structure (a stop held low or high is one),
    fewest joints changed from the start first, MAX_SCENE_KERNELS in all at most; a
    structure too large for a scene kernel (``scene_header`` None) is left out."""
    try:
        sim = Simulation(scene, kernel="numpy")
    except MbdfmuError:
        return [Equations(scene, kernel="numpy")]
    first = sim.stepped_equations
    if sim.events is None:
        return [first]
    start = {k: m.state for k, m in sim.events.mode.items()}
    modes = sorted(itertools.islice(every_mode(scene), MAX_MODES_LOOKED_AT),
                   key=lambda mode: sum(m.state != start[k] for k, m in mode.items()))
    found, seen = [first], {scene_header(first)}
    for mode in modes:
        if len(found) == MAX_SCENE_KERNELS:
            break
        eq = sim.events.mode_equations(mode)
        header = scene_header(eq)
        if header is not None and header not in seen:
            seen.add(header)
            found.append(eq)
    return found


def _load(scene_path, values: dict[str, float] | None):
    """The scene's file, its data and text with ``values`` written in (so the shipped
    scene.json and scene.toml carry them, and the FMU's start values are them), and the
    scene built from them, assembled once to prove it can start."""
    scene_path = resolve_scene_path(scene_path)
    try:
        data, text = with_start_values(scene_path, values or {})
    except SceneError as exc:
        raise BuildError(f"build parameters: {exc}") from None
    scene = scene_from_dict(data, source=scene_path.name)
    assemble(Equations(scene, kernel="numpy"))   # a scene that cannot start is no FMU
    return scene_path, data, text, scene


def build_fmu(scene_path, output=None, parameters: dict[str, float] | None = None,
              fmi_version: int = 2, scene_kernel: bool | None = None) -> Path:
    """Build the FMU of a scene file (or a shipped scene's name); returns its path (default
    ``<Model>.fmu`` in the cwd). ``parameters``: start values baked into the FMU
    (``{"crank.mass": 0.3}``; names and ranges as ``mbdfmu.with_parameters`` checks them);
    ``fmi_version``: 2 (FMI 2.0) or 3 (FMI 3.0, the same variables and behaviour);
    ``scene_kernel``: ship the C kernel built for this scene besides the generic one
    (default ``$MBDFMU_SCENE_KERNEL``, else yes)."""
    with_scene_kernel = wants_scene_kernel(scene_kernel)
    scene_path, data, text, scene = _load(scene_path, parameters)
    table = variable_table(scene)
    core, core_files = _core_files()
    outputs_ = tuple(v.name for v in table if v.causality == "output")
    states, derivatives = state_names(scene)
    source = fill_template(TEMPLATE, {"CORE_PACKAGE": core, "SCENE_FILE": "scene.json",
                                      "OUTPUTS": outputs_, "STATES": tuple(states),
                                      "ACCELERATIONS": tuple(d for d in derivatives
                                                             if d not in states),
                                      "KERNEL_FILE": KERNEL_FILE})
    run = scene.simulation
    settings = settings_from_scene(scene)
    experiment = DefaultExperiment(0.0, run.t_end, settings.output_interval_for(run.t_end),
                                   run.rtol)
    info = ModelInfo(description=scene.description, author=scene.author or "mbdfmu",
                     version=scene.version or __version__,
                     generation_tool=f"mbdfmu {__version__} (native FMI {fmi_version}.0 runtime)")
    resources = {**core_files, "scene.toml": text.encode(),
                 "scene.json": json.dumps(data, indent=1, sort_keys=True).encode(),
                 **shipped_kernel(scene, with_scene_kernel)}
    capabilities = Capabilities(can_interpolate_inputs=True, max_output_derivative_order=2,
                                provides_directional_derivative=True)
    ports = osp.scene_ports(scene, set(outputs_))
    return write_checked(output, scene.name, table, source, info=info,
                         default_experiment=experiment, extra_resources=resources,
                         capabilities=capabilities, fmi_version=fmi_version,
                         extra_files=osp.extra_files(ports))
