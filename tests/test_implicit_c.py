"""genalpha and ali3p in the C kernel (integrators/implicit_c.py, ckernel/implicit.h)
against their Python path and against closed forms.

The C step is meant to be the Python step (newton.py's iteration) on another linear
solver, so the two must agree to a small fraction of the method's own error; if one of
them changes (the Newton test, the predictor) without the other, these tests fail. The
errors are against P1's elliptic solution and P2's exact one-degree-of-freedom reduction
(bench/closed_forms.py), over a segment of P2 that passes its first singular crossing.
"""
import tomllib
from pathlib import Path

import numpy as np
import pytest

import mbdfmu
from mbdfmu.bench import closed_forms
from mbdfmu.equations import ckernel
from mbdfmu.integrators import implicit_c
from mbdfmu.model.reader import scene_from_dict

SCENES = Path(__file__).resolve().parents[1] / "scenes"

pytestmark = pytest.mark.skipif(not ckernel.available(), reason="no C compiler for the kernel")

STEPS = (4e-3, 2e-3, 1e-3)
# P1 over 1 s; P2 N = 2 over 0.6 s (its cranks pass the horizontal, a singular
# configuration, near t = 0.45 s)
CASES = {"pendulum": 1.0, "n_four_bar_2": 0.6}


def tip(res, scene: str):
    """(x, y) of P1's bob or of P2's B0 over the run, and the exact ones."""
    if scene == "pendulum":
        ex = closed_forms.pendulum(res.time)
        return np.stack([res["bob.x"], res["bob.y"]]), np.stack([ex["x"], ex["y"]])
    phi = res["crank0.phi"]
    got = np.stack([res["crank0.x"] + 0.5 * np.cos(phi), res["crank0.y"] + 0.5 * np.sin(phi)])
    ex = closed_forms.n_four_bar_B0(res.time, 2)
    return got, np.stack([ex["x"], ex["y"]])


def run(scene, method, h, compiled, monkeypatch, **options):
    monkeypatch.setattr(implicit_c, "ENABLED", compiled)
    sim = mbdfmu.Simulation(mbdfmu.load_scene(scene), method=method, step=h, kernel="c", method_options=options)
    assert (sim.integrator.c_newton is not None) == compiled
    res = mbdfmu.simulate(scene, CASES[scene], method=method, step=h, kernel="c",
                          output_interval=0.02, method_options=options)
    return tip(res, scene)


@pytest.mark.parametrize("scene", list(CASES))
@pytest.mark.parametrize("method", ["genalpha", "ali3p"])
def test_c_and_python_steps_agree_and_converge_at_order_two(scene, method, monkeypatch):
    errors = []
    for h in STEPS:
        got_c, exact = run(scene, method, h, True, monkeypatch)
        got_py, _ = run(scene, method, h, False, monkeypatch)
        error = float(np.max(np.hypot(*(got_py - exact))))
        difference = float(np.max(np.hypot(*(got_c - got_py))))
        # measured: differences 1e-5 to 1e-4 of the error (rounding of another solver)
        assert difference <= 1e-2 * error, (h, difference, error)
        errors.append(float(np.max(np.hypot(*(got_c - exact)))))
    ratios = [errors[0] / errors[1], errors[1] / errors[2]]
    assert all(3.0 < r < 5.5 for r in ratios), (errors, ratios)


def test_step_control_agrees_with_the_python_step(monkeypatch):
    """genalpha with step control on P1: the C attempts and the error filter through the
    kept matrix (implicit_control.py) take about the same steps as the Python ones."""
    results = {}
    for compiled in (True, False):
        monkeypatch.setattr(implicit_c, "ENABLED", compiled)
        results[compiled] = mbdfmu.simulate("pendulum", 0.3, method="genalpha", kernel="c",
                                            rtol=1e-6, output_interval=0.05,
                                            method_options={"step_control": "adaptive"})
    a, b = results[True], results[False]
    # the controller's thresholds turn rounding differences into other step sequences
    # (measured 703 and 701 steps), each within the tolerance
    assert abs(a.stats["nsteps"] - b.stats["nsteps"]) <= 0.03 * b.stats["nsteps"]
    for res in (a, b):
        got, exact = tip(res, "pendulum")
        error = float(np.max(np.hypot(*(got - exact))))
        assert error < 5e-6      # measured 1.7e-6 (rtol 1e-6 of 1 m per second)
    assert float(np.max(np.abs(a["bob.x"] - b["bob.x"]))) <= 0.05 * error   # measured 0.5 %


def test_what_the_c_step_covers_and_how():
    """A spring to the ground gives K 3 x 3 blocks (banded Schur complement); translational
    joints (line rows) and forces of the state between two moving bodies the dense LU
    (implicit_dense.h); beyond DENSE_MAX unknowns the Python step."""
    for scene, method, blocks, dense in (
            (mbdfmu.load_scene("slider_crank"), "genalpha", 0, 1),
            (mbdfmu.load_scene("rod_pendulum"), "ali3p", 0, 0),
            (mbdfmu.load_scene("andrews"), "genalpha", 1, 0),
            (spring_pendulum(1e8), "genalpha", 1, 0),
            (spring_pendulum(1e8, between_bodies=True), "ali3p", 0, 1)):
        newton = mbdfmu.Simulation(scene, method=method, kernel="c").integrator.c_newton
        assert (newton.settings.blocks, newton.settings.dense) == (blocks, dense), scene.name
    big = mbdfmu.load_scene("n_four_bar_40")        # no line rows: banded, whatever its size
    assert not mbdfmu.Simulation(big, method="ali3p", kernel="c").integrator.c_newton.dense


def test_a_dense_case_beyond_its_size_runs_in_python(monkeypatch):
    monkeypatch.setattr(implicit_c, "DENSE_MAX", 8)      # the slider-crank: n + m = 9 + 9
    sim = mbdfmu.Simulation(mbdfmu.load_scene("slider_crank"), method="genalpha", kernel="c")
    assert sim.integrator.c_newton is None


def spring_pendulum(k: float, between_bodies: bool = False):
    """The shipped stiff spring (P1's link a spring, scenes/stiff_spring.toml) with
    stiffness k (N/m); with ``between_bodies`` hung from a second, pinned body instead of
    the ground."""
    with open(SCENES / "stiff_spring.toml", "rb") as f:
        data = tomllib.load(f)
    data["force"][0]["stiffness"] = k
    if between_bodies:
        data["body"].append({"name": "hook", "mass": 1.0, "inertia": 1.0, "position": [0.0, 0.0]})
        data["joint"] = [{"name": "pin", "type": "revolute", "body_i": "ground",
                          "point_i": [0.0, 0.0], "body_j": "hook", "point_j": [0.0, 0.0]}]
        data["force"][0]["body_i"] = "hook"
    return scene_from_dict(data)


@pytest.mark.parametrize("method", ["genalpha", "ali3p"])
def test_blocks_with_constraints_agree_on_andrews(method, monkeypatch):
    """Andrews' squeezer (a spring to the ground, seven bodies): the C step with K's
    blocks and the Python step agree far inside the method's error (its change from h to
    h / 2)."""
    runs = {}
    for h, compiled in ((2e-5, True), (2e-5, False), (1e-5, True)):
        monkeypatch.setattr(implicit_c, "ENABLED", compiled)
        res = mbdfmu.simulate("andrews", 0.003, method=method, step=h, kernel="c",
                              output_interval=5e-4)
        runs[h, compiled] = np.stack([res[n] for n in res.names if n.endswith(".phi")])
    error = float(np.max(np.abs(runs[2e-5, True] - runs[1e-5, True])))
    difference = float(np.max(np.abs(runs[2e-5, True] - runs[2e-5, False])))
    assert difference <= 1e-6 * error, (difference, error)    # measured 1e-15 against 1e-6


def test_a_stiff_spring_under_auto_meets_its_tolerance_in_c(monkeypatch):
    """auto sends a 1e10 N/m spring to genalpha with step control (integrators/choose.py):
    its attempts in C with K's block, against the rigid pendulum's closed form, which the
    spring follows to about 3 m g / k."""
    results = {}
    for compiled in (True, False):
        monkeypatch.setattr(implicit_c, "ENABLED", compiled)
        results[compiled] = mbdfmu.simulate(spring_pendulum(1e10), 0.2, method="auto",
                                            output_interval=0.01)
    res = results[True]
    assert res.method == "auto->genalpha"
    exact = closed_forms.pendulum(res.time, J=1e-6)
    error = float(np.max(np.hypot(res["bob.x"] - exact["x"], res["bob.y"] - exact["y"])))
    assert error < 1e-6, error          # measured 4.3e-7 (the default tolerance: 1e-6 m)
    assert res.stats["nsteps"] == results[False].stats["nsteps"]
    assert float(np.max(np.abs(res["bob.x"] - results[False]["bob.x"]))) <= 1e-3 * error


@pytest.mark.parametrize("scene, method, control", [
    ("n_four_bar_2", "genalpha", "fixed"), ("slider_crank", "genalpha", "fixed"),
    ("slider_crank", "ali3p", "fixed"), ("slider_crank", "genalpha", "adaptive")])
def test_a_saved_state_continues_bit_for_bit(scene, method, control):
    """The kept iteration matrix is part of the run's state (an FMU's saved state), the
    banded one (P2) and the dense LU (the slider-crank); with step control the controller's
    step too (its runs of steps in C, integrators/implicit_runs.py)."""
    sim = mbdfmu.Simulation(mbdfmu.load_scene(scene), method=method, step=1e-3, kernel="c",
                            method_options={"step_control": control})
    sim.advance(0.3)
    saved = sim.integrator.get_state()
    sim.advance(0.5)
    first = sim.integrator.q.copy()
    sim.integrator.set_state(saved)
    sim.advance(0.5)
    assert np.array_equal(sim.integrator.q, first)
