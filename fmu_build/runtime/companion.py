"""Companion models: the small FMUs next to a mechanism (a DC motor, a hydraulic cylinder,
a trajectory, a controller), on the same runtime as the scene FMUs.

A companion source (``scenarios/<name>/<model>.py``) imports this module as

    from mbdfmu.fmu_build.runtime import companion as base

and defines one subclass of ``CompanionSlave`` with

1. ``VARIABLES``: one table of ``Var(name, kind, unit, start, description)`` with kind
   ``parameter``, ``input`` or ``output``; a variable's value reference is its index;
2. ``initial_state()``: the internal state (a dict of floats) from the parameters and
   inputs in ``self.values``;
3. ``step(t, h, state)``: the state at ``t + h`` from the state at ``t``, inputs held
   (zero-order hold) over the step; raise ``Discard(reason)`` for a step that may be
   retried;
4. ``outputs(state)``: every output by name, from the state, ``self.values`` and
   ``self.time`` (an output that reads an input is direct feedthrough).

``fmu_build.companion`` builds the FMU: the source with its import line pointed at this
module inside the FMU's runtime package, and a ``Model`` (``CompanionModel``) that runs the
companion. Everything FMI (the state machine, get/set checks, statuses, the state format)
is the runtime's; this module adds only what companions share: outputs computed when read
(so they follow the inputs and the time), a non-finite state refused with ``Discard``, the
state saved as a table of floats, and ``rk4`` for companions that integrate.
"""

from __future__ import annotations

import math
from typing import NamedTuple

from .slave import Slave
from .status import Discard

__all__ = ["Var", "CompanionSlave", "CompanionModel", "Discard", "rk4"]
KINDS = ("parameter", "input", "output")


class Var(NamedTuple):
    """One variable of a companion: ``kind`` is parameter, input or output."""

    name: str
    kind: str
    unit: str
    start: float
    description: str


def rk4(rhs, t: float, y: list[float], h: float, max_substep: float) -> list[float]:
    """Classical Runge-Kutta over [t, t + h] in equal substeps no longer than ``max_substep``.

    ``rhs(t, y) -> dy/dt`` on lists of floats; substep times are ``t + k h / n``.
    """
    n = max(1, math.ceil(h / max_substep - 1e-9))
    dt = h / n
    y = list(y)
    for k in range(n):
        tk = t + k * dt
        k1 = rhs(tk, y)
        k2 = rhs(tk + dt / 2, [a + dt / 2 * b for a, b in zip(y, k1)])
        k3 = rhs(tk + dt / 2, [a + dt / 2 * b for a, b in zip(y, k2)])
        k4 = rhs(tk + dt, [a + dt * b for a, b in zip(y, k3)])
        y = [a + dt / 6 * (b + 2 * c + 2 * d + e) for a, b, c, d, e in zip(y, k1, k2, k3, k4)]
    return y


class CompanionSlave:
    """A companion's physics; ``host`` is whatever holds its ``values`` and ``time`` (the
    FMU's ``CompanionModel``, or a stand-in when the builder inspects it)."""

    VARIABLES: tuple[Var, ...] = ()
    DESCRIPTION = ""
    AUTHOR = "mbdfmu"
    VERSION = "0.1.0"

    def __init__(self, host):
        self.host = host

    values = property(lambda self: self.host.values,
                      doc="Parameters and inputs (and the last outputs) by name.")
    time = property(lambda self: self.host.time, doc="The communication point (s).")

    def log(self, text: str) -> None:
        self.host.log(text)

    def initial_state(self) -> dict:
        """The internal state at the start time (from parameters and inputs)."""
        return {}

    def step(self, t: float, h: float, state: dict) -> dict:
        """The internal state at ``t + h``; inputs hold their values over the step."""
        return state

    def outputs(self, state: dict) -> dict:
        """Every output by name."""
        raise NotImplementedError(f"{type(self).__name__} does not implement outputs()")


def _state_problem(state) -> str | None:
    if not isinstance(state, dict) or not all(isinstance(k, str) for k in state):
        return "the companion state must be a table of numbers by name"
    bad = [k for k, v in state.items()
           if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v)]
    return f"state {', '.join(bad)} is not a finite number" if bad else None


class CompanionModel(Slave):
    """The FMI side of a companion FMU: runs ``COMPANION`` (set by the builder)."""

    COMPANION: type[CompanionSlave] = CompanionSlave
    OUTPUTS: tuple[str, ...] = ()

    def setup(self):
        self.companion = self.COMPANION(self)
        self.state = None          # the companion's state; None until initialized

    def initialize(self):
        state = self.companion.initial_state()
        problem = _state_problem(state)
        if problem:
            raise ValueError(f"initial_state(): {problem}: {state}")
        self.state = {k: float(v) for k, v in state.items()}
        self.calculate()

    def calculate(self):
        out = self.companion.outputs(self.state)
        self.values.update({name: float(out[name]) for name in self.OUTPUTS})

    def step(self, time, step_size):
        state = self.companion.step(float(time), float(step_size), dict(self.state))
        problem = _state_problem(state)
        if problem:
            raise Discard(f"over [{time!r}, {time + step_size!r}] s: {problem} ({state}); "
                          "retry with a smaller step or other inputs")
        self.state = {k: float(v) for k, v in state.items()}

    def save_state(self):
        return {"state": self.state}

    def check_state(self, tree):
        if not isinstance(tree, dict) or set(tree) != {"state"}:
            return "the model state must be a table {'state': ...}"
        return None if tree["state"] is None else _state_problem(tree["state"])

    def restore_state(self, tree):
        self.state = None if tree["state"] is None else dict(tree["state"])
