"""rk4p's communication steps in the FMU's C wrapper (ckernel/fixed.h) for scenes with end
stops and friction (the contact mode's event functions watched after each step in C,
ckernel/events.h) and for scenes with an energy audit (its check after each step in C,
its state carried back to Python). References: the same FMU sent through Python at every
doStep (fmi2SetDebugLogging after each), the closed-form impact times of the slider
(event_checks.py) and a Simulation stepped by Python alone; never the C run's own output."""

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
from event_checks import SLIDER_T1, slider_impacts  # noqa: E402
from fmu_models.harness import OK  # noqa: E402
from fmu_models.scenes import scene_fmu, scene_host  # noqa: E402,F401
from test_fmu_dense_run import lockstep, taken_by_wrapper  # noqa: E402

pytestmark = pytest.mark.skipif(not ckernel.available(), reason="no C compiler for the kernel")
SCENES = Path(__file__).resolve().parents[1] / "scenes"


def rk4p_host(scene_host, path, name):
    host = scene_host(path, name)
    assert host.fmu.setString([host.vr["solver.method"]], ["rk4p"]) is None
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
    fast, slow = rk4p_host(scene_host, path, "fast"), rk4p_host(scene_host, path, "slow")
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
