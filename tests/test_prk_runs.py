"""dop853p / rk45p steps taken in C: runs of steps in one call (``c_steps.prk_run``,
ckernel/adaptive.h ``mbd_prk_run``) and trials next to singular configurations
(``mbd_prk_trial_near``), held to the Python step loop and the numpy kernel (same accepted
and rejected steps, values to round-off) and to P2 N = 2's exact reduction."""

import math
import tomllib

import numpy as np
import pytest

import mbdfmu
from mbdfmu.bench.closed_forms import n_four_bar_B0
from mbdfmu.integrators import c_steps, starting_step
from mbdfmu.integrators.work import WorkLimit
from mbdfmu.model.reader import resolve_scene_path, scene_from_dict

COUNTERS = ("nsteps", "nrejected", "naccel", "nprojections")


def _run(scene, method, t_end, monkeypatch, *, runs=True, kernel="c", **options):
    """(Simulation after advance(t_end), calls of the C run, attempts decided in Python)."""
    calls, attempts = [], []

    def counted(*args, **kwargs):
        calls.append(1)
        return prk_run(*args, **kwargs)

    def attempt(*args, **kwargs):
        attempts.append(1)
        return prk_attempt(*args, **kwargs)
    prk_run, prk_attempt = c_steps.ckernel_prk_run, c_steps.prk_attempt
    monkeypatch.setattr(c_steps, "PRK_RUNS", runs)
    monkeypatch.setattr(c_steps, "ckernel_prk_run", counted)
    monkeypatch.setattr(c_steps, "prk_attempt", attempt)
    sim = mbdfmu.Simulation(scene, method=method, kernel=kernel, **options)
    sim.advance(t_end)
    monkeypatch.setattr(c_steps, "ckernel_prk_run", prk_run)
    monkeypatch.setattr(c_steps, "prk_attempt", prk_attempt)
    return sim, len(calls), len(attempts)


def _same_run(a, b, rel):
    for name in COUNTERS:
        assert getattr(a.integrator.stats, name) == getattr(b.integrator.stats, name), name
    out_a, out_b = a.outputs(), b.outputs()
    for name, value in out_a.items():
        assert out_b[name] == pytest.approx(value, rel=rel, abs=rel), name


def _b0_error(sim, t_end):
    exact = n_four_bar_B0([t_end], 2)
    out = sim.outputs()
    phi = out["crank0.phi"]
    return math.hypot(out["crank0.x"] + 0.5 * math.cos(phi) - float(exact["x"][-1]),
                      out["crank0.y"] + 0.5 * math.sin(phi) - float(exact["y"][-1]))


@pytest.mark.parametrize("method", ["dop853p", "rk45p"])
def test_p2_runs_in_c_take_the_python_loops_steps(method, monkeypatch):
    # 10 s of P2 N = 2 pass its singular configurations (cranks horizontal) 6 times, the
    # steps planned across them (singular_zone.py), energy audited all along: every
    # attempt in C, none left to Python
    scene = mbdfmu.load_scene("n_four_bar_2")
    options = dict(rtol=1e-6, atol=2e-8)
    looped, none, in_python = _run(scene, method, 10.0, monkeypatch, runs=False, **options)
    ran, calls, left = _run(scene, method, 10.0, monkeypatch, **options)
    stats = looped.integrator.stats
    assert none == 0 and in_python == stats.nsteps + stats.nrejected
    assert calls >= 1 and left == 0
    _same_run(looped, ran, 1e-8)
    audit_a, audit_b = looped.integrator.audit, ran.integrator.audit
    assert audit_b.checks == audit_a.checks == ran.integrator.stats.nsteps
    assert audit_b.worst == pytest.approx(audit_a.worst, rel=1e-6)
    assert _b0_error(ran, 10.0) < 1e-6


def test_p2_trials_near_singular_configurations_match_the_numpy_kernel(monkeypatch):
    # the numpy kernel takes every step in Python (stages, the error estimate along the
    # constraints near the singular configurations, projections)
    scene = mbdfmu.load_scene("n_four_bar_2")
    options = dict(rtol=1e-6, atol=2e-8)
    numpy_run, _, _ = _run(scene, "dop853p", 10.0, monkeypatch, kernel="numpy", **options)
    c_run, _, _ = _run(scene, "dop853p", 10.0, monkeypatch, runs=False, **options)
    _same_run(numpy_run, c_run, 1e-8)
    assert _b0_error(numpy_run, 10.0) < 1e-6


def test_runs_in_c_with_a_damped_spring(monkeypatch):
    # Andrews' mechanism with a damper in its spring: forces that change with the state
    # and no energy audit (not conservative)
    data = tomllib.loads(resolve_scene_path("andrews").read_text())
    for force in data["force"]:
        if force["type"] == "spring_damper":
            force["damping"] = 20.0
    scene = scene_from_dict(data)
    options = dict(rtol=1e-6, atol=1e-9)
    looped, _, _ = _run(scene, "dop853p", 0.03, monkeypatch, runs=False, **options)
    ran, calls, _ = _run(scene, "dop853p", 0.03, monkeypatch, **options)
    assert ran.integrator.audit is None and calls >= 1
    assert ran.integrator.stats.nsteps > 20
    _same_run(looped, ran, 1e-8)
    # the damper takes energy out: below the undamped run's crank speed at the end
    undamped, _, _ = _run(mbdfmu.load_scene("andrews"), "dop853p", 0.03, monkeypatch, **options)
    assert abs(ran.outputs()["crank.omega"]) < abs(undamped.outputs()["crank.omega"])


@pytest.mark.parametrize("method", ["dop853p", "rk45p"])
def test_runs_in_c_follow_a_drivers_motion(method, monkeypatch):
    # P4's slider-crank with its motor on a harmonic motion (0.3 rad at 40 Hz): the run
    # evaluates the motion at every stage's time in C (ckernel/motions.h) and takes the
    # Python loop's steps; the crank's angle is the motion's
    data = tomllib.loads(resolve_scene_path("slider_crank").read_text())
    data["driver"][0]["motion"] = dict(type="harmonic", offset=0.0, amplitude=0.3,
                                       frequency=40.0)
    scene = scene_from_dict(data)
    looped, none, in_python = _run(scene, method, 0.05, monkeypatch, runs=False)
    ran, calls, left = _run(scene, method, 0.05, monkeypatch)
    assert none == 0 and in_python > 20 and calls >= 1 and left == 0
    _same_run(looped, ran, 1e-12)
    angle = ran.outputs()["crank.phi"]
    assert angle == pytest.approx(0.3 * math.sin(2 * math.pi * 40.0 * 0.05), abs=1e-9)


def test_dense_outputs_inside_a_run_of_steps(monkeypatch):
    # outputs every 10 ms, inside steps the run took (dense output of its last step)
    scene = mbdfmu.load_scene("n_four_bar_2")
    values = []
    for runs in (False, True):
        monkeypatch.setattr(c_steps, "PRK_RUNS", runs)
        sim = mbdfmu.Simulation(scene, method="dop853p", kernel="c", rtol=1e-7, atol=2e-9)
        phis = []
        for t in np.arange(1, 101) * 0.01:
            sim.advance(t, dense=True)
            phis.append(sim.outputs()["crank0.phi"])
        values.append(np.array(phis))
    assert np.max(np.abs(values[0] - values[1])) < 1e-10


def _failure(scene, monkeypatch, runs, prepare, **advance):
    monkeypatch.setattr(c_steps, "PRK_RUNS", runs)
    sim = mbdfmu.Simulation(scene, method="dop853p", kernel="c", rtol=1e-6, atol=2e-8)
    prepare(sim)
    with pytest.raises(mbdfmu.SolverError) as failure:
        sim.advance(10.0, **advance)
    stats = sim.integrator.stats
    return str(failure.value), (stats.nsteps, stats.nrejected)


def test_runs_in_c_stop_where_the_python_loop_stops(monkeypatch):
    # a work limit of 50 steps (the runs stop at it, not at their 64 attempts) and an
    # energy budget a million times tighter than the method's (the audit's check fails
    # after some step): the same message at the same time, the state rolled back alike
    scene = mbdfmu.load_scene("n_four_bar_2")

    def nothing(sim):
        pass

    def tight(sim):
        sim.integrator.audit.factor *= 1e-6
    for prepare, advance in ((nothing, dict(limit=WorkLimit(max_steps=50))), (tight, {})):
        looped = _failure(scene, monkeypatch, False, prepare, **advance)
        ran = _failure(scene, monkeypatch, True, prepare, **advance)
        assert ran == looped
        assert "t = " in ran[0]


def _landing_runs(name, method, kernel, times):
    sim = mbdfmu.Simulation(resolve_scene_path(name), method=method, kernel=kernel, rtol=1e-6)
    for t in times:
        sim.advance(t, dense=False)
    return sim


@pytest.mark.parametrize("kernel", ["c", "numpy"])
@pytest.mark.parametrize("name", ["n_four_bar_2", "four_bar", "parallelogram"])
def test_a_landing_dop853p_run_leaves_out_the_unread_end_evaluation(name, kernel, monkeypatch):
    # DOP853's error weights at the unprojected end are 0 (Hairer's estimate): an advance
    # that lands on its target, without dense output or a watch, does not evaluate y' there.
    # Against the same run made to evaluate it: the same doubles and steps, one evaluation
    # fewer per attempt, in the C runs and in the Python loop alike
    from mbdfmu.integrators.projected_rk import DOP853P
    times = np.linspace(0.1, 3.0, 7)
    skipped = _landing_runs(name, "dop853p", kernel, times)
    monkeypatch.setattr(c_steps, "PRK_RUNS", False)
    in_python = _landing_runs(name, "dop853p", kernel, times)
    monkeypatch.setattr(DOP853P, "error_reads_end", True)
    evaluated = _landing_runs(name, "dop853p", kernel, times)
    a, b = vars(skipped.integrator.stats), vars(evaluated.integrator.stats)
    np.testing.assert_array_equal(skipped.output_vector(), evaluated.output_vector())
    np.testing.assert_array_equal(in_python.output_vector(), skipped.output_vector())
    assert vars(in_python.integrator.stats) == a
    assert {k: a[k] for k in COUNTERS if k != "naccel"} == \
        {k: b[k] for k in COUNTERS if k != "naccel"}
    assert b["naccel"] - a["naccel"] == a["nsteps"] + a["nrejected"] > 0
    assert skipped.integrator.dense is None      # no dense output to misread


@pytest.mark.parametrize("method, dense", [("dop853p", True), ("rk45p", False)])
def test_a_run_whose_end_evaluation_is_read_evaluates_it(method, dense, monkeypatch):
    # dense output reads it, and so does rk45p's error estimate (its weight there is not 0)
    from mbdfmu.integrators.projected_rk import DOP853P
    def counts():
        sim = mbdfmu.Simulation(resolve_scene_path("n_four_bar_2"), method=method,
                                kernel="c", rtol=1e-6)
        for t in np.linspace(0.1, 3.0, 7):
            sim.advance(t, dense=dense)
        assert sim.integrator.dense is not None
        return vars(sim.integrator.stats).copy(), sim.output_vector()
    before, out = counts()
    monkeypatch.setattr(DOP853P, "error_reads_end", True)
    after, out_after = counts()
    assert before == after and np.array_equal(out, out_after)


@pytest.mark.parametrize("name", ["n_four_bar_2", "andrews", "pendulum_torque", "gear_pair"])
def test_a_start_in_c_is_pythons_to_the_last_bit(name, monkeypatch):
    """A pair's start in C (y' and the singularity indicator in one call, then the starting
    step: one evaluation and numpy's pairwise sums) gives the Python path's doubles and
    counts its evaluations, over tolerances that move the step by decades, both pairs."""
    scene = mbdfmu.load_scene(name)
    taken = []

    def in_c(function):
        def call(rk):
            taken.append(function(rk))
            return taken[-1]
        return call
    start_in_c, initial_step_in_c = starting_step.start_in_c, starting_step.initial_step_in_c
    for method in ("dop853p", "rk45p"):
        for rtol in (1e-3, 1e-6, 1e-10):
            monkeypatch.setattr(starting_step, "start_in_c", in_c(start_in_c))
            monkeypatch.setattr(starting_step, "initial_step_in_c", in_c(initial_step_in_c))
            c = mbdfmu.Simulation(scene, method=method, kernel="c", rtol=rtol).integrator
            assert len(taken) == 2 and None not in taken      # both C paths were taken
            taken.clear()
            monkeypatch.setattr(starting_step, "start_in_c", lambda rk: None)
            monkeypatch.setattr(starting_step, "initial_step_in_c", lambda rk: None)
            python = mbdfmu.Simulation(scene, method=method, kernel="c", rtol=rtol).integrator
            assert c.h == python.h and 0.0 < c.h < math.inf
            assert np.array_equal(c.f, python.f)
            assert c.zone.indicator == python.zone.indicator
            assert c.stats.naccel == python.stats.naccel
