"""A force input set before every communication step, as a co-simulation master sets the
crane's cylinder force: an embedded pair or rk4p restarts from its state without
re-projecting it (``Simulation._reinitialize``; the FMU wrapper's ``ckernel/adaptive.h`` and
``fixed.h`` likewise, held bit for bit to Python by tests/test_fmu_fast.py). Checked here against the crane's two-degree-of-
freedom equations of motion written out independently (a boom on a ground pivot, a pendulum
load at its tip) and integrated by scipy with the same piecewise-constant force."""

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
