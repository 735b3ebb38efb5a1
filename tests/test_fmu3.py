"""FMI 3.0 export: every shipped scene's FMI 3.0 FMU against the FMI 2.0 FMU of the same
scene (the reference: its own tests hold it to closed forms and ``mbdfmu simulate``) in
fmpy and in Ecos, with fmpy's validation; states, statuses, input and output derivatives
of the FMI 3.0 API; Ecos' command line (no Python inside) from a clean environment;
companion sources built as FMI 3.0."""

from __future__ import annotations

import math
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT / "tests") not in sys.path:
    sys.path.insert(0, str(ROOT / "tests"))

fmpy = pytest.importorskip("fmpy")
from fmpy import read_model_description  # noqa: E402
from fmpy.validation import validate_fmu  # noqa: E402

from fmu_models import hosts  # noqa: E402
from fmu_models.fmi3_host import (DISCARD, ERROR, OK, Host3, ecospy_run, fmpy_run,  # noqa: E402
                                  largest_difference)
from mbdfmu.fmu_build import BuildError, build  # noqa: E402
from mbdfmu.fmu_build.scene_fmu import build_fmu  # noqa: E402

SCENES = sorted((ROOT / "scenes").glob("*.toml"))
COMPANIONS = sorted(p for p in (ROOT / "scenarios").glob("*/*.py")
                    if "CompanionSlave" in p.read_text() and p.name != "reference.py")
STEPS = 50


@pytest.fixture(scope="module")
def pair(tmp_path_factory):
    """(FMI 2.0 FMU, FMI 3.0 FMU) of a scene, built once."""
    root, built = tmp_path_factory.mktemp("fmi3"), {}

    def get(stem: str):
        if stem not in built:
            built[stem] = tuple(build_fmu(ROOT / "scenes" / f"{stem}.toml",
                                          root / f"{stem}_{v}.fmu", fmi_version=v)
                                for v in (2, 3))
        return built[stem]
    return get


def _run_length(stem: str) -> tuple[float, float]:
    """(t_end, h) of the cross-check (benchmarks/fmu_hosts_matrix.py's)."""
    import mbdfmu
    h = 10.0 ** math.floor(math.log10(mbdfmu.load_scene(ROOT / "scenes" / f"{stem}.toml")
                                      .simulation.t_end / 500))
    return STEPS * h, h


# ----------------------------------------------------------------------------- every scene

@pytest.mark.parametrize("scene", SCENES, ids=[p.stem for p in SCENES])
def test_every_fmi3_fmu_validates_and_equals_the_fmi2_fmu_in_fmpy_and_ecos(scene, pair):
    fmu2, fmu3 = pair(scene.stem)
    assert validate_fmu(str(fmu3)) == []
    md2, md3 = read_model_description(str(fmu2)), read_model_description(str(fmu3))
    assert md3.fmiVersion == "3.0" and md3.coSimulation.maxOutputDerivativeOrder == 2
    same = {v.name: (v.valueReference, v.causality, v.variability, v.unit, v.start)
            for v in md2.modelVariables}
    extra = {v.name: v for v in md3.modelVariables if v.name not in same}
    for v in md3.modelVariables:
        if v.name in same:
            assert same[v.name] == (v.valueReference, v.causality, v.variability, v.unit,
                                    v.start), v.name
    inputs = [v.name for v in md2.modelVariables if v.causality == "input"]
    assert set(extra) == {"time"} | {f"der({u})" for u in inputs} | {f"der({u},2)" for u in inputs}
    assert extra["time"].causality == "independent"
    t_end, h = _run_length(scene.stem)
    assert largest_difference(fmpy_run(fmu2, t_end, h), fmpy_run(fmu3, t_end, h)) <= 1e-12
    pytest.importorskip("ecospy")
    assert largest_difference(ecospy_run(fmu2, t_end, h), ecospy_run(fmu3, t_end, h)) <= 1e-12


def test_ecos_command_line_runs_an_fmi3_fmu_without_python_in_a_clean_environment(pair, tmp_path):
    pytest.importorskip("ecospy")
    fmu2, fmu3 = pair("slider_crank")
    t_end, h = 0.05, 1e-3
    run = hosts.run_ecos_cli(hosts.ecos_cli(tmp_path), fmu3, tmp_path, t_end + h / 2, h)
    assert run.returncode == 0, (run.stdout + run.stderr)[-2000:]
    got = hosts.read_ecos_csv(tmp_path / f"{fmu3.stem}.csv")
    expected = fmpy_run(fmu2, t_end, h)
    assert len(got["time"]) == len(expected["time"])
    names = [n for n in got if n in expected and n != "time"]
    assert len(names) > 10
    assert max(np.max(np.abs(np.array(got[n]) - expected[n])) for n in names) < 1e-6


# ----------------------------------------------------------------------------- the API

def _driven(path):
    """pendulum_torque with a ramped torque (value and derivative inputs), 0.1 s stepped."""
    host = Host3(path).init()
    host.set(**{"drive.torque": 1.0, "der(drive.torque)": 20.0, "der(drive.torque,2)": 200.0})
    assert host.step(0.1)[0] == OK
    return host


def test_fmi3_states_replay_bit_for_bit_and_load_only_into_their_fmu(pair):
    _, fmu3 = pair("pendulum_torque")
    host = _driven(fmu3)
    outs = [v.name for v in host.md.modelVariables if v.causality == "output"]
    state = host.fmu.getFMUState()
    blob = host.fmu.serializeFMUState(state)
    for _ in range(3):
        host.step(0.01)
    first = host.get(*outs)
    other = Host3(fmu3, "b").init()
    restored = other.fmu.deserializeFMUState(blob)
    other.fmu.setFMUState(restored)
    other.t = 0.1
    for _ in range(3):
        other.step(0.01)
    assert other.get(*outs) == first
    host.fmu.setFMUState(state)
    host.t = 0.1
    for _ in range(3):
        host.step(0.01)
    assert host.get(*outs) == first
    foreign = Host3(pair("slider_force")[1], "c").init()
    assert foreign.status(lambda f: f.deserializeFMUState(blob)) == ERROR
    assert "fmi3DeserializeFMUState: refused" in foreign.last()[2]


def test_fmi3_derivative_inputs_follow_the_polynomial_like_fmi2_input_derivatives(pair):
    """slider_force: F = 1 + 20 t + 100 t^2 given at t = 0 as a value and two derivative
    inputs; one step of 0.1 s lands on the closed form, as the FMI 2.0 FMU with
    fmi2SetRealInputDerivatives."""
    from fmpy import extract
    from fmpy.fmi2 import FMU2Slave

    fmu2, fmu3 = pair("slider_force")
    host = Host3(fmu3).init()
    host.set(**{"push.fx": 1.0, "der(push.fx)": 20.0, "der(push.fx,2)": 200.0})
    assert host.step(0.1)[:3:2] == (OK, 0.1)
    t, m = 0.1, 2.0
    x = (t * t / 2 + 20 * t ** 3 / 6 + 200 * t ** 4 / 24) / m
    assert host.get("slider.x")[0] == pytest.approx(x, rel=1e-9)
    md2 = read_model_description(str(fmu2))
    vr = {v.name: v.valueReference for v in md2.modelVariables}
    slave = FMU2Slave(guid=md2.guid, unzipDirectory=extract(str(fmu2)),
                      modelIdentifier="SliderForce", instanceName="b")
    slave.instantiate()
    slave.setupExperiment(startTime=0.0)
    slave.enterInitializationMode()
    slave.exitInitializationMode()
    slave.setReal([vr["push.fx"]], [1.0])
    slave.setRealInputDerivatives([vr["push.fx"]] * 2, [1, 2], [20.0, 200.0])
    slave.doStep(0.0, 0.1)
    names = [v.name for v in md2.modelVariables if v.causality == "output"]
    assert host.get(*names) == list(slave.getReal([vr[n] for n in names]))
    slave.freeInstance()


def test_fmi3_output_derivatives_equal_the_fmi2_ones(pair):
    from fmpy import extract
    from fmpy.fmi2 import FMU2Slave

    fmu2, fmu3 = pair("pendulum_torque")
    host = _driven(fmu3)
    outs = [v.name for v in host.md.modelVariables if v.causality == "output"]
    refs = [host.vr[n] for n in outs]
    d3 = [host.fmu.getOutputDerivatives(refs, [k] * len(refs)) for k in (1, 2)]
    md2 = read_model_description(str(fmu2))
    slave = FMU2Slave(guid=md2.guid, unzipDirectory=extract(str(fmu2)),
                      modelIdentifier=md2.coSimulation.modelIdentifier, instanceName="b")
    slave.instantiate()
    slave.setupExperiment(startTime=0.0)
    slave.enterInitializationMode()
    slave.exitInitializationMode()
    torque = host.vr["drive.torque"]
    slave.setReal([torque], [1.0])
    slave.setRealInputDerivatives([torque] * 2, [1, 2], [20.0, 200.0])
    slave.doStep(0.0, 0.1)
    d2 = [list(slave.getRealOutputDerivatives(refs, [k] * len(refs))) for k in (1, 2)]
    assert [list(d) for d in d3] == d2
    assert host.status(lambda f: f.getOutputDerivatives(refs[:1], [3])) == ERROR
    assert "fmi3GetOutputDerivatives" in host.last()[2]
    slave.freeInstance()


@pytest.mark.parametrize("call, words", [
    (lambda f: f.doStep(0.0, 1e-3), "fmi3DoStep is not allowed in state Instantiated "
                                   "(allowed in: Step Mode)"),
    (lambda f: f.enterEventMode(), "fmi3EnterEventMode: this FMU has no Event Mode"),
    (lambda f: f.getFloat32([0]), "fmi3GetFloat32"),
])
def test_fmi3_misuse_before_initialization_is_an_error_naming_fmi3_functions(pair, call, words):
    host = Host3(pair("slider_crank")[1])
    assert host.status(call) == ERROR
    assert host.last()[:2] == (ERROR, "logStatusError") and words in host.last()[2], host.last()


def test_fmi3_statuses_after_initialization(pair):
    host = Host3(pair("slider_force")[1]).init()
    assert host.status(lambda f: f.setFloat64([host.vr["push.fx"]], [math.nan])) == DISCARD
    assert host.last()[2] == 'fmi3SetFloat64: "push.fx" = nan is not finite; value not applied'
    assert host.step(1e-3)[0] == OK and host.get("time") == [1e-3]
    assert host.status(lambda f: f.doStep(0.5, 1e-3)) == ERROR
    assert "fmi3DoStep: currentCommunicationPoint 0.5 is not the FMU's time" in host.last()[2]
    assert host.status(lambda f: f.getFloat64([99999])) == ERROR
    assert "fmi3GetFloat64: unknown Float64 value reference 99999" in host.last()[2]
    bad = Host3(pair("slider_force")[1], "b")
    bad.fmu.enterInitializationMode(startTime=0.0)
    bad.set(**{"slider.mass": -1.0})
    assert bad.status(lambda f: f.exitInitializationMode()) == ERROR
    assert "fmi3ExitInitializationMode" in bad.last()[2] and "slider.mass" in bad.last()[2]


def test_an_fmi3_solver_failure_is_discarded_and_the_step_can_be_retried(pair):
    host = Host3(pair("slider_crank")[1])
    host.fmu.enterInitializationMode(startTime=0.0)
    host.fmu.setInt32([host.vr["solver.max_steps_per_communication_step"]], [3])
    host.fmu.exitInitializationMode()
    assert host.step(1.0)[0] == DISCARD
    assert "solver.max_steps_per_communication_step" in host.last()[2]
    assert host.step(1e-4)[0] == OK


# ----------------------------------------------------------------------------- builds

@pytest.mark.parametrize("source", COMPANIONS, ids=[p.stem for p in COMPANIONS])
def test_companion_sources_build_as_fmi3_and_run_like_fmi2(source, tmp_path):
    fmu2 = build(source, tmp_path / "c2.fmu")
    fmu3 = build(source, tmp_path / "c3.fmu", fmi_version=3)
    assert validate_fmu(str(fmu3)) == []
    assert largest_difference(fmpy_run(fmu2, 0.02, 1e-3), fmpy_run(fmu3, 0.02, 1e-3)) <= 1e-12


def test_the_command_line_builds_fmi3_and_refuses_other_versions(tmp_path):
    out = subprocess.run([sys.executable, "-m", "mbdfmu", "build", "pendulum", "--fmi-version",
                          "3", "-o", str(tmp_path / "P.fmu")], capture_output=True, text=True)
    assert out.returncode == 0, out.stderr
    assert read_model_description(str(tmp_path / "P.fmu")).fmiVersion == "3.0"
    with pytest.raises(BuildError, match="FMI 2.0 and 3.0"):
        build("pendulum", tmp_path / "Q.fmu", fmi_version=4)


def test_fmi3_get_float64_after_a_step_never_serves_a_stale_value(pair):
    """fmi3GetFloat64 is served from the values the slave published after a step (the C
    side, as fmi2GetReal); every other call makes it read through Python again: after a
    state restore and a set the values are the restored and the set ones, and the
    independent variable time (not among the published values) is the instance's time."""
    _, fmu3 = pair("slider_force")
    h3 = Host3(fmu3).init()
    first = []
    for k in range(5):
        h3.set(**{"push.fx": math.sin(20 * h3.t)})
        assert h3.step(1e-3)[0] == OK
        first.append(h3.get("slider.x")[0])
    state = h3.fmu.getFMUState()
    for k in range(5):
        h3.set(**{"push.fx": 2.0})
        assert h3.step(1e-3)[0] == OK
    assert h3.get("slider.x")[0] != first[-1]
    h3.fmu.setFMUState(state)
    assert h3.get("slider.x")[0] == first[-1]          # the restored state's value
    h3.set(**{"push.fx": 0.5})
    assert h3.get("push.fx") == [0.5]                   # set values read back at once
    assert h3.get("time") == [pytest.approx(0.005)]     # the restored state's time
    assert h3.status(lambda f: f.getFloat64([10 ** 6])) == ERROR
    assert "fmi3GetFloat64" in h3.last()[2]
