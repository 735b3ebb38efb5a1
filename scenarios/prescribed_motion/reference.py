"""Closed-form reference of the prescribed_motion scenario: P4 of
../../docs/problems.md.

For a crank angle theta(t) with rate w = theta' and acceleration theta'', P4's kinematics
(extended by the theta'' terms) give every body's velocity and acceleration, and the
driving torque follows from the power balance

    torque * w = dT/dt + g sum(m v_y) - F_load . v_B

(kinetic energy rate, gravity power, power of the slider load). With theta'' = 0 this is
P4's torque. Only the data (masses, inertias, lengths, load, gravity) come from the scene.
"""

from __future__ import annotations

import importlib.util
import math
from pathlib import Path

import numpy as np

import mbdfmu

HERE = Path(__file__).resolve().parent


def slider_crank(theta, w, wd, r, l):
    """Velocities and accelerations (P4 plus theta'' terms) at crank angle theta, rate w,
    acceleration wd: a dict of arrays."""
    s, c = np.sin(theta), np.cos(theta)
    sphi = -(r / l) * s
    cphi = np.sqrt(1.0 - sphi ** 2)
    phid = -r * c * w / (l * cphi)
    phidd = (r * s * w ** 2 - r * c * wd + l * phid ** 2 * sphi) / (l * cphi)
    xB = r * c + l * cphi
    xBd = -r * w * s - l * phid * sphi
    xBdd = -r * wd * s - r * w ** 2 * c - l * phidd * sphi - l * phid ** 2 * cphi
    vA = r * w * np.stack([-s, c])
    aA = r * (wd * np.stack([-s, c]) - w ** 2 * np.stack([c, s]))
    return dict(xB=xB, xBd=xBd, xBdd=xBdd, phid=phid, phidd=phidd,
                v1=vA / 2, a1=aA / 2,                                   # crank centre
                v2=(vA + np.stack([xBd, 0 * xBd])) / 2,                 # rod centre
                a2=(aA + np.stack([xBdd, 0 * xBdd])) / 2)


def torque(theta, w, wd, D):
    """The driving torque of the power balance."""
    k = slider_crank(theta, w, wd, D["r"], D["l"])
    dT = (D["m1"] * np.sum(k["v1"] * k["a1"], axis=0) + D["J1"] * w * wd
          + D["m2"] * np.sum(k["v2"] * k["a2"], axis=0) + D["J2"] * k["phid"] * k["phidd"]
          + D["m3"] * k["xBd"] * k["xBdd"])
    gravity = D["g"] * (D["m1"] * k["v1"][1] + D["m2"] * k["v2"][1])
    load = D["fx"] * k["xBd"]
    return (dT + gravity - load) / w


def _data(scenario) -> dict:
    scene = mbdfmu.load_scene(scenario.instance("mechanism").source)
    p = {q.name: q.value for q in mbdfmu.parameters(scene)}
    joints = {j.name: j for j in scene.joints}
    return dict(r=math.dist(joints["A"].point_i, joints["O"].point_j),
                l=math.dist(joints["B"].point_i, joints["A"].point_j), g=-p["gravity.y"],
                m1=p["crank.mass"], J1=p["crank.inertia"], m2=p["rod.mass"],
                J2=p["rod.inertia"], m3=p["slider.mass"], fx=p["load.fx"])


def reference(scenario, times) -> dict[str, np.ndarray]:
    """The effort and the motion at ``times`` for the trajectory the scenario sets."""
    spec = importlib.util.spec_from_file_location("_pm_trajectory", HERE / "trajectory.py")
    traj = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(traj)
    tp = scenario.instance_parameters("trajectory")
    args = [tp.get(k, 0.0) for k in ("start", "rate", "amplitude", "frequency")]
    times = np.asarray(times, dtype=float)
    theta, w, wd = np.array([traj.motion(t, *args) for t in times]).T
    D = _data(scenario)
    k = slider_crank(theta, w, wd, D["r"], D["l"])
    return {"mechanism.motor.effort": torque(theta, w, wd, D), "mechanism.crank.phi": theta,
            "mechanism.crank.omega": w, "mechanism.slider.x": k["xB"],
            "mechanism.slider.vx": k["xBd"]}
