"""The FMU's steps past the solver's step its wrapper reads (ckernel/dense_run.h): the
wrapper takes dop853p's next steps, builds their interpolant and reads it, without Python,
and every value it serves is the one Python computes when the same doSteps go through it
(fmi2SetDebugLogging after each step sends the next one there). References: the slow
instance (Python's step loop and interpolant) and scipy's DOP853 interpolant formula in
numpy (dense_output.dop853_interpolant), never the C run's own output."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parent))

import mbdfmu  # noqa: E402
from mbdfmu.equations import ckernel  # noqa: E402
from mbdfmu.integrators import dense_output  # noqa: E402
from mbdfmu.integrators.tableaux import DOP853_D  # noqa: E402
from fmu_models.harness import DISCARD, OK, get_state  # noqa: E402
from fmu_models.scenes import scene_fmu, scene_host  # noqa: E402,F401

pytestmark = pytest.mark.skipif(not ckernel.available(), reason="no C compiler for the kernel")
H = 1e-3
# A conservative mechanism with every force the kernel's energy audit sums: a spring, a
# rotational spring, a constant torque and a constant force off the centre of mass.
KITCHEN = mbdfmu.model.scene_from_dict({
    "name": "ConservativeKitchen", "gravity": [0.0, -9.81],
    "body": [{"name": "crank", "mass": 1.0, "inertia": 0.1, "position": [0.5, 0.0]},
             {"name": "bob", "mass": 0.5, "inertia": 0.02, "position": [1.5, 0.0]}],
    "joint": [{"name": "pin", "type": "revolute", "body_i": "ground", "body_j": "crank",
               "point_j": [-0.5, 0.0]},
              {"name": "hinge", "type": "revolute", "body_i": "crank", "point_i": [0.5, 0.0],
               "body_j": "bob", "point_j": [-0.5, 0.0]}],
    "force": [{"name": "spring", "type": "spring_damper", "body_i": "ground",
               "point_i": [0.0, 1.0], "body_j": "bob", "point_j": [0.5, 0.0],
               "stiffness": 300.0, "damping": 0.0, "rest_length": 1.0},
              {"name": "tors", "type": "rotational_spring_damper", "joint": "hinge",
               "stiffness": 4.0, "damping": 0.0, "rest_angle": 0.2},
              {"name": "twist", "type": "torque", "body": "crank", "value": 1.5},
              {"name": "push", "type": "force", "body": "bob", "point": [0.2, 0.05],
               "value": [2.0, -1.0]}]}, source="kitchen")


def taken_by_wrapper(h) -> int:
    return sum(int(m.split(": ")[1].split()[0]) for _, _, m in h.messages
               if "taken by the wrapper" in m)


def lockstep(fast, slow, steps: int, compare: bool = True, catch_up_at=()) -> None:
    """``steps`` 1 ms doSteps of both instances, ``slow`` sent through Python for the next
    one after each (fmi2SetDebugLogging), their outputs the same bit for bit after each;
    ``fast`` made to catch up after the steps numbered in ``catch_up_at``."""
    names = fast.outputs
    for k in range(steps):
        assert fast.step(H) == OK and slow.step(H) == OK, (fast.messages[-3:],
                                                           slow.messages[-3:])
        if compare:
            assert fast.real(*names) == slow.real(*names), k
        assert slow.status("fmi2SetDebugLogging", True, 0, None) == OK
        if k in catch_up_at:
            assert fast.status("fmi2SetDebugLogging", True, 0, None) == OK


def test_steps_past_the_solvers_step_are_the_wrappers_and_pythons_values(scene_fmu,
                                                                          scene_host):
    """P2 N = 2 (auto -> dop853p, energy audit on) over 1.2 s at 1 ms, through the cranks'
    first horizontal crossing (t = 0.79 s): bit for bit Python's values at every doStep,
    and Python entered for none but the first and those a catch-up sends there (before,
    at the end of every solver step: about one doStep in 80)."""
    path = scene_fmu("n_four_bar_2")
    fast, slow = scene_host(path, "fast").init(), scene_host(path, "slow").init()
    names = fast.outputs
    # at 400 and 800 Python catches up, takes the state over and arms the wrapper again
    lockstep(fast, slow, 1200, catch_up_at=(400, 800))
    assert fast.status("fmi2SetDebugLogging", True, 0, None) == OK    # the slave catches up
    # Python took the first doStep and the one after each catch-up only, the crossing too
    assert taken_by_wrapper(fast) == 1197, taken_by_wrapper(fast)
    assert fast.real(*names) == slow.real(*names)


def test_redundant_constraints_stay_in_the_wrapper(scene_fmu, scene_host):
    """The parallelogram (a redundant row: S singular at every state): eq. 14 in its
    null-space form, the projections' and the error estimate's minimum-norm solves, all in
    C, so the wrapper takes its doSteps (every one went through Python before), bit for
    bit Python's values."""
    path = scene_fmu("parallelogram")
    fast, slow = scene_host(path, "fast").init(), scene_host(path, "slow").init()
    lockstep(fast, slow, 200)
    assert fast.status("fmi2SetDebugLogging", True, 0, None) == OK
    assert taken_by_wrapper(fast) == 199, taken_by_wrapper(fast)


def test_held_force_inputs_ride_along_bit_for_bit(tmp_path, scene_host):
    """The crane's mechanism (dop853p, its cylinder force an input) with the force set once
    and then held: the wrapper's runs carry the held force into every stage and extra
    stage, as Python's steps do, and take almost every doStep."""
    from mbdfmu.fmu_build.scene_fmu import build_fmu
    root = Path(__file__).resolve().parents[1]
    path = build_fmu(root / "scenarios" / "hydraulic_crane" / "crane.toml", tmp_path / "c.fmu")
    fast, slow = scene_host(path, "fast").init(), scene_host(path, "slow").init()
    for h in (fast, slow):
        assert h.set_real([h.vr["cylinder.actuator"]], [8000.0]) == OK
    lockstep(fast, slow, 600)
    assert fast.status("fmi2SetDebugLogging", True, 0, None) == OK
    assert taken_by_wrapper(fast) >= 599, taken_by_wrapper(fast)


def test_a_restored_state_goes_on_with_the_wrappers_steps_bit_for_bit(scene_fmu, scene_host):
    """A state saved between the wrapper's runs (Python catches up, then the wrapper is
    armed again) and restored repeats the same values."""
    h = scene_host(scene_fmu("n_four_bar_2"), "saved").init()
    names = h.outputs
    for _ in range(150):
        assert h.step(H) == OK
    state, t0 = get_state(h), h.t

    def run():
        return [h.real(*names) for _ in range(300) if h.step(H) == OK]
    first = run()
    assert h.status("fmi2SetFMUstate", state) == OK
    h.t = t0
    assert run() == first and len(first) == 300


def test_a_run_the_wrapper_cannot_finish_is_pythons_unchanged(scene_fmu, scene_host):
    """A doStep needing more solver steps than solver.max_steps_per_communication_step
    allows: the wrapper's run puts everything back and Python discards the step, saying
    why; the FMU stays where it was and goes on with the slow instance's values."""
    path = scene_fmu("n_four_bar_2")
    fast, slow = scene_host(path, "fast"), scene_host(path, "slow")
    for h in (fast, slow):
        assert h.set_int("solver.max_steps_per_communication_step", 2) == OK
        h.init()
    lockstep(fast, slow, 50, compare=False)
    discards(fast, 0.5, "solver.max_steps_per_communication_step")
    lockstep(fast, slow, 200)


def discards(h, step: float, setting: str) -> None:
    """A doStep of ``step`` s is discarded, the message naming ``setting``, with every output
    as it was."""
    before = h.real(*h.outputs)
    assert h.status("fmi2DoStep", h.t, step, 1) == DISCARD
    assert setting in h.messages[-1][2]
    assert h.real(*h.outputs) == before


def test_the_c_interpolant_is_scipys_dop853_formula():
    """DOP853's interpolant as the kernel builds it (mbd_dop853_dense, which the FMU's
    wrapper and Python's reads share) against dense_output.dop853_interpolant, scipy's
    formula in numpy, with the same evaluations of eq. 14, at the steps of a P2 run: equal
    to round-off, and the interpolant meets both ends of its step."""
    sim = mbdfmu.Simulation("n_four_bar_2", kernel="c", method="dop853p", rtol=1e-8,
                            atol=1e-10)
    rk = sim.integrator
    for k in range(40):
        sim.advance(0.05 * (k + 1))
        step = rk.dense
        F = rk._interpolant(step)

        def rhs(t, y):
            qdd, _ = sim.equations.accelerations(t, y[:15], y[15:])
            return np.concatenate((y[15:], qdd))
        reference = dense_output.dop853_interpolant(step, rhs)
        # each row is h times sums of stages, weighted up to DOP853_D's (cancelling) ones
        scale = step.h * np.abs(step.K).max() * np.abs(DOP853_D).sum(axis=1).max()
        np.testing.assert_allclose(F, reference, rtol=0, atol=1e-14 * scale)
        step.coefficients = F
        np.testing.assert_array_equal(dense_output.dop853_value(step, 0.0), step.y_old)
        np.testing.assert_allclose(dense_output.dop853_value(step, 1.0), step.y_new,
                                   rtol=0, atol=1e-14 * np.abs(step.y_new).max())


def test_the_wrappers_run_checks_the_cpu_limit_and_python_discards(scene_fmu, scene_host):
    """The wrapper's run checks the doStep's CPU limit on the thread's clock, as Python's
    loop does: a long doStep (100 s of P2, thousands of solver steps) under a 10 ms limit
    is given back with everything as it was, and Python discards it, saying why; the FMU
    goes on with Python's values. A long doStep under the default limit is the wrapper's."""
    path = scene_fmu("n_four_bar_2")
    fast, slow = scene_host(path, "fast"), scene_host(path, "slow").init()
    assert fast.set_real([fast.vr["solver.max_cpu_per_communication_step"]], [0.01]) == OK
    fast.init()
    names = fast.outputs
    lockstep(fast, slow, 5, compare=False)
    discards(fast, 100.0, "solver.max_cpu_per_communication_step")
    lockstep(fast, slow, 20)
    assert slow.step(8.0) == OK                                 # default limits
    assert slow.status("fmi2SetDebugLogging", True, 0, None) == OK
    other = scene_host(path, "other").init()
    for _ in range(25):
        assert other.step(H) == OK
    assert other.step(8.0) == OK
    assert other.real(*names) == slow.real(*names)
    assert other.status("fmi2SetDebugLogging", True, 0, None) == OK
    assert taken_by_wrapper(other) == 25      # the first 1 ms doStep was Python's


def test_andrews_squeezer_runs_in_the_wrapper_with_its_springs_energy_audit(scene_fmu,
                                                                           scene_host):
    """Andrews' squeezer (a spring and a constant torque; auto -> dop853p, its energy
    audited): the kernel checks the energy of springs and constant loads too
    (stepping.h total_energy), so the wrapper takes its doSteps, bit for bit Python's; they
    all went through Python before (several ms each)."""
    path = scene_fmu("andrews")
    fast, slow = scene_host(path, "fast").init(), scene_host(path, "slow").init()
    lockstep(fast, slow, 100)
    assert fast.status("fmi2SetDebugLogging", True, 0, None) == OK
    assert taken_by_wrapper(fast) >= 95, taken_by_wrapper(fast)


@pytest.mark.parametrize("name", ["andrews", "kitchen"])
def test_the_kernels_energy_audit_is_the_scenes_energy(name, monkeypatch):
    """A run of steps in C with the energy audited (prk_run) takes every step there, with no
    energy jump for Python to look at, and its audit's last energy is forces.py's total
    energy (kinetic, gravity, springs, rotational springs, constant torques and forces off
    a centre) at the state reached, to round-off."""
    from mbdfmu.integrators.projected_rk import ProjectedRK
    scene = KITCHEN if name == "kitchen" else name
    sim = mbdfmu.Simulation(scene, kernel="c", method="dop853p", rtol=1e-8, atol=1e-10)
    assert sim.integrator.audit is not None and sim.integrator.watch is None

    def python_step(self, h):
        raise AssertionError("the C run handed a step to Python")
    monkeypatch.setattr(ProjectedRK, "_step_impl", python_step)
    sim.advance(0.02)
    rk = sim.integrator
    energy = sim.equations.total_energy(rk.q, rk.qd)
    assert rk.audit.checks > 3
    assert abs(rk.audit.last_energy - energy) <= 1e-12 * max(1.0, rk.audit.magnitude)


def test_the_wrappers_untimed_landing_steps_leave_a_long_dostep_to_python(tmp_path,
                                                                        scene_host):
    """The wrapper's landing steps (the crane, its force set before each doStep) are not
    timed: under the FMU's default CPU limit a doStep needing more attempts than Python
    takes between two checks of it (10 s of the crane, about 150 attempts) is Python's,
    with Python's values; a 1 ms doStep stays the wrapper's."""
    from mbdfmu.fmu_build.scene_fmu import build_fmu
    root = Path(__file__).resolve().parents[1]
    path = build_fmu(root / "scenarios" / "hydraulic_crane" / "crane.toml", tmp_path / "c.fmu")
    fast, slow = scene_host(path, "fast").init(), scene_host(path, "slow").init()
    names = fast.outputs
    for step in (H, H, H, 10.0, H):
        for h in (fast, slow):
            assert h.set_real([h.vr["cylinder.actuator"]], [8000.0 + 100.0 * h.t]) == OK
            assert h.step(step) == OK
        assert fast.real(*names) == slow.real(*names)
        assert slow.status("fmi2SetDebugLogging", True, 0, None) == OK
    assert fast.status("fmi2SetDebugLogging", True, 0, None) == OK
    # the 2nd, 3rd and last; the 1st and the 10 s one are Python's
    assert taken_by_wrapper(fast) == 3


@pytest.mark.parametrize("stem, steps, wrapper", [
    ("slider_stop", 3600, 0.985), ("crane_stop", 2000, 0.989), ("incline_stick", 1000, 0.99),
    ("incline_slide", 1000, 0.99)])
def test_scenes_with_stops_and_friction_read_their_modes_in_the_wrapper(
        scene_fmu, scene_host, stem, steps, wrapper):
    """The end-stop and friction scenes at 1 ms through their events: the slider's and
    the crane's impacts, each coming to rest on its stop, the block sticking, the block
    sliding up, then back down. The wrapper takes the steps, watching the mode's event
    functions after each in C (events.h) within the event runner's horizon, and reads
    their dense output, in each mode: the stop's force and the static friction from the
    held coordinate's driver effort, the sliding friction from the kernel's friction
    iteration. Python takes a doStep whose step changes an event function's sign within
    it, and the events: bit for bit Python's values at every doStep, and at least the
    given share of the doSteps the wrapper's (before the wrapper closed in on a stop
    ahead itself, slider_stop's share was 0.978 and crane_stop's 0.986)."""
    path = scene_fmu(stem)
    fast, slow = scene_host(path, "fast").init(), scene_host(path, "slow").init()
    lockstep(fast, slow, steps)
    assert fast.status("fmi2SetDebugLogging", True, 0, None) == OK
    taken = taken_by_wrapper(fast)
    assert taken >= wrapper * steps, taken
    events = [m for _, _, m in fast.messages if m.startswith("t = ") and "joint" in m]
    assert events, fast.messages[-3:]


def wrapper_do_step(sim, t_end: float) -> np.ndarray:
    """The doStep of ``sim`` to t_end taken by the run as the FMU's wrapper calls it
    (``fast_steps.arm``), ``sim`` caught up after it; the first three outputs it served."""
    import ctypes

    from mbdfmu import fast_steps

    published = (np.arange(3), np.arange(3))
    function, model, run = fast_steps.arm(sim, None, 1e-12, None, published)
    step = ctypes.CFUNCTYPE(ctypes.c_int, ctypes.c_void_p, ctypes.c_void_p, ctypes.c_double,
                            ctypes.c_double, ctypes.c_void_p)(function)
    values = np.zeros(3)
    assert step(model, run, sim.t, t_end - sim.t, values.ctypes.data) == 0
    fast_steps.catch_up(sim, (np.zeros(0, dtype=np.int64), np.zeros(0, dtype=np.int64)))
    return values


def same_runs(python, wrapper, values) -> None:
    assert python.integrator.stats.nsteps == wrapper.integrator.stats.nsteps
    assert python.integrator.stats.naccel == wrapper.integrator.stats.naccel
    assert python.integrator.t == wrapper.integrator.t
    assert python.events.horizon == wrapper.events.horizon
    np.testing.assert_array_equal(wrapper.q, python.q)
    np.testing.assert_array_equal(wrapper.qd, python.qd)
    np.testing.assert_array_equal(values, python.output_vector()[:3])


def test_the_wrappers_dense_run_keeps_the_event_runners_horizon():
    """The event runner's horizon caps every step of the doStep that starts before it, in
    Python (EventRunner.advance) and in the wrapper's dense run (dense_run.h) alike: two
    Simulations of slider_stop, one stepped by Python, one by the run called as the FMU's
    wrapper calls it, end the same doStep on the same steps, bit for bit."""
    scene = mbdfmu.load_scene(Path(__file__).resolve().parents[1] / "scenes" / "slider_stop.toml")
    python, wrapper = (mbdfmu.Simulation(scene, kernel="c") for _ in range(2))
    for sim in (python, wrapper):
        sim.advance(0.2)
    start, h = python.integrator.t, python.integrator.h
    t_end = start + 0.12 * h                        # past the step read at 0.2
    for sim in (python, wrapper):
        sim.events.horizon = start + 0.05 * h
    python.advance(t_end)
    values = wrapper_do_step(wrapper, t_end)
    # steps of at most 0.05 h from the step's end: three of them to pass t_end
    assert python.integrator.t == pytest.approx(start + 0.15 * h, rel=1e-12)
    same_runs(python, wrapper, values)


@pytest.mark.parametrize("stem, start, end", [("slider_stop", 0.436, 0.437),
                                              ("crane_stop", 0.02, 0.22)])
def test_the_wrappers_dense_run_closes_in_on_a_stop_ahead(stem, start, end):
    """A step past the doStep's end that crosses a stop is taken again from its start with
    the horizon 0.9 of the way to where the crossing comes, in Python and in the wrapper's
    run alike (dense_run.h run_within_horizon): slider_stop's doStep from 0.436 s to
    0.437 s, whose step would reach the impact at 1.366 s, and crane_stop's from 0.02 s to
    0.22 s, four steps of which the last reaches the boom's stop, the run putting itself
    back over that step only, end on the same steps with the same horizon, bit for bit.
    Before, the wrapper handed such a doStep to Python, and about every second doStep of
    slider_stop that Python took was one."""
    scene = mbdfmu.load_scene(Path(__file__).resolve().parents[1] / "scenes" / f"{stem}.toml")
    python, wrapper = (mbdfmu.Simulation(scene, kernel="c") for _ in range(2))
    for sim in (python, wrapper):
        sim.advance(start)
        assert sim.events.horizon is None
    python.advance(end)
    values = wrapper_do_step(wrapper, end)
    assert python.events.horizon is not None and python.events.log == []
    same_runs(python, wrapper, values)
