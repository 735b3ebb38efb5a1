"""The Exudyn models of benchmarks/exudyn_compare.py are the same physics as our scenes:
checked against the independent closed forms of tests/exact_solutions.py (P1 elliptic, P2's
one-DOF reduction, P4's kinematics and driving torque), the crane against our dop853p at a
tight tolerance, genalpha's order, and the script's bookkeeping (failed runs are
rows, the CPU time to a level, the exit status without Exudyn). No timing asserts."""

from __future__ import annotations

import importlib.util
import math
import sys
from pathlib import Path

import numpy as np
import pytest

import exact_solutions as ref  # tests/exact_solutions.py: independent of mbdfmu

exu = pytest.importorskip("exudyn")

ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def ec():
    """benchmarks/exudyn_compare.py as a module (benchmarks/ is not a package)."""
    spec = importlib.util.spec_from_file_location("exudyn_compare",
                                                  ROOT / "benchmarks" / "exudyn_compare.py")
    mod = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = mod  # its dataclasses look their module up there
    try:
        spec.loader.exec_module(mod)
        yield mod
    finally:
        sys.modules.pop(spec.name, None)


def _final_point(ec, key, *, step, t_end):
    problem = ec.PROBLEMS[key]
    scene = ec.load_problem_scene(problem)
    model = ec.exudyn_model(scene)
    info = ec.solve_exudyn(model, step=step, t_end=t_end)
    assert info["status"] == "ok", info["reason"]
    assert info["nsteps"] == round(t_end / step)  # no step reductions on the way
    return ec.exudyn_point(model, problem.body, problem.point), scene


def test_p1_exudyn_pendulum_follows_the_elliptic_solution(ec):
    (x, y), scene = _final_point(ec, "P1", step=1e-4, t_end=2.0)
    bob = scene.bodies[0]
    exact = ref.simple_pendulum(np.array([2.0]), L=1.0, m=bob.mass, J=bob.inertia)
    err = math.hypot(x - exact["x"][0], y - exact["y"][0])
    assert err < 1e-5  # genalpha at 0.1 ms: about 2e-7


def test_p2_exudyn_double_four_bar_follows_the_reduction_through_a_singular_pass(ec):
    # By t = 1 s the cranks have passed the horizontal once (at t = 0.71 s).
    (x, y), _ = _final_point(ec, "P2N2", step=1e-4, t_end=1.0)
    exact = ref.n_four_bar(np.array([1.0]), 2)
    assert math.hypot(x - exact["B0_x"][0], y - exact["B0_y"][0]) < 1e-5


def test_exudyn_genalpha_error_falls_as_h_squared(ec):
    errors = []
    for h in (2e-3, 1e-3):
        (x, y), scene = _final_point(ec, "P1", step=h, t_end=2.0)
        exact = ref.simple_pendulum(np.array([2.0]), J=scene.bodies[0].inertia)
        errors.append(math.hypot(x - exact["x"][0], y - exact["y"][0]))
    assert 3.0 < errors[0] / errors[1] < 5.0


def test_run_rows_error_and_failures(ec, monkeypatch):
    problem = ec.PROBLEMS["P2N2"]
    scene = ec.load_problem_scene(problem)
    row = ec.run_exudyn(problem, scene, step=1e-3, t_end=0.5)
    assert row["status"] == "ok" and row["error"] < 1e-4 and row["nsteps"] == 500
    row = ec.run_mbdfmu(problem, scene, method="rk4p", kind="step", setting=1e-2, t_end=0.5)
    assert row["status"] == "ok" and row["error"] < 1e-6

    def failing(*args, **kwargs):
        raise ec.mbdfmu.SolverError("no convergence", 0.7144)

    monkeypatch.setattr(ec.mbdfmu, "Simulation", failing)
    row = ec.run_mbdfmu(problem, scene, method="genalpha", kind="step", setting=1e-3, t_end=1.0)
    assert row["status"] == "failed" and "no convergence" in row["reason"]
    assert row["error"] == "" and "from the horizontal" in row["note"]


def test_cheapest_run_per_level_and_ratio(ec):
    def r(tool, method, err, cpu, status="ok"):
        return {"problem": "P1", "tool": tool, "method": method, "kind": "step", "setting": 1.0,
                "status": status, "error": err, "cpu_s": cpu}

    rows = [r("exudyn", "genalpha", 1e-3, 0.1), r("exudyn", "genalpha", 1e-5, 1.0),
            r("exudyn", "genalpha", "", 9.0, status="failed"),
            r("mbdfmu", "dop853p", 1e-5, 0.2), r("mbdfmu", "dop853p", 1e-7, 0.3),
            r("mbdfmu", "rk4p", 1e-9, 5.0)]
    table = ec.level_table(rows, "P1")
    at = {e["level"]: e for e in table}
    assert at[1e-4]["exudyn"]["cpu_s"] == 1.0 and at[1e-4]["mbdfmu_best"][1] == "dop853p"
    assert at[1e-4]["ratio"] == pytest.approx(0.2)
    assert at[1e-6]["exudyn"] is None and "ratio" not in at[1e-6]
    assert at[1e-8]["mbdfmu_best"][:2] == (5.0, "rk4p")


def test_without_exudyn_the_script_says_how_to_install_it(ec, monkeypatch, capsys):
    monkeypatch.setattr(ec, "exu", None)
    assert ec.main(["--quick"]) == 2
    assert "pip install exudyn" in capsys.readouterr().err


# The slider-crank (P4) and the crane's mechanism: translational joint, driver, point load,
# actuated spring-damper translated as well.

W = 314.1592653589793  # rad/s: scenes/slider_crank.toml's motor


def test_p4_exudyn_slider_crank_follows_the_closed_form_and_its_torque(ec):
    scene = ec.mbdfmu.load_scene(ROOT / "scenes" / "slider_crank.toml")
    t_end = 0.0155  # crank at 279 deg: the slider fast, the torque far from zero
    model = ec.exudyn_model(scene)
    info = ec.solve_exudyn(model, step=1e-4, t_end=t_end)
    assert info["status"] == "ok" and info["nsteps"] == 155
    exact = ref.slider_crank(np.array([W * t_end]), W, r=0.1, l=0.3, crank_mass=0.2,
                             crank_inertia=1.6667e-4, rod_mass=0.2, rod_inertia=1.5e-3,
                             slider_mass=0.4, load=(-10.0, 0.0))
    x, y = ec.exudyn_point(model, "slider", (0.0, 0.0))
    assert abs(x - exact["xB"][0]) < 1e-9 and abs(y) < 1e-12   # the driver is exact
    # The motor's torque is minus the driver constraint's multiplier (peak about 356 N m).
    torque = -float(model.mbs.GetObjectOutput(model.drivers["motor"], exu.OutputVariableType.Force))
    assert exact["torque"][0] > 80.0 and abs(torque - exact["torque"][0]) < 1.0  # about 0.11


def _crane(ec):
    return ec.mbdfmu.load_scene(ROOT / "scenarios" / "hydraulic_crane" / "crane.toml")


def _load_position(ec, model):
    return np.array(ec.exudyn_point(model, "load", (0.0, 0.0)))


def _exudyn_crane_load(ec, scene, force, *, push, step, t_end):
    model = ec.exudyn_model(scene, actuators={"cylinder": push})
    ec.set_before_each_step(model, "cylinder", force)
    info = ec.solve_exudyn(model, step=step, t_end=t_end)
    assert info["status"] == "ok" and info["nsteps"] == round(t_end / step)
    return np.array(ec.exudyn_point(model, "load", (0.0, 0.0)))


def test_crane_exudyn_with_its_force_held_and_set_per_step_matches_dop853p(ec):
    """The cylinder's sign (positive pushes the boom up) and the per-step setting, against our
    adaptive method at a tight tolerance, its input held over each 1 ms as a master sets it."""
    scene, push, t_end = _crane(ec), 8840.0, 0.5   # 5 % over the force that holds the boom

    def swing(t):  # sampled at the start of each 1 ms communication step
        return push * (1.0 + 0.2 * math.sin(20.0 * math.floor(t / 1e-3 + 1e-6) * 1e-3))

    errors = {}
    for name, force in (("held", lambda t: push), ("swing", swing)):
        sim = ec.mbdfmu.Simulation(scene, method="dop853p", rtol=1e-11, atol=1e-13)
        for k in range(round(t_end / 1e-3)):
            sim.set_input("cylinder.actuator", force(k * 1e-3))
            sim.advance((k + 1) * 1e-3)
        out = sim.outputs()
        assert out["load.y"] + 0.6026613384098776 > 0.05   # lifted, not held
        for step in (1e-3, 2.5e-4):
            load = _exudyn_crane_load(ec, scene, force, push=push, step=step, t_end=t_end)
            errors[name, step] = math.hypot(load[0] - out["load.x"], load[1] - out["load.y"])
    assert errors["held", 1e-3] < 1e-6   # about 2e-8
    # A force that jumps every 1 ms costs genalpha its second order: first order, about 1e-4
    # at 1 ms, converging to our solution as its step shrinks.
    assert errors["swing", 1e-3] < 3e-4
    assert 3.0 < errors["swing", 1e-3] / errors["swing", 2.5e-4] < 5.0
