"""genalpha's and ali3p's step-size control (``integrators/implicit_control.py``).

Reference: the stiff limit of P1. The pendulum's rod replaced by a spring of stiffness k
(rest length 1 m) on a 1 kg bob released horizontally at rest follows the rigid pendulum's
elliptic solution (tests/exact_solutions.py) to the spring's stretch, about 3 m g / k
(3e-9 m at k = 1e10 N/m), far below the tolerance.
"""
import tomllib

import numpy as np
import pytest

import exact_solutions as ref

mbdfmu = pytest.importorskip("mbdfmu")
from mbdfmu.model.reader import scene_from_dict  # noqa: E402

TOL = 1e-6 * 1.0 + 1e-8        # default rtol times the 1 m mechanism, plus atol


def spring_pendulum(k: float):
    """The shipped stiff spring (P1's link a spring of rest length 1 m from the pivot to
    the bob, scenes/stiff_spring.toml) with stiffness k (N/m)."""
    return mbdfmu.with_parameters(mbdfmu.load_scene("stiff_spring"), {"rod.stiffness": k})


def bob_error(res) -> float:
    ex = ref.simple_pendulum(res.time, J=1e-6)
    return float(np.max(np.hypot(res["bob.x"] - ex["x"], res["bob.y"] - ex["y"])))


def test_auto_stiff_spring_meets_its_tolerance_over_one_second():
    res = mbdfmu.simulate(spring_pendulum(1e10), 1.0, output_interval=0.01)
    assert res.method == "auto->genalpha"
    # measured 9.5e-7 in 5506 steps (the fixed 1 ms step auto used before: 9.1e-6)
    assert bob_error(res) < TOL
    assert res.stats["nsteps"] < 20000


def test_fixed_step_stays_fixed_unless_asked():
    scene = spring_pendulum(1e10)
    fixed = mbdfmu.simulate(scene, 0.05, method="genalpha", step=1e-3, output_interval=0.01)
    assert fixed.stats["nsteps"] == 50
    controlled = mbdfmu.simulate(scene, 0.05, method="genalpha", output_interval=0.01,
                                 method_options={"step_control": "adaptive"})
    assert controlled.stats["nsteps"] != 50
    assert bob_error(controlled) < TOL


def test_ali3p_step_control_keeps_the_rigid_pendulum_near_its_tolerance():
    # rigid P1 over 1 s at rtol 1e-6: the control is per unit step on an estimate of the
    # position's local error alone, so the global error is near the tolerance rather than
    # below it (measured with genalpha: 2.6e-6; at rtol 1e-8, 5.2e-8)
    scene = mbdfmu.load_scene(ref.SCENES / "pendulum.toml")
    res = mbdfmu.simulate(scene, 1.0, method="ali3p", output_interval=0.05,
                          method_options={"step_control": "adaptive"})
    assert bob_error(res) < 5 * TOL
    assert res.stats["nrejected"] < 0.1 * res.stats["nsteps"]


def test_step_control_is_an_option_with_a_rule():
    with pytest.raises(mbdfmu.SettingError, match="step_control must be"):
        mbdfmu.simulate(spring_pendulum(1e8), 0.01, method="genalpha",
                        method_options={"step_control": "yes"})


def test_a_sudden_force_along_a_stiff_spring_does_not_hold_the_step_to_its_ringing():
    """A 3 N push set along a 1e10 N/m spring rings its fast mode (3e-10 m, period 63 µs).
    Filtered once, the error of a step over that mode no longer falls with h (the filter
    divides it by about (h w)^2), so each rejection cut the step further until it resolved
    the ringing: about 6700 steps in 20 ms. Filtered twice after a rejection (Hairer and
    Wanner, Solving ODEs II, sec. IV.8, Radau5's remedy) the step follows the slow motion.
    Reference: the rigid pendulum with the same push by dop853p at rtol 1e-10 (the spring
    stretches by about 1e-9 m)."""
    data = tomllib.loads((ref.SCENES / "pendulum.toml").read_text())
    push = {"name": "push", "type": "force", "body": "bob", "point": [0.0, 0.0],
            "input": True}
    rigid = scene_from_dict({**data, "force": [push]})
    spring = scene_from_dict({**data, "joint": [], "force": [
        {"name": "rod", "type": "spring_damper", "body_i": "ground", "point_i": [0.0, 0.0],
         "body_j": "bob", "point_j": [0.0, 0.0], "stiffness": 1e10, "damping": 0.0,
         "rest_length": 1.0}, push]})
    runs = {}
    for name, scene, options in (("spring", spring, {}),
                                 ("rigid", rigid, dict(method="dop853p", rtol=1e-10,
                                                       atol=1e-12))):
        sim = mbdfmu.Simulation(scene, kernel="c", **options)
        sim.set_input("push.fx", 3.0)
        rows = []
        for k in range(1, 21):
            sim.advance(k * 1e-3)
            rows.append([sim.outputs()["bob.x"], sim.outputs()["bob.y"]])
        runs[name] = (np.array(rows), getattr(sim.integrator, "current", sim.integrator))
    (got, auto), (expected, _) = runs["spring"], runs["rigid"]
    assert auto.name == "genalpha"
    assert auto.stats.nsteps < 100, auto.stats.nsteps      # measured 13 (6705 before)
    assert float(np.max(np.abs(got - expected))) < TOL
