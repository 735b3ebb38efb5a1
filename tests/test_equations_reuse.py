"""A Simulation made from another's equations (``for_another_run``: the structure shared, the C
kernel's state its own) runs as one made from the scene, bit for bit, alone or stepped in turn
with the one whose equations it took; and the assembly that now runs in C meets the
constraints to the assembly tolerance."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

import mbdfmu
from mbdfmu.equations.limits import ModeEquations
from mbdfmu.equations.projection import ASSEMBLY_TOL, assemble, initial_estimates
from mbdfmu.errors import InputError, SettingError

ROOT = Path(__file__).resolve().parents[1]
CRANE = ROOT / "scenarios" / "hydraulic_crane" / "crane.toml"
# (scene, method, an input set before the run or None)
RUNS = [("n_four_bar_2", "dop853p", None), ("slider_crank", "rk45p", None),
        ("pendulum_torque", "dop853p", ("drive.torque", 2.5)),
        ("crane_stop", "dop853p", None), ("four_bar", "genalpha", None)]


def _scene(name):
    return mbdfmu.load_scene(ROOT / "scenes" / f"{name}.toml")


def _start(source, method, given, kernel=None):
    sim = mbdfmu.Simulation(source, method=method, kernel=kernel)
    if given is not None:
        sim.set_input(*given)
    return sim


def _trace(sim, times):
    """The output vector and state at each time (dense reads: the kernel's dense state)."""
    rows = []
    for t in times:
        sim.advance(t)
        rows.append(np.concatenate((sim.output_vector(), sim.q, sim.qd)))
    return np.array(rows)


@pytest.mark.parametrize("kernel", ["c", "numpy"])
@pytest.mark.parametrize("name, method, given", RUNS)
def test_a_run_from_another_runs_equations_is_the_run_from_the_scene(name, method, given,
                                                                      kernel):
    times = np.linspace(0.05, 0.6, 12)
    alone = _start(_scene(name), method, given, kernel)
    expected, stats = _trace(alone, times), vars(alone.integrator.stats).copy()
    # a second run from the first's equations, and a third from the second's, each stepped in
    # turn with the one before it: any state they shared would show in one of them
    first = _start(_scene(name), method, given, kernel)
    second = _start(first.equations, method, given)
    assert second.equations is not first.equations
    assert second.equations.constraint_set is first.equations.constraint_set
    if kernel == "c":
        assert second.equations.ckernel is not first.equations.ckernel
        assert second.equations.ckernel.address != first.equations.ckernel.address
    traces = {id(first): [], id(second): []}
    for t in times:
        for sim in (second, first):
            sim.advance(t)
            traces[id(sim)].append(np.concatenate((sim.output_vector(), sim.q, sim.qd)))
    for sim in (first, second):
        np.testing.assert_array_equal(np.array(traces[id(sim)]), expected)
        assert vars(sim.integrator.stats) == stats


def test_the_equations_of_another_kernel_or_of_a_contact_mode_are_refused_in_one_line():
    sim = mbdfmu.Simulation(_scene("pendulum"), kernel="c")
    with pytest.raises(SettingError) as info:
        mbdfmu.Simulation(sim.equations, kernel="numpy")
    assert "\n" not in str(info.value) and str(info.value).startswith("kernel: 'numpy' differs")
    mbdfmu.Simulation(sim.equations, kernel="c")            # its own kernel named: taken
    mode = ModeEquations(_scene("slider_stop"), {}, kernel="c")
    with pytest.raises(InputError) as info:
        mbdfmu.Simulation(mode)
    assert "\n" not in str(info.value) and "contact mode" in str(info.value)


@pytest.mark.parametrize("name", ["n_four_bar_2", "slider_crank", "four_bar", "parallelogram",
                                  "crane_stop", "rack_pinion"])
def test_assembly_in_c_meets_the_constraints_and_moves_the_scene_least(name):
    # the C kernel's assembly against the constraints themselves, evaluated by the numpy
    # kernel, and against the numpy kernel's own assembly (the same Newton iteration)
    # from estimates a millimetre and some mrad off, so that Newton has work to do
    c_eq = mbdfmu.Simulation(_scene(name), kernel="c").equations
    np_eq = mbdfmu.Simulation(_scene(name), kernel="numpy").equations
    q0, qd0 = initial_estimates(c_eq)
    rng = np.random.default_rng(7)
    estimates = (q0 + rng.uniform(-1e-3, 1e-3, q0.size), qd0 + rng.uniform(-0.1, 0.1, q0.size))
    q, qd = assemble(c_eq, estimates=estimates)
    q_np, qd_np = assemble(np_eq, estimates=estimates)
    Psi, J, nu, _ = np_eq.constraints(0.0, q, qd)
    tol = ASSEMBLY_TOL * np_eq.length_scale
    assert np.max(np.abs(Psi), initial=0.0) <= tol
    assert np.max(np.abs(J @ qd - nu), initial=0.0) <= 1e-12 * max(1.0, np.max(np.abs(qd)))
    # the same iteration, its increments solved another way (where S is singular, as the
    # parallelogram's, by another minimum-norm solve): Gauss-Newton's end point depends on its
    # path by round-off times the curvature, far below the estimates' 1e-3
    np.testing.assert_allclose(q, q_np, rtol=0, atol=1e-9)
    np.testing.assert_allclose(qd, qd_np, rtol=0, atol=1e-10 * max(1.0, np.max(np.abs(qd_np))))
