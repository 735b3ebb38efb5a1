"""genalpha and ali3p in the C kernel with the whole iteration matrix factorised by a
dense LU (ckernel/implicit_dense.h): translational and slot joints (line rows, whose
geometric stiffness couples a body's coordinates and two bodies' angles) and forces of the
state between two moving bodies, which the banded Schur complement does not take.

As in test_implicit_c.py, the C step is meant to be the Python step with another linear
solver: the two agree to a small fraction of the method's error (against closed forms:
P4's kinematics, P11's reduction, the rigid pendulum; or a tight DOP853 reference), and a
saved state continues bit for bit (test_implicit_c.py).
"""
import math
from pathlib import Path

import numpy as np
import pytest

import mbdfmu
from mbdfmu.bench import closed_forms
from mbdfmu.equations import ckernel
from mbdfmu.integrators import implicit_c
from mbdfmu.errors import InputError
from mbdfmu.model.reader import bundled_scene, scene_from_dict
from mbdfmu.model.toml_table import load_toml
from test_implicit_c import spring_pendulum

pytestmark = pytest.mark.skipif(not ckernel.available(), reason="no C compiler for the kernel")
METHODS = ("genalpha", "ali3p")
CRANE = Path(__file__).resolve().parents[1] / "scenarios" / "hydraulic_crane" / "crane.toml"
HOLD = 8420.0          # N: about the cylinder force that holds the crane's boom (fmu_speed.py)


def both(monkeypatch, scene, t_end, method, **settings):
    """The run with the C steps and with the Python steps, and the C run's KernelNewton."""
    out = {}
    for compiled in (True, False):
        monkeypatch.setattr(implicit_c, "ENABLED", compiled)
        sim = mbdfmu.Simulation(scene, method=method, kernel="c", step=settings.get("step"))
        assert (sim.integrator.c_newton is not None) == compiled
        if compiled:
            newton = sim.integrator.c_newton
        out[compiled] = mbdfmu.simulate(scene, t_end, method=method, kernel="c", **settings)
    return out[True], out[False], newton


def free_slider_crank():
    """P4 without its motor, turning at a tenth of its speed, with a spring (200 N/m,
    0.5 N s/m) from the crank pin to the slider: line rows and a two-body force together."""
    data = load_toml(bundled_scene("slider_crank"), InputError)
    del data["driver"]
    for body in data["body"]:
        body["velocity"] = [0.1 * v for v in body.get("velocity", [0.0, 0.0])]
        body["angular_velocity"] = 0.1 * body.get("angular_velocity", 0.0)
    data["force"].append({"name": "spring", "type": "spring_damper", "body_i": "crank",
                          "point_i": [0.05, 0.0], "body_j": "slider", "point_j": [0.0, 0.0],
                          "stiffness": 200.0, "damping": 0.5, "rest_length": 0.3})
    return scene_from_dict(data)


@pytest.mark.parametrize("method", METHODS)
def test_driven_slider_crank_holds_its_closed_form_kinematics(method, monkeypatch):
    """P4 (driven at 3000 rpm): positions from the constraints to rounding, the motor's
    torque as DOP853 at rtol 1e-12 gives it, C and Python steps alike."""
    scene = mbdfmu.load_scene("slider_crank")
    c, py, newton = both(monkeypatch, scene, 0.05, method, step=1e-3, output_interval=0.005)
    assert newton.dense
    ref = mbdfmu.simulate(scene, 0.05, method="dop853p", rtol=1e-12, atol=1e-14, kernel="c",
                          output_interval=0.005)
    exact = closed_forms.slider_crank(314.1592653589793 * c.time, r=0.1, l=0.3)
    for res in (c, py):
        assert np.max(np.abs(res["slider.x"] - exact["xB"])) < 1e-12     # measured 1e-16
        assert np.max(np.abs(res["motor.effort"] - ref["motor.effort"])) < 1e-9   # 2e-12


@pytest.mark.parametrize("method", METHODS)
def test_free_slider_crank_with_a_spring_agrees_with_the_python_step(method, monkeypatch):
    scene = free_slider_crank()
    ref = mbdfmu.simulate(scene, 0.3, method="dop853p", rtol=1e-12, atol=1e-14, kernel="c",
                          output_interval=0.01)
    c, py, newton = both(monkeypatch, scene, 0.3, method, step=1e-3, output_interval=0.01,
                         rtol=0.1, atol=0.1)
    assert newton.dense and newton.settings.fd == 1
    error = max(float(np.max(np.abs(c[n] - ref[n]))) for n in ("crank.phi", "slider.x"))
    difference = max(float(np.max(np.abs(c[n] - py[n]))) for n in ("crank.phi", "slider.x"))
    assert error < 0.01                       # measured 3e-3 (genalpha), 2e-3 (ali3p)
    assert difference <= 1e-6 * error, (difference, error)     # measured 3e-13, 5e-13


@pytest.mark.parametrize("method", METHODS)
def test_slot_rod_converges_at_order_two_in_c(method, monkeypatch):
    """P11 (a rod hanging from a pin in a horizontal slot) against its reduction."""
    errors = []
    for h in (4e-3, 2e-3, 1e-3):
        c, py, newton = both(monkeypatch, mbdfmu.load_scene("slot_rod"), 1.0, method, step=h, output_interval=0.02)
        assert newton.dense
        exact = closed_forms.rod_in_slot(c.time)["phi"]
        errors.append(float(np.max(np.abs(c["rod.phi"] - exact))))
        difference = float(np.max(np.abs(c["rod.phi"] - py["rod.phi"])))
        # measured 1e-7 of the error; 2.2e-6 at 1 ms since the grid's step is the
        # method's own between output points (newton.ImplicitMethod.fixed_grid): rounding
        assert difference <= 1e-5 * errors[-1], (h, difference, errors[-1])
    ratios = [errors[0] / errors[1], errors[1] / errors[2]]
    assert all(3.8 < r < 4.2 for r in ratios), (errors, ratios)      # measured 3.99


@pytest.mark.parametrize("method", METHODS)
def test_crane_mechanism_agrees_with_the_python_step(method, monkeypatch):
    """The hydraulic crane's mechanism with its cylinder force held near HOLD: the
    difference of the C and Python steps far inside the method's error (its change from h
    to h / 2)."""
    runs = {}
    force = {"cylinder": lambda t: HOLD * (1.0 + 0.05 * math.sin(2.0 * math.pi * t))}
    for h, compiled in ((2e-3, True), (2e-3, False), (1e-3, True)):
        monkeypatch.setattr(implicit_c, "ENABLED", compiled)
        res = mbdfmu.simulate(CRANE, 0.5, method=method, step=h, kernel="c", rtol=1e-6,
                              atol=1e-8, output_interval=0.01, inputs=force)
        runs[h, compiled] = np.stack([res["boom.phi"], res["load.phi"]])
    error = float(np.max(np.abs(runs[2e-3, True] - runs[1e-3, True])))
    difference = float(np.max(np.abs(runs[2e-3, True] - runs[2e-3, False])))
    assert difference <= 1e-6 * error, (difference, error)   # measured 2e-14 against 2.3e-7


def test_a_stiff_spring_between_two_bodies_under_auto_in_c(monkeypatch):
    """A 1e10 N/m spring hung from a pinned body: auto's genalpha with step control, its
    attempts and error filter through the dense LU, against the rigid pendulum."""
    scene = spring_pendulum(1e10, between_bodies=True)
    results = {}
    for compiled in (True, False):
        monkeypatch.setattr(implicit_c, "ENABLED", compiled)
        sim = mbdfmu.Simulation(scene, method="auto")
        sim.advance(1e-3)
        assert (sim.integrator.current.c_newton is not None) == compiled
        if compiled:
            assert sim.integrator.current.c_newton.dense
        results[compiled] = mbdfmu.simulate(scene, 0.2, method="auto", output_interval=0.01)
    res = results[True]
    assert res.method == "auto->genalpha"
    exact = closed_forms.pendulum(res.time, J=1e-6)
    error = float(np.max(np.hypot(res["bob.x"] - exact["x"], res["bob.y"] - exact["y"])))
    assert error < 1e-6, error          # the default tolerance: 1e-6 m
    assert res.stats["nsteps"] == results[False].stats["nsteps"]
    assert float(np.max(np.abs(res["bob.x"] - results[False]["bob.x"]))) <= 1e-3 * error



def bead_on_arm():
    """A pendulum arm with a bead in a slot along it (a line row between two moving bodies,
    off both centres, so every term of its geometric stiffness is there) and a spring from
    the arm's tip to the bead."""
    return scene_from_dict({
        "name": "bead", "gravity": [0.0, -9.81],
        "body": [{"name": "arm", "mass": 2.0, "inertia": 0.2, "position": [0.5, 0.0],
                  "angular_velocity": 1.0, "velocity": [0.0, 0.5]},
                 {"name": "bead", "mass": 0.5, "inertia": 0.01, "position": [0.8, -0.1]}],
        "joint": [{"name": "pivot", "type": "revolute", "body_i": "ground",
                   "point_i": [0.0, 0.0], "body_j": "arm", "point_j": [-0.5, 0.0]},
                  {"name": "slot", "type": "slot", "body_i": "arm", "point_i": [0.0, 0.0],
                   "axis_i": [1.0, 0.0], "body_j": "bead", "point_j": [0.0, 0.1]}],
        "force": [{"name": "spring", "type": "spring_damper", "body_i": "arm",
                   "point_i": [0.5, 0.0], "body_j": "bead", "point_j": [0.0, 0.0],
                   "stiffness": 500.0, "damping": 2.0, "rest_length": 0.1}]})


def python_matrix(it, h):
    """The Python step's iteration matrix at its predictor (genalpha.py, ali3p.py)."""
    t1 = it.t + h
    if it.name == "genalpha":
        am, af, beta, gamma = it.coefficients
        D = h * h * beta * (1.0 - af) / (1.0 - am)
        G = h * gamma * (1.0 - af) / (1.0 - am)
        a = (af * it.qdd - am * it.a + (1.0 - af) * it.qdd) / (1.0 - am)
        q = it.qw + h * it.qd + h * h * ((0.5 - beta) * it.a + beta * a)
        qd = it.qd + h * ((1.0 - gamma) * it.a + gamma * a)
        _, J = it.constraints(t1, q)
        return it._iteration_matrix(t1, q, qd, J, it.lam, D, G)
    dq = h * it.qd + 0.5 * h * h * it.qdd
    _, J = it.constraints(t1, it.qw + dq)
    return it._augmented_matrix(t1, it.qw + dq, (2.0 / h) * dq - it.qd, J, it.lam, h,
                                0.25 * h * h * it.alpha(h))


@pytest.mark.parametrize("method", METHODS)
def test_the_dense_matrix_is_the_python_steps(method):
    """The matrix the kernel factorises at the predictor (one iteration: factorised there)
    against the Python step's matrix there, through their solves; at h = 10 ms the line
    row's geometric stiffness and the spring's Jacobian change it by percents."""
    h = 0.01
    sim = mbdfmu.Simulation(bead_on_arm(), method=method, step=h, kernel="c", rtol=0.1, atol=0.1)
    it = sim.integrator
    newton = it.c_newton
    assert newton.dense and newton.settings.fd == 1
    p = newton.prepare(it)
    p.max_iter = 1
    u = it.inputs(it.t + h)
    newton.kernel.implicit_attempt(p, it.matrix.kept, implicit_c.step_state(it), h,
                                   it.equations.motion_values(it.t + h, u), u.forces)
    S = python_matrix(it, h)
    b = np.random.default_rng(1).standard_normal(S.shape[0])
    want = np.linalg.solve(S, b)
    got = newton.kernel.implicit_solve(p, it.matrix.kept, b)
    assert np.max(np.abs(got - want)) <= 1e-9 * np.max(np.abs(want))      # measured 2e-17
    n = it.equations.n
    bare = S.copy()
    bare[:n, :n] = np.diag(it.equations.mass)
    assert np.max(np.abs(np.linalg.solve(bare, b) - want)) > 1e-3 * np.max(np.abs(want))  # 7e-3
