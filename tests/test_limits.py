"""End stops with restitution and Coulomb friction (issue 14) against closed forms.

The shipped scenes slider_stop, incline_stick and incline_slide run through ``simulate()`` and
through their FMUs in fmpy at the default settings and at rtol 1e-10: positions to 1e-8, the
stop's, friction and normal forces to 1e-6 relative, every transition at its closed-form time
to 1e-9 s (``event_checks.py``). The FMUs: test_limit_fmus.py.
"""

from __future__ import annotations

import dataclasses

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
