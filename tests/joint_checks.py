"""The P8-P11 scenes' results against their closed forms (tests/exact_solutions.py).

``CHECKS[scene](time, result)`` asserts positions to 1e-8 and reactions and efforts to 1e-6
relative; ``result[name]`` is an output's values at ``time``: a ``mbdfmu.Result`` or the
structured array of ``fmpy.simulate_fmu``, so the same checks judge ``simulate()`` and the
FMUs.
"""

from __future__ import annotations

import math

import numpy as np

import exact_solutions as ref

POSITION_TOL, REACTION_RTOL = 1e-8, 1e-6


def close(actual, expected, tol=POSITION_TOL):
    np.testing.assert_allclose(actual, expected, rtol=0, atol=tol)


def close_rel(actual, expected):
    expected = np.broadcast_to(np.asarray(expected, dtype=float), np.shape(actual))
    np.testing.assert_allclose(actual, expected, rtol=REACTION_RTOL,
                               atol=REACTION_RTOL * np.abs(expected).max())


def gear_pair(t, res):
    g = ref.G
    ex = ref.geared_pair(t, torque=0.1, J_in=0.005, inertia_out=0.04, ratio=-0.5)
    close(res["pinion.phi"], ex["q_in"])
    close(res["wheel.phi"], ex["q_out"])
    close(res["wheel.omega"], -0.5 * ex["alpha"] * t)
    for body, x in (("pinion", 0.0), ("wheel", 0.3)):
        close(res[f"{body}.x"], x)
        close(res[f"{body}.y"], 0.0)
    close_rel(res["mesh.effort"], ex["effort"])
    # the bearings carry the weights only (the coupler loads no bearing), in the discs' frames
    for joint, body, m in (("bearing_in", "pinion", 1.0), ("bearing_out", "wheel", 2.0)):
        phi = res[f"{body}.phi"]
        close_rel(np.hypot(res[f"{joint}.Fx"], res[f"{joint}.Fy"]), m * g)
        close(res[f"{joint}.Fx"], m * g * np.sin(phi), REACTION_RTOL * m * g)
        close(res[f"{joint}.Fy"], m * g * np.cos(phi), REACTION_RTOL * m * g)
        assert np.abs(res[f"{joint}.Tz"]).max() < 1e-9


def rack_pinion(t, res):
    ex = ref.geared_pair(t, torque=0.05, J_in=0.00125, inertia_out=0.5, ratio=0.05)
    close(res["pinion.phi"], ex["q_in"])
    close(res["rack.x"], ex["q_out"])
    close(res["rack.y"], -0.05)
    close(res["rack.phi"], 0.0)
    close_rel(res["mesh.effort"], ex["effort"])              # N, on the rack along the guide
    close_rel(res["guide.Fy"], 0.5 * ref.G)                   # the rack's weight
    assert np.abs(res["guide.Fx"]).max() < 1e-12
    assert np.abs(res["guide.Tz"]).max() < 1e-9               # the mesh force acts at its centre
    close_rel(res["bearing.Fx"] ** 2 + res["bearing.Fy"] ** 2, ref.G ** 2)


def rolling_disc(t, res):
    ex = ref.rolling_incline(t, m=2.0, J=0.01, r=0.1, slope=math.pi / 6, s0=2.0)
    close(res["disc.x"], ex["x"])
    close(res["disc.y"], ex["y"])
    close(res["disc.phi"], ex["phi"])
    close_rel(res["contact.Fx"], ex["friction"])             # up the slope
    close_rel(res["contact.Fy"], ex["normal"])


def slot_rod(t, res):
    ex = ref.slot_rod(t)
    assert np.abs(res["rod.x"] - ex["x"]).max() < 1e-12      # no horizontal force at all
    close(res["rod.y"], ex["y"])
    close(res["rod.phi"], ex["phi"])
    pin_y = res["rod.y"] - 0.5 * np.sin(res["rod.phi"])       # point_j = (-0.5, 0) on the slot
    assert np.abs(pin_y).max() < 1e-10
    assert np.abs(res["slot.Fx"]).max() < 1e-12
    close_rel(res["slot.Fy"], ex["Fy"])


CHECKS = {"gear_pair": gear_pair, "rack_pinion": rack_pinion, "rolling_disc": rolling_disc,
          "slot_rod": slot_rod}
