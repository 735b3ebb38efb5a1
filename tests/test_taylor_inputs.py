"""Force inputs that follow their Taylor polynomial (fmi2SetRealInputDerivatives, a
co-simulation master's extrapolation): the C kernel's steps take the inputs at all of a
step's stage times from one evaluation (``SimulationInputs.forces_at``), the doubles the
input at each time gives, and a run lands on the closed form of the motion."""

from __future__ import annotations

import numpy as np
import pytest

import mbdfmu
from mbdfmu import simulation_inputs
from mbdfmu.equations import ckernel
from mbdfmu.signals import Held, LinearTable, TaylorInput

pytestmark = pytest.mark.skipif(not ckernel.available(), reason="no C compiler for the kernel")


def test_the_inputs_at_a_steps_stage_times_are_those_at_each_time():
    """A Taylor polynomial (orders 0 to 2) and a held value side by side: ``forces_at`` is
    ``inputs_at(t).forces`` at each time, to the bit; a table input leaves it to
    ``inputs_at`` (None)."""
    sim = mbdfmu.Simulation("slider_force", kernel="c")
    sim.set_input("push.fy", 0.25)
    sim.set_input("push.fx", 1.5)
    sim.set_input_derivative("push.fx", 1, -20.0)
    sim.set_input_derivative("push.fx", 2, 300.0)
    assert isinstance(sim._forces["push"], TaylorInput)
    times = 0.1 * np.array([0.0, 1 / 18, 1 / 12, 0.125, 0.3125, 0.375, 0.8, 0.9, 1.0])
    block = sim.forces_at(times)
    assert np.array_equal(block, np.array([sim.inputs_at(t).forces for t in times]))
    fx = 1.5 - 20.0 * times + 150.0 * times ** 2
    np.testing.assert_allclose(block[:, 0], fx, rtol=1e-15, atol=1e-15)
    assert Held(np.array([2.0, 3.0])).at_times(times).shape == (times.size, 2)
    sim.set_input_signal("push", LinearTable([0.0, 1.0], [[0.0, 0.0], [1.0, 1.0]]))
    assert sim.forces_at(times) is None


def test_a_run_with_input_derivatives_takes_its_stage_inputs_at_once_to_the_same_doubles(
        monkeypatch):
    """slider_force (a 2 kg slider, frictionless) pushed by F = 1 + 20 t + 100 t^2 given
    as a value and two derivatives at t = 0, under dop853p on the C kernel: the run with
    the stage inputs taken at once is the run taking them one time at a time, bit for bit,
    and x lands on the closed form (t^2 / 2 + 20 t^3 / 6 + 200 t^4 / 24) / m."""
    def run():
        sim = mbdfmu.Simulation("slider_force", method="dop853p", kernel="c", rtol=1e-10,
                                atol=1e-12)
        sim.set_input("push.fx", 1.0)
        sim.set_input_derivative("push.fx", 1, 20.0)
        sim.set_input_derivative("push.fx", 2, 200.0)
        sim.advance(0.1)
        return sim.output_vector(), sim.outputs()["slider.x"], sim.integrator.stats.nsteps
    fast, x, steps = run()
    with monkeypatch.context() as m:
        m.setattr(simulation_inputs.SimulationInputs, "forces_at", lambda self, times: None)
        plain, _, _ = run()
    assert steps > 1 and np.array_equal(fast, plain)
    t, mass = 0.1, 2.0
    assert x == pytest.approx((t * t / 2 + 20 * t ** 3 / 6 + 200 * t ** 4 / 24) / mass,
                              rel=1e-9)


@pytest.mark.parametrize("order", ["fx first", "fy first"])
def test_setting_one_component_keeps_the_others_polynomial(order):
    """A master that sets each input's value and then its derivatives, one input after the
    other: push.fx = 1 + 20 t + 100 t^2 (value and two derivatives) and push.fy = 5 (a value
    alone), in either order. fx follows its polynomial (x on the closed form) whichever
    comes first: setting fy holds fy only; and after a step, fx set again without
    derivatives is held from then on, while fy (not set again) stays held."""
    sim = mbdfmu.Simulation("slider_force", method="dop853p", kernel="c", rtol=1e-10,
                            atol=1e-12)
    sets = [lambda: (sim.set_input("push.fx", 1.0), sim.set_input_derivative("push.fx", 1, 20.0),
                     sim.set_input_derivative("push.fx", 2, 200.0)),
            lambda: sim.set_input("push.fy", 5.0)]
    for action in (sets if order == "fx first" else sets[::-1]):
        action()
    sim.advance(0.1)
    t, mass = 0.1, 2.0
    x = (t * t / 2 + 20 * t ** 3 / 6 + 200 * t ** 4 / 24) / mass
    assert sim.outputs()["slider.x"] == pytest.approx(x, rel=1e-9)
    assert sim.inputs_at(0.1).forces[1] == 5.0
    sim.set_input("push.fx", 2.0)
    assert isinstance(sim._forces["push"], Held)
    np.testing.assert_array_equal(sim.inputs_at(0.15).forces[:2], [2.0, 5.0])


def test_a_component_not_set_again_follows_its_polynomial_on():
    """fy given a value and a derivative at t = 0, fx's derivative alone at t = 0.1: fy
    still follows 5 + 10 t, rebased to t = 0.1 (the doubles of the polynomial there)."""
    sim = mbdfmu.Simulation("slider_force", kernel="c")
    sim.set_input("push.fy", 5.0)
    sim.set_input_derivative("push.fy", 1, 10.0)
    sim.advance(0.1)
    sim.set_input_derivative("push.fx", 1, 3.0)
    signal = sim._forces["push"]
    assert isinstance(signal, TaylorInput) and signal.t0 == 0.1
    fx, fy = sim.inputs_at(0.3).forces[:2]
    assert fx == pytest.approx(0.6, rel=1e-14) and fy == pytest.approx(8.0, rel=1e-14)


def test_an_fmu_stepped_by_a_master_that_sets_input_by_input(tmp_path):
    """The slider_force FMU in fmpy, its master setting each input and then its
    derivatives, input by input (fmi2SetReal fx, fmi2SetRealInputDerivatives fx, then
    fmi2SetReal fy): one 0.1 s step lands x on fx's closed form, as when every value is set
    before every derivative."""
    from mbdfmu.fmu_build.scene_fmu import build_fmu
    from test_cosim_coupling import _slave

    fmu, vr, _ = _slave(build_fmu("slider_force", tmp_path / "S.fmu"))
    fmu.setReal([vr["push.fx"]], [1.0])
    fmu.setRealInputDerivatives([vr["push.fx"]] * 2, [1, 2], [20.0, 200.0])
    fmu.setReal([vr["push.fy"]], [5.0])
    fmu.doStep(0.0, 0.1)
    t, mass = 0.1, 2.0
    x = (t * t / 2 + 20 * t ** 3 / 6 + 200 * t ** 4 / 24) / mass
    assert fmu.getReal([vr["slider.x"]])[0] == pytest.approx(x, rel=1e-9)
    fmu.terminate()
    fmu.freeInstance()
