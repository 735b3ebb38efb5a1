"""The FMU's C wrapper with a driver position the master sets before every step
(fmi2SetReal of motor.position, and of its velocity and acceleration where given): rk4p's
steps in C (ckernel/fixed.h) follow the driver's sampled motion (ckernel/motions.h, the
twin of signals.SampledDriver) and restart with a projection after each set, as
Simulation._reinitialize. References: the same FMU sent through Python at every doStep
(fmi2SetDebugLogging after each), and P4's driving torque from the power balance
(``reference.py`` of the prescribed-motion scenario); never the C run's own output."""

from __future__ import annotations

import ctypes
import importlib.util
import math
import sys
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parent))

from mbdfmu.equations import ckernel  # noqa: E402
from fmu_models.harness import OK  # noqa: E402
from mbdfmu.fmu_build.scene_fmu import build_fmu  # noqa: E402
from fmu_models.scenes import scene_host  # noqa: E402,F401
from test_fmu_dense_run import taken_by_wrapper  # noqa: E402

pytestmark = pytest.mark.skipif(not ckernel.available(), reason="no C compiler for the kernel")
SCENARIO = Path(__file__).resolve().parents[1] / "scenarios" / "prescribed_motion"
SCENES = Path(__file__).resolve().parents[1] / "scenes"
W, H = 314.1592653589793, 1e-3          # P4's crank rate (rad/s), the communication step (s)


@pytest.fixture(scope="module")
def driven_fmu(tmp_path_factory):
    return build_fmu(SCENARIO / "slider_crank.toml",
                     tmp_path_factory.mktemp("driven") / "driven.fmu")


def p4_torque(theta, w):
    """P4's driving torque at crank angle theta and constant rate w (the scenario's
    ``reference.py``: the power balance of the kinetic energy, gravity and the load)."""
    spec = importlib.util.spec_from_file_location("prescribed_reference",
                                                  SCENARIO / "reference.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    mechanism = SimpleNamespace(source=SCENARIO / "slider_crank.toml")
    data = module._data(SimpleNamespace(instance=lambda name: mechanism))
    return module.torque(theta, w, 0.0 * theta, data)


def _lockstep(scene_host, path, method, steps, inputs, values_at):
    """Two hosts of the FMU (``method``), the master setting ``inputs`` to ``values_at(t)``
    before every 1 ms step; "slow" sent through Python at every doStep, their values equal
    bit for bit after each. Returns (fast, slow, the outputs the fast one served, a row a
    step)."""
    hosts = []
    for name in ("fast", "slow"):
        host = scene_host(path, name)
        assert host.fmu.setString([host.vr["solver.method"]], [method]) is None
        hosts.append(host.init())
    fast, slow = hosts
    names, served = fast.outputs, []
    vrs = (ctypes.c_uint * len(inputs))(*(fast.vr[name] for name in inputs))
    for k in range(steps):
        values = (ctypes.c_double * len(inputs))(*values_at(k * H))
        for host in (fast, slow):
            assert not inputs or host.status("fmi2SetReal", vrs, len(inputs), values) == OK
            assert host.step(H) == OK, host.messages[-3:]
        served.append(fast.real(*names))
        assert served[-1] == slow.real(*names), k
        assert slow.status("fmi2SetDebugLogging", True, 0, None) == OK
    assert fast.status("fmi2SetDebugLogging", True, 0, None) == OK
    return fast, slow, np.array(served)


def _run(scene_host, path, method, motion, steps, fields=("position",)):
    """``_lockstep`` with the driver's ``fields`` set from ``motion(t)`` = (p, v, a).
    Returns (fast, slow, the efforts the fast one served)."""
    which = [("position", "velocity", "acceleration").index(f) for f in fields]
    fast, slow, served = _lockstep(scene_host, path, method, steps,
                                   [f"motor.{f}" for f in fields],
                                   lambda t: [motion(t)[i] for i in which])
    return fast, slow, served[:, fast.outputs.index("motor.effort")]


@pytest.mark.parametrize("method", ["rk4p", "dop853p", "rk45p"])
@pytest.mark.parametrize("fields", [("position",), ("position", "velocity", "acceleration")])
def test_a_driver_position_set_before_every_step_keeps_the_steps_in_the_wrapper(
        scene_host, driven_fmu, fields, method):
    """P4's crank at 314.16 rad/s set every 1 ms for 0.3 s (positions alone, then with
    their derivatives), with rk4p (fixed.h) and the embedded pairs' landing steps
    (adaptive.h; dop853p is the scene's method): every value the wrapper serves is
    Python's bit for bit, the wrapper takes every doStep but the first, and the driving
    torque is P4's power balance. Before, every doStep of a position-driven FMU went
    through Python."""
    steps = 300
    fast, slow, efforts = _run(scene_host, driven_fmu, method, lambda t: (W * t, W, 0.0),
                               steps, fields)
    assert taken_by_wrapper(fast) >= steps - 1, taken_by_wrapper(fast)
    assert taken_by_wrapper(slow) == 0
    # the inputs as the master last set them, once Python caught up (fast_steps.held_inputs)
    last = [f"motor.{f}" for f in fields]
    assert fast.real(*last) == slow.real(*last) == list((W * (steps - 1) * H, W, 0.0)[:len(last)])
    exact = p4_torque(W * H * np.arange(1, steps + 1), W)
    # derived velocity: the first two steps start from rest (its history fills)
    start = 0 if len(fields) == 3 else 3
    assert np.abs(efforts[start:] - exact[start:]).max() < 1e-6 * np.abs(exact).max()


@pytest.mark.parametrize("method", ["rk4p", "dop853p"])
def test_the_steps_where_the_derived_accelerations_warning_turns_are_pythons(
        scene_host, driven_fmu, method):
    """phi = 0.01 sin(2 pi 20 t) rad set as positions alone at 1 ms: the derived
    acceleration's estimated error, about 2 h times the jerk against the largest
    acceleration so far, is above 10 % (signals.LARGE_ERROR) except near the jerk's zeros,
    so the warning turns on and off four times a period. The doSteps at which it turns are
    Python's, which logs it each time it turns on; the wrapper takes the others. The
    warnings and every value are those of the run in Python."""
    def motion(t):
        return 0.01 * math.sin(2.0 * math.pi * 20.0 * t), 0.0, 0.0
    steps = 400
    fast, slow, _ = _run(scene_host, driven_fmu, method, motion, steps)
    warned = [[m for _, _, m in h.messages if "derived from motor.position" in m]
              for h in (fast, slow)]
    assert warned[0] == warned[1] and len(warned[0]) >= 10, warned[0][:2]
    assert steps - 1 - 2 * len(warned[0]) <= taken_by_wrapper(fast) < steps - 1


@pytest.mark.parametrize("method", ["dop853p", "rk45p"])
def test_an_embedded_pair_in_a_scene_with_a_driver_takes_set_forces_in_the_wrapper(
        scene_host, tmp_path, method):
    """The slider-crank with its motor on a harmonic motion (0.3 rad at 40 Hz) and its
    slider's load an input the master sets before every 1 ms step: the embedded pair's
    landing steps evaluate the motion at each stage's time in C (motions.h) and restart
    without a projection after each set (a force moves no constraint). Every value the
    wrapper serves is Python's bit for bit, every doStep but the first is the wrapper's.
    Before, a pair's doSteps in any scene with a driver went through Python."""
    text = (SCENES / "slider_crank.toml").read_text()
    linear = 'motion = { type = "linear", start = 0.0, rate = 314.1592653589793 }'
    assert linear in text and "value = [-10.0, 0.0]" in text
    scene = tmp_path / "slider_crank_pushed.toml"
    scene.write_text(text.replace(linear, 'motion = { type = "harmonic", offset = 0.0, '
                                  'amplitude = 0.3, frequency = 40.0 }')
                     .replace("value = [-10.0, 0.0]", "input = true"))
    path = build_fmu(scene, tmp_path / "pushed.fmu")
    steps = 300
    fast, _, _ = _lockstep(scene_host, path, method, steps, ["load.fx"],
                           lambda t: [-10.0 - 5.0 * math.sin(2.0 * math.pi * 7.0 * t)])
    assert taken_by_wrapper(fast) >= steps - 1, taken_by_wrapper(fast)


@pytest.mark.parametrize("motor", ["linear", "harmonic"])
@pytest.mark.parametrize("method", ["dop853p", "rk45p"])
def test_an_embedded_pairs_dense_reads_and_runs_follow_the_drivers_motion(
        scene_host, tmp_path, method, motor):
    """P4's slider-crank (its motor at 314.16 rad/s, or on a harmonic motion of 0.3 rad at
    40 Hz) with no inputs: Python reads the pair's dense output at each 1 ms point and
    steps past it. The wrapper now does both with the driver's motion at the point read,
    at every stage's time and at DOP853's extra nodes (motions.h): every value is Python's
    bit for bit and every doStep but the first is the wrapper's. Before, every doStep of a
    scene with drivers under an embedded pair went through Python."""
    text = (SCENES / "slider_crank.toml").read_text()
    linear = 'motion = { type = "linear", start = 0.0, rate = 314.1592653589793 }'
    assert linear in text
    if motor == "harmonic":
        text = text.replace(linear, 'motion = { type = "harmonic", offset = 0.0, '
                            'amplitude = 0.3, frequency = 40.0 }')
    scene = tmp_path / f"slider_crank_{motor}.toml"
    scene.write_text(text)
    path = build_fmu(scene, tmp_path / f"{motor}.fmu")
    steps = 400
    fast, _, served = _lockstep(scene_host, path, method, steps, [], lambda t: [])
    assert taken_by_wrapper(fast) >= steps - 1, taken_by_wrapper(fast)
    if motor == "linear":     # P4's torque from the power balance, to the stated accuracy
        exact = p4_torque(W * H * np.arange(1, steps + 1), W)
        effort = served[:, fast.outputs.index("motor.effort")]
        assert np.abs(effort - exact).max() < 1e-4 * np.abs(exact).max()


# slider_stop's slider carrying an arm on a driven shoulder (0.5 kg, its centre 0.2 m below
# the shoulder at the start), pushed with 10 N: the slider comes to rest on its end stop,
# and the arm's swing pulls it off twice a period (its force on the slider peaks above
# the push), when the stop's force, which follows the driver's acceleration, falls to zero
ARM = """
[[body]]
name = "arm"
mass = 0.5
inertia = 0.01
position = [0.5, -0.2]
angle = -1.5707963267948966

[[joint]]
name = "shoulder"
type = "revolute"
body_i = "slider"
point_i = [0.0, 0.0]
body_j = "arm"
point_j = [-0.2, 0.0]

[[driver]]
name = "swing"
joint = "shoulder"
"""
SWING = 'motion = { type = "harmonic", offset = -1.5707963267948966, amplitude = 0.8, ' \
        'frequency = 2.0 }\n'


def swing_angle(t: float) -> float:
    return -0.5 * math.pi + 0.8 * math.sin(4.0 * math.pi * t)


@pytest.mark.parametrize("swing", ["scene", "input"])
@pytest.mark.parametrize("method", [None, "rk45p", "rk4p"])
def test_a_driven_arm_on_a_slider_with_an_end_stop_keeps_the_steps_in_the_wrapper(
        scene_host, tmp_path, method, swing):
    """slider_stop's slider with a driven arm on it, its swing from the scene (harmonic) or
    set by the master before every step: with dop853p (the scene's auto), rk45p and rk4p
    the wrapper's steps follow the driver's motion in the contact mode's equations and
    watch the stop's event functions; every value and event is Python's, and only the
    doSteps with an event (with a pair, and a few the event runner's horizon shortens
    before it) are Python's.
    Before, every doStep of a driven scene with end stops or friction went through
    Python."""
    push = "value = [-2.0, 0.0]"
    assert push in (SCENES / "slider_stop.toml").read_text()
    # 10 N: the slider rests on its stop and the swing pulls it off (with the angle set
    # every step, a release at a set whose return comes within the step: test_stop_return)
    text = (SCENES / "slider_stop.toml").read_text().replace(
        push, "value = [-10.0, 0.0]") + ARM + (
        SWING if swing == "scene" else 'motion = { type = "input", '
        'initial = -1.5707963267948966 }\n')
    scene = tmp_path / f"arm_{swing}.toml"
    scene.write_text(text)
    path = build_fmu(scene, tmp_path / f"arm_{swing}.fmu")
    steps = 3000
    hosts = []
    for name in ("fast", "slow"):
        host = scene_host(path, name)
        if method is not None:
            assert host.fmu.setString([host.vr["solver.method"]], [method]) is None
        hosts.append(host.init())
    fast, slow = hosts
    inputs = [] if swing == "scene" else ["swing.position", "swing.velocity",
                                          "swing.acceleration"]

    def values_at(t):
        w = 4.0 * math.pi
        return [swing_angle(t), 0.8 * w * math.cos(w * t), -0.8 * w * w * math.sin(w * t)]
    vrs = (ctypes.c_uint * max(len(inputs), 1))(*(fast.vr[n] for n in inputs))
    names = fast.outputs
    for k in range(steps):
        values = (ctypes.c_double * 3)(*values_at(k * H))
        for host in (fast, slow):
            assert not inputs or host.status("fmi2SetReal", vrs, 3, values) == OK
            assert host.step(H) == OK, host.messages[-3:]
        assert fast.real(*names) == slow.real(*names), k
        assert slow.status("fmi2SetDebugLogging", True, 0, None) == OK
    assert fast.status("fmi2SetDebugLogging", True, 0, None) == OK
    logged = [[m for _, _, m in h.messages if m.startswith("t = ") and "joint" in m]
              for h in (fast, slow)]
    assert logged[0] == logged[1], logged[0][:3]
    assert sum("rests against" in m for m in logged[0]) >= 1
    assert sum("leaves its lower stop" in m for m in logged[0]) >= 3
    # Python's: the doStep of each event, and with a pair a few before it, whose steps the
    # event runner's horizon shortens (as without drivers: test_fmu_dense_run.py)
    per_event = 1 if method == "rk4p" else 5
    assert taken_by_wrapper(fast) >= steps - 1 - per_event * len(logged[0]), (
        taken_by_wrapper(fast), len(logged[0]))
