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
from event_checks import CHECKS, check_events

SETTINGS = {"default": {}, "rtol 1e-10": dict(rtol=1e-10, atol=1e-10), "rk4p": dict(method="rk4p"),
            "rk45p": dict(method="rk45p")}


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


def test_revolute_friction_and_stop_on_a_torqued_disc():
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
    res = mbdfmu.simulate(scene, t_end=2.0, output_interval=0.05)
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
        scene.forces[0], value=0.4),)), t_end=0.5, output_interval=0.1)
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
