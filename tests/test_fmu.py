"""The FMUs built from scenes, run the way masters run them: fmpy and OSP libcosim.

Each FMU is built once per session (``fmu`` fixture). ``Slave`` drives one instance through
fmpy's ``FMU2Slave`` with logging on, so every failure can be checked for its status and its
logged reason. The reference is always mbdfmu itself (``simulate`` or ``Simulation``) or a
closed form from ``exact_solutions.py``.
"""
from __future__ import annotations

import json
import math
import shutil
import subprocess
import sys
import textwrap
import zipfile
from ctypes import byref
from pathlib import Path
from xml.etree import ElementTree

import numpy as np
import pytest

import mbdfmu
import exact_solutions as ref
from mbdfmu.fmu_build.scene_fmu import build_fmu

fmpy = pytest.importorskip("fmpy")
from fmpy import extract, read_model_description, simulate_fmu  # noqa: E402
from fmpy.fmi1 import FMICallException  # noqa: E402
from fmpy.fmi2 import FMU2Slave  # noqa: E402
from fmu_logs import CALLBACKS as _CALLBACKS, LOGS as _LOGS  # noqa: E402
from fmpy.validation import validate_fmu  # noqa: E402

SCENES = Path(__file__).resolve().parents[1] / "scenes"
SCENE_FILES = sorted(SCENES.glob("*.toml"))
OK, DISCARD, ERROR, FATAL = 0, 2, 3, 4
W = 314.1592653589793  # the slider-crank's crank rate, rad/s
SLIDER_CRANK = dict(r=0.1, l=0.3, crank_mass=0.2, crank_inertia=1.6667e-4, rod_mass=0.2,
                    rod_inertia=1.5e-3, slider_mass=0.4, load=(-10.0, 0.0))
UNITS = {"m", "rad", "m/s", "rad/s", "N", "N.m", "kg", "kg.m2", "J"}


# ----------------------------------------------------------------------------- fixtures

def _variant(text: str, name: str, replacements: dict[str, str]) -> str:
    text = text.replace('name = "SliderCrank"', f'name = "{name}"', 1)
    for old, new in replacements.items():
        assert old in text, old
        text = text.replace(old, new)
    return text


LINEAR_MOTOR = 'motion = { type = "linear", start = 0.0, rate = 314.1592653589793 }'
VARIANTS = {
    # the motor's angle comes from the master
    "slider_crank_input": ("SliderCrankInput", {LINEAR_MOTOR: 'motion = { type = "input" }'}),
    # the motor's angle oscillates: 0.3 sin(2 pi 40 t), exact derivatives (a reference)
    "slider_crank_harmonic": ("SliderCrankHarmonic", {LINEAR_MOTOR: 'motion = { type = '
                              '"harmonic", offset = 0.0, amplitude = 0.3, frequency = 40.0 }'}),
}
# The slider's position comes from the master; beyond r + l = 0.4 m the loop cannot close.
# Assembled with the crank at pi/2 (away from the dead centres x = 0.2 and 0.4).
SLIDE_SCENE = """
name = "SliderCrankSlide"
description = "Slider-crank whose slider position is an input"
[[body]]
name = "crank"
mass = 0.2
inertia = 1.6667e-4
position = [0.0, 0.05]
angle = 1.5707963267948966
[[body]]
name = "rod"
mass = 0.2
inertia = 1.5e-3
position = [0.1414213562373095, 0.05]
angle = -0.3398369094541219
[[body]]
name = "slider"
mass = 0.4
inertia = 1.0e-4
position = [0.282842712474619, 0.0]
[[joint]]
name = "O"
type = "revolute"
body_i = "ground"
point_i = [0.0, 0.0]
body_j = "crank"
point_j = [-0.05, 0.0]
[[joint]]
name = "A"
type = "revolute"
body_i = "crank"
point_i = [0.05, 0.0]
body_j = "rod"
point_j = [-0.15, 0.0]
[[joint]]
name = "B"
type = "revolute"
body_i = "rod"
point_i = [0.15, 0.0]
body_j = "slider"
point_j = [0.0, 0.0]
[[joint]]
name = "guide"
type = "translational"
body_i = "ground"
point_i = [0.0, 0.0]
axis_i = [1.0, 0.0]
body_j = "slider"
point_j = [0.0, 0.0]
[[driver]]
name = "motor"
joint = "guide"
motion = { type = "input", initial = 0.282842712474619 }
"""


@pytest.fixture(scope="session")
def scene_file(tmp_path_factory):
    """Path of a shipped scene, or of a variant of the slider-crank written for these tests."""
    folder = tmp_path_factory.mktemp("scenes")

    def get(stem: str) -> Path:
        if stem == "slider_crank_slide":
            path = folder / f"{stem}.toml"
            path.write_text(SLIDE_SCENE)
            return path
        if stem not in VARIANTS:
            return SCENES / f"{stem}.toml"
        path = folder / f"{stem}.toml"
        if not path.exists():
            name, replacements = VARIANTS[stem]
            path.write_text(_variant((SCENES / "slider_crank.toml").read_text(), name, replacements))
        return path
    return get


@pytest.fixture(scope="session")
def fmu(tmp_path_factory, scene_file):
    """Build (once per session) the FMU of a scene stem; returns its path."""
    folder = tmp_path_factory.mktemp("fmus")
    built: dict[str, Path] = {}

    def get(stem: str) -> Path:
        if stem not in built:
            built[stem] = build_fmu(scene_file(stem), folder / f"{stem}.fmu")
        return built[stem]
    return get


_NAMES = iter(range(10 ** 9))


class Slave:
    """One FMU instance driven by hand through fmpy, with its log messages kept."""

    def __init__(self, path: Path, name: str = "instance"):
        md = read_model_description(path)
        self.md = md
        self.dir = extract(path)
        self.vr = {v.name: v.valueReference for v in md.modelVariables}
        self.type = {v.name: v.type for v in md.modelVariables}
        name = f"{name}_{next(_NAMES)}"  # unique: log messages are sorted by it
        self.messages: list[tuple[int, str, str]] = _LOGS.setdefault(name, [])
        self.fmu = FMU2Slave(guid=md.guid, unzipDirectory=self.dir, instanceName=name,
                             modelIdentifier=md.coSimulation.modelIdentifier)
        self.fmu.instantiate(callbacks=_CALLBACKS, loggingOn=True)
        self.t = 0.0

    def init(self, t0: float = 0.0, inputs=None, **parameters) -> None:
        self.fmu.setupExperiment(startTime=t0)
        self.fmu.enterInitializationMode()
        self.set(**parameters)
        self.set(**(inputs or {}))
        self.fmu.exitInitializationMode()
        self.t = t0

    def set(self, **values) -> None:
        for key, value in values.items():
            name = key.replace("__", ".")
            if self.type[name] == "String":
                self.fmu.setString([self.vr[name]], [value])
            elif self.type[name] == "Integer":
                self.fmu.setInteger([self.vr[name]], [value])
            else:
                self.fmu.setReal([self.vr[name]], [value])

    def status(self, call, *args) -> int:
        """A call through fmpy's wrapper; its status (fmpy raises on discard and worse)."""
        try:
            getattr(self.fmu, call)(*args)
        except FMICallException as exc:
            return exc.status
        return OK

    def get(self, *names) -> np.ndarray:
        return np.array(self.fmu.getReal([self.vr[n] for n in names]))

    def step(self, h: float) -> int:
        """doStep from self.t; the status (fmpy raises on discard and worse)."""
        try:
            self.fmu.doStep(self.t, h)
        except FMICallException as exc:
            return exc.status
        self.t += h
        return OK

    def run(self, steps, names, inputs=None) -> np.ndarray:
        """Outputs after each step; ``inputs(t)`` gives inputs to set before each step."""
        rows = []
        for h in steps:
            if inputs is not None:
                self.set(**inputs(self.t))
            assert self.step(h) == OK, self.messages[-3:]
            rows.append(self.get(*names))
        return np.array(rows)

    def logged(self) -> str:
        return "\n".join(m for _, _, m in self.messages)

    def close(self) -> None:
        self.status("terminate")        # fmi2Error in the Error state: free it anyway
        self.fmu.freeInstance()
        shutil.rmtree(self.dir, ignore_errors=True)


@pytest.fixture
def slave():
    opened: list[Slave] = []

    def open_(path, name="instance"):
        opened.append(Slave(path, name))
        return opened[-1]
    yield open_
    for s in opened:
        s.close()


def _outputs(path: Path) -> list[str]:
    return [v.name for v in read_model_description(path).modelVariables
            if v.causality == "output"]


# ----------------------------------------------------------------------------- build

@pytest.mark.parametrize("scene", SCENE_FILES, ids=[p.stem for p in SCENE_FILES])
def test_every_scene_fmu_validates_and_describes_itself(scene, tmp_path):
    path = build_fmu(scene, tmp_path / f"{scene.stem}.fmu")
    assert validate_fmu(str(path)) == []
    loaded = mbdfmu.load_scene(scene)
    md = read_model_description(path)
    assert md.modelName == loaded.name == md.coSimulation.modelIdentifier
    assert md.description == loaded.description
    assert md.generationTool.startswith(f"mbdfmu {mbdfmu.__version__}")
    assert md.version and md.author
    assert md.defaultExperiment.stopTime and md.defaultExperiment.stepSize
    assert md.coSimulation.canGetAndSetFMUstate and md.coSimulation.canSerializeFMUstate
    defined = {u.name for u in md.unitDefinitions}
    for v in md.modelVariables:
        assert v.description, v.name
        if v.type == "Real" and v.name != "solver.atol":
            assert v.unit in defined, v.name
    used = {v.unit for v in md.modelVariables}
    assert UNITS & used and used - {None} <= defined


def test_default_outputs_are_body_states_reactions_and_efforts(fmu):
    names = _outputs(fmu("slider_crank"))
    assert names[:6] == ["crank.x", "crank.y", "crank.phi", "crank.vx", "crank.vy", "crank.omega"]
    assert {"O.Fx", "O.Fy", "O.Tz", "guide.Fy", "motor.effort"} <= set(names)
    assert not any(n.startswith(("energy.", "constraint.")) for n in names)


def test_scene_outputs_globs_select_the_outputs(tmp_path, fmu):
    text = (SCENES / "slider_crank.toml").read_text()
    scene = tmp_path / "sc.toml"
    scene.write_text(text.replace('description = "', 'outputs = ["slider.*", "motor.effort", '
                                  '"energy.*"]\ndescription = "', 1))
    names = _outputs(build_fmu(scene, tmp_path / "sc.fmu"))
    assert _config(tmp_path / "sc.fmu")["model_module"] != _config(fmu("slider_crank"))["model_module"]
    assert names == ["slider.x", "slider.y", "slider.phi", "slider.vx", "slider.vy",
                     "slider.omega", "motor.effort", "energy.kinetic", "energy.potential"]


def test_inputs_and_parameters_are_what_the_scene_needs(fmu):
    md = read_model_description(fmu("slider_crank_input"))
    by = {}
    for v in md.modelVariables:
        by.setdefault(v.causality, []).append(v.name)
    assert by["input"] == ["motor.position", "motor.velocity", "motor.acceleration"]
    params = by["parameter"]
    assert {"gravity.x", "gravity.y", "crank.mass", "crank.inertia", "load.fx", "load.fy",
            "solver.method", "solver.step", "solver.rtol", "solver.atol"} <= set(params)
    assert all(v.variability == "fixed" for v in md.modelVariables if v.causality == "parameter")
    assert "input" not in {v.causality for v in read_model_description(fmu("slider_crank")).modelVariables}


def _config(path: Path) -> dict:
    with zipfile.ZipFile(path) as z:
        return json.loads(z.read("resources/mbdfmu.json"))


def test_the_fmu_ships_its_scene_and_a_uniquely_named_core(fmu):
    with zipfile.ZipFile(fmu("slider_crank")) as z:
        names = z.namelist()
    module = _config(fmu("slider_crank"))["model_module"]
    assert module.startswith("model_") and f"resources/{module}.py" in names
    assert "resources/scene.json" in names and "resources/scene.toml" in names
    cores = {n.split("/")[1] for n in names if n.startswith("resources/_mbdfmu_")}
    assert len(cores) == 1
    assert not any(n.startswith("resources/mbdfmu/") or n.endswith(("cli.py", "plotting.py"))
                   for n in names)
    # module names follow the code: the same outputs share one module (safely: the scene
    # is read per instance), other outputs get another; the FMUs differ (GUID)
    other = _config(fmu("slider_crank_input"))
    assert other["model_module"] == module
    assert other["guid"] != _config(fmu("slider_crank"))["guid"]


# ----------------------------------------------------------------------------- equality with mbdfmu

@pytest.mark.parametrize("method, step", [(None, None), ("taylor", 1e-5), ("rk45p", None)])
def test_simulate_fmu_equals_simulate(fmu, method, step):
    start = {}
    if method:
        start["solver.method"] = method
    if step:
        start["solver.step"] = step
    res = simulate_fmu(fmu("slider_crank"), stop_time=0.02, output_interval=1e-3,
                       start_values=start)
    expected = mbdfmu.simulate(SCENES / "slider_crank.toml", t_end=0.02, output_interval=1e-3,
                               method=method, step=step)
    assert len(res) == len(expected.time)
    for name in _outputs(fmu("slider_crank")):
        np.testing.assert_allclose(res[name], expected[name], rtol=0, atol=1e-12 * max(
            1.0, np.abs(expected[name]).max()), err_msg=name)


def test_uneven_communication_steps_equal_the_simulation_stepped_alike(fmu, slave):
    steps = [1e-3, 2.5e-3, 3e-4, 1e-5, 4e-3, 7e-4, 1e-3]
    s = slave(fmu("slider_crank"))
    s.init()
    names = _outputs(fmu("slider_crank"))
    got = s.run(steps, names)
    sim = mbdfmu.Simulation(mbdfmu.load_scene(SCENES / "slider_crank.toml"))
    t, rows = 0.0, []
    for h in steps:
        t += h
        sim.advance(t)
        out = sim.outputs()
        rows.append([out[n] for n in names])
    np.testing.assert_allclose(got, np.array(rows), rtol=1e-12, atol=1e-12)


def test_parameters_set_before_initialization_change_the_model(fmu, slave):
    s = slave(fmu("pendulum_torque"))
    s.init(gravity__y=-1.62, rod__mass=2.0)
    ours = s.run([1e-3] * 20, ["rod.phi"], inputs=lambda t: {"drive.torque": 0.5})
    scene = mbdfmu.with_parameters(mbdfmu.load_scene(SCENES / "pendulum_torque.toml"),
                                   {"gravity.y": -1.62, "rod.mass": 2.0})
    sim = mbdfmu.Simulation(scene)
    sim.set_input("drive.torque", 0.5)
    expected = []
    for k in range(1, 21):
        sim.advance(k * 1e-3)
        expected.append(sim.outputs()["rod.phi"])
    np.testing.assert_allclose(ours[:, 0], expected, rtol=1e-12)


# ----------------------------------------------------------------------------- inputs

def _p4_torque(t):
    return ref.slider_crank(W * np.asarray(t), W, **SLIDER_CRANK)["torque"]


def _motor_signal(t, derivatives: bool):
    cols = ["motor.position"] + (["motor.velocity", "motor.acceleration"] if derivatives else [])
    sig = np.zeros(len(t), dtype=[("time", float)] + [(c, float) for c in cols])
    sig["time"] = t
    sig["motor.position"] = W * t
    if derivatives:
        sig["motor.velocity"] = W
    return sig


@pytest.mark.parametrize("derivatives", [False, True], ids=["position", "position+derivatives"])
def test_position_driven_motor_effort_matches_p4(fmu, derivatives):
    h, t_end = 1e-4, 0.02
    t = np.arange(round(t_end / h) + 1) * h
    res = simulate_fmu(fmu("slider_crank_input"), stop_time=t_end, output_interval=h,
                       input=_motor_signal(t, derivatives), output=["motor.effort", "crank.phi"])
    exact = _p4_torque(res["time"])
    err = np.abs(res["motor.effort"] - exact) / np.abs(exact).max()
    # Positions only: the history needs a few samples (signals.HISTORY_LENGTH); a linear
    # motion is then reproduced exactly. With all three inputs: exact from the first step.
    first = 4 if not derivatives else 1
    assert err[first:].max() < 1e-9
    np.testing.assert_allclose(res["crank.phi"][first:], W * res["time"][first:], rtol=1e-12)


def _effort_error(fmu_path, slave, scene_file, h):
    """Max effort error of position-only inputs phi = 0.3 sin(2 pi 40 t), after the history
    has filled, against the same motion prescribed with exact derivatives."""
    s = slave(fmu_path, f"positions{h}")
    s.init()
    n = round(0.01 / h)
    got = s.run([h] * n, ["motor.effort"], inputs=lambda t: {
        "motor.position": 0.3 * math.sin(2 * math.pi * 40.0 * t)})[:, 0]
    sim = mbdfmu.Simulation(mbdfmu.load_scene(scene_file("slider_crank_harmonic")))
    exact = []
    for k in range(1, n + 1):
        sim.advance(k * h)
        exact.append(sim.outputs()["motor.effort"])
    tail = slice(round(0.002 / h), None)
    return np.abs(got[tail] - np.array(exact)[tail]).max() / np.abs(exact).max()


def test_position_only_inputs_converge_at_the_documented_order(fmu, slave, scene_file):
    # signals.py: the acceleration of the quadratic through the last three positions, held
    # over the step, has an O(h) error, and so has the effort (linear in the acceleration).
    path = fmu("slider_crank_input")
    e1 = _effort_error(path, slave, scene_file, 2e-4)
    e2 = _effort_error(path, slave, scene_file, 1e-4)
    assert e2 < 5e-2
    assert 1.7 < e1 / e2 < 2.4, (e1, e2)


def test_coarse_position_samples_log_a_warning(fmu, slave):
    # 0.3 sin(2 pi 40 t) sampled every 2 ms: the derived acceleration's estimated error
    # (cubic minus quadratic) is large against the motion; the step still succeeds
    s = slave(fmu("slider_crank_input"), "coarse_positions")
    s.init()
    s.run([2e-3] * 10, ["motor.effort"], inputs=lambda t: {
        "motor.position": 0.3 * math.sin(2 * math.pi * 40.0 * t)})
    warnings = [m for status, _, m in s.messages if status == 1]
    assert any("derived from motor.position samples" in m for m in warnings), s.messages


def test_torque_driven_pendulum_follows_its_energy_integral(fmu, slave):
    # Uniform rod (m = 1, L = 1) about its end: I = m L^2 / 3; constant torque T from rest at
    # the bottom: I w^2 / 2 = T th - m g L / 2 (1 - cos th), th from the downward vertical.
    s = slave(fmu("pendulum_torque"))
    s.init()
    rest = s.run([1e-2] * 5, ["rod.phi", "rod.omega"])
    np.testing.assert_allclose(rest, [[-math.pi / 2, 0.0]] * 5, atol=1e-12)
    T, I, mgc = 2.0, 1.0 / 3.0, 9.81 * 0.5
    out = s.run([1e-3] * 400, ["rod.phi", "rod.omega"], inputs=lambda t: {"drive.torque": T})
    th, w = out[:, 0] + math.pi / 2, out[:, 1]
    np.testing.assert_allclose(0.5 * I * w ** 2, T * th - mgc * (1 - np.cos(th)),
                               atol=1e-7 * T * th.max())
    assert th.max() > 0.3


def test_force_driven_slider_moves_as_newton_says(fmu, slave):
    # m = 2 kg on a frictionless x guide: x = F t^2 / (2 m); F_y is taken by the guide.
    s = slave(fmu("slider_force"))
    s.init()
    out = s.run([1e-2] * 50, ["slider.x", "slider.vx", "slider.y", "guide.Fy"],
                inputs=lambda t: {"push.fx": 3.0, "push.fy": 5.0})
    t = np.arange(1, 51) * 1e-2
    np.testing.assert_allclose(out[:, 0], 3.0 * t ** 2 / 4.0, rtol=1e-10)
    np.testing.assert_allclose(out[:, 1], 1.5 * t, rtol=1e-10)
    np.testing.assert_allclose(out[:, 2], 0.0, atol=1e-12)
    np.testing.assert_allclose(np.abs(out[:, 3]), abs(5.0 - 2.0 * 9.81), rtol=1e-10)


def test_get_real_mixes_outputs_inputs_and_parameters_in_any_order(fmu, slave):
    # outputs are served from one list; a call that also names an input or a parameter
    # must give the same values as reading each alone
    s = slave(fmu("slider_force"))
    s.init(slider__mass=2.0)
    s.set(push__fx=3.0, push__fy=5.0)
    assert s.step(0.1) == OK
    names = ["guide.Fy", "push.fx", "slider.x", "slider.mass", "slider.vx"]
    together = s.get(*names)
    alone = np.array([s.get(n)[0] for n in names])
    np.testing.assert_array_equal(together, alone)
    assert together[1] == 3.0 and together[3] == 2.0
    assert together[2] == pytest.approx(3.0 * 0.1 ** 2 / 4.0, rel=1e-10)


# ----------------------------------------------------------------------------- FMU state

def _position_only(t):
    return {"motor.position": W * t + 0.3 * math.sin(2 * math.pi * 40 * t)}


def test_state_restore_replays_bit_for_bit(fmu, slave):
    names = _outputs(fmu("slider_crank_input"))
    s = slave(fmu("slider_crank_input"))
    s.init()
    s.run([1e-4] * 7, names, inputs=_position_only)  # the input history matters
    state, t1 = s.fmu.getFMUstate(), s.t
    steps = [1e-4, 3e-4, 5e-5, 1e-4]
    first = s.run(steps, names, inputs=_position_only)
    for _ in range(2):  # restoring the same state twice works too
        s.fmu.setFMUstate(state)
        s.t = t1
        assert np.array_equal(s.run(steps, names, inputs=_position_only), first)
    data = s.fmu.serializeFMUstate(state)
    s.fmu.freeFMUstate(state)
    other = slave(fmu("slider_crank_input"), "other")
    other.init()
    restored = other.fmu.deSerializeFMUstate(data)
    other.fmu.setFMUstate(restored)
    other.fmu.freeFMUstate(restored)
    other.t = t1
    assert np.array_equal(other.run(steps, names, inputs=_position_only), first)


def test_reset_and_repeated_instantiation_start_over(fmu, slave):
    path = fmu("pendulum_torque")
    s = slave(path)
    s.init()
    torque = lambda t: {"drive.torque": 1.0 + t}  # noqa: E731
    first = s.run([1e-3] * 30, ["rod.phi", "rod.omega"], inputs=torque)
    s.fmu.reset()
    s.init()
    assert np.array_equal(s.run([1e-3] * 30, ["rod.phi", "rod.omega"], inputs=torque), first)
    for k in range(3):
        again = Slave(path, f"again{k}")
        again.init()
        assert np.array_equal(again.run([1e-3] * 30, ["rod.phi", "rod.omega"], inputs=torque),
                              first)
        again.close()


def test_instances_and_different_fmus_stepped_alternately_equal_solo_runs(fmu, slave):
    pend, push = fmu("pendulum_torque"), fmu("slider_force")
    a, b, c = slave(pend, "a"), slave(pend, "b"), slave(push, "c")
    for s in (a, b, c):
        s.init()
    inputs = {"a": lambda t: {"drive.torque": 1.0}, "b": lambda t: {"drive.torque": -3.0 * t},
              "c": lambda t: {"push.fx": 2.0, "push.fy": 0.0}}
    names = {"a": ["rod.phi", "rod.omega"], "b": ["rod.phi", "rod.omega"],
             "c": ["slider.x", "slider.vx"]}
    together = {k: [] for k in "abc"}
    for _ in range(40):
        for key, s in zip("abc", (a, b, c)):
            together[key].append(s.run([1e-3], names[key], inputs=inputs[key])[0])
    for key, path in zip("abc", (pend, pend, push)):
        solo = slave(path, f"solo_{key}")
        solo.init()
        assert np.array_equal(solo.run([1e-3] * 40, names[key], inputs=inputs[key]),
                              np.array(together[key])), key
    assert not np.array_equal(together["a"], together["b"])


# ----------------------------------------------------------------------------- libcosim

def test_libcosim_runs_the_fmu_like_fmpy(fmu):
    cosim = pytest.importorskip("libcosimpy.CosimExecution")
    from libcosimpy.CosimEnums import CosimVariableType
    from libcosimpy.CosimObserver import CosimObserver
    from libcosimpy.CosimSlave import CosimLocalSlave

    path, h, n = fmu("slider_crank"), 1e-3, 20
    md = read_model_description(path)
    vr = {v.name: v.valueReference for v in md.modelVariables}
    names = ["slider.x", "motor.effort", "O.Fx"]
    execution = cosim.CosimExecution.from_step_size(step_size=int(h * 1e9))
    index = execution.add_local_slave(CosimLocalSlave(fmu_path=str(path), instance_name="sc"))
    series = CosimObserver.create_time_series()
    execution.add_observer(series)
    for name in names:
        series.start_time_series(index, value_reference=vr[name],
                                 variable_type=CosimVariableType.REAL)
    assert execution.simulate_until(target_time=int(n * h * 1e9))
    expected = simulate_fmu(path, stop_time=n * h, output_interval=h, output=names)
    for name in names:
        times, _, values = series.time_series_real_samples(index, vr[name], from_step=0,
                                                           sample_count=n + 1)
        k = len(values)
        assert k >= n
        np.testing.assert_allclose(np.array(times) * 1e-9, expected["time"][:k], atol=1e-12)
        np.testing.assert_allclose(values, expected[name][:k], rtol=1e-12,
                                   atol=1e-12 * np.abs(expected[name]).max())


# ----------------------------------------------------------------------------- failures

def test_non_finite_input_is_discarded_with_a_reason_and_can_be_retried(fmu, slave):
    s = slave(fmu("slider_force"))
    s.init()
    s.set(push__fx=2.0)
    assert s.status("setReal", [s.vr["push.fx"]], [math.nan]) == DISCARD
    assert '"push.fx" = nan is not finite' in s.messages[-1][2]
    assert s.messages[-1][0] == DISCARD and s.get("push.fx")[0] == 2.0   # not applied
    assert s.step(1e-2) == OK
    s.set(push__fx=1.0)
    assert s.step(1e-2) == OK


def test_a_loop_that_cannot_close_is_an_error_and_a_saved_state_goes_on(fmu, slave):
    # the slider pushed beyond r + l = 0.4 m: the position projection (Newton) cannot converge,
    # at any communication step, so fmi2Error (not fmi2Discard, which a master would retry)
    s = slave(fmu("slider_crank_slide"))
    s.init(inputs={"motor.position": 0.3})
    before = s.get("slider.x", "crank.phi")
    saved = s.fmu.getFMUState()
    s.set(motor__position=0.45)
    assert s.step(1e-3) == ERROR
    assert s.messages[-1][0] == ERROR and "projection" in s.messages[-1][2]
    assert "fmi2SetFMUstate" in s.messages[-1][2]
    s.fmu.setFMUState(saved)
    np.testing.assert_array_equal(s.get("slider.x", "crank.phi"), before)
    s.set(motor__position=0.31)
    assert s.step(1e-3) == OK
    assert s.get("slider.x")[0] == pytest.approx(0.31, abs=1e-9)


def test_a_blown_up_state_is_an_error_and_a_smaller_solver_step_passes(fmu, slave):
    s = slave(fmu("pendulum"))
    s.init(**{"solver.method": "taylor", "solver.step": 0.2})
    assert s.step(2.0) == ERROR
    assert s.messages[-1][0] == ERROR and "taylor" in s.messages[-1][2]
    assert s.t == 0.0
    s.fmu.reset()
    s.init(**{"solver.method": "taylor", "solver.step": 1e-4})
    assert s.step(0.05) == OK


def test_after_an_error_every_step_is_refused_with_the_reason(fmu, slave):
    s = slave(fmu("pendulum_torque"))
    s.init()
    s.t = 0.5  # a communication point that is not the FMU's time: a master error
    assert s.step(1e-3) == ERROR
    assert s.messages[-1][1] == "logStatusError" and "not the FMU's time" in s.messages[-1][2]
    s.t = 0.0
    assert s.step(1e-3) == ERROR
    assert s.messages[-1][0] == ERROR and "refused" in s.messages[-1][2]
    s.fmu.reset()
    s.init()
    assert s.step(1e-3) == OK


def _init_status(s, **values) -> int:
    s.fmu.setupExperiment(startTime=0.0)
    s.fmu.enterInitializationMode()
    s.set(**values)
    return s.status("exitInitializationMode")


@pytest.mark.parametrize("values, words", [
    (dict(rod__mass=-1.0), '"rod.mass" must be positive, got -1'),
    ({"solver.method": "euler"}, 'solver.method "euler" is not a method'),
    ({"solver.method": "rk5"}, 'solver.method "rk5" is not a method'),
    ({"solver.rtol": 2.0}, "solver.rtol must be below 1"),
    ({"solver.max_steps_per_communication_step": -5},
     "solver.max_steps_per_communication_step must be 0 (no limit) or positive"),
])
def test_a_bad_parameter_fails_exit_initialization_naming_it(fmu, slave, values, words):
    s = slave(fmu("pendulum_torque"))
    assert _init_status(s, **values) == ERROR
    assert s.messages[-1][:2] == (ERROR, "logStatusError")
    assert "fmi2ExitInitializationMode" in s.messages[-1][2] and words in s.messages[-1][2]
    assert s.step(1e-3) == ERROR and "refused" in s.messages[-1][2]
    s.fmu.reset()
    s.init()
    assert s.step(1e-3) == OK


def test_setting_a_parameter_after_initialization_is_an_error(fmu, slave):
    s = slave(fmu("pendulum_torque"))
    s.init()
    assert s.status("setReal", [s.vr["rod.mass"]], [5.0]) == ERROR
    assert s.messages[-1][0] == ERROR and 'parameter "rod.mass" is fixed' in s.messages[-1][2]
    assert s.get("rod.mass")[0] == 1.0
    assert s.step(1e-3) == ERROR and "refused" in s.messages[-1][2]
    s.fmu.reset()
    s.init()
    assert s.step(1e-3) == OK


# ----------------------------------------------------------------------------- the host

HOST_SCRIPT = textwrap.dedent("""
    import sys
    sys.path.insert(0, {decoy!r})
    if {preimport!r}:
        import mbdfmu                   # a different "installed" mbdfmu, already imported
        assert mbdfmu.__version__ == "0.0.decoy"
    from fmpy import simulate_fmu
    res = simulate_fmu({fmu!r}, stop_time=0.01, output_interval=1e-3)
    print(repr(float(res["motor.effort"][-1])))
""")
DECOYS = {
    # another version of mbdfmu installed (and imported) in the host
    "other-version": ('__version__ = "0.0.decoy"\n'
                      "def __getattr__(name):\n"
                      "    raise AttributeError(f'decoy has no {name}')\n", True),
    # mbdfmu not installed: any import of it fails
    "not-installed": ('raise ImportError("mbdfmu is not installed in this host")\n', False),
}


@pytest.mark.parametrize("decoy", DECOYS)
def test_the_fmu_does_not_depend_on_the_hosts_mbdfmu(fmu, tmp_path, decoy):
    source, preimport = DECOYS[decoy]
    package = tmp_path / "site" / "mbdfmu"
    package.mkdir(parents=True)
    (package / "__init__.py").write_text(source)
    path = fmu("slider_crank")
    script = HOST_SCRIPT.format(decoy=str(package.parent), fmu=str(path), preimport=preimport)
    out = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True,
                         timeout=120, cwd=tmp_path)
    assert out.returncode == 0, out.stderr
    # bit for bit with the same kernel (FMUs run the C kernel they ship, compiled from the
    # same source as the one the Python API compiles, unless MBDFMU_KERNEL says otherwise)
    expected = mbdfmu.simulate(SCENES / "slider_crank.toml", t_end=0.01, output_interval=1e-3,
                               kernel="c")
    assert float(out.stdout.strip()) == expected["motor.effort"][-1]


def test_the_model_description_parses_as_xml_with_unit_definitions_first(fmu):
    with zipfile.ZipFile(fmu("slider_crank")) as z:
        root = ElementTree.fromstring(z.read("modelDescription.xml"))
    tags = [child.tag for child in root]
    assert tags.index("UnitDefinitions") < tags.index("LogCategories") < tags.index(
        "DefaultExperiment") < tags.index("ModelVariables") < tags.index("ModelStructure")


def test_the_start_time_of_setup_experiment_is_honoured(fmu, slave):
    s = slave(fmu("slider_crank"))
    s.init(t0=0.25)
    names = ["crank.phi", "motor.effort", "slider.x"]
    got = s.run([1e-3] * 5, names)
    sim = mbdfmu.Simulation(mbdfmu.load_scene(SCENES / "slider_crank.toml"), t0=0.25)
    expected = []
    for k in range(1, 6):
        sim.advance(0.25 + k * 1e-3)
        expected.append([sim.outputs()[n] for n in names])
    np.testing.assert_allclose(got, expected, rtol=1e-12, atol=1e-12)


def test_setting_an_output_is_an_error(fmu, slave):
    s = slave(fmu("slider_force"))
    s.init()
    assert s.status("setReal", [s.vr["slider.x"]], [3.0]) == ERROR
    assert s.messages[-1][0] == ERROR and '"slider.x" is an output' in s.messages[-1][2]
    assert s.get("slider.x")[0] == 0.0


def test_a_corrupt_serialized_state_is_refused_with_a_reason(fmu, slave):
    s = slave(fmu("slider_force"))
    s.init()
    assert s.status("deSerializeFMUstate", b"not a state") == ERROR
    assert s.messages[-1][0] == ERROR and "fmi2DeSerializeFMUstate: refused" in s.messages[-1][2]
    assert s.step(1e-3) == ERROR and "refused" in s.messages[-1][2]
