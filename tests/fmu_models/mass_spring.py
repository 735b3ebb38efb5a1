"""Toy model of the native-wrapper tests: a damped mass-spring driven by a force.

    m x'' + c x' + k x = F,   x(0) = x0, x'(0) = v0

with the force F held constant over each communication step. Each step is integrated
exactly (the underdamped closed form, as a 2x2 transition matrix), so results can be
checked against the closed-form solution to rounding.

Test hooks: the Integer input ``fault`` makes the next step fail: 1 with ``Discard``
(retryable), 2 with a plain exception (fmi2Error). The Boolean input ``frozen`` holds
the state still. ``label`` is a tunable String parameter.

This file is the source of an FMU's model module: it runs inside the FMU's runtime
package (``from . import ...``) and is never imported by the tests directly.
"""

import math

import numpy as np

from . import Discard, Slave

FAULT_NONE, FAULT_DISCARD, FAULT_ERROR = 0, 1, 2


def transition(m: float, k: float, c: float, h: float) -> np.ndarray:
    """Phi(h) with [y, v](t + h) = Phi(h) [y, v](t) for m y'' + c y' + k y = 0 (underdamped)."""
    w0 = math.sqrt(k / m)
    zeta = c / (2.0 * math.sqrt(k * m))
    wd = w0 * math.sqrt(1.0 - zeta * zeta)
    decay = math.exp(-zeta * w0 * h)
    cos, sin = math.cos(wd * h), math.sin(wd * h)
    return decay * np.array([[cos + zeta * w0 / wd * sin, sin / wd],
                             [-w0 * w0 / wd * sin, cos - zeta * w0 / wd * sin]])


class Model(Slave):
    """Damped mass-spring (SI units: kg, N/m, N.s/m, m, m/s, N)."""

    def setup(self):
        self.state = np.zeros(2)   # [x (m), v (m/s)]; set from x0, v0 by initialize()

    def initialize(self):
        v = self.values
        for name in ("m", "k"):
            if not v[name] > 0:
                raise ValueError(f"{name} = {v[name]} must be positive")
        zeta = v["c"] / (2.0 * math.sqrt(v["k"] * v["m"]))
        if not 0 <= zeta < 1:
            raise ValueError(f"damping ratio {zeta} must be in [0, 1) (underdamped)")
        self.state = np.array([v["x0"], v["v0"]], dtype=float)
        v["x"], v["v"] = float(self.state[0]), float(self.state[1])
        self.log(f"initialized: x = {v['x']} m, v = {v['v']} m/s", "logModel")

    def step(self, time, step_size):
        v = self.values
        if v["fault"] == FAULT_DISCARD:
            raise Discard(f"fault input {FAULT_DISCARD} asks to discard the step at t = {time}")
        if v["fault"] == FAULT_ERROR:
            raise RuntimeError(f"fault input {FAULT_ERROR} asks for an error at t = {time}")
        if v["frozen"]:
            return
        rest = np.array([v["F"] / v["k"], 0.0])
        self.state = transition(v["m"], v["k"], v["c"], step_size) @ (self.state - rest) + rest
        v["x"], v["v"] = float(self.state[0]), float(self.state[1])

    def save_state(self):
        return {"state": self.state}

    def check_state(self, tree):
        state = tree.get("state") if isinstance(tree, dict) else None
        if not (isinstance(state, np.ndarray) and state.shape == (2,) and state.dtype == float):
            return "the model state must be {'state': a float array of shape (2,)}"
        return None

    def restore_state(self, tree):
        problem = self.check_state(tree)
        if problem:
            raise ValueError(problem)
        self.state = tree["state"]
