"""Monolithic reference of the dc_motor_slider_crank scenario: one ODE, integrated by scipy.

Independent of mbdfmu's equations: the slider-crank has one degree of freedom, the crank
angle theta, and P4's kinematics (../../docs/problems.md) give every body's
position as a function of theta. With ``M(theta)`` the generalized inertia (the kinetic
energy is ``M theta'^2 / 2``), Lagrange's equation and the armature circuit are

    M theta'' + M'(theta) theta'^2 / 2 = kt i + Q_gravity(theta) - c_O theta' - c_load x_B,theta^2 theta'
    L di/dt = V - R i - ke theta'

where ``x_B,theta`` is the slider's velocity per unit crank rate. Only the data (masses,
inertias, dampers, lengths, motor constants) come from the scene and the connections file.
"""

from __future__ import annotations

import math

import numpy as np
from scipy.integrate import solve_ivp

import mbdfmu


def kinematics(theta: float, r: float, l: float) -> dict:
    """Positions of the centres of mass and their first and second derivatives in theta
    (P4 with a unit crank rate): keys x1, y1, x2, y2, xB, phi, each a (value, d/dtheta,
    d2/dtheta2) triple."""
    s, c = math.sin(theta), math.cos(theta)
    sphi = -(r / l) * s
    cphi = math.sqrt(1.0 - sphi * sphi)
    phi1 = -r * c / (l * cphi)
    phi2 = (r * s + l * phi1 ** 2 * sphi) / (l * cphi)
    xB = (r * c + l * cphi, -r * s - l * sphi * phi1,
          -r * c - l * cphi * phi1 ** 2 - l * sphi * phi2)
    return {
        "x1": (r / 2 * c, -r / 2 * s, -r / 2 * c),
        "y1": (r / 2 * s, r / 2 * c, -r / 2 * s),
        "x2": ((r * c + xB[0]) / 2, (-r * s + xB[1]) / 2, (-r * c + xB[2]) / 2),
        "y2": (r * s / 2, r * c / 2, -r * s / 2),
        "xB": xB,
        "phi": (math.atan2(sphi, cphi), phi1, phi2),
    }


def _data(scenario) -> dict:
    scene = mbdfmu.load_scene(scenario.instance("mechanism").source)
    p = {q.name: q.value for q in mbdfmu.parameters(scene)}
    joints = {j.name: j for j in scene.joints}
    r = math.dist(joints["A"].point_i, joints["O"].point_j)   # on the crank: O to A
    l = math.dist(joints["B"].point_i, joints["A"].point_j)   # on the rod: A to B
    motor = scenario.instance_parameters("motor")
    return dict(r=r, l=l, g=-p["gravity.y"], m1=p["crank.mass"], J1=p["crank.inertia"],
                m2=p["rod.mass"], J2=p["rod.inertia"], m3=p["slider.mass"],
                c_O=p["bearing.damping"], c_load=p["load.damping"], **motor)


def rhs(t, y, d):
    theta, omega, i = y
    k = kinematics(theta, d["r"], d["l"])
    (_, x1t, x1tt), (_, y1t, y1tt) = k["x1"], k["y1"]
    (_, x2t, x2tt), (_, y2t, y2tt) = k["x2"], k["y2"]
    (_, xBt, xBtt), (_, pt, ptt) = k["xB"], k["phi"]
    M = (d["m1"] * (x1t ** 2 + y1t ** 2) + d["J1"] + d["m2"] * (x2t ** 2 + y2t ** 2)
         + d["J2"] * pt ** 2 + d["m3"] * xBt ** 2)
    dM = 2 * (d["m1"] * (x1t * x1tt + y1t * y1tt) + d["m2"] * (x2t * x2tt + y2t * y2tt)
              + d["J2"] * pt * ptt + d["m3"] * xBt * xBtt)
    Q = (d["kt"] * i - d["g"] * (d["m1"] * y1t + d["m2"] * y2t)
         - d["c_O"] * omega - d["c_load"] * xBt ** 2 * omega)
    return [omega, (Q - 0.5 * dM * omega ** 2) / M,
            (d["voltage"] - d["R"] * i - d["ke"] * omega) / d["L"]]


def reference(scenario, times) -> dict[str, np.ndarray]:
    """The scenario's variables at ``times`` (rtol 1e-12), named as the co-simulation names
    them."""
    d = _data(scenario)
    times = np.asarray(times, dtype=float)
    sol = solve_ivp(rhs, (0.0, float(times[-1])), [0.0, 0.0, d["i0"]], method="DOP853",
                    t_eval=times, rtol=1e-12, atol=1e-12, args=(d,))
    if not sol.success:
        raise RuntimeError(f"reference ODE failed: {sol.message}")
    theta, omega, i = sol.y
    xB = np.array([kinematics(th, d["r"], d["l"])["xB"] for th in theta])
    return {"mechanism.crank.phi": theta, "mechanism.crank.omega": omega,
            "motor.current": i, "motor.torque": d["kt"] * i,
            "mechanism.slider.x": xB[:, 0], "mechanism.slider.vx": xB[:, 1] * omega}
