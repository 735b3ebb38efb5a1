"""Monolithic reference of the cart_pendulum_pid scenario: one ODE, integrated by scipy.

Independent of mbdfmu's equations. Cart position x, pole angle theta from the upright
(theta = phi - pi/2, positive to the left), pole centre at l_c from the hinge, pole inertia
J about its centre:

    (M + m) x'' - m l_c cos(theta) theta'' + m l_c sin(theta) theta'^2 = F
    (J + m l_c^2) theta'' - m l_c cos(theta) x'' = m g l_c sin(theta)

closed by the controller's law (continuous: the limit of a vanishing communication step)
with its integral state z' = x - x_ref(t), integrated piecewise around the set-point step.
"""

from __future__ import annotations

import math

import numpy as np
from scipy.integrate import solve_ivp

import mbdfmu


def _data(scenario) -> dict:
    scene = mbdfmu.load_scene(scenario.instance("mechanism").source)
    p = {q.name: q.value for q in mbdfmu.parameters(scene)}
    hinge = next(j for j in scene.joints if j.name == "hinge")
    pole = next(b for b in scene.bodies if b.name == "pole")
    return dict(M=p["cart.mass"], m=p["pole.mass"], J=p["pole.inertia"], g=-p["gravity.y"],
                lc=-hinge.point_j[0], phi0=pole.angle, c=scenario.instance_parameters("controller"))


def reference(scenario, times) -> dict[str, np.ndarray]:
    """The scenario's variables at ``times`` (rtol 1e-11)."""
    D = _data(scenario)
    c = D["c"]
    M, m, J, g, lc = D["M"], D["m"], D["J"], D["g"], D["lc"]

    def force(t, y, x_ref):
        x, th, v, om, z = y
        f = (c["kp_x"] * (x - x_ref) + c["ki_x"] * z + c["kd_x"] * v
             + c["kp_phi"] * (th + math.pi / 2 - c["phi_ref"]) + c["kd_phi"] * om)
        return max(-c["force_max"], min(c["force_max"], f))

    def rhs(t, y, x_ref):
        x, th, v, om, z = y
        F = force(t, y, x_ref)
        s, co = math.sin(th), math.cos(th)
        A = np.array([[M + m, -m * lc * co], [-m * lc * co, J + m * lc ** 2]])
        b = np.array([F - m * lc * s * om ** 2, m * g * lc * s])
        xdd, thdd = np.linalg.solve(A, b)
        return [v, om, xdd, thdd, x - x_ref]

    times = np.asarray(times, dtype=float)
    ts = c["t_step"]
    pieces = [(0.0, min(ts, times[-1]), c["x_ref0"])]
    if ts < times[-1]:
        pieces.append((ts, float(times[-1]), c["x_ref1"]))
    y = [0.0, D["phi0"] - math.pi / 2, 0.0, 0.0, 0.0]
    rows = np.empty((len(times), 5))
    refs = np.empty(len(times))
    for k, (lo, hi, x_ref) in enumerate(pieces):
        sel = (times >= lo) & ((times < hi) if k < len(pieces) - 1 else (times <= hi))
        sol = solve_ivp(rhs, (lo, hi), y, method="DOP853", rtol=1e-11, atol=1e-12,
                        t_eval=times[sel], dense_output=True, args=(x_ref,))
        if not sol.success:
            raise RuntimeError(f"reference ODE failed: {sol.message}")
        rows[sel] = sol.y.T
        refs[sel] = x_ref
        y = sol.sol(hi)
    x, th, v, om, z = rows.T
    F = np.array([force(t, r, xr) for t, r, xr in zip(times, rows, refs)])
    return {"mechanism.cart.x": x, "mechanism.cart.vx": v,
            "mechanism.pole.phi": th + math.pi / 2, "mechanism.pole.omega": om,
            "controller.force": F, "controller.x_ref": refs,
            "mechanism.pole.x": x - lc * np.sin(th), "mechanism.pole.y": lc * np.cos(th)}
