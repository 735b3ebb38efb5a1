"""Runs of genalpha's and ali3p's controlled steps in C (integrators/implicit_runs.py
``implicit_run``, ckernel/implicit_run.h) against Python's step loop taking the same C
attempts one at a time (``IMPLICIT_RUNS`` off): the step control's decisions, the commits,
the energy audit and the work limit are written twice, so the two must give the same
values, steps and failures to the last bit. The cases cover a stiff spring under auto
(no constraints, K's 3 x 3 block), the pendulum, P2 through its singular crossing (where
the kernel hands attempts back to Python), and the slider-crank driven by its motor (the
motion table at every step's end; the dense LU)."""
import numpy as np
import pytest

import mbdfmu
from mbdfmu.equations import ckernel
from mbdfmu.errors import SolverError, WorkLimitError
from mbdfmu.integrators import implicit_runs
from mbdfmu.integrators.work import WorkLimit

pytestmark = pytest.mark.skipif(not ckernel.available(), reason="no C compiler for the kernel")

ADAPTIVE = {"step_control": "adaptive"}


def spring_pendulum(k: float):
    """The shipped stiff spring (P1's link a spring, scenes/stiff_spring.toml) with
    stiffness k (N/m): auto picks genalpha."""
    return mbdfmu.with_parameters(mbdfmu.load_scene("stiff_spring"), {"rod.stiffness": k})


CASES = {
    "stiff spring, auto": (lambda: spring_pendulum(1e10), 0.1, dict(method="auto")),
    "pendulum, genalpha": ("pendulum", 0.3, dict(method="genalpha", rtol=1e-6,
                                                 method_options=ADAPTIVE)),
    "P2 N = 2, genalpha": ("n_four_bar_2", 1.0, dict(method="genalpha",
                                                     method_options=ADAPTIVE)),
    "slider-crank, ali3p": ("slider_crank", 0.3, dict(method="ali3p", method_options=ADAPTIVE)),
    "slider-crank, genalpha": ("slider_crank", 0.3, dict(method="genalpha",
                                                         method_options=ADAPTIVE)),
}


def spy_runs(monkeypatch, runs: bool) -> list:
    """IMPLICIT_RUNS set to ``runs``; the steps each C run took, collected."""
    monkeypatch.setattr(implicit_runs, "IMPLICIT_RUNS", runs)
    taken, real = [], implicit_runs.implicit_run

    def counted(method, t_target, rejections):
        before = method.stats.nsteps
        out = real(method, t_target, rejections)
        taken.append(method.stats.nsteps - before)
        return out
    monkeypatch.setattr(implicit_runs, "implicit_run", counted)
    return taken


def scene_of(case):
    scene = CASES[case][0]
    return scene() if callable(scene) else scene


@pytest.mark.parametrize("case", list(CASES))
def test_runs_in_c_are_the_python_loop_bit_for_bit(case, monkeypatch):
    _, t_end, options = CASES[case]
    results, taken = {}, {}
    for runs in (True, False):
        taken[runs] = spy_runs(monkeypatch, runs)
        results[runs] = mbdfmu.simulate(scene_of(case), t_end, kernel="c",
                                        output_interval=1e-3, **options)
    c, py = results[True], results[False]
    assert c.method == py.method and c.method.split("->")[-1] in ("genalpha", "ali3p")
    for name in py.names:
        assert np.array_equal(c[name], py[name]), name
    for counter in ("nsteps", "nrejected", "nprojections"):
        assert c.stats[counter] == py.stats[counter], counter
    assert not taken[False]
    # the runs took the steps (P2 hands some attempts at its crossing back to Python)
    assert sum(taken[True]) >= 0.95 * c.stats["nsteps"], (sum(taken[True]), c.stats)


def test_the_work_limit_stops_both_at_the_same_step(monkeypatch):
    outcome = {}
    for runs in (True, False):
        spy_runs(monkeypatch, runs)
        sim = mbdfmu.Simulation(spring_pendulum(1e10), kernel="c")
        sim.advance(0.01)
        with pytest.raises(WorkLimitError) as info:
            sim.advance(0.05, WorkLimit(max_steps=7))
        outcome[runs] = (str(info.value), sim.t, sim.integrator.current.stats.nsteps)
    assert outcome[True] == outcome[False]
    assert "7 internal steps did not reach t = 0.05 s" in outcome[True][0]


def test_a_broken_energy_balance_stops_both_with_the_same_reason(monkeypatch):
    """The audit's allowance cut a million-fold: the run's energy check fails inside the C
    run, and Python gives the same reason at the same step."""
    outcome = {}
    for runs in (True, False):
        spy_runs(monkeypatch, runs)
        sim = mbdfmu.Simulation("pendulum", method="genalpha", kernel="c", rtol=1e-6,
                                method_options=ADAPTIVE)
        sim.integrator.audit.factor *= 1e-6
        with pytest.raises(SolverError, match="energy balance broken") as info:
            sim.advance(0.3)
        outcome[runs] = (str(info.value), sim.integrator.stats.nsteps)
    assert outcome[True] == outcome[False]
