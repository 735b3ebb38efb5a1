"""Closed forms of the end-stop and friction scenes (issue 14) and their checks.

``EVENTS[scene]`` are the closed-form times (s) of the scene's transitions, ``CHECKS[scene](t,
res)`` assert positions and rates to 1e-8 and the stop's, friction and normal forces to 1e-6
relative; ``res[name]`` is a ``mbdfmu.Result`` or fmpy's structured array. Nothing here imports
mbdfmu: the numbers come from Newton's laws of a block on a line, and for the crane from its
one-degree-of-freedom Lagrange equation integrated by scipy between impacts.
"""

from __future__ import annotations

import math

import numpy as np
from scipy.integrate import solve_ivp
from scipy.optimize import brentq

from mbdfmu.scenes import variants

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


# ----------------------------------------------------------------- crane boom on its end stop
# Boom angle phi; pivot at the origin; boom centre 1 m out (150 kg, J 50 about it); cylinder
# from G = (0.4, -0.6) to B = 0.8 (cos phi, sin phi); barrel (J 2) centred at G, rod (10 kg,
# J 1) centred at B; the cylinder's length L = |B - G| stops at 0.7 m, restitution 0.3.
CRANE_G, CRANE_B, CRANE_LOW, CRANE_E = np.array([0.4, -0.6]), 0.8, 0.7, 0.3
CRANE_GRAVITY_LOAD = (150.0 + 10.0 * CRANE_B) * G          # V(phi) = this x sin(phi)


def crane_theta_rate(phi):
    """d theta / d phi of the cylinder's direction (complex-safe: complex-step derivative)."""
    dx, dy = CRANE_B * np.cos(phi) - CRANE_G[0], CRANE_B * np.sin(phi) - CRANE_G[1]
    return CRANE_B * (dx * np.cos(phi) + dy * np.sin(phi)) / (dx * dx + dy * dy)


def crane_length(phi):
    return math.hypot(CRANE_B * math.cos(phi) - CRANE_G[0], CRANE_B * math.sin(phi) - CRANE_G[1])


def crane_length_rate(phi):
    """dL / d phi = (B - G) . dB/dphi / L."""
    dx, dy = CRANE_B * math.cos(phi) - CRANE_G[0], CRANE_B * math.sin(phi) - CRANE_G[1]
    return CRANE_B * (-dx * math.sin(phi) + dy * math.cos(phi)) / math.hypot(dx, dy)


def _crane_rhs(t, y):
    phi, w = y
    th = crane_theta_rate(phi)
    dth = (crane_theta_rate(phi + 1e-30j)).imag / 1e-30     # complex step: exact to round-off
    mass = 200.0 + 10.0 * CRANE_B ** 2 + 3.0 * th * th     # boom about the pivot, rod, J_b + J_r
    return [w, -(3.0 * th * dth * w * w + CRANE_GRAVITY_LOAD * math.cos(phi)) / mass]


def crane_reference(t_end=1.5, settle=1e-7):
    """(impact times, rest time, rest angle, segments): the boom released at rest from 0.2 rad,
    each impact at L = 0.7 m reversing phi' times -0.3, until a flight is below ``settle`` s."""
    rest_angle = brentq(lambda p: crane_length(p) - CRANE_LOW, -0.5, 0.2)
    hit = lambda t, y: crane_length(y[0]) - CRANE_LOW       # noqa: E731
    hit.terminal, hit.direction = True, -1
    t0, y0, impacts, segments = 0.0, [0.2, 0.0], [], []
    options = dict(method="DOP853", rtol=1e-13, atol=1e-15, dense_output=True)
    while True:
        start = t0
        if impacts:     # the first half of the flight (2 v / a) without the event: it starts on it
            half = t0 + abs(y0[1] / _crane_rhs(t0, y0)[1])
            sol = solve_ivp(_crane_rhs, (t0, half), y0, **options)
            segments.append((t0, half, sol.sol))
            start, y0 = half, sol.y[:, -1]
        sol = solve_ivp(_crane_rhs, (start, t_end), y0, events=hit, **options)
        segments.append((start, sol.t[-1], sol.sol))
        if not sol.t_events[0].size:
            return impacts, None, rest_angle, segments
        t1 = float(sol.t_events[0][0])
        impacts.append(t1)
        if impacts[-2:-1] and t1 - t0 < settle:
            # flights this short see a constant acceleration: the rest ones sum to e / (1 - e)
            # times the last
            return impacts, t1 + (t1 - t0) * CRANE_E / (1 - CRANE_E), rest_angle, segments
        t0, y0 = t1, [rest_angle, -CRANE_E * sol.y_events[0][0][1]]


CRANE = crane_reference()


def crane_stop(t, res):
    impacts, rest, rest_angle, segments = CRANE
    phi, w = np.full_like(t, rest_angle), np.zeros_like(t)
    for a, b, sol in segments:
        inside = (t >= a) & (t <= b) & (t < rest)
        if inside.any():
            phi[inside], w[inside] = sol(t[inside])
    close(res["boom.phi"], phi)
    close(res["boom.omega"], w)
    close(res["boom.x"], np.cos(phi))
    close(res["rod.y"], CRANE_B * np.sin(phi))
    limit = CRANE_GRAVITY_LOAD * math.cos(rest_angle) / crane_length_rate(rest_angle)
    close_rel(res["stroke.limit"], np.where(t > rest, limit, 0.0), limit)


# crane_stop with an actuator force between barrel and rod along the stroke (N, positive
# pushing them apart, as a hydraulic cylinder's): resting on the lower stop, the stop's
# force and the actuator's add up to the one that holds the boom, so the stop's force is
# CRANE_HOLD - u, and the boom leaves the stop at the first input above CRANE_HOLD
CRANE_HOLD = CRANE_GRAVITY_LOAD * math.cos(CRANE[2]) / crane_length_rate(CRANE[2])
CRANE_ACTUATOR = variants.CYLINDER


def crane_actuator(k: int, h: float = 1e-3) -> float:
    """The cylinder force (N) set before communication step k of h: pulling in while the
    boom falls onto its lower stop and comes to rest, then rising past CRANE_HOLD."""
    return -1000.0 if k < 800 else 1e5 * (k - 800) * h


CHECKS = {"slider_stop": slider_stop, "incline_stick": _incline(0.8),
          "incline_slide": _incline(0.2), "crane_stop": crane_stop}


def expected_events(name: str, count: int) -> list[tuple[float, str, str]]:
    """The closed form's first ``count`` transitions: (time, joint, first word of what)."""
    if name == "slider_stop":       # the last impact rests: at the accumulation time
        return [(float(tk), "guide", "hits") for tk in slider_impacts(count)]
    if name == "crane_stop":        # the reference's impacts, then the rest at its accumulation
        impacts = CRANE[0][:count - 1]
        return ([(tk, "stroke", "hits") for tk in impacts]
                + [(None, "stroke", "hits")] * (count - 1 - len(impacts)) + [(CRANE[1], "stroke",
                                                                             "hits")])
    if name == "incline_stick":
        return [(incline_times(0.8), "ramp", "stops"), (incline_times(0.8), "ramp", "sticks")]
    return [(incline_times(0.2), "ramp", "stops"), (incline_times(0.2), "ramp", "slips:")]


def check_events(name: str, events) -> None:
    """Transition times to 1e-9 s, in order; a slider's rest at the accumulation time."""
    expected = expected_events(name, len(events))
    assert [(j, w.split()[0]) for _, j, w in events] == [(j, w) for _, j, w in expected]
    known = [k for k, e in enumerate(expected) if e[0] is not None]
    np.testing.assert_allclose([events[k][0] for k in known], [expected[k][0] for k in known],
                               rtol=0, atol=1e-9)
    if name in ("slider_stop", "crane_stop"):
        assert len(events) > 15 and "rests" in events[-1][2]
        rest = SLIDER_REST if name == "slider_stop" else CRANE[1]
        assert abs(events[-1][0] - rest) < 1e-9
