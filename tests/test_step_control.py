"""dop853p's PI step-size controller (integrators/adaptive.py): Hairer's formula, fewer
rejections than the I controller for the same accuracy, against P2 N = 2's exact reduction,
and the controller's memory carried by saved states as by the run itself. Also the pairs'
tableaux (integrators/tableaux.py), held to scipy's, and the imports an FMU's cold start
leaves out."""

import math

import numpy as np
import pytest

import mbdfmu
from mbdfmu.bench.closed_forms import n_four_bar_B0
from mbdfmu.integrators import adaptive
from mbdfmu.integrators.projected_rk import DOP853P, MAX_FACTOR, MIN_FACTOR, RK45P, SAFETY


def hairer_dop853_step(h, err, facold, beta):
    """The step after an accepted one in Hairer's DOP853 code (dop853.f, labels 35-41:
    FAC11 = ERR**EXPO1, FAC = FAC11 / FACOLD**BETA, FAC = MAX(FACC2, MIN(FACC1, FAC / SAFE)),
    HNEW = H / FAC), with FACC1 = 1 / FAC1 and FACC2 = 1 / FAC2 for the factor range
    [FAC1, FAC2] = [MIN_FACTOR, MAX_FACTOR]."""
    expo1 = 1.0 / 8.0 - beta * 0.2
    fac = err ** expo1 / facold ** beta
    fac = max(1.0 / MAX_FACTOR, min(1.0 / MIN_FACTOR, fac / SAFETY))
    return h / fac


@pytest.mark.parametrize("err", [1e-9, 1e-4, 0.03, 0.5, 0.999])
@pytest.mark.parametrize("err_old", [1e-4, 0.01, 0.7])
def test_an_accepted_steps_proposal_is_hairers_dop853(err, err_old):
    got = adaptive.accepted_step(0.01, err, err_old, DOP853P.alpha, DOP853P.beta, SAFETY,
                                 MAX_FACTOR)
    assert got == pytest.approx(hairer_dop853_step(0.01, err, err_old, DOP853P.beta),
                                rel=1e-14)
    assert DOP853P.beta == 0.04 and RK45P.beta == 0.0


def test_the_memory_damps_growth_and_a_rejection_ignores_it():
    """err_old^beta < 1 damps the proposal; a rejected step's retry uses err alone."""
    args = (DOP853P.alpha, DOP853P.beta, SAFETY, MAX_FACTOR)
    assert adaptive.accepted_step(1.0, 0.5, 0.9, *args) < \
        adaptive.accepted_step(1.0, 0.5, 0.99, *args)
    assert adaptive.rejected_step(1.0, 4.0, DOP853P.alpha, SAFETY, MIN_FACTOR) == \
        pytest.approx(SAFETY * 4.0 ** -DOP853P.alpha)


def _p2_run(monkeypatch, beta, rtol, t_end=10.0):
    monkeypatch.setattr(DOP853P, "beta", beta)
    monkeypatch.setattr(DOP853P, "alpha", 1.0 / 8.0 - 0.2 * beta)
    sim = mbdfmu.Simulation("n_four_bar_2", method="dop853p", rtol=rtol, kernel="c")
    sim.advance(t_end)
    exact, out = n_four_bar_B0([t_end], 2), sim.outputs()
    phi = out["crank0.phi"]
    err = math.hypot(out["crank0.x"] + 0.5 * math.cos(phi) - float(exact["x"][-1]),
                     out["crank0.y"] + 0.5 * math.sin(phi) - float(exact["y"][-1]))
    return sim.integrator.stats, err


@pytest.mark.parametrize("rtol", [1e-4, 1e-6])
def test_p2_with_fewer_rejections_and_evaluations_than_the_i_controller(monkeypatch, rtol):
    """P2 N = 2 over 10 s (ten singular crossings), B0 against the exact reduction: the PI
    controller rejects fewer steps and evaluates eq. (14) no more often than the I
    controller (beta = 0, Hairer's DOP853 default), and is as accurate."""
    pi, err_pi = _p2_run(monkeypatch, 0.04, rtol)
    i, err_i = _p2_run(monkeypatch, 0.0, rtol)
    assert pi.nrejected < 0.85 * i.nrejected
    assert pi.naccel <= i.naccel
    assert err_pi < 10 * rtol and err_pi < 2 * err_i


def test_a_saved_state_carries_the_controllers_memory():
    """P2 N = 2 advanced in 50 ms communication steps (dop853p lands on each): a state saved
    at 2 s and restored in a new Simulation goes on with the same steps, bit for bit; the
    same state with the memory reset (an I-controller start) goes on with other steps."""
    def run(sim, t0):
        for k in range(1, 41):
            sim.advance(t0 + 0.05 * k)
        return sim.q.copy()
    first = mbdfmu.Simulation("n_four_bar_2", method="dop853p", kernel="c")
    run(first, 0.0)
    state = first.get_state()
    assert state["integrator"]["err_old"] != adaptive.ERR_OLD_MIN
    ahead = run(first, 2.0)
    again = mbdfmu.Simulation("n_four_bar_2", method="dop853p", kernel="c")
    again.set_state(state)
    np.testing.assert_array_equal(run(again, 2.0), ahead)
    forgot = mbdfmu.Simulation("n_four_bar_2", method="dop853p", kernel="c")
    state["integrator"]["err_old"] = adaptive.ERR_OLD_MIN
    forgot.set_state(state)
    assert not np.array_equal(run(forgot, 2.0), ahead)


def test_the_pairs_tableaux_are_scipys_to_the_last_bit():
    from scipy.integrate import DOP853, RK45

    from mbdfmu.integrators import tableaux
    for name in ("A", "B", "C", "E3", "E5", "A_EXTRA", "C_EXTRA", "D"):
        np.testing.assert_array_equal(getattr(tableaux, "DOP853_" + name), getattr(DOP853, name))
    for name in ("A", "B", "C", "E", "P"):
        np.testing.assert_array_equal(getattr(tableaux, "RK45_" + name), getattr(RK45, name))
    assert (tableaux.DOP853_STAGES, tableaux.RK45_STAGES) == (DOP853.n_stages, RK45.n_stages)


def test_a_simulation_imports_neither_scipy_integrate_nor_interpolate():
    """What an FMU imports at load (every shipped module) and runs: scipy.integrate and
    scipy.interpolate, a large share of its cold start, are imported only where needed."""
    import subprocess
    import sys
    code = ("import pkgutil, importlib, sys, mbdfmu\n"
            "for m in ('model', 'equations', 'integrators'):\n"
            "    p = importlib.import_module('mbdfmu.' + m)\n"
            "    for i in pkgutil.walk_packages(p.__path__, p.__name__ + '.'):\n"
            "        if 'compiled' not in i.name: importlib.import_module(i.name)\n"
            "import mbdfmu.fast_steps\n"
            "mbdfmu.Simulation('n_four_bar_2', kernel='c').advance(0.5)\n"
            "print(sorted(m for m in ('scipy.integrate', 'scipy.interpolate') if m in sys.modules))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.split() == ["[]"]
