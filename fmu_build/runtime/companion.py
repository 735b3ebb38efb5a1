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

A class that also defines ``rates(state)`` (the state's time derivative at ``self.time``)
exposes its continuous states and provides directional derivatives (``companion_states``).

Derivatives (docs/fmu.md, "Derivatives"): every companion FMU gives the first and second
time derivatives of its outputs (``maxOutputDerivativeOrder`` 2), by default from one-sided
differences of ``outputs`` along ``step`` (``DERIVATIVE_STEP``), or exactly where the class
defines ``output_derivatives(state)``. A class that sets ``INTERPOLATES_INPUTS = True``
follows input derivatives (``canInterpolateInputs``): its ``step`` and ``outputs`` read
inputs with ``self.input(name, t)``, the input's Taylor polynomial from where it was set.

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

from . import companion_states
from .slave import Slave
from .status import Discard, FmiError

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
    INTERPOLATES_INPUTS = False
    # Time step (s) of the one-sided differences that give output derivatives by default.
    DERIVATIVE_STEP = 1e-4

    def __init__(self, host):
        self.host = host

    values = property(lambda self: self.host.values,
                      doc="Parameters and inputs (and the last outputs) by name.")
    time = property(lambda self: self.host.time, doc="The communication point (s).")

    def log(self, text: str) -> None:
        self.host.log(text)

    def input(self, name: str, t: float | None = None) -> float:
        """Input ``name`` at time ``t`` (default: now): its value where it was set, plus
        the Taylor terms of the derivatives the master gave with it."""
        return self.host.input_at(name, self.time if t is None else t)

    def input_taylor(self, name: str, t: float) -> list[float]:
        """Input ``name`` and its derivatives at time ``t``: ``[u, u', u'', ...]`` (just
        ``[u]`` for an input held)."""
        return self.host.taylor_at(name, t)

    def initial_state(self) -> dict:
        """The internal state at the start time (from parameters and inputs)."""
        return {}

    def step(self, t: float, h: float, state: dict) -> dict:
        """The internal state at ``t + h``; inputs hold their values over the step."""
        return state

    def outputs(self, state: dict) -> dict:
        """Every output by name."""
        raise NotImplementedError(f"{type(self).__name__} does not implement outputs()")


def _finite(x) -> bool:
    return isinstance(x, (int, float)) and not isinstance(x, bool) and math.isfinite(x)


def check_derivatives(table, names, orders, causality: str, highest: int = 2) -> None:
    """Input or output derivatives may be asked of that causality and orders 1..highest."""
    for name, order in zip(names, orders):
        if table.by_name[name].causality != causality:
            raise FmiError(f'"{name}" is not an {causality}')
        if not 1 <= order <= highest:
            raise FmiError(f'derivative order {order} of "{name}": this FMU gives orders '
                           f"1 to {highest}")


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
    # state key -> its variable (an output of that name, or a local), with rates() only
    STATE_VARIABLES: dict[str, str] = {}

    def setup(self):
        self.companion = self.COMPANION(self)
        self.state = None          # the companion's state; None until initialized
        self.taylor = {}           # input -> [time set, derivative 1, derivative 2, ...]
        self.pending = {}          # input -> {order: value} set since the last step

    def input_at(self, name: str, t: float) -> float:
        value = self.values[name]
        anchor = self.taylor.get(name)
        if anchor:
            tau, term = t - anchor[0], 1.0
            for k, d in enumerate(anchor[1:], start=1):
                term *= tau / k
                value += d * term
        return value

    def taylor_at(self, name: str, t: float) -> list[float]:
        anchor = self.taylor.get(name) or [t]
        d = [self.values[name]] + list(anchor[1:])
        tau = t - anchor[0]
        out = []
        for k in range(len(d)):
            term, total = 1.0, 0.0
            for j in range(k, len(d)):
                total += d[j] * term
                term *= tau / (j - k + 1)
            out.append(total)
        return out

    def set_input_derivatives(self, names, orders, values):
        if not self.COMPANION.INTERPOLATES_INPUTS:
            super().set_input_derivatives(names, orders, values)
        check_derivatives(self.variables, names, orders, "input")
        for name, order, value in zip(names, orders, values):
            self.pending.setdefault(name, {})[order] = float(value)

    def _anchor_inputs(self, time):
        """Inputs set (or given derivatives) since the last step start their polynomial now
        (FMI 3.0's derivative inputs are not inputs of the companion). Idempotent at one
        time: called again, a polynomial anchored now gives the same value."""
        for name in set(self.set_since_step) | set(self.pending):
            if name in self.pending and name not in self.set_since_step:
                self.values[name] = self.input_at(name, time)
            variable = self.variables.by_name[name]
            if variable.causality == "input" and variable.derivative is None:
                given = self.pending.get(name, {})
                top = max(given, default=0)
                self.taylor[name] = [time] + [given.get(k, 0.0) for k in range(1, top + 1)]

    def output_derivatives(self, names, orders):
        check_derivatives(self.variables, names, orders, "output")
        # an output that reads an input follows the input's derivatives set since the step
        # (dy/du du/dt): without them the derivatives at t0 miss that term
        self._anchor_inputs(self.time)
        exact = getattr(self.companion, "output_derivatives", None)
        table = exact(self.state) if exact else self._differenced()
        return [table[name][order - 1] for name, order in zip(names, orders)]

    def _differenced(self):
        """(d/dt, d2/dt2) of every output from one-sided differences of order 4 and 3 at
        t, t + d, ..., t + 4 d along ``step`` (inputs following their polynomials)."""
        d, t0 = self.COMPANION.DERIVATIVE_STEP, self.time
        rows = []
        try:
            for k in range(5):
                state = self.companion.step(t0, k * d, dict(self.state)) if k else self.state
                self._fmi_time = t0 + k * d
                out = self.companion.outputs(state)
                rows.append([float(out[n]) for n in self.OUTPUTS])
        finally:
            self._fmi_time = t0
        y0, y1, y2, y3, y4 = rows
        first = [(-25 * a + 48 * b - 36 * c + 16 * e - 3 * f) / (12 * d)
                 for a, b, c, e, f in zip(y0, y1, y2, y3, y4)]
        second = [(35 * a - 104 * b + 114 * c - 56 * e + 11 * f) / (12 * d * d)
                  for a, b, c, e, f in zip(y0, y1, y2, y3, y4)]
        return {n: (first[i], second[i]) for i, n in enumerate(self.OUTPUTS)}

    def initialize(self):
        state = self.companion.initial_state()
        problem = _state_problem(state)
        if problem:
            raise ValueError(f"initial_state(): {problem}: {state}")
        self.state = {k: float(v) for k, v in state.items()}
        self.calculate()

    def calculate(self):
        # inputs set since the step hold (or follow their new derivatives) from now, not
        # from where the last polynomial started
        self._anchor_inputs(self.time)
        out = self.companion.outputs(self.state)
        self.values.update({name: float(out[name]) for name in self.OUTPUTS})
        if self.STATE_VARIABLES:
            self.values.update({v: self.state[k] for k, v in self.STATE_VARIABLES.items()})
            rates = self.companion.rates(self.state)
            self.values.update({companion_states.derivative_name(v): float(rates[k])
                                for k, v in self.STATE_VARIABLES.items()})

    def directional_derivative(self, unknowns, knowns, seeds):
        if not self.STATE_VARIABLES:
            return super().directional_derivative(unknowns, knowns, seeds)
        if self.state is None:
            raise FmiError("directional derivatives are given after initialization")
        return companion_states.directional(self, unknowns, knowns, seeds)

    def step(self, time, step_size):
        self._anchor_inputs(float(time))
        state = self.companion.step(float(time), float(step_size), dict(self.state))
        problem = _state_problem(state)
        if problem:
            raise Discard(f"over [{time!r}, {time + step_size!r}] s: {problem} ({state}); "
                          "retry with a smaller step or other inputs")
        self.state = {k: float(v) for k, v in state.items()}
        self.pending = {}

    def save_state(self):
        return {"state": self.state, "taylor": {k: list(v) for k, v in self.taylor.items()},
                "pending": [[n, k, v] for n, d in self.pending.items() for k, v in d.items()]}

    def check_state(self, tree):
        if not isinstance(tree, dict) or set(tree) != {"state", "taylor", "pending"}:
            return "the model state must be a table {'state', 'taylor', 'pending'}"
        inputs = {v.name for v in self.variables.variables if v.causality == "input"}
        taylor, pending = tree["taylor"], tree["pending"]
        if not isinstance(taylor, dict) or not set(taylor) <= inputs or not all(
                isinstance(v, list) and v and all(_finite(x) for x in v) for v in taylor.values()):
            return "the inputs' polynomials must be lists of numbers by input name"
        if not isinstance(pending, list) or not all(
                isinstance(e, list) and len(e) == 3 and e[0] in inputs and isinstance(e[1], int)
                and _finite(e[2]) for e in pending):
            return "the pending input derivatives must be [input, order, value] entries"
        return None if tree["state"] is None else _state_problem(tree["state"])

    def restore_state(self, tree):
        self.state = None if tree["state"] is None else dict(tree["state"])
        self.taylor = {k: list(v) for k, v in tree["taylor"].items()}
        self.pending = {}
        for name, order, value in tree["pending"]:
            self.pending.setdefault(name, {})[order] = value
