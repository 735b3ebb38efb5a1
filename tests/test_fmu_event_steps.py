"""The FMU's C wrapper in scenes with end stops and friction beyond the dense runs
(test_fmu_dense_run.py): rk4p's steps (ckernel/fixed.h), and the steps of every method
after a force input the master sets before each step (fixed.h, adaptive.h), each
watching the contact mode's event functions in C (ckernel/events.h); and rk4p's steps in
scenes with an energy audit (its check in C, its state carried back to Python).
References: the same FMU sent through Python at every doStep (fmi2SetDebugLogging after
each), the closed forms of event_checks.py and a Simulation stepped by Python alone;
never the C run's own output."""

from __future__ import annotations

import ctypes
import sys
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parent))

import mbdfmu  # noqa: E402
from mbdfmu import fast_steps  # noqa: E402
from mbdfmu.equations import ckernel  # noqa: E402
from event_checks import (CRANE_ACTUATOR, CRANE_HOLD, SLIDER_T1, crane_actuator,  # noqa: E402
                          slider_impacts)
from fmu_models.harness import OK  # noqa: E402
from mbdfmu.fmu_build.scene_fmu import build_fmu  # noqa: E402
from fmu_models.scenes import scene_fmu, scene_host  # noqa: E402,F401
from test_fmu_dense_run import lockstep, taken_by_wrapper  # noqa: E402

pytestmark = pytest.mark.skipif(not ckernel.available(), reason="no C compiler for the kernel")
SCENES = Path(__file__).resolve().parents[1] / "scenes"


def method_host(scene_host, path, name, method="rk4p"):
    """An initialized host of the FMU at path with solver.method set (None: the scene's)."""
    host = scene_host(path, name)
    if method is not None:
        assert host.fmu.setString([host.vr["solver.method"]], [method]) is None
    return host.init()


@pytest.mark.parametrize("stem, steps, events", [
    ("slider_stop", 3600, 30), ("crane_stop", 1500, 15), ("incline_stick", 1000, 2),
    ("incline_slide", 1000, 2), ("n_four_bar_2", 1500, 0)])
def test_rk4p_steps_are_the_wrappers_through_events_and_energy_checks(
        scene_fmu, scene_host, stem, steps, events):
    """rk4p at 1 ms through the slider's and the crane's impacts and rests, the block's
    sticking and slipping, and P2 N = 2 under its energy audit: every value the wrapper
    serves is Python's bit for bit, Python takes only the doSteps in which an event
    function changes sign (and the first), and the events are those of the run in Python.
    Before, every doStep of these went through Python (an event watch or an energy audit
    kept rk4p's steps there)."""
    path = scene_fmu(stem)
    fast, slow = method_host(scene_host, path, "fast"), method_host(scene_host, path, "slow")
    lockstep(fast, slow, steps)
    assert fast.status("fmi2SetDebugLogging", True, 0, None) == OK
    logged = [[m for _, _, m in h.messages if m.startswith("t = ") and "joint" in m]
              for h in (fast, slow)]
    assert logged[0] == logged[1] and len(logged[0]) >= events, logged[0][:3]
    # at most one Python doStep per event (an accumulation has several in one), and the first
    assert taken_by_wrapper(fast) >= steps - 1 - len(logged[0]), taken_by_wrapper(fast)


def test_rk4p_wrapper_hands_back_the_impacts_step_with_the_audit_as_it_was():
    """slider_stop with rk4p (energy audit on in flight) stepped by the wrapper's run in
    doSteps of 5 ms, five rk4p steps each: the doStep holding the first impact (t1 =
    (1 + sqrt 3) / 2 s) is handed back with the state, the error estimate and the energy
    audit of its start (its steps before the impact undone), so that Python, taking it,
    finds the same impact at the same time as a Simulation that Python stepped alone."""
    scene = mbdfmu.load_scene(SCENES / "slider_stop.toml")
    python, wrapper = (mbdfmu.Simulation(scene, kernel="c", method="rk4p") for _ in range(2))
    t, h = 1.3, 5e-3
    for sim in (python, wrapper):
        sim.advance(t)
    assert wrapper.integrator.audit is not None
    function, model, run = fast_steps.arm(wrapper, None, 1e-12, None, (np.arange(3),) * 2)
    step = ctypes.CFUNCTYPE(ctypes.c_int, ctypes.c_void_p, ctypes.c_void_p, ctypes.c_double,
                            ctypes.c_double, ctypes.c_void_p)(function)
    values = np.zeros(3)
    while step(model, run, t, h, values.ctypes.data) == 0:
        python.advance(t + h)
        np.testing.assert_array_equal(values, python.output_vector()[:3])
        t += h
    assert t < SLIDER_T1 < t + h
    none = np.zeros(0, dtype=np.int64)
    fast_steps.catch_up(wrapper, (none, none))
    assert wrapper.integrator.t == python.integrator.t == t
    np.testing.assert_array_equal(wrapper.integrator.q, python.integrator.q)
    np.testing.assert_array_equal(wrapper.integrator.f, python.integrator.f)
    assert vars(wrapper.integrator.audit) == vars(python.integrator.audit)
    assert vars(wrapper.integrator.accuracy) == vars(python.integrator.accuracy)
    for sim in (python, wrapper):
        sim.advance(t + h)
    assert wrapper.events.log == python.events.log
    assert wrapper.events.log[0][0] == pytest.approx(slider_impacts(1)[0], abs=1e-9)
    np.testing.assert_array_equal(wrapper.q, python.q)



@pytest.mark.parametrize("method", [None, "rk4p", "rk45p"])
def test_a_force_set_before_every_step_keeps_the_steps_in_the_wrapper_through_events(
        scene_host, tmp_path, method):
    """crane_stop with its cylinder force as an input the master sets before every 1 ms
    step (a hydraulic cylinder with end stops, event_checks.crane_actuator), with the
    scene's method (auto: dop853p), rk4p and rk45p: the boom falls onto its lower stop,
    bounces and rests, the rising force lifts it off at the first step whose force exceeds
    CRANE_HOLD (closed form), and it comes to rest on the upper stop. The wrapper takes the
    sets and the steps, watching the mode's event functions from their values at each
    restart with the new force, and hands back the doSteps that change a sign: the one
    the force lifts the boom at among them. Every value is Python's bit for bit. Before,
    every doStep of this scene went through Python (a set input in a scene with stops)."""
    scene = tmp_path / "crane_force.toml"
    scene.write_text((SCENES / "crane_stop.toml").read_text() + CRANE_ACTUATOR)
    path = build_fmu(scene, tmp_path / "crane_force.fmu")
    fast, slow = (method_host(scene_host, path, name, method) for name in ("fast", "slow"))
    names, vr, steps = fast.outputs, (ctypes.c_uint * 1)(fast.vr["cylinder.actuator"]), 1400
    for k in range(steps):
        for host in (fast, slow):
            value = (ctypes.c_double * 1)(crane_actuator(k))
            assert host.status("fmi2SetReal", vr, 1, value) == OK
            assert host.step(1e-3) == OK, host.messages[-3:]
        assert fast.real(*names) == slow.real(*names), k
        assert slow.status("fmi2SetDebugLogging", True, 0, None) == OK
    assert fast.status("fmi2SetDebugLogging", True, 0, None) == OK
    logged = [[m for _, _, m in h.messages if m.startswith("t = ") and "joint" in m]
              for h in (fast, slow)]
    assert logged[0] == logged[1]
    leave = next(k for k in range(steps) if crane_actuator(k) > CRANE_HOLD)
    left = [float(m.split()[2]) for m in logged[0] if "leaves its lower stop" in m]
    assert left == [pytest.approx(leave * 1e-3, abs=1e-12)]
    assert "rests against it" in logged[0][-1] and "upper stop" in logged[0][-1]
    assert taken_by_wrapper(fast) >= steps - 1 - len(logged[0]), taken_by_wrapper(fast)


@pytest.mark.parametrize("stem, steps, wrapper", [
    ("n_four_bar_2", 1200, 0.99), ("slider_stop", 3600, 0.95), ("incline_slide", 1000, 0.95)])
def test_rk45p_steps_past_the_read_are_the_wrappers(scene_fmu, scene_host, stem, steps, wrapper):
    """rk45p at 1 ms: the wrapper's dense runs take its steps past the step it reads too,
    with Dormand-Prince 5(4)'s interpolant (``mbd_rk45_dense``, which Python's
    RK45P._interpolant calls), through P2's singular crossing and the slider's impacts and
    the block's slip: every value Python's bit for bit. Before, every doStep past an rk45p
    step went through Python."""
    path = scene_fmu(stem)
    fast, slow = (method_host(scene_host, path, name, "rk45p") for name in ("fast", "slow"))
    lockstep(fast, slow, steps)
    assert fast.status("fmi2SetDebugLogging", True, 0, None) == OK
    assert taken_by_wrapper(fast) >= wrapper * steps, taken_by_wrapper(fast)


def test_the_rk45_interpolant_in_c_is_k_transposed_times_p():
    """``mbd_rk45_dense`` against numpy's K^T P (dense_output.rk45_interpolant) on random
    stages: the same to round-off, in the (2n, 4) layout dense.h reads."""
    from mbdfmu.integrators.tableaux import RK45_P
    sim = mbdfmu.Simulation(mbdfmu.load_scene(SCENES / "n_four_bar_2.toml"), kernel="c")
    K = np.random.default_rng(7).normal(size=(RK45_P.shape[0], 2 * sim.equations.n))
    Q = sim.equations.ckernel.rk45_dense(K, RK45_P)
    np.testing.assert_allclose(Q, K.T @ RK45_P, rtol=1e-14, atol=1e-14)
