"""A joint that leaves its end stop and comes back within one step.

slider_stop's slider, pushed onto its lower stop with 10 N, carries an arm on a driven
shoulder whose angle the master sets before every 1 ms step (test_fmu_driver_steps.ARM).
Twice a swing the arm's pull on the slider crosses the push: at a set the stop's force
turns negative, so the slider leaves its stop with zero rate, and within the step the
pull falls again and brings it back. Before, the runner took that return at once (the
slider sat a round-off inside its stop after its held row let go): an impact at zero rate
that left again, at the same instant, until the run stopped with "the contact modes
chatter" at t = 2.056 s (rk4p, rk45p). The references are the physics of a unilateral
contact (no penetration, a stop that only pushes) and the three methods' agreement, each
locating the events with its own steps.
"""

from __future__ import annotations

import math
import sys
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parent))

import mbdfmu  # noqa: E402
from test_fmu_driver_steps import ARM, swing_angle  # noqa: E402

SCENES = Path(__file__).resolve().parents[1] / "scenes"
H, STEPS, W = 1e-3, 3000, 4.0 * math.pi


def arm_on_slider(folder: Path) -> Path:
    push = "value = [-2.0, 0.0]"
    text = (SCENES / "slider_stop.toml").read_text()
    assert push in text
    path = folder / "arm_on_slider.toml"
    path.write_text(text.replace(push, "value = [-10.0, 0.0]") + ARM
                    + 'motion = { type = "input", initial = -1.5707963267948966 }\n')
    return path


def run(path: Path, method: str):
    """(the event log, the slider's coordinate and the stop's force after each step)."""
    sim = mbdfmu.Simulation(path, method=method, kernel="c")
    x, force = [], []
    for k in range(STEPS):
        t = k * H
        sim.set_input("swing.position", swing_angle(t))
        sim.set_input("swing.velocity", 0.8 * W * math.cos(W * t))
        sim.set_input("swing.acceleration", -0.8 * W * W * math.sin(W * t))
        sim.advance((k + 1) * H)
        out = sim.outputs()
        x.append(out["slider.x"])
        force.append(out["guide.limit"])
    return sim.events.log, np.array(x), np.array(force)


@pytest.fixture(scope="module")
def runs(tmp_path_factory):
    path = arm_on_slider(tmp_path_factory.mktemp("arm"))
    return {method: run(path, method) for method in ("rk4p", "rk45p", "dop853p")}


@pytest.mark.parametrize("method", ["rk4p", "rk45p", "dop853p"])
def test_a_slider_that_leaves_its_stop_at_a_set_comes_back_inside_the_step(runs, method):
    log, x, force = runs[method]
    leaves = [t for t, _, what in log if what == "leaves its lower stop"]
    rests = [t for t, _, what in log if "rests against it" in what]
    assert len(leaves) >= 4 and len(rests) >= 4
    # the release at t = 2.056 s, where the modes chattered: left at that set, back on the
    # stop with a bounce that dies out before the next set (at rest again by then)
    assert 2.056 in leaves
    back = [t for t in rests if 2.056 < t < 2.057]
    assert len(back) == 1, [e for e in log if 2.05 < e[0] < 2.06][:5]
    # a unilateral contact: never inside the stop beyond the projection's round-off, and
    # at rest its force pushes (guide.limit > 0: the stop pushes the coordinate up)
    assert x.min() > -1e-12
    on_stop = x < 1e-12
    assert np.all(force[on_stop] >= -1e-9)
    assert np.all(force[~on_stop] == 0.0)


def test_the_three_methods_find_the_same_releases_and_rests(runs):
    """Each method steps and locates with its own steps: the times of the releases and of
    the rests agree to the event location's tolerance and the methods' accuracy."""
    times = {}
    for method, (log, _, _) in runs.items():
        times[method] = [(what.split(" at ")[0] if "rests" not in what else "rests", t)
                         for t, _, what in log
                         if "rests" in what or what == "leaves its lower stop"]
    assert [w for w, _ in times["rk4p"]] == [w for w, _ in times["dop853p"]]
    assert [w for w, _ in times["rk45p"]] == [w for w, _ in times["dop853p"]]
    for method in ("rk4p", "rk45p"):
        np.testing.assert_allclose([t for _, t in times[method]],
                                   [t for _, t in times["dop853p"]], rtol=0, atol=1e-7)
