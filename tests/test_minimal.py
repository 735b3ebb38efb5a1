"""The minimal-coordinate method (``integrators/minimal.py``) against closed forms: P1's
elliptic solution, P2 N = 2's exact one-degree-of-freedom reduction, P4's slider-crank
kinematics and motor torque; and its partition re-chosen where the chosen coordinate stops
determining the others."""

from __future__ import annotations

import numpy as np
import pytest

import exact_solutions as ref

mbdfmu = pytest.importorskip("mbdfmu")
from mbdfmu.integrators import METHODS  # noqa: E402
from mbdfmu.integrators.minimal import MinimalCoordinates, _block_conditioning  # noqa: E402

from test_integrators import SC, W, b0, run, scene, wrap  # noqa: E402

KERNELS = ["c", "numpy"]


def test_minimal_is_registered_like_the_other_methods():
    assert METHODS["minimal"] is MinimalCoordinates and MinimalCoordinates.adaptive


@pytest.mark.parametrize("kernel", KERNELS)
def test_p1_minimal_against_the_elliptic_solution(kernel, monkeypatch):
    monkeypatch.setenv("MBDFMU_KERNEL", kernel)
    res = run("pendulum", 3.0, method="minimal", rtol=1e-10, atol=1e-12, output_interval=0.05)
    ex = ref.simple_pendulum(res.time, J=1e-6)
    np.testing.assert_allclose(res["bob.x"], ex["x"], atol=1e-8)
    np.testing.assert_allclose(res["bob.y"], ex["y"], atol=1e-8)
    # the dependent coordinates are solved at every stage: the constraint holds throughout
    assert np.max(res["constraint.position_error"]) < 1e-10


@pytest.mark.parametrize("kernel", KERNELS)
def test_p2_minimal_follows_the_exact_reduction_through_the_crossings(kernel, monkeypatch):
    monkeypatch.setenv("MBDFMU_KERNEL", kernel)
    # rtol 1e-9: at 1e-10 (rtol/100 per step) the numpy kernel stops at the second
    # crossing, its energy balance broken by the dependent solves' round-off there
    res = run("n_four_bar_2", 4.0, method="minimal", rtol=1e-9, atol=1e-11, output_interval=0.1)
    ex = ref.n_four_bar(res.time, 2)
    x, y = b0(res)
    # measured 3.1e-8 (kernel c, 45 steps) and 5.2e-10 (numpy, 76 steps) through the crossings
    np.testing.assert_allclose(x, ex["B0_x"], atol=1e-7)
    np.testing.assert_allclose(y, ex["B0_y"], atol=1e-7)


@pytest.mark.parametrize("kernel", KERNELS)
def test_p4_minimal_slider_crank_kinematics_and_torque(kernel, monkeypatch):
    # no degrees of freedom: every coordinate is dependent, the solves give the motion
    monkeypatch.setenv("MBDFMU_KERNEL", kernel)
    res = run("slider_crank", 0.02, method="minimal", rtol=1e-8, atol=1e-10,
              output_interval=5e-4)
    ex = ref.slider_crank(W * res.time, W, **SC)
    np.testing.assert_allclose(wrap(res["rod.phi"] - ex["phi"]), 0, atol=1e-10)
    np.testing.assert_allclose(res["slider.x"], ex["xB"], atol=4e-11)
    np.testing.assert_allclose(res["slider.vx"], ex["xB_d"], atol=1e-10 * np.abs(ex["xB_d"]).max())
    np.testing.assert_allclose(res["motor.effort"], ex["torque"],
                               atol=1e-9 * np.abs(ex["torque"]).max())


@pytest.mark.parametrize("kernel", KERNELS)
def test_p2_minimal_at_1_ms_communication_steps_stays_on_its_branch(kernel, monkeypatch):
    """Stepped through Simulation.advance at 1 ms (an FMU's master): outputs come from the
    dense output, so the steps do not land next to the singular configuration at 0.79 s;
    landing there once put the run on the other branch (2 m off, energy conserved, success
    claimed). The same numbers as at 10 ms steps, within 100 rtol of the exact reduction."""
    monkeypatch.setenv("MBDFMU_KERNEL", kernel)
    ends = []
    for h in (1e-3, 1e-2):
        sim = mbdfmu.Simulation(scene("n_four_bar_2"), method="minimal")
        for k in range(round(1.5 / h)):
            sim.advance((k + 1) * h)
        phi = sim.outputs()["crank0.phi"]
        ends.append((sim.outputs()["crank0.x"] + 0.5 * np.cos(phi),
                     sim.outputs()["crank0.y"] + 0.5 * np.sin(phi)))
    ex = ref.n_four_bar(np.array([1.5]), 2)
    np.testing.assert_allclose(ends[0], ends[1], rtol=0, atol=1e-12)
    np.testing.assert_allclose(ends[0], (ex["B0_x"][0], ex["B0_y"][0]), atol=100 * 1e-6)


@pytest.mark.parametrize("kernel", KERNELS)
def test_minimal_rechooses_a_coordinate_that_stops_determining_the_others(kernel, monkeypatch):
    # P1 released horizontally with bob.y forced as the independent coordinate: at the
    # bottom dy/dtheta = 0 and y no longer tells on which side the bob is, so the run is
    # right only if the partition is chosen again before the bottom
    monkeypatch.setenv("MBDFMU_KERNEL", kernel)
    sim = mbdfmu.Simulation(scene("pendulum"), method="minimal", rtol=1e-10, atol=1e-12)
    integrator = sim.integrator
    forced = np.zeros(integrator.q.size, dtype=bool)
    forced[1] = True                                     # bob.y
    _, J = integrator.constraints(integrator.t, integrator.q)
    integrator.independent = forced
    integrator.chosen_conditioning = _block_conditioning(J, forced)
    period = ref.simple_pendulum([0.0], J=1e-6)["period"]
    times = np.linspace(0.0, 0.5 * period, 21)[1:]       # through the bottom to the far side
    xs = []
    for t in times:
        sim.advance(t)
        xs.append(sim.q[0])
    assert not integrator.independent[1]                 # re-chosen
    np.testing.assert_allclose(xs, ref.simple_pendulum(times, J=1e-6)["x"], atol=1e-7)
