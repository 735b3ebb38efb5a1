"""Fixed-step methods keep their stated accuracy or stop (issue 12): the runs that claimed
success far beyond it (taylor on Andrews' mechanism and on P2 N = 40, rk4p at 0.1 s on
P2 N = 2) now stop with the reason and the time, the error estimate they report bounds
their true error against the closed forms and the independent Andrews model of
tests/exact_solutions.py, and right runs go on."""

from __future__ import annotations

import functools

import numpy as np
import pytest

import exact_solutions as ref
import mbdfmu
from mbdfmu.model.reader import bundled_scene

# What the stated accuracy allows (10 (atol + rtol L), stated_accuracy.allowed_error) when
# none is given: rtol 1e-3, atol 1e-5, L the mechanism's size (1 m, 2 m and 40 m here).
ALLOWED = {"andrews": 0.0101, "n_four_bar_2": 0.0201, "n_four_bar_40": 0.4001}


def scene(name):
    return mbdfmu.load_scene(bundled_scene(name))


def p2_error(res, n):
    """B0's largest distance (m) from the exact one-DOF reduction."""
    ex = ref.n_four_bar(res.time, n)
    phi = res["crank0.phi"]
    x, y = res["crank0.x"] + 0.5 * np.cos(phi), res["crank0.y"] + 0.5 * np.sin(phi)
    return float(np.max(np.hypot(x - ex["B0_x"], y - ex["B0_y"])))


@functools.lru_cache(maxsize=None)
def andrews_reference(times: tuple):
    return ref.andrews_trajectory(np.array(times))    # a slow rtol 1e-12 run: once


def andrews_error(res):
    """The largest body-angle error (rad) against the independent Cartesian model."""
    ex = andrews_reference(tuple(res.time))
    bodies = [b.name for b in scene("andrews").bodies]
    return max(float(np.max(np.abs(res[f"{b}.phi"] - ex["q"][3 * i + 2])))
               for i, b in enumerate(bodies))


@pytest.mark.parametrize("name, t_end, kw, stop, loose, est_over_err", [
    # was: 0.14 rad off at 0.03 s, reported as a success; stops at 0.0125 s
    ("andrews", 0.03, {"method": "taylor", "step": 1e-5}, r"0\.01\d*", 0.5, (1.0, 4.0)),
    # was: 0.0109 rad off at 0.03 s with an estimate of 4e-4 (checks every 50 steps missed
    # the peak of its local error), reported as a success; stops at 0.019 s
    ("andrews", 0.03, {"method": "baumgarte", "step": 5e-4}, r"0\.01\d*", 0.5, (1.0, 8.0)),
    # was: B0 0.13 m off over 10 s; stops at 1.5 s (checks that follow its local error)
    ("n_four_bar_2", 10.0, {"method": "rk4p", "step": 0.1}, r"1\.\d+", 0.1, (1.0, 6.0)),
    # was: B0 0.42 m off at 2.5 s; stops at 1.9 s
    ("n_four_bar_40", 2.5, {"method": "taylor", "step": 5e-3}, r"1\.\d+", 0.1, (1.0, 4.0)),
])
def test_formerly_silent_fixed_step_runs_stop_and_their_estimate_bounds_the_error(
        name, t_end, kw, stop, loose, est_over_err):
    interval = 1e-3 if name == "andrews" else 0.1
    # an AccuracyError (a SolverError): a smaller step may succeed, so auto retries one
    with pytest.raises(mbdfmu.AccuracyError,
                       match=rf"t = {stop} s: {kw['method']}: estimated error .* exceeds "
                             rf"{ALLOWED[name]:.3g}, what the stated accuracy rtol = 0\.001"):
        mbdfmu.simulate(scene(name), t_end, output_interval=interval, **kw)
    # stated loosely, the same run goes to the end: its estimate bounds its true error
    # (measured: andrews 0.229 against 0.142 rad, P2 N = 2 0.264 against 0.178 m,
    # N = 40 0.726 against 0.419 m), within a small factor
    res = mbdfmu.simulate(scene(name), t_end, output_interval=interval, rtol=loose, **kw)
    error = andrews_error(res) if name == "andrews" else p2_error(res, int(name[11:]))
    low, high = est_over_err
    assert low * error <= res.stats["error_estimate"] <= high * error


@pytest.mark.parametrize("name, t_end, kw, measured", [
    ("n_four_bar_2", 10.0, {"method": "rk4p", "step": 0.01}, 3.0e-6),
    ("n_four_bar_40", 2.5, {"method": "rk4p", "step": 5e-3}, 1.1e-8),
    ("andrews", 0.03, {"method": "rk4p", "step": 1e-4}, 2.2e-6),
    ("andrews", 0.03, {"method": "baumgarte", "step": 2e-5}, 8.4e-7),
])
def test_right_fixed_step_runs_go_on_with_an_estimate_that_bounds_their_error(
        name, t_end, kw, measured):
    interval = 1e-3 if name == "andrews" else 0.1
    res = mbdfmu.simulate(scene(name), t_end, output_interval=interval, **kw)
    error = andrews_error(res) if name == "andrews" else p2_error(res, int(name[11:]))
    assert error == pytest.approx(measured, rel=0.5)
    # an upper bound, conservative by up to about a hundred on these smooth runs (the
    # velocity errors carried as in free flight), and within what the stated accuracy allows
    assert error <= res.stats["error_estimate"] <= min(200 * error, ALLOWED[name])


def test_a_drift_beyond_the_stated_accuracy_is_an_accuracy_error():
    # taylor does not project: at h = 5 ms and rtol 1e-8 the pendulum's constraint
    # violation (a lower bound of its error) passes 10 (atol + rtol L) = 1.01e-7 m at
    # t = 0.015 s. Like the estimate and the energy balance it is the stated accuracy of
    # a fixed step, an AccuracyError: a smaller step may keep it (auto retries one)
    with pytest.raises(mbdfmu.AccuracyError, match=r"t = 0\.015 s: taylor: constraint violation "
                       r".* exceeds 1\.01e-07, what the stated accuracy rtol = 1e-08"):
        mbdfmu.simulate(scene("pendulum"), 1.0, output_interval=0.1, method="taylor",
                        step=5e-3, rtol=1e-8)
