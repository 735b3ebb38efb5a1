"""Monolithic reference of the quarter_car scenario: chassis and wheel as one four-state
linear ODE solved exactly (matrix exponential). Only the data come from the scene and the
connections file; independent of mbdfmu's equations and of the wheel FMU's code."""

from __future__ import annotations

from pathlib import Path

import numpy as np
from scipy.linalg import expm

from mbdfmu.model.toml_table import tomllib


def reference(scenario, times) -> dict:
    scene = tomllib.loads((Path(scenario.folder) / "chassis.toml").read_text())
    body = scene["body"][0]
    m1, y0 = float(body["mass"]), float(body["position"][1])
    p = scenario.parameters
    m2, kt, dt = p["wheel.m"], p["wheel.c"], p.get("wheel.d", 0.0)
    ks, ds = p["wheel.cc"], p["wheel.dc"]
    a = np.array([[0.0, 1.0, 0.0, 0.0],
                  [-ks / m1, -ds / m1, ks / m1, ds / m1],
                  [0.0, 0.0, 0.0, 1.0],
                  [ks / m2, ds / m2, -(kt + ks) / m2, -(dt + ds) / m2]])
    start = np.array([y0, 0.0, p.get("wheel.x0", 0.0), p.get("wheel.v0", 0.0)])
    s = np.array([expm(a * t) @ start for t in np.asarray(times, dtype=float)])
    force = ks * (s[:, 2] - s[:, 0]) + ds * (s[:, 3] - s[:, 1])
    return {"chassis.chassis.y": s[:, 0], "chassis.chassis.vy": s[:, 1], "wheel.x": s[:, 2],
            "wheel.v": s[:, 3], "wheel.coupling_force": force}
