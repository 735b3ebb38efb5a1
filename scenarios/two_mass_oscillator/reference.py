"""Monolithic reference of the two_mass_oscillator scenarios: the four-state linear ODE
of both masses, solved exactly (matrix exponential); only the data come from the
connections file. Independent of mbdfmu and of the oscillator FMU's code."""

from __future__ import annotations

import numpy as np
from scipy.linalg import expm


def parameters(scenario) -> dict:
    """m1, c1, d1, m2, c2, d2, the coupling cc, dc and the start state, from the start
    values (the coupling element is the one mass1 holds)."""
    p = scenario.parameters

    def get(name, default=0.0):
        return float(p.get(name, default))

    return {"m1": get("mass1.m", 1.0), "c1": get("mass1.c", 100.0), "d1": get("mass1.d", 0.1),
            "m2": get("mass2.m", 1.0), "c2": get("mass2.c", 100.0), "d2": get("mass2.d", 0.1),
            "cc": get("mass1.cc"), "dc": get("mass1.dc"),
            "start": np.array([get("mass1.x0"), get("mass1.v0"), get("mass2.x0"),
                               get("mass2.v0")])}


def system_matrix(q: dict) -> np.ndarray:
    """d/dt [x1, v1, x2, v2] = A [x1, v1, x2, v2]."""
    m1, m2, cc, dc = q["m1"], q["m2"], q["cc"], q["dc"]
    return np.array([
        [0.0, 1.0, 0.0, 0.0],
        [-(q["c1"] + cc) / m1, -(q["d1"] + dc) / m1, cc / m1, dc / m1],
        [0.0, 0.0, 0.0, 1.0],
        [cc / m2, dc / m2, -(q["c2"] + cc) / m2, -(q["d2"] + dc) / m2]])


def reference(scenario, times) -> dict:
    q = parameters(scenario)
    a = system_matrix(q)
    states = np.array([expm(a * t) @ q["start"] for t in np.asarray(times, dtype=float)])
    force = q["cc"] * (states[:, 0] - states[:, 2]) + q["dc"] * (states[:, 1] - states[:, 3])
    return {"mass1.x": states[:, 0], "mass1.v": states[:, 1], "mass2.x": states[:, 2],
            "mass2.v": states[:, 3], "mass1.coupling_force": force}
