"""Closed forms of the end-stop and friction scenes (issue 14) and their checks.

``EVENTS[scene]`` are the closed-form times (s) of the scene's transitions, ``CHECKS[scene](t,
res)`` assert positions and rates to 1e-8 and the stop's, friction and normal forces to 1e-6
relative; ``res[name]`` is a ``mbdfmu.Result`` or fmpy's structured array. Nothing here imports
mbdfmu: the numbers come from Newton's laws of a block on a line.
"""

from __future__ import annotations

import math

import numpy as np

G = 9.81
POSITION_TOL, FORCE_RTOL = 1e-8, 1e-6
SQ3 = math.sqrt(3.0)


def close(actual, expected, tol=POSITION_TOL):
    np.testing.assert_allclose(actual, np.broadcast_to(expected, np.shape(actual)), rtol=0,
                               atol=tol)


def close_rel(actual, expected, scale):
    close(actual, expected, FORCE_RTOL * scale)


# ----------------------------------------------------------------- slider against a stop
# x'' = -2 m/s^2 towards the stop at 0; thrown from 0.5 m at +1 m/s; restitution 0.5.
SLIDER_A, SLIDER_E = 2.0, 0.5
SLIDER_T1 = (1.0 + SQ3) / 2.0                                # x = 0.5 + t - t^2 = 0
SLIDER_V1 = SQ3                                              # speed at the first impact
SLIDER_REST = SLIDER_T1 + 2 * SLIDER_E * SLIDER_V1 / (SLIDER_A * (1 - SLIDER_E))


def slider_impacts(count: int) -> np.ndarray:
    """The first ``count`` impact times: each flight 2 v / a, v halved at every impact."""
    flights = 2 * SLIDER_V1 * SLIDER_E ** np.arange(1, count) / SLIDER_A
    return SLIDER_T1 + np.concatenate(([0.0], np.cumsum(flights)))


def slider_stop_motion(t):
    """x, vx of the slider at times t (the closed form, bounce by bounce)."""
    t = np.asarray(t, dtype=float)
    x, v = 0.5 + t - t * t, 1.0 - 2.0 * t
    impacts = slider_impacts(60)
    for k, tk in enumerate(impacts):
        vk = SLIDER_V1 * SLIDER_E ** (k + 1)                 # leaving the stop
        s = t >= tk
        tau = t[s] - tk
        x[s], v[s] = vk * tau - tau * tau, vk - 2.0 * tau
    rest = t >= SLIDER_REST
    x[rest], v[rest] = 0.0, 0.0
    return x, v


def slider_stop(t, res):
    x, v = slider_stop_motion(t)
    close(res["slider.x"], x)
    close(res["slider.vx"], v)
    close(res["slider.y"], 0.0)
    close_rel(res["guide.Fy"], G, G)                         # the weight, normal to the guide
    close_rel(res["guide.limit"], np.where(t > SLIDER_REST, SLIDER_A, 0.0), SLIDER_A)


# ----------------------------------------------------------------- blocks on an incline
SLOPE = math.radians(30.0)
C, S = math.cos(SLOPE), math.sin(SLOPE)
V0 = 2.0                                                     # thrown up the slope (m/s)


def incline_times(mu: float) -> float:
    """When the block thrown up the slope stops: its deceleration is g (sin + mu cos)."""
    return V0 / (G * (S + mu * C))


def incline_motion(t, mu: float):
    """(s, s', friction) along the slope's axis (down the slope), the block thrown up."""
    t = np.asarray(t, dtype=float)
    up = G * (S + mu * C)
    ts = incline_times(mu)
    s, rate = -V0 * t + 0.5 * up * t * t, -V0 + up * t
    friction = np.full_like(t, mu * G * C)                  # opposes the upward slide
    after = t >= ts
    s_top, tau = -V0 * ts + 0.5 * up * ts * ts, t[after] - ts
    if mu > S / C:                                           # it sticks: friction holds the weight
        s[after], rate[after], friction[after] = s_top, 0.0, -G * S
    else:                                                    # it slides back down
        down = G * (S - mu * C)
        s[after], rate[after] = s_top + 0.5 * down * tau * tau, down * tau
        friction[after] = -mu * G * C
    return s, rate, friction


def _incline(mu):
    def check(t, res):
        s, rate, friction = incline_motion(t, mu)
        close(res["block.x"], s * C)
        close(res["block.y"], -s * S)
        close(res["block.vx"], rate * C)
        close(res["block.vy"], -rate * S)
        close_rel(res["ramp.Fy"], G * C, G * C)             # normal reaction m g cos
        ts = incline_times(mu)
        at_stop = np.abs(t - ts) < 1e-9                      # the output at the stop itself
        close_rel(res["ramp.friction"][~at_stop], friction[~at_stop], G)
    return check


CHECKS = {"slider_stop": slider_stop, "incline_stick": _incline(0.8),
          "incline_slide": _incline(0.2)}


def expected_events(name: str, count: int) -> list[tuple[float, str, str]]:
    """The closed form's first ``count`` transitions: (time, joint, first word of what)."""
    if name == "slider_stop":       # the last impact rests: at the accumulation time
        return [(float(tk), "guide", "hits") for tk in slider_impacts(count)]
    if name == "incline_stick":
        return [(incline_times(0.8), "ramp", "stops"), (incline_times(0.8), "ramp", "sticks")]
    return [(incline_times(0.2), "ramp", "stops"), (incline_times(0.2), "ramp", "slips:")]


def check_events(name: str, events) -> None:
    """Transition times to 1e-9 s, in order; a slider's rest at the accumulation time."""
    expected = expected_events(name, len(events))
    assert [(j, w.split()[0]) for _, j, w in events] == [(j, w) for _, j, w in expected]
    np.testing.assert_allclose([e[0] for e in events], [e[0] for e in expected], rtol=0,
                               atol=1e-9)
    if name == "slider_stop":
        assert len(events) > 30 and "rests" in events[-1][2]
        assert abs(events[-1][0] - SLIDER_REST) < 1e-9
