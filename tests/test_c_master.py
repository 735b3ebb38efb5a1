"""benchmarks/c_master.py, the C master whose CPU time fmu_speed.py reports as the FMU's own
cost, really steps the FMU as fmpy does: the crane's mechanism with its cylinder force set
before every step gives the same boom angle after 320 steps in both hosts (the force is
computed by the same libm sin in C and in Python). No timing asserts."""

from __future__ import annotations

import importlib.util
import math
import shutil
from pathlib import Path

import pytest
from fmpy import extract, read_model_description
from fmpy.fmi2 import FMU2Slave

ROOT = Path(__file__).resolve().parents[1]
CRANE = ROOT / "scenarios" / "hydraulic_crane" / "crane.toml"
HOLD, SWING, H, STEPS = 8420.0, 0.05, 1e-3, 300

pytestmark = pytest.mark.skipif(shutil.which("gcc") is None, reason="no gcc to build the C master")


@pytest.fixture(scope="module")
def c_master():
    """benchmarks/c_master.py as a module (benchmarks/ is not a package)."""
    spec = importlib.util.spec_from_file_location("c_master", ROOT / "benchmarks" / "c_master.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def fmpy_boom_angle(fmu: Path, force_vr: int, phi_vr: int) -> float:
    md = read_model_description(fmu)
    folder = extract(fmu)
    s = FMU2Slave(guid=md.guid, unzipDirectory=folder, instanceName="fmpy",
                  modelIdentifier=md.coSimulation.modelIdentifier)
    s.instantiate()
    s.setupExperiment(startTime=0.0)
    s.enterInitializationMode()
    s.exitInitializationMode()
    t = 0.0
    for _ in range(STEPS + 20):                    # the C master's 20 untimed steps, then STEPS
        s.setReal([force_vr], [HOLD * (1.0 + SWING * math.sin(2.0 * math.pi * t))])
        s.doStep(t, H)
        t += H
    phi = s.getReal([phi_vr])[0]
    s.terminate()
    s.freeInstance()
    shutil.rmtree(folder, ignore_errors=True)
    return phi


def test_the_c_master_steps_the_crane_as_fmpy_does(c_master, tmp_path):
    from mbdfmu.fmu_build.scene_fmu import build_fmu
    fmu = build_fmu(CRANE, tmp_path / "crane.fmu")
    names = {v.name: v.valueReference for v in read_model_description(fmu).modelVariables}
    binary = c_master.compile_master(tmp_path)
    run = c_master.c_master_run_values(binary, fmu, h=H, n=STEPS, hold=HOLD, swing=SWING,
                                       input_vr=names["cylinder.actuator"],
                                       outputs=[names["boom.phi"]])
    expected = fmpy_boom_angle(fmu, names["cylinder.actuator"], names["boom.phi"])
    assert run["cpu_s"] > 0.0
    assert run["first_output"] == pytest.approx(expected, rel=0, abs=1e-14)
    # the force moved the boom: the run is not a held state that any host would give
    assert abs(expected - 0.2) > 1e-4
