"""Monolithic reference of the hydraulic_crane scenario: one ODE, integrated by scipy.

Independent of mbdfmu's equations. Two degrees of freedom: the boom angle ``a`` (from +x)
and the load's swing angle ``b`` (from the downward vertical). With the boom's inertia
about the pivot ``I = J_boom + m_boom d^2`` (d: pivot to centre), the tip at ``L_b`` and
the load's centre ``L_p`` below the hook, Lagrange's equations are

    (I + m_p L_b^2) a'' + C sin(b - a) b'' + C cos(b - a) b'^2 = Q_a
    (J_p + m_p L_p^2) b'' + C sin(b - a) a'' - C cos(b - a) a'^2 = -m_p g L_p sin b

with ``C = m_p L_b L_p`` and ``Q_a = -(m_boom d + m_p L_b) g cos a + F ds/da``, where the
cylinder of length ``s(a) = |K(a) - G|`` (K on the boom at ``e`` from the pivot) pushes
with F. The hydraulics are the companion's equations (pressures in chambers A and B), and
the valve command its trapezoid, both evaluated exactly in time here.
"""

from __future__ import annotations

import importlib.util
import math
from pathlib import Path

import numpy as np
from scipy.integrate import solve_ivp

import mbdfmu

HERE = Path(__file__).resolve().parent


def _module(name: str):
    spec = importlib.util.spec_from_file_location(f"_crane_ref_{name}", HERE / f"{name}.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def _data(scenario) -> dict:
    scene = mbdfmu.load_scene(scenario.instance("mechanism").source)
    p = {q.name: q.value for q in mbdfmu.parameters(scene)}
    joints = {j.name: j for j in scene.joints}
    cyl = next(f for f in scene.forces if f.name == "cylinder")
    d = -joints["pivot"].point_j[0]                        # pivot to the boom's centre
    return dict(g=-p["gravity.y"], mb=p["boom.mass"], Ib=p["boom.inertia"] + p["boom.mass"] * d ** 2,
                d=d, Lb=joints["hook"].point_i[0] + d, mp=p["load.mass"], Jp=p["load.inertia"],
                Lp=-joints["hook"].point_j[0], G=np.array(cyl.point_i), e=cyl.point_j[0] + d,
                hyd=scenario.instance_parameters("hydraulics"),
                cmd=scenario.instance_parameters("command"))


def cylinder(a: float, ad: float, D: dict):
    """Length s, rate s' and ds/da of the cylinder at boom angle a and rate ad."""
    K = D["e"] * np.array([math.cos(a), math.sin(a)])
    dK = D["e"] * np.array([-math.sin(a), math.cos(a)])
    r = K - D["G"]
    s = float(np.hypot(*r))
    dsda = float(r @ dK) / s
    return s, dsda * ad, dsda


def reference(scenario, times) -> dict[str, np.ndarray]:
    """The scenario's variables at ``times`` (rtol 1e-11), named as the co-simulation names
    them (``mechanism.boom.phi`` is the boom angle, ``mechanism.load.phi = b - pi/2``)."""
    D = _data(scenario)
    hyd, cmd = D["hyd"], D["cmd"]
    cyl_model = _module("hydraulic_cylinder")
    trapezoid = _module("valve_command").trapezoid
    orifice = cyl_model.orifice
    k = hyd["Q_nom"] / math.sqrt(hyd["dp_nom"])
    C = D["mp"] * D["Lb"] * D["Lp"]
    A11, A22 = D["Ib"] + D["mp"] * D["Lb"] ** 2, D["Jp"] + D["mp"] * D["Lp"] ** 2

    def flows(u, pA, pB):
        u = max(-1.0, min(1.0, u))
        ps, pt, dpt = hyd["p_supply"], hyd["p_tank"], hyd["dp_t"]
        if u >= 0:
            qa, qb = k * u * orifice(ps - pA, dpt), -k * u * orifice(pB - pt, dpt)
        else:
            qa, qb = -k * -u * orifice(pA - pt, dpt), k * -u * orifice(ps - pB, dpt)
        leak = hyd["C_leak"] * (pA - pB)
        return qa - leak, qb + leak

    def force(y):
        a, b, ad, bd, pA, pB = y
        _, sd, _ = cylinder(a, ad, D)
        return pA * hyd["A_A"] - pB * hyd["A_B"] - hyd["b"] * sd

    def rhs(t, y):
        a, b, ad, bd, pA, pB = y
        s, sd, dsda = cylinder(a, ad, D)
        F = pA * hyd["A_A"] - pB * hyd["A_B"] - hyd["b"] * sd
        Qa = -(D["mb"] * D["d"] + D["mp"] * D["Lb"]) * D["g"] * math.cos(a) + F * dsda
        Qb = -D["mp"] * D["g"] * D["Lp"] * math.sin(b)
        sn, cs = math.sin(b - a), math.cos(b - a)
        M = np.array([[A11, C * sn], [C * sn, A22]])
        rhs2 = np.array([Qa - C * cs * bd ** 2, Qb + C * cs * ad ** 2])
        add, bdd = np.linalg.solve(M, rhs2)
        x = s - hyd["s_min"]
        VA = hyd["V_A0"] + hyd["A_A"] * x
        VB = hyd["V_B0"] + hyd["A_B"] * (hyd["stroke"] - x)
        u = trapezoid(t, cmd["t_open"], cmd["t_close"], cmd["ramp"], cmd["opening"])
        qa, qb = flows(u, pA, pB)
        return [ad, bd, add, bdd, hyd["beta"] / VA * (qa - hyd["A_A"] * sd),
                hyd["beta"] / VB * (qb + hyd["A_B"] * sd)]

    scene = mbdfmu.load_scene(scenario.instance("mechanism").source)
    a0 = next(b.angle for b in scene.bodies if b.name == "boom")
    pA0 = (hyd["force0"] + hyd["pB0"] * hyd["A_B"]) / hyd["A_A"]
    times = np.asarray(times, dtype=float)
    # The valve command has kinks: integrate piecewise so the error control never steps
    # across one.
    kinks = [cmd["t_open"], cmd["t_open"] + cmd["ramp"], cmd["t_close"], cmd["t_close"] + cmd["ramp"]]
    bounds = sorted({0.0, float(times[-1])} | {t for t in kinks if 0 < t < times[-1]})
    y = [a0, 0.0, 0.0, 0.0, pA0, hyd["pB0"]]
    rows = np.empty((len(times), 6))
    for lo, hi in zip(bounds[:-1], bounds[1:]):
        sel = (times >= lo) & (times <= hi)
        sol = solve_ivp(rhs, (lo, hi), y, method="DOP853", rtol=1e-11, atol=1e-9,
                        t_eval=times[sel], dense_output=True)
        if not sol.success:
            raise RuntimeError(f"reference ODE failed: {sol.message}")
        rows[sel] = sol.y.T
        y = sol.sol(hi)
    a, b, ad, bd, pA, pB = rows.T
    F = np.array([force(r) for r in rows])
    tip = D["Lb"] * np.stack([np.cos(a), np.sin(a)])
    return {"mechanism.boom.phi": a, "mechanism.boom.omega": ad,
            "mechanism.load.phi": b - math.pi / 2, "mechanism.load.omega": bd,
            "mechanism.load.x": tip[0] + D["Lp"] * np.sin(b),
            "mechanism.load.y": tip[1] - D["Lp"] * np.cos(b),
            "hydraulics.force": F, "hydraulics.p_A": pA, "hydraulics.p_B": pB,
            "mechanism.cylinder.length": np.array([cylinder(x, 0, D)[0] for x in a])}
