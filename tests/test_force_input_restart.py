"""A force input set before every communication step, as a co-simulation master sets the
crane's cylinder force: an embedded pair or rk4p restarts from its state without
re-projecting it (``Simulation._reinitialize``; the FMU wrapper's ``ckernel/adaptive.h`` and
``fixed.h`` likewise, held bit for bit to Python by tests/test_fmu_fast.py). Checked here against the crane's two-degree-of-
freedom equations of motion written out independently (a boom on a ground pivot, a pendulum
load at its tip) and integrated by scipy with the same piecewise-constant force."""

import ctypes
import math
from pathlib import Path

import numpy as np
import pytest
from scipy.integrate import solve_ivp

mbdfmu = pytest.importorskip("mbdfmu")

ROOT = Path(__file__).resolve().parents[1]
CRANE = ROOT / "scenarios" / "hydraulic_crane" / "crane.toml"
# crane.toml: boom 2 m, 150 kg, J 50 kg m^2 (pivot at the origin, centre 1 m out); load
# 200 kg, J 2 kg m^2, centre 1 m from the hinge at the boom's tip; cylinder from (0.4, -0.6)
# to the boom 0.8 m from the pivot; gravity 9.81 m/s^2 down
M1, J1, M2, J2, G = 150.0, 50.0, 200.0, 2.0, 9.81
BASE, ARM = np.array([0.4, -0.6]), 0.8
PUSH = 8840.0          # N: about 5 % over the force that holds the boom up


def force(k: int) -> float:
    """The force a master sets at the start of communication step k (1 ms steps)."""
    return PUSH * (1.0 + 0.2 * math.sin(0.02 * k))


def crane_rhs(force_n: float):
    """d/dt (th1, th2, th1', th2'): th1 the boom's angle, th2 the load's body angle (its x
    axis from the hinge to its centre), Lagrange's equations of the two bodies."""
    def rhs(t, y):
        a, b, wa, wb = y
        ea, eb = np.array([math.cos(a), math.sin(a)]), np.array([math.cos(b), math.sin(b)])
        na, nb = np.array([-ea[1], ea[0]]), np.array([-eb[1], eb[0]])   # d e / d angle
        # centre velocities: c1' = na wa, c2' = 2 na wa + nb wb
        J1c, J2c = np.column_stack((na, 0 * na)), np.column_stack((2 * na, nb))
        a1c, a2c = -ea * wa**2, -2 * ea * wa**2 - eb * wb**2       # centripetal parts
        M = M1 * J1c.T @ J1c + M2 * J2c.T @ J2c + np.diag([J1, J2])
        g = np.array([0.0, -G])
        rod = ARM * ea - BASE
        Q = J1c.T @ (M1 * (g - a1c)) + J2c.T @ (M2 * (g - a2c))
        Q[0] += force_n * (rod / np.linalg.norm(rod)) @ (ARM * na)   # pushes the ends apart
        return [wa, wb, *np.linalg.solve(M, Q)]
    return rhs


@pytest.mark.parametrize("method", ["dop853p", "rk4p"])
def test_crane_force_set_every_step_follows_its_equations_of_motion(method):
    steps, h = 300, 1e-3
    sim = mbdfmu.Simulation(mbdfmu.load_scene(CRANE), method=method)   # rtol 1e-9
    assert sim.method_name == method
    y = np.array([0.2, -math.pi / 2, 0.0, 0.0])
    for k in range(steps):
        sim.set_input("cylinder.actuator", force(k))
        sim.advance((k + 1) * h)
        y = solve_ivp(crane_rhs(force(k)), (k * h, (k + 1) * h), y, method="DOP853",
                      rtol=1e-13, atol=1e-13).y[:, -1]
    out = sim.outputs()
    tip = 2.0 * np.array([math.cos(y[0]), math.sin(y[0])])
    load = tip + np.array([math.cos(y[1]), math.sin(y[1])])
    assert out["load.y"] - (-0.6026613384098776) > 0.01          # lifted, not held
    assert out["boom.phi"] == pytest.approx(y[0], abs=1e-10)
    assert out["boom.omega"] == pytest.approx(y[2], abs=1e-10)
    assert out["load.phi"] == pytest.approx(y[1], abs=1e-10)
    assert math.hypot(out["load.x"] - load[0], out["load.y"] - load[1]) < 1e-10


def test_the_wrappers_restart_after_a_force_set_is_pythons_whole_evaluation():
    """The FMU wrapper's dop853p doSteps with the force set before each (mbd_prk_set, then
    mbd_prk_fast_step, whose restart solves eq. (14) with Psi_q, gamma and S's factor kept
    from the last step's end) against Python's Simulation.set_input + advance, which
    evaluates all of eq. (14) again: the state, f = (q', q''), the singularity indicator and
    the counters bit for bit after 300 doSteps (a restart's q'' off by 1e-12 relative fails
    here); the indicator is singular.py's (numpy) at the final state to round-off."""
    from mbdfmu import fast_steps
    from mbdfmu.equations import singular

    h, steps, vr = 1e-3, 300, 7
    python, wrapper = (mbdfmu.Simulation(mbdfmu.load_scene(CRANE), method="dop853p",
                                         kernel="c") for _ in "ab")
    for sim in (python, wrapper):            # the slave's first step goes through Python
        sim.set_input("cylinder.actuator", force(0))
        sim.advance(h)
    first = vars(wrapper.integrator.stats).copy()
    for k in range(1, steps):
        python.set_input("cylinder.actuator", force(k))
        python.advance(k * h + h)          # the slave's end: t + h, as the wrapper's
    slot = wrapper.equations.layout.forces["cylinder"].start
    inputs = (np.array([vr]), np.array([slot]))
    none = np.zeros(0, dtype=np.int64)
    step, model, context, setter = fast_steps.arm(wrapper, None, 1e-9, inputs, (none, none))
    call = ctypes.CFUNCTYPE(ctypes.c_int, ctypes.c_void_p, ctypes.c_void_p, ctypes.c_double,
                            ctypes.c_double, ctypes.c_void_p)(step)
    set_real = ctypes.CFUNCTYPE(ctypes.c_int, ctypes.c_void_p, ctypes.c_void_p, ctypes.c_size_t,
                                ctypes.c_void_p, ctypes.c_void_p)(setter)
    values, ref = np.zeros(vr + 1), (ctypes.c_uint * 1)(vr)
    for k in range(1, steps):
        value = np.array([force(k)])
        assert set_real(context, ref, 1, value.ctypes.data, values.ctypes.data) == 0
        assert call(model, context, k * h, h, values.ctypes.data) == 0
    moved, _, _ = fast_steps.catch_up(wrapper, inputs)
    assert moved and wrapper.t == python.t
    a, b = wrapper.integrator, python.integrator
    assert (a.q.tobytes(), a.qd.tobytes(), a.f.tobytes()) == \
        (b.q.tobytes(), b.qd.tobytes(), b.f.tobytes())
    assert a.zone.indicator == b.zone.indicator
    # the same steps and evaluations: neither reads y' at a trial's unprojected end
    # (ProjectedRK.skip_end; the wrapper's, c_steps.fast_prk_run)
    assert vars(a.stats) == vars(b.stats)
    assert a.stats.nsteps + a.stats.nrejected > first["nsteps"] + first["nrejected"]
    numpy_indicator = singular.singularity_indicator(b.constraints(b.t, b.q, sparse=True)[1])
    assert a.zone.indicator == pytest.approx(numpy_indicator, rel=1e-12)


def test_held_force_inputs_take_runs_of_c_steps_with_the_python_loops_values(monkeypatch):
    """The crane's cylinder force held at PUSH, dop853p over 2 s in Python's advance: the
    steps run as one C call (c_steps.prk_run, its force inputs held over the run) and give
    the doubles, counters and outputs of the Python loop of C trials, step for step; a
    force set between advances restarts as before."""
    from mbdfmu.integrators import c_steps
    runs = []
    real = c_steps.prk_run
    monkeypatch.setattr(c_steps, "prk_run", lambda *a, **k: runs.append(1) or real(*a, **k))

    def drive(in_runs: bool):
        monkeypatch.setattr(c_steps, "PRK_RUNS", in_runs)
        sim = mbdfmu.Simulation(CRANE, method="dop853p", kernel="c")
        rows = []
        for k in range(1, 21):
            sim.set_input("cylinder.actuator", force(k))
            sim.advance(0.1 * k)
            rows.append(sim.output_vector())
        return np.array(rows), vars(sim.integrator.stats)
    fast, fast_stats = drive(True)
    assert runs
    runs.clear()
    plain, plain_stats = drive(False)
    assert not runs and fast_stats == plain_stats
    assert np.array_equal(fast, plain)
