"""End stops with restitution and Coulomb friction (issue 14) against closed forms.

The shipped scenes slider_stop, incline_stick and incline_slide run through ``simulate()`` and
through their FMUs in fmpy at the default settings and at rtol 1e-10: positions to 1e-8, the
stop's, friction and normal forces to 1e-6 relative, every transition at its closed-form time
to 1e-9 s (``event_checks.py``). The FMUs: test_limit_fmus.py.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

import mbdfmu
from mbdfmu.errors import MbdfmuError

import exact_solutions as ref
from event_checks import CHECKS, CRANE_ACTUATOR, CRANE_HOLD, check_events, crane_actuator

# "C kernel": the modes with a stop or a sticking joint evaluated in C (each attempt a C
# call), the sliding ones on the numpy kernel; what every FMU runs by default
SETTINGS = {"default": {}, "rtol 1e-10": dict(rtol=1e-10, atol=1e-10), "rk4p": dict(method="rk4p"),
            "rk45p": dict(method="rk45p"), "C kernel": dict(kernel="c"),
            "C kernel, rtol 1e-10": dict(kernel="c", rtol=1e-10, atol=1e-10),
            "C kernel, rk4p": dict(kernel="c", method="rk4p")}


@pytest.mark.parametrize("setting", SETTINGS)
@pytest.mark.parametrize("name", CHECKS)
def test_simulate_matches_the_closed_form(name, setting):
    res = mbdfmu.simulate(ref.SCENES / f"{name}.toml", **SETTINGS[setting])
    CHECKS[name](res.time, res)
    check_events(name, res.events)


def test_an_event_inside_a_fixed_step_is_located_inside_it():
    # rk4p with 0.25 s steps: the first impact at 1.366 s falls inside the step from 1.25 s
    res = mbdfmu.simulate(ref.SCENES / "slider_stop.toml", method="rk4p", step=0.25,
                          output_interval=0.5)
    CHECKS["slider_stop"](res.time, res)
    check_events("slider_stop", res.events)


def test_contact_leaves_when_the_stop_would_pull():
    # the slider resting on its stop is pulled away by a force that turns at t = 0.5 s:
    # the stop lets go when its force crosses zero, then x = (t - 0.5)^2 / 2 (a = 1 m/s^2)
    scene = mbdfmu.load_scene(ref.SCENES / "slider_stop.toml")
    body = dataclasses.replace(scene.bodies[0], position=(0.0, 0.0), velocity=(0.0, 0.0))
    scene = dataclasses.replace(scene, bodies=(body,))
    pull = lambda t: np.array([t - 0.5, 0.0])                   # noqa: E731
    f = dataclasses.replace(scene.forces[0], input=True)
    scene = dataclasses.replace(scene, forces=(f,))
    res = mbdfmu.simulate(scene, t_end=1.0, output_interval=0.1, inputs={"push": pull})
    assert res.events[0][2] == "rests against its lower stop" and res.events[0][0] == 0.0
    assert res.events[1][2] == "leaves its lower stop"
    assert abs(res.events[1][0] - 0.5) < 1e-9
    t = res.time
    np.testing.assert_allclose(res["slider.x"], np.where(t > 0.5, (t - 0.5) ** 3 / 6, 0.0),
                               rtol=0, atol=1e-8)
    np.testing.assert_allclose(res["guide.limit"], np.where(t < 0.5, 0.5 - t, 0.0), rtol=0,
                               atol=1e-9)


def test_bad_limit_and_friction_keys_get_one_line_errors(tmp_path):
    base = (ref.SCENES / "slider_stop.toml").read_text()
    bad = {
        "limits = [0.0, 2.0]": ("limits = [2.0, 0.0]", "lower 2 is not below upper 0"),
        "restitution = 0.5": ("restitution = 1.5", "restitution must be between 0 and 1"),
    }
    cases = [base.replace(old, new) for old, (new, _) in bad.items()]
    cases.append(base.replace("restitution = 0.5", "friction = { coefficient = -0.1 }"))
    cases.append(base.replace("restitution = 0.5", "friction = { coulomb = 1, radius = 0.1 }"))
    cases.append(base.replace("restitution = 0.5", "friction = { coefficent = 0.1 }"))
    cases.append(base.replace("position = [0.5, 0.0]", "position = [2.5, 0.0]"))
    expected = [w for _, w in bad.values()] + [
        "coefficient", "friction.radius is for revolute joints only", "coefficent",
        "outside its limits"]
    for k, (text, what) in enumerate(zip(cases, expected)):
        path = tmp_path / f"bad{k}.toml"
        path.write_text(text)
        with pytest.raises(MbdfmuError) as info:
            mbdfmu.simulate(path)
        message = str(info.value)
        assert what in message and "\n" not in message, message
        assert "guide" in message or "limits" in message


def test_implicit_methods_are_refused_with_a_reason():
    with pytest.raises(MbdfmuError, match="does not locate the events"):
        mbdfmu.simulate(ref.SCENES / "slider_stop.toml", method="genalpha")


def test_state_round_trip_continues_bit_for_bit():
    sim = mbdfmu.Simulation(mbdfmu.load_scene(ref.SCENES / "incline_slide.toml"))
    sim.advance(0.2)
    state = sim.get_state()
    sim.advance(0.5)
    first = sim.output_vector()
    sim.set_state(state)
    sim.advance(0.5)
    np.testing.assert_array_equal(sim.output_vector(), first)


def test_check_reports_stops_friction_and_their_rows(capsys, tmp_path):
    from mbdfmu.cli import main

    assert main(["check", str(ref.SCENES / "slider_stop.toml")]) == 0
    out = capsys.readouterr().out
    assert "limits [0, 2] restitution 0.5" in out
    assert "end stops on guide" in out and "at the start: guide free: 0 rows held" in out
    # resting on its stop at the start: the stop's row is held, no degree of freedom left
    text = (ref.SCENES / "slider_stop.toml").read_text()
    path = tmp_path / "resting.toml"
    path.write_text(text.replace("position = [0.5, 0.0]", "position = [0.0, 0.0]")
                    .replace("velocity = [1.0, 0.0]", "velocity = [0.0, 0.0]"))
    assert main(["check", str(path)]) == 0
    assert "guide lower: 1 rows held, degrees of freedom 0" in capsys.readouterr().out
    path.write_text(text.replace("restitution = 0.5", "restitution = -1"))
    assert main(["check", str(path)]) != 0
    err = capsys.readouterr().err.strip()
    assert "restitution must be between 0 and 1" in err and "\n" not in err


@pytest.mark.parametrize("kernel", [None, "c"])
def test_revolute_friction_and_stop_on_a_torqued_disc(kernel):
    # a 2 kg disc (J = 0.5 kg m^2) on a ground bearing at its centre, torque 2 N.m, friction
    # 0.5 + 0.1 x 0.05 m x |F| (|F| = m g: the bearing carries the weight), stop at 1 rad:
    # slides with alpha = (2 - bound) / J, hits the stop at sqrt(2 / alpha) s and rests on it
    # (restitution 0), the stop then holding the whole torque (-2 N.m) and friction 0
    bound = 0.5 + 0.1 * 0.05 * 2.0 * ref.G
    alpha = (2.0 - bound) / 0.5
    scene = mbdfmu.model.scene_from_dict({
        "name": "disc", "gravity": [0.0, -ref.G],
        "body": [{"name": "disc", "mass": 2.0, "inertia": 0.5, "position": [0.0, 0.0]}],
        "joint": [{"name": "bearing", "type": "revolute", "body_i": "ground", "body_j": "disc",
                   "limits": [-1.0, 1.0],
                   "friction": {"coulomb": 0.5, "coefficient": 0.1, "radius": 0.05}}],
        "force": [{"name": "drive", "type": "torque", "body": "disc", "value": 2.0}]})
    res = mbdfmu.simulate(scene, t_end=2.0, output_interval=0.05, kernel=kernel)
    hit = math.sqrt(2.0 / alpha)
    assert [e[2].split()[0] for e in res.events] == ["slips:", "hits"]
    assert res.events[0][0] == 0.0 and abs(res.events[1][0] - hit) < 1e-9
    t = res.time
    np.testing.assert_allclose(res["disc.phi"], np.minimum(0.5 * alpha * t * t, 1.0), rtol=0,
                               atol=1e-8)
    moving = t < hit
    np.testing.assert_allclose(res["bearing.friction"], np.where(moving, -bound, 0.0),
                               rtol=1e-6)
    np.testing.assert_allclose(res["bearing.limit"], np.where(moving, 0.0, -2.0), rtol=1e-6)
    # below the bound it sticks: friction holds the torque
    held = mbdfmu.simulate(dataclasses.replace(scene, forces=(dataclasses.replace(
        scene.forces[0], value=0.4),)), t_end=0.5, output_interval=0.1, kernel=kernel)
    assert [e[2] for e in held.events] == ["sticks"]
    np.testing.assert_allclose(held["disc.phi"], 0.0, atol=1e-12)
    np.testing.assert_allclose(held["bearing.friction"], -0.4, rtol=1e-9)


def test_output_derivatives_follow_the_contact_mode():
    # sliding down the incline: block.vx' = a cos 30, the friction constant; sticking on the
    # stop side (incline_stick after its stop): every derivative zero
    from mbdfmu.simulation import output_time_derivatives
    from event_checks import C, G, S

    sim = mbdfmu.Simulation(mbdfmu.load_scene(ref.SCENES / "incline_slide.toml"))
    sim.advance(1.0)
    first, _ = output_time_derivatives(sim)
    d = dict(zip(sim.output_names, first))
    assert d["block.vx"] == pytest.approx(G * (S - 0.2 * C) * C, rel=1e-6)
    assert abs(d["ramp.friction"]) < 1e-6
    sim = mbdfmu.Simulation(mbdfmu.load_scene(ref.SCENES / "incline_stick.toml"))
    sim.advance(1.0)
    first, second = output_time_derivatives(sim)
    assert np.abs(first).max() < 1e-6 and np.abs(second).max() < 1e-3


def test_a_body_held_at_rest_does_not_stall_dop853p():
    # sticking, the block's rates are round-off: dop853p's error estimate must not become 0 / 0
    res = mbdfmu.simulate(ref.SCENES / "incline_stick.toml", method="dop853p", rtol=1e-4,
                          atol=1e-4)
    CHECKS["incline_stick"](res.time, res)


def test_analysis_refuses_stops_and_friction_in_one_line():
    with pytest.raises(MbdfmuError) as info:
        mbdfmu.equilibrium(ref.SCENES / "incline_stick.toml")
    assert "do not handle joint limits or friction" in str(info.value)
    assert "\n" not in str(info.value)


def test_the_c_kernel_projects_a_scene_with_stops_on_psi_alone():
    # as projection.project_positions: a q whose constraints are met within the tolerance is
    # left as it is (a Newton increment more would move what the stops' rows hold)
    from mbdfmu.equations.limits import ModeEquations
    from mbdfmu.equations.projection import project_positions

    scene = mbdfmu.load_scene(ref.SCENES / "crane_stop.toml")
    sim = mbdfmu.Simulation(scene, kernel="c")
    eq = ModeEquations(scene, {}, kernel="c")
    tol = 1e-9
    q = sim.q + 0.2 * tol * np.cos(np.arange(sim.q.size))        # Psi within tol, not zero
    assert 0 < np.max(np.abs(eq.constraint_values(0.0, q)[0])) <= tol
    expected, _ = project_positions(eq, 0.0, q, tol=tol)
    assert np.array_equal(expected, q)
    projected, _ = eq.ckernel.project(q, sim.qd, eq.motion_values(0.0), tol, 10)
    assert np.array_equal(projected, q)


def _swinging_rod(coefficient: float):
    # a 1 m, 2 kg rod (J = 1/6 kg m^2) on a ground pivot at one end, turning at 3 rad/s,
    # friction 0.2 N m + coefficient x 0.05 m x |F|: the bearing force |F| (weight,
    # centripetal and tangential) depends on the friction torque, which depends on |F|
    return mbdfmu.model.scene_from_dict({
        "name": "rod", "gravity": [0.0, -ref.G],
        "body": [{"name": "rod", "mass": 2.0, "inertia": 1.0 / 6.0, "position": [0.5, 0.0],
                  "velocity": [0.0, 1.5], "angular_velocity": 3.0}],
        "joint": [{"name": "pivot", "type": "revolute", "body_i": "ground", "body_j": "rod",
                   "point_i": [0.0, 0.0], "point_j": [-0.5, 0.0],
                   "friction": {"coulomb": 0.2, "coefficient": coefficient, "radius": 0.05}}]})


def test_sliding_friction_in_c_iterates_as_the_numpy_path():
    # the C kernel's friction iteration (ckernel/friction.h) against the numpy one of
    # ModeEquations, at a state where the bearing force and the friction torque are coupled
    from mbdfmu.equations.limits import ModeEquations

    scene = _swinging_rod(0.8)
    q = np.array([0.4, 0.3, 0.6435011087932844])
    qd = np.array([-0.9, 1.2, 3.0])
    got = {}
    for kernel in ("numpy", "c"):
        eq = ModeEquations(scene, {0: 1}, kernel=kernel)
        qdd, lam = eq.accelerations(0.0, q, qd)
        got[kernel] = qdd, lam, float(eq.last_friction[0])
    (qdd0, lam0, f0), (qdd1, lam1, f1) = got["numpy"], got["c"]
    np.testing.assert_allclose(qdd1, qdd0, rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(lam1, lam0, rtol=1e-12, atol=1e-12)
    assert f1 == pytest.approx(f0, rel=1e-13) and f0 < -0.2
    # the bearing's force is that of the rod's acceleration and weight, and the friction is
    # its bound: the Coulomb torque plus coefficient x radius x that force
    r = q[:2]
    force = 2.0 * qdd1[:2] - 2.0 * np.array([0.0, -ref.G])
    assert -f1 == pytest.approx(0.2 + 0.8 * 0.05 * math.hypot(*force), rel=1e-12)
    assert math.hypot(*r) == pytest.approx(0.5)


def test_sliding_friction_that_cannot_converge_stops_with_its_reason():
    # coefficient x radius too large: neither kernel finds the friction torque
    from mbdfmu.equations.limits import ModeEquations
    from mbdfmu.errors import SolverError

    scene = _swinging_rod(400.0)
    q = np.array([0.4, 0.3, 0.6435011087932844])
    for kernel in ("numpy", "c"):
        eq = ModeEquations(scene, {0: 1}, kernel=kernel)
        with pytest.raises(SolverError, match="sliding friction of pivot does not converge"):
            eq.accelerations(0.0, q, np.array([-0.9, 1.2, 3.0]))


def test_sliding_friction_in_c_on_a_turning_guide():
    # a slider in a guide on a turning arm (offset pins, the guide's axis not along the arm):
    # the C kernel's coordinate gradient and normal force (friction.h) against the numpy
    # path's, whose gradient is held to finite differences of the coordinate
    from mbdfmu.equations.limits import Coordinate, ModeEquations

    scene = mbdfmu.model.scene_from_dict({
        "name": "arm", "gravity": [0.0, -ref.G],
        "body": [{"name": "arm", "mass": 3.0, "inertia": 0.4, "position": [0.5, 0.1]},
                 {"name": "slider", "mass": 1.0, "inertia": 0.02, "position": [0.9, 0.5],
                  "angle": 0.3}],
        "joint": [{"name": "hub", "type": "revolute", "body_i": "ground", "body_j": "arm",
                   "point_i": [0.0, 0.0], "point_j": [-0.5, -0.1]},
                  {"name": "guide", "type": "translational", "body_i": "arm",
                   "body_j": "slider", "axis_i": [0.9, 0.2], "point_i": [0.1, 0.05],
                   "point_j": [-0.05, 0.02], "frame_angle": 0.4,
                   "friction": {"coulomb": 0.3, "coefficient": 0.25}}],
        "force": [{"name": "drive", "type": "torque", "body": "arm", "value": 5.0}]})
    q = np.array([0.45, 0.2, 0.25, 0.8, 0.55, 0.4])
    qd = np.array([-0.1, 0.3, 2.0, -0.6, 1.1, 1.7])
    coordinate = Coordinate(scene, scene.joints[1])
    step = 1e-7
    numeric = [(coordinate.value(q + step * e) - coordinate.value(q - step * e)) / (2 * step)
               for e in np.eye(6)]
    np.testing.assert_allclose(coordinate.gradient(q), numeric, atol=1e-8)
    got = {}
    for kernel in ("numpy", "c"):
        eq = ModeEquations(scene, {1: -1}, kernel=kernel)
        qdd, lam = eq.accelerations(0.0, q, qd)
        got[kernel] = np.concatenate((qdd, lam, eq.last_friction))
    np.testing.assert_allclose(got["c"], got["numpy"], rtol=1e-11, atol=1e-11)
    assert got["c"][-1] > 0.3                 # sliding down: the force pushes up, past F0


@pytest.mark.parametrize("method", ["auto", "rk4p", "rk45p"])
def test_an_input_that_releases_a_resting_stop_releases_it_at_that_instant(method, tmp_path):
    """crane_stop with its cylinder force as an input, set before every 1 ms step: the boom
    falls onto its lower stop and rests there, the stop's force CRANE_HOLD - u (closed
    form: the stop and the actuator push along the same stroke); the first step whose force
    exceeds CRANE_HOLD lets it leave at its start, with every method. Before, the watch
    after a step missed a sign the input had changed at the step's start: the boom left
    at times that depended on the method (dop853p and rk45p 0.07 s apart), and with rk4p
    never."""
    path = tmp_path / "crane_force.toml"
    path.write_text((ref.SCENES / "crane_stop.toml").read_text() + CRANE_ACTUATOR)
    sim = mbdfmu.Simulation(mbdfmu.load_scene(path), method=method, kernel="c")
    limits = []
    for k in range(900):
        sim.set_input("cylinder.actuator", crane_actuator(k))
        sim.advance((k + 1) * 1e-3)
        limits.append(sim.outputs()["stroke.limit"])
    leave = next(k for k in range(900) if crane_actuator(k) > CRANE_HOLD)
    assert [e[1:] for e in sim.events.log if "leaves its" in e[2]] == [
        ("stroke", "leaves its lower stop")]
    assert [e[0] for e in sim.events.log if "leaves its" in e[2]] == [leave * 1e-3]
    rest = next(e[0] for e in sim.events.log if "rests" in e[2])
    resting = range(int(rest / 1e-3) + 1, leave)
    np.testing.assert_allclose([limits[k] for k in resting],
                               [CRANE_HOLD - crane_actuator(k) for k in resting],
                               rtol=0, atol=1e-6 * CRANE_HOLD)


@pytest.mark.parametrize("method", ["auto", "rk4p", "rk45p"])
def test_an_input_that_breaks_static_friction_slips_the_block_at_that_instant(method, tmp_path):
    """incline_stick (mu = 0.8 on 30 degrees) with a force input on the block along the
    ramp, downhill, rising by 0.01 N a 1 ms step from t = 0.8 s: sticking, the friction
    holds m g sin 30 + F (closed form) within its bound mu m g cos 30, and the block slips
    downhill at the start of the first step whose force exceeds the bound, with every
    method (the friction's margin that the input made negative at a step's start)."""
    path = tmp_path / "incline_pull.toml"
    path.write_text((ref.SCENES / "incline_stick.toml").read_text()
                    + '[[force]]\nname = "pull"\ntype = "force"\nbody = "block"\ninput = true\n')
    sim = mbdfmu.Simulation(mbdfmu.load_scene(path), method=method, kernel="c")
    weight, bound = 9.81 * 0.5, 0.8 * 9.81 * math.cos(math.pi / 6)

    def pull(k):
        return 0.0 if k < 800 else 0.01 * (k - 800)
    friction = []
    for k in range(1100):
        sim.set_input("pull.fx", pull(k) * math.cos(math.pi / 6))
        sim.set_input("pull.fy", -pull(k) * 0.5)
        sim.advance((k + 1) * 1e-3)
        friction.append(sim.outputs()["ramp.friction"])
    slip = next(k for k in range(1100) if weight + pull(k) > bound)
    assert [e[1:] for e in sim.events.log[2:]] == [("ramp", "slips: its coordinate rising")]
    assert sim.events.log[2][0] == slip * 1e-3
    sticking = range(200, slip)
    np.testing.assert_allclose([friction[k] for k in sticking],
                               [-(weight + pull(k)) for k in sticking], rtol=1e-9)


def test_events_that_do_not_let_the_time_advance_stop_the_run_with_a_reason(monkeypatch):
    # modes that chatter at one instant (each event's transition leaving the next one due
    # at the same time: here every impact of slider_stop handled without moving the state
    # on) used to loop for ever inside one advance: an FMU hung its host. The runner stops
    # after MAX_EVENTS_AT_ONCE events at one time, with a SolverError naming them.
    from mbdfmu.integrators import events
    monkeypatch.setattr(events, "MAX_EVENTS_AT_ONCE", 50)

    def handle_in_place(self, integrator, crossed, g1):
        self.log.append((float(integrator.t), "guide", "hits its lower stop (in place)"))
        if len(self.log) > 10_000:                      # without the guard: fail, not hang
            raise RuntimeError("the event loop did not stop")
        integrator.set_state(self.watching[0])          # the time does not advance
    monkeypatch.setattr(events.EventRunner, "_handle", handle_in_place)
    sim = mbdfmu.Simulation(ref.SCENES / "slider_stop.toml", method="rk4p", kernel="numpy")
    with pytest.raises(mbdfmu.SolverError, match=r"51 events at t = .* without the time "
                                                 r"advancing .*joint guide"):
        sim.advance(2.0)
