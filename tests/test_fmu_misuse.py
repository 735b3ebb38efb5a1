"""Every misuse of the reliability findings, replayed on real scene FMUs (slider_force,
slider_crank, pendulum_torque) through fmpy's low-level FMU2Slave: the FMI status, the
logged reason, and a valid call afterwards where the standard allows one. Also: bounded
work per doStep (the steps that hung), fmi2SetupExperiment's tolerance, build-time start
values, and 1000 refused byte strings in fmi2DeSerializeFMUstate.
"""

from __future__ import annotations

import ctypes
import json
import math
import sys
import time
import warnings
import zipfile
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT / "tests") not in sys.path:
    sys.path.insert(0, str(ROOT / "tests"))

pytest.importorskip("fmpy")
from fmpy import read_model_description  # noqa: E402

import mbdfmu  # noqa: E402
from mbdfmu.fmu_build import BuildError  # noqa: E402
from mbdfmu.fmu_build.scene_fmu import build_fmu  # noqa: E402
from fmu_models.harness import (DISCARD, ERROR, OK, deserialize, get_state,  # noqa: E402
                                mutations, serialize)
from fmu_models.scenes import SCENES, scene_fmu, scene_host  # noqa: E402,F401

H = 1e-3
CPU = "solver.max_cpu_per_communication_step"
STEPS = "solver.max_steps_per_communication_step"


def _init(h, **values):
    h.fmu.setupExperiment(startTime=0.0)
    h.fmu.enterInitializationMode()
    for name, value in values.items():
        if name == STEPS:
            assert h.set_int(name, value) == OK
        else:
            assert h.set_real([h.vr[name]], [value]) == OK
    assert h.status("fmi2ExitInitializationMode") == OK, h.messages[-3:]
    return h


def _after_error_reset_works(h):
    """fmi2Error: stepping is refused with the reason; fmi2Reset starts over."""
    assert h.step() == ERROR and "earlier call returned fmi2Error" in h.last()[2]
    assert h.status("fmi2Reset") == OK
    h.t = 0.0
    _init(h)
    assert h.step(H) == OK


# ------------------------------------------------------------------ arguments of fmi2DoStep

@pytest.mark.parametrize("stem", ["slider_force", "slider_crank"])
@pytest.mark.parametrize("point, step, words", [
    (math.nan, H, "currentCommunicationPoint = nan"),
    (math.inf, H, "currentCommunicationPoint = inf"),
    (0.0, math.nan, "communicationStepSize = nan"),
    (0.0, math.inf, "communicationStepSize = inf"),
    (0.0, -1e-3, "communicationStepSize = -0.001 must be positive"),
    (0.0, 0.0, "communicationStepSize = 0"),
    (0.5, H, "currentCommunicationPoint 0.5 is not the FMU's time 0.0"),
])
def test_invalid_time_arguments_are_errors_naming_them(scene_fmu, scene_host, stem, point,
                                                      step, words):
    h = _init(scene_host(scene_fmu(stem)))
    assert h.status("fmi2DoStep", point, step, 1) == ERROR
    assert h.last()[:2] == (ERROR, "logStatusError") and words in h.last()[2], h.last()
    _after_error_reset_works(h)


@pytest.mark.parametrize("stem, step", [("slider_crank", 1e300), ("pendulum_torque", 1e5),
                                        ("slider_crank", 1e3)])
def test_steps_that_hung_return_discard_promptly_and_the_fmu_goes_on(scene_fmu, scene_host,
                                                                    stem, step):
    """The hangs of the findings: bounded by the work limits (here 0.5 CPU s; fixed-step
    methods are refused before their first step), fmi2Discard with the reason, the FMU at
    its last communication point, a smaller step then passes."""
    h = _init(scene_host(scene_fmu(stem)), **{CPU: 0.5})
    before = h.real(*h.outputs)
    start = time.perf_counter()
    assert h.step(step) == DISCARD
    assert time.perf_counter() - start < 5.0
    assert h.last()[:2] == (DISCARD, "logStatusDiscard")
    assert ("solver.max_" in h.last()[2] and "did not reach" in h.last()[2]) or \
        "more than solver.max_steps_per_communication_step" in h.last()[2], h.last()
    assert h.real(*h.outputs) == before
    last = ctypes.c_double()
    assert h.status("fmi2GetRealStatus", 2, ctypes.byref(last)) == OK and last.value == 0.0
    assert h.step(H) == OK


def test_a_diverging_step_is_an_error_with_its_reason_and_no_python_warning(scene_fmu,
                                                                            scene_host):
    """A torque of 1e200 N m makes the pendulum's state overflow: fmi2Error with the
    solver's reason in the log, and no numpy RuntimeWarning, which the FMU's Python would
    print to the host's stderr (an FMU reports through its logger; before, every overflow
    and invalid value inside the step raised one). The FMU runs in this interpreter, so
    its warnings are this process's."""
    h = _init(scene_host(scene_fmu("pendulum_torque")))
    assert h.step(H) == OK
    assert h.set_real([h.vr["drive.torque"]], [1e200]) == OK
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        assert h.step(H) == ERROR
    assert h.last()[:2] == (ERROR, "logStatusError") and "non-finite" in h.last()[2], h.last()
    assert not [w for w in caught if issubclass(w.category, RuntimeWarning)], caught[:3]


def test_a_huge_step_of_a_slider_at_rest_returns_promptly_where_it_was(scene_fmu, scene_host):
    """The findings' other hang (doStep(0, 1e300) on slider_force): at rest with no force
    its q'' is exactly 0 (gravity is the guide's reaction), so every error estimate is 0
    and the steps grow tenfold each to the end: OK at once, the slider where it was."""
    h = _init(scene_host(scene_fmu("slider_force")), **{CPU: 0.5})
    start = time.perf_counter()
    assert h.step(1e300) == OK, h.messages[-2:]
    assert time.perf_counter() - start < 5.0
    assert h.real("slider.x", "slider.y", "slider.vx") == [0.0, 0.0, 0.0]


def test_the_default_step_limit_refuses_a_fixed_step_run_before_it_starts(scene_fmu, scene_host):
    h = _init(scene_host(scene_fmu("slider_crank")))
    start = time.perf_counter()
    assert h.step(1e300) == DISCARD
    assert time.perf_counter() - start < 1.0
    assert "takes 1e+303 steps of 0.001 s, more than " \
           "solver.max_steps_per_communication_step = 100000" in h.last()[2], h.last()
    assert h.step(H) == OK


def test_a_step_limit_of_zero_means_none(scene_fmu, scene_host):
    h = _init(scene_host(scene_fmu("slider_crank")), **{STEPS: 0})
    assert h.step(0.2) == OK        # 200 internal steps; the default would allow them too
    h2 = _init(scene_host(scene_fmu("slider_crank"), "b"), **{STEPS: 50})
    assert h2.step(0.2) == DISCARD and "takes 200 steps" in h2.last()[2]


# ------------------------------------------------------------------ value references, states

def test_unknown_references_keep_the_valid_values_of_a_mixed_call(scene_fmu, scene_host):
    h = _init(scene_host(scene_fmu("slider_force")))
    h.set_real([h.vr["push.fx"]], [2.0])
    assert h.step(0.1) == OK
    x = h.real("slider.x")[0]
    code, (got, missing) = h.get_real(h.vr["slider.x"], 99999)
    assert code == ERROR and got == x and math.isnan(missing)
    assert "fmi2GetReal: unknown Real value reference 99999" in h.last()[2]
    _after_error_reset_works(h)
    h2 = _init(scene_host(scene_fmu("slider_force"), "b"))
    assert h2.set_real([h2.vr["push.fx"], 99999], [3.0, 1.0]) == ERROR
    assert "fmi2SetReal: unknown Real value reference 99999" in h2.last()[2]
    assert h2.real("push.fx") == [3.0]
    method = h2.vr["solver.method"]
    values = (ctypes.c_char_p * 2)()
    assert h2.status("fmi2GetString", (ctypes.c_uint * 2)(method, 4242), 2, values) == ERROR
    assert values[0] == b"auto" and values[1] == b""
    assert "fmi2GetString: unknown String value reference 4242" in h2.last()[2]
    code, values = h2.get_real(method)
    assert code == ERROR and "is solver.method, not a Real variable" in h2.last()[2]


def test_step_after_terminate_and_terminate_twice_are_errors(scene_fmu, scene_host):
    h = _init(scene_host(scene_fmu("slider_crank")))
    assert h.step(H) == OK
    assert h.status("fmi2Terminate") == OK
    assert h.step(H) == ERROR and "not allowed in state Terminated" in h.last()[2]
    assert h.real("crank.phi")        # values can still be read
    h2 = _init(scene_host(scene_fmu("slider_crank"), "b"))
    assert h2.status("fmi2Terminate") == OK and h2.status("fmi2Terminate") == ERROR
    assert "fmi2Terminate is not allowed in state Terminated" in h2.last()[2]
    assert h2.status("fmi2Reset") == OK


@pytest.mark.parametrize("stage", ["Instantiated", "Initialization Mode"])
def test_step_before_initialization_is_an_error_naming_the_state(scene_fmu, scene_host, stage):
    h = scene_host(scene_fmu("slider_crank"))
    h.fmu.setupExperiment(startTime=0.0)
    if stage != "Instantiated":
        h.fmu.enterInitializationMode()
    assert h.step(H) == ERROR and f"not allowed in state {stage}" in h.last()[2]
    _after_error_reset_works(h)


def test_state_of_another_scene_fmu_is_refused(scene_fmu, scene_host):
    a = _init(scene_host(scene_fmu("slider_crank")))
    assert a.step(H) == OK
    blob = serialize(a, get_state(a))
    b = _init(scene_host(scene_fmu("pendulum_torque"), "b"))
    code, _ = deserialize(b, blob)
    assert code == ERROR and "fmi2DeSerializeFMUstate: refused" in b.last()[2], b.last()


def test_deserialize_refuses_1000_blobs_on_a_scene_fmu_and_runs_nothing(scene_fmu, scene_host,
                                                                       tmp_path):
    h = _init(scene_host(scene_fmu("slider_crank")))
    for _ in range(3):
        assert h.step(H) == OK
    blob = serialize(h, get_state(h))
    marker = tmp_path / "pwned"
    count = 0
    for data in mutations(blob, h.fmu.guid, marker, count=1000):
        code, _ = deserialize(h, data)
        assert code == ERROR, data[:80]
        assert h.last()[:2] == (ERROR, "logStatusError")
        assert "fmi2DeSerializeFMUstate: refused:" in h.last()[2], h.last()
        count += 1
    assert count == 1000 and not marker.exists()
    code, state = deserialize(h, blob)          # the genuine one still loads
    assert code == OK and h.status("fmi2SetFMUstate", state) == OK
    h.t = 3 * H
    assert h.step(H) == OK


# ------------------------------------------------------------------ settings and start values

def test_setup_experiment_tolerance_becomes_solver_rtol_and_is_logged(scene_fmu, scene_host):
    h = scene_host(scene_fmu("pendulum_torque"))
    h.fmu.setupExperiment(tolerance=1e-9, startTime=0.0)
    h.fmu.enterInitializationMode()
    h.fmu.exitInitializationMode()
    assert any("tolerance 1e-09 used as solver.rtol" in m for _, _, m in h.messages)
    got = []
    for _ in range(20):
        assert h.step(1e-2) == OK
        got.append(h.real("rod.phi")[0])
    expected = mbdfmu.simulate(SCENES / "pendulum_torque.toml", t_end=0.2, output_interval=1e-2,
                               kernel="numpy", rtol=1e-9)["rod.phi"][1:]
    np.testing.assert_allclose(got, expected, rtol=0, atol=1e-12)


def test_start_values_baked_in_at_build_time(tmp_path):
    path = build_fmu(SCENES / "pendulum_torque.toml", tmp_path / "p.fmu",
                     parameters={"rod.mass": 2.5, "gravity.y": -1.62})
    starts = {v.name: v.start for v in read_model_description(path).modelVariables}
    assert float(starts["rod.mass"]) == 2.5 and float(starts["gravity.y"]) == -1.62
    from fmpy import simulate_fmu
    got = simulate_fmu(path, stop_time=0.05, output_interval=1e-2)
    scene = mbdfmu.with_parameters(mbdfmu.load_scene(SCENES / "pendulum_torque.toml"),
                                   {"rod.mass": 2.5, "gravity.y": -1.62})
    expected = mbdfmu.simulate(scene, t_end=0.05, output_interval=1e-2, kernel="numpy")
    np.testing.assert_allclose(got["rod.phi"], expected["rod.phi"], rtol=0, atol=1e-12)
    with pytest.raises(BuildError, match='"rod.mass" must be positive'):
        build_fmu(SCENES / "pendulum_torque.toml", tmp_path / "q.fmu", parameters={"rod.mass": -1})
    with pytest.raises(BuildError, match='unknown parameter "rod.mas"'):
        build_fmu(SCENES / "pendulum_torque.toml", tmp_path / "q.fmu", parameters={"rod.mas": 1})


def test_outputs_are_calculated_from_parameters_set_in_initialization(scene_fmu, scene_host):
    """initial="calculated": in Initialization Mode the outputs follow the parameters."""
    h = scene_host(scene_fmu("pendulum_torque"))
    h.fmu.setupExperiment(startTime=0.0)
    h.fmu.enterInitializationMode()
    assert h.set_real([h.vr["rod.mass"]], [3.0]) == OK
    names = h.outputs
    got = h.real(*names)
    scene = mbdfmu.with_parameters(mbdfmu.load_scene(SCENES / "pendulum_torque.toml"),
                                   {"rod.mass": 3.0})
    expected = mbdfmu.Simulation(scene, kernel="numpy").outputs()
    assert got == pytest.approx([expected[n] for n in names], abs=1e-12)
    assert h.status("fmi2ExitInitializationMode") == OK


def test_the_model_description_declares_dependencies_and_initial_unknowns(scene_fmu):
    with zipfile.ZipFile(scene_fmu("slider_crank")) as z:
        text = z.read("modelDescription.xml").decode()
        config = json.loads(z.read("resources/mbdfmu.json"))
    md = read_model_description(scene_fmu("slider_crank"))
    outputs = [v for v in md.modelVariables if v.causality == "output"]
    assert outputs and all(v.initial == "calculated" and v.start is None for v in outputs)
    assert [u.variable.name for u in md.outputs] == [v.name for v in outputs]
    # no direct feedthrough: outputs depend on the exposed states only, body states on none
    states = {v.derivative.name for v in md.modelVariables if v.derivative is not None}
    assert all({d.name for d in u.dependencies} <= states for u in md.outputs)
    assert all(u.dependencies == [] for u in md.outputs if u.variable.name in states)
    locals_ = [v.name for v in md.modelVariables if v.causality == "local"]
    assert locals_ == ["crank.ax", "crank.ay", "crank.alpha", "rod.ax", "rod.ay", "rod.alpha",
                       "slider.ax", "slider.ay", "slider.alpha"]
    assert [u.variable.name for u in md.initialUnknowns] == [v.name for v in outputs] + locals_
    assert [u.variable.name for u in md.derivatives] == [   # in value-reference order
        f"{b}.{c}" for b in ("crank", "rod", "slider") for c in ("vx", "vy", "omega")] + locals_
    # the body-state outputs and, in Derivatives, the velocities (derivatives of positions)
    assert text.count('dependencies=""') == len(states) + len(states) // 2
    assert config["python_library"]       # hosts without Python load this libpython


def test_mbdfmu_build_says_in_one_line_that_a_c_compiler_is_missing(tmp_path, monkeypatch,
                                                                    capsys):
    from mbdfmu.cli import main
    monkeypatch.setenv("CC", "no-such-cc")
    monkeypatch.setenv("MBDFMU_CACHE_DIR", str(tmp_path / "cache"))   # nothing compiled yet
    assert main(["build", "slider_crank", "-o", str(tmp_path / "x.fmu")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "no C compiler found" in err[0] and "apt-get install gcc" in err[0]
    assert not (tmp_path / "x.fmu").exists()
