"""Driver velocity and acceleration derived from position samples alone (signals.py),
checked on the slider-crank against the same motion given analytically (issue 12)."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest

from mbdfmu.signals import SampledDriver

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))
# the loop of benchmarks/position_inputs.py (docs/fmu.md's table): the slider-crank from
# rest driven by phi = sin(2 pi t) rad, 20 samples a period at the coarsest step
from position_inputs import efforts  # noqa: E402


@pytest.fixture(scope="module")
def scenes(tmp_path_factory):
    """The folder of the scenes the benchmark writes (motor an input, and analytic)."""
    return tmp_path_factory.mktemp("position_inputs")


def _efforts(folder, h, full=False):
    """Effort at each communication point with the motor's position set before every step
    (as the FMU sets it), and the exact effort; the first three steps (history) left out."""
    return efforts(h, full, folder)


@pytest.fixture(scope="module")
def exact_range(scenes):
    _, exact, _ = _efforts(scenes, 1e-3)
    return exact.min(), exact.max()


@pytest.mark.parametrize("h", [1e-3, 5e-3, 1e-2, 2e-2, 5e-2])
def test_position_only_effort_stays_within_the_exact_range(scenes, exact_range, h):
    # the derived acceleration is a second divided difference: the motion's acceleration at
    # a time among the samples, never beyond its range (the cubic overshot the peaks)
    got, _, _ = _efforts(scenes, h)
    lo, hi = exact_range
    assert lo - 1e-6 * (hi - lo) <= got.min() and got.max() <= hi + 1e-6 * (hi - lo), \
        (got.min(), got.max(), lo, hi)


def test_position_only_effort_error_is_first_order(scenes):
    # documented in docs/fmu.md: order h, as with full inputs (acceleration held over a step)
    errors = []
    for h in (1e-2, 5e-3, 2.5e-3):
        got, exact, _ = _efforts(scenes, h)
        errors.append(np.abs(got - exact).max() / np.abs(exact).max())
    ratios = [errors[0] / errors[1], errors[1] / errors[2]]
    assert all(1.8 < r < 2.3 for r in ratios), (errors, ratios)


def test_large_derived_acceleration_error_is_reported_once(scenes):
    # 50 ms samples of a 1 Hz motion: the estimate (cubic minus quadratic) is large
    _, _, coarse = _efforts(scenes, 5e-2)
    assert coarse and all("motor.position" in line and "\n" not in line for line in coarse)
    # full inputs: nothing derived, nothing reported
    assert _efforts(scenes, 5e-2, full=True)[2] == []


def test_sampled_driver_reproduces_a_quadratic_and_estimates_a_cubic():
    d = SampledDriver(0.0)
    for t in (0.0, 0.1, 0.2):
        d.set(t, position=1.0 + 2.0 * t + 1.5 * t * t)
    np.testing.assert_allclose(d(0.25), (1.0 + 0.5 + 1.5 * 0.0625, 2.0 + 0.75, 3.0),
                               rtol=1e-12)
    d = SampledDriver(0.0)
    for t in (0.0, 0.1, 0.2, 0.3):
        d.set(t, position=t ** 3)
    # the quadratic's acceleration is the second divided difference 6 * 0.2; the cubic's at
    # 0.4 is 6 * 0.4: the estimate is their difference
    assert d(0.3)[2] == pytest.approx(1.2, rel=1e-12)
    assert d.error == pytest.approx(1.2, rel=1e-9)
    assert d.error_is_large()


def test_constant_rate_motion_reports_no_round_off_as_error():
    # A crank at 314.16 rad/s sampled every 1 ms for 2 s (as a master sets it): the
    # samples' differences are round-off alone, which the old estimate (polyfit minus the
    # quadratic) reported as a large error at 219 of the 2000 steps.
    w, h, t = 314.1592653589793, 1e-3, 0.0
    d = SampledDriver(0.0)
    large = 0
    for _ in range(2000):
        d.set(t, position=w * (t + h))
        large += d.error_is_large()
        t += h
    assert large == 0
    assert d(t)[1] == pytest.approx(w, rel=1e-9) and abs(d.error) < 1e-4


def test_error_estimate_matches_an_independent_cubic_fit_at_uneven_samples():
    # the closed form (Newton's third divided difference) against numpy's exact cubic
    # through the same four samples of a quartic, at uneven times
    times = (0.3, 0.31, 0.325, 0.33)
    d = SampledDriver(0.0)
    for t in times:
        d.set(t, position=2.0 * t ** 4 - t ** 3 + 0.5 * t)
    x = times[-1] + (times[-1] - times[-2])
    cubic = np.polyfit(times, [2.0 * t ** 4 - t ** 3 + 0.5 * t for t in times], 3)
    quadratic = np.polyfit(times[1:], [2.0 * t ** 4 - t ** 3 + 0.5 * t for t in times[1:]], 2)
    expected = np.polyval(np.polyder(cubic, 2), x) - 2.0 * quadratic[0]
    assert d.error == pytest.approx(expected, rel=1e-6)
