"""The bench's P8-P11 cases: the package's closed forms (bench/closed_forms.py) agree with the
tests' independent ones, and each case's error function reads round-off for a tight run and
the closed form's own difference for a perturbed scene."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from mbdfmu.bench import cases, sweep
from mbdfmu.bench import closed_forms as pkg

import exact_solutions as ref

T = np.linspace(0.0, 2.0, 21)


def test_package_closed_forms_match_the_independent_ones():
    for ratio, inertia_out in ((-0.5, 0.04), (0.05, 0.5)):
        mine = pkg.geared(T, torque=0.1, inertia_in=0.005, inertia_out=inertia_out, ratio=ratio)
        theirs = ref.geared_pair(T, torque=0.1, J_in=0.005, inertia_out=inertia_out, ratio=ratio)
        np.testing.assert_allclose(mine["q_in"], theirs["q_in"], rtol=1e-15)
        np.testing.assert_allclose(mine["q_out"], theirs["q_out"], rtol=1e-15)
    mine = pkg.disc_on_incline(T, mass=2.0, inertia=0.01, radius=0.1, slope=math.pi / 6, start=2.0)
    theirs = ref.rolling_incline(T, m=2.0, J=0.01, r=0.1, slope=math.pi / 6, s0=2.0)
    for k in ("x", "y", "phi"):
        np.testing.assert_allclose(mine[k], theirs[k], atol=1e-14)
    mine, theirs = pkg.rod_in_slot(T), ref.slot_rod(T)
    for k in ("theta", "y", "phi"):
        np.testing.assert_allclose(mine[k], theirs[k], atol=1e-11)


@pytest.mark.parametrize("key", ["P8", "P9", "P10", "P11"])
def test_error_of_a_tight_run_is_round_off_and_of_a_perturbed_scene_its_difference(key):
    case = cases.CASES[key]
    scene = cases.case_scene(case)
    t_out = np.linspace(0.0, 1.0, 11)
    out, _, _, reason = sweep.simulate_outputs(scene, t_out, "dop853p", "rtol", 1e-11, math.inf)
    assert not reason and cases.ERRORS[key](case, scene, t_out, out, {}) < 1e-9
    # gravity 1e-3 stronger (P10, P11) or a heavier output body (P8, P9): the error is the
    # distance between the two closed-form motions (the tests' own closed forms)
    if key in ("P10", "P11"):
        other = dataclasses.replace(scene, gravity=(0.0, -ref.G * 1.001))
    else:
        heavier = dataclasses.replace(scene.bodies[1], mass=scene.bodies[1].mass * 1.001,
                                      inertia=scene.bodies[1].inertia * 1.001)
        other = dataclasses.replace(scene, bodies=(scene.bodies[0], heavier))
    out, _, _, reason = sweep.simulate_outputs(other, t_out, "dop853p", "rtol", 1e-11, math.inf)
    assert not reason
    assert cases.ERRORS[key](case, scene, t_out, out, {}) == pytest.approx(
        _closed_form_distance(key, t_out), rel=1e-6)


def _closed_form_distance(key, t):
    """The largest difference the case's error measures between the scene's closed-form
    motion and the perturbed one."""
    if key in ("P8", "P9"):
        torque, J_in, out, ratio = ((0.1, 0.005, 0.04, -0.5) if key == "P8"
                                    else (0.05, 0.00125, 0.5, 0.05))
        a, b = (ref.geared_pair(t, torque=torque, J_in=J_in, inertia_out=out * f, ratio=ratio)
                for f in (1.0, 1.001))
        return max(np.abs(a["q_in"] - b["q_in"]).max(), np.abs(a["q_out"] - b["q_out"]).max())
    if key == "P10":
        a, b = (ref.rolling_incline(t, m=2.0, J=0.01, r=0.1, slope=math.pi / 6, s0=2.0, g=g)
                for g in (ref.G, ref.G * 1.001))
        return np.hypot(a["x"] - b["x"], a["y"] - b["y"]).max()
    a, b = (ref.slot_rod(t, g=g) for g in (ref.G, ref.G * 1.001))
    return max(np.abs(a["phi"] - b["phi"]).max(), np.abs(a["y"] - b["y"]).max())
