"""The end-stop and friction scenes through their FMUs in fmpy, against the same closed forms
as ``simulate()`` (``event_checks.py``): positions to 1e-8, forces to 1e-6 relative, and the
transitions the FMU logs at their closed-form times to 1e-9 s, at the FMU's default solver
settings and at solver.rtol = 1e-10. One case per scene by default, the rest with
MBDFMU_SLOW=1."""

from __future__ import annotations

import os
import re

import numpy as np
import pytest

fmpy = pytest.importorskip("fmpy")
from fmpy.fmi2 import FMU2Slave  # noqa: E402

from mbdfmu.fmu_build import build  # noqa: E402
from mbdfmu.model import load_scene  # noqa: E402

import exact_solutions as ref  # noqa: E402
import fmu_logs  # noqa: E402
from event_checks import CHECKS, check_events  # noqa: E402

SLOW = [pytest.mark.slow,
        pytest.mark.skipif(not os.environ.get("MBDFMU_SLOW"), reason="long run; set MBDFMU_SLOW=1")]
START = {"default": {}, "rtol 1e-10": {"solver.rtol": 1e-10, "solver.atol": 1e-10},
         "rk4p": {"solver.method": "rk4p"}}
FAST = {("slider_stop", "default"), ("incline_stick", "rk4p"), ("incline_slide", "rtol 1e-10"),
        ("crane_stop", "default")}
EVENT_LINE = re.compile(r"^t = (\S+) s: joint (\w+) (.*)$")


def cases():
    return [pytest.param(name, start, marks=[] if (name, start) in FAST else SLOW,
                         id=f"{name}-{start}") for name in CHECKS for start in START]


@pytest.fixture(scope="module")
def fmus(tmp_path_factory):
    folder = tmp_path_factory.mktemp("limit_fmus")
    return {name: build(ref.SCENES / f"{name}.toml", folder / f"{name}.fmu") for name in CHECKS}


def _instance(path, name: str, folder):
    """An fmpy instance of the FMU at ``path`` logging through the process's one logger."""
    md = fmpy.read_model_description(str(path))
    slave = FMU2Slave(guid=md.guid, unzipDirectory=fmpy.extract(str(path), str(folder)),
                      modelIdentifier=md.coSimulation.modelIdentifier, instanceName=name)
    slave.instantiate(callbacks=fmu_logs.CALLBACKS, loggingOn=True)
    return slave


@pytest.mark.parametrize("name, start", cases())
def test_fmu_matches_the_closed_form(fmus, name, start, tmp_path):
    t_end = load_scene(ref.SCENES / f"{name}.toml").simulation.t_end
    # the log through the process's one logger (fmu_logs), never a logger= callback, which
    # fmpy would keep process-wide after freeing it
    instance = f"limits-{name}-{start}"
    fmu_logs.take(instance)
    slave = _instance(fmus[name], instance, tmp_path)
    try:
        table = fmpy.simulate_fmu(str(fmus[name]), stop_time=t_end, output_interval=t_end / 40,
                                  start_values=START[start], fmu_instance=slave)
    finally:
        slave.freeInstance()
    lines = fmu_logs.take(instance)
    time = np.asarray(table["time"], dtype=float)
    assert time[-1] == pytest.approx(t_end)
    CHECKS[name](time, {n: np.asarray(table[n], dtype=float) for n in table.dtype.names})
    events = [(float(m[1]), m[2], m[3]) for m in map(EVENT_LINE.match, lines) if m]
    check_events(name, events)
    # the C kernel runs every contact mode: no note of another kernel
    assert not any("numpy kernel" in line for line in lines)


def test_fmu_state_keeps_the_contact_mode(fmus, tmp_path):
    # slider_stop saved before its impacts, serialized, restored in a second instance: the
    # same impacts and the same rest on the stop, bit for bit
    from fmpy import extract, read_model_description
    from fmpy.fmi2 import FMU2Slave

    md = read_model_description(str(fmus["slider_stop"]))
    vr = {v.name: v.valueReference for v in md.modelVariables}
    names = ["slider.x", "slider.vx", "guide.limit"]

    def open_(name):
        fmu = FMU2Slave(guid=md.guid, unzipDirectory=extract(str(fmus["slider_stop"]),
                                                            str(tmp_path / name)),
                        modelIdentifier=md.coSimulation.modelIdentifier, instanceName=name)
        fmu.instantiate()
        fmu.setupExperiment(startTime=0.0)
        fmu.enterInitializationMode()
        fmu.exitInitializationMode()
        return fmu

    def run(fmu, t0):
        rows = []
        for k in range(8):
            fmu.doStep(t0 + 0.5 * k, 0.5)
            rows.append(fmu.getReal([vr[n] for n in names]))
        return np.array(rows)

    first = open_("first")
    first.doStep(0.0, 0.5)
    data = first.serializeFMUstate(first.getFMUstate())
    reference = run(first, 0.5)
    second = open_("second")
    state = second.deSerializeFMUstate(data)
    second.setFMUstate(state)
    assert np.array_equal(run(second, 0.5), reference)
    assert reference[-1][2] == pytest.approx(2.0) and abs(reference[-1][0]) < 1e-12   # at rest
    for fmu in (first, second):
        fmu.terminate()
        fmu.freeInstance()
