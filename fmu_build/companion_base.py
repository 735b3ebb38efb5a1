"""The base class of the companion FMUs of the co-simulation scenarios (pythonfmu 0.7).

A companion is a small model next to a mechanism: a DC motor, a hydraulic cylinder, a
trajectory generator, a controller. Its source (``scenarios/<name>/<model>.py``) subclasses
``CompanionSlave`` and gives

1. ``VARIABLES``: one table of ``Var(name, kind, unit, start, description)`` with kind
   ``parameter``, ``input`` or ``output``; a variable's value reference is its index;
2. ``initial_state()``: the internal state (a dict of floats) from the parameters and inputs;
3. ``step(t, h, state)``: the state at ``t + h`` from the state at ``t``, inputs held
   (zero-order hold) over the step;
4. ``outputs(state)``: every output from the state, the parameters and the inputs (an
   output that reads an input is direct feedthrough).

The base class does the rest: variables and their units in the model description, outputs
computed when read (so they follow inputs set since the last step), the FMU state (the
whole instance: values, internal state and time, so a master can roll back), and the one
error path: a non-finite input or state gives fmi2Discard with a logged reason and leaves
the instance at its last communication point; any other exception is logged and the
instance refuses to step until fmi2Reset (pythonfmu turns an escaping exception into
fmi2Fatal, which crashes some masters).

This file is shipped inside each companion FMU under a name unique to its content
(``fmu companion builder``), so it imports only the standard library and pythonfmu.
"""

from __future__ import annotations

import copy
import math
import pickle
import re
from typing import NamedTuple
from xml.etree.ElementTree import Element, SubElement

from pythonfmu.fmi2slave import (Fmi2Causality, Fmi2Initial, Fmi2Slave, Fmi2Status,
                                 Fmi2Variability, Real)

# Relative tolerance between the master's communication point and the instance's time.
TIME_TOLERANCE = 1e-9

# SI base-unit exponents of each unit symbol a companion may use (FMI 2.0 BaseUnit names).
UNIT_SYMBOLS = {
    "1": {}, "kg": {"kg": 1}, "m": {"m": 1}, "s": {"s": 1}, "rad": {"rad": 1}, "A": {"A": 1},
    "N": {"kg": 1, "m": 1, "s": -2}, "J": {"kg": 1, "m": 2, "s": -2},
    "W": {"kg": 1, "m": 2, "s": -3}, "Pa": {"kg": 1, "m": -1, "s": -2},
    "V": {"kg": 1, "m": 2, "s": -3, "A": -1}, "Ohm": {"kg": 1, "m": 2, "s": -3, "A": -2},
    "H": {"kg": 1, "m": 2, "s": -2, "A": -2}, "Hz": {"s": -1},
}


class Var(NamedTuple):
    """One variable of a companion: ``kind`` is parameter, input or output."""

    name: str
    kind: str
    unit: str
    start: float
    description: str


def base_units(unit: str) -> dict[str, int]:
    """SI exponents of a unit name such as ``N.m/A``, ``m3/s`` or ``m3/(s.Pa)``."""
    exponents: dict[str, int] = {}
    numerator, _, denominator = unit.partition("/")
    if denominator.startswith("(") and denominator.endswith(")"):
        denominator = denominator[1:-1]
    for part, sign in ((numerator, 1), (denominator, -1)):
        for token in filter(None, part.split(".")):
            match = re.fullmatch(r"([A-Za-z]+|1)(-?\d*)", token)
            if match is None or match.group(1) not in UNIT_SYMBOLS:
                raise ValueError(f'unit "{unit}": unknown symbol "{token}"; '
                                 f"known: {', '.join(UNIT_SYMBOLS)}")
            for base, e in UNIT_SYMBOLS[match.group(1)].items():
                exponents[base] = exponents.get(base, 0) + sign * e * int(match.group(2) or 1)
    return {k: v for k, v in exponents.items() if v}


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


class Discard(Exception):
    """A step the master may retry (smaller, or with other inputs): the reason is logged."""


class CompanionSlave(Fmi2Slave):
    """A companion FMU: variables from ``VARIABLES``, physics in three methods."""

    VARIABLES: tuple[Var, ...] = ()
    DESCRIPTION = ""
    AUTHOR = "mbdfmu"
    VERSION = "0.1.0"

    def __init__(self, **kwargs):
        super().__init__(**kwargs)
        self.description = self.DESCRIPTION or None
        self.author = self.AUTHOR
        self.version = self.VERSION
        self.values = {v.name: float(v.start) for v in self.VARIABLES if v.kind != "output"}
        self.time = 0.0
        self.state: dict | None = None      # None until fmi2ExitInitializationMode
        self.failed: str | None = None
        self._cache = None
        for v in self.VARIABLES:
            self.register_variable(self._variable(v))

    # ------------------------------------------------------------------ for subclasses

    def initial_state(self) -> dict:
        """The internal state at the start time (from parameters and inputs)."""
        return {}

    def step(self, t: float, h: float, state: dict) -> dict:
        """The internal state at ``t + h``; inputs hold their values over the step."""
        return state

    def outputs(self, state: dict) -> dict:
        """Every output by name."""
        raise NotImplementedError

    # ------------------------------------------------------------------ variables

    def _variable(self, v: Var) -> Real:
        if v.kind == "output":
            return Real(v.name, causality=Fmi2Causality.output,
                        variability=Fmi2Variability.continuous, initial=Fmi2Initial.exact,
                        description=v.description, getter=lambda: self._output(v.name),
                        setter=lambda value: self._refuse(v.name))
        if v.kind == "input":
            return Real(v.name, causality=Fmi2Causality.input,
                        variability=Fmi2Variability.continuous, description=v.description,
                        getter=lambda: self.values[v.name],
                        setter=lambda value: self._set(v.name, value))
        if v.kind == "parameter":
            return Real(v.name, causality=Fmi2Causality.parameter,
                        variability=Fmi2Variability.fixed, description=v.description,
                        getter=lambda: self.values[v.name],
                        setter=lambda value: self._set(v.name, value, parameter=True))
        raise ValueError(f'variable "{v.name}": kind "{v.kind}" is not parameter, input or output')

    def _set(self, name: str, value: float, parameter: bool = False) -> None:
        if parameter and self.state is not None:
            self.log(f'parameter "{name}" is fixed after initialization; {value!r} ignored',
                     Fmi2Status.error)
            return
        self.values[name] = float(value)
        self._cache = None

    def _refuse(self, name: str) -> None:
        self.log(f'"{name}" is an output and cannot be set; value ignored', Fmi2Status.error)

    def _current_state(self) -> dict:
        # Before initialization ends the state follows the parameters as they are set.
        return self.state if self.state is not None else self.initial_state()

    def _output(self, name: str) -> float:
        try:
            if self._cache is None:
                self._cache = self.outputs(self._current_state())
            return float(self._cache[name])
        except Exception as exc:  # noqa: BLE001 - the FMI boundary: nothing may escape
            self.log(f'output "{name}": {type(exc).__name__}: {exc}', Fmi2Status.error)
            return math.nan

    # ------------------------------------------------------------------ FMI calls

    def setup_experiment(self, start_time, stop_time=None, tolerance=None):
        self.time = float(start_time)

    def exit_initialization_mode(self):
        try:
            self.state = self.initial_state()
            self._cache = None
        except Exception as exc:  # noqa: BLE001
            self._fail("fmi2ExitInitializationMode", f"{type(exc).__name__}: {exc}")

    def do_step(self, current_time, step_size):
        if self.failed is not None:
            self.log(f"fmi2DoStep refused: the FMU failed earlier ({self.failed})",
                     Fmi2Status.error)
            return False
        try:
            if self.state is None:
                raise RuntimeError("fmi2DoStep before fmi2ExitInitializationMode")
            if abs(current_time - self.time) > TIME_TOLERANCE * max(1.0, abs(self.time)):
                raise RuntimeError(f"communication point {current_time!r} is not the "
                                   f"FMU's time {self.time!r}")
            if not step_size > 0.0:
                raise Discard(f"step size {step_size!r} must be positive")
            bad = [n for v in self.VARIABLES if v.kind == "input"
                   for n in [v.name] if not math.isfinite(self.values[n])]
            if bad:
                raise Discard(f"input {', '.join(bad)} is not finite")
            state = self.step(float(current_time), float(step_size), dict(self.state))
            if not all(math.isfinite(x) for x in state.values()):
                raise Discard(f"the state became non-finite over [{current_time!r}, "
                              f"{current_time + step_size!r}]: {state}")
        except Discard as exc:
            self.log(f"fmi2DoStep discarded at t = {self.time!r}: {exc}", Fmi2Status.discard)
            return False
        except Exception as exc:  # noqa: BLE001
            self._fail("fmi2DoStep", f"{type(exc).__name__}: {exc}")
            return False
        self.state = state
        self.time = float(current_time + step_size)
        self._cache = None
        return True

    def _fail(self, call: str, reason: str) -> None:
        self.failed = f"{call}: {reason}"
        self.log(f"{self.failed} (the FMU now refuses to step; fmi2Reset starts over)",
                 Fmi2Status.error)

    # ------------------------------------------------------------------ FMU state

    def _get_fmu_state(self):
        return {"values": dict(self.values), "time": self.time,
                "state": copy.deepcopy(self.state), "failed": self.failed}

    def _set_fmu_state(self, state):
        try:
            self.values = dict(state["values"])
            self.time = float(state["time"])
            self.state = copy.deepcopy(state["state"])
            self.failed = state["failed"]
            self._cache = None
        except Exception as exc:  # noqa: BLE001
            self._fail("fmi2SetFMUstate", f"{type(exc).__name__}: {exc}")

    @staticmethod
    def _fmu_state_to_bytes(state):
        return pickle.dumps(state, protocol=pickle.HIGHEST_PROTOCOL)

    @staticmethod
    def _fmu_state_from_bytes(data):
        return pickle.loads(data)

    # ------------------------------------------------------------------ model description

    def to_xml(self, model_options=None):
        """pythonfmu's description plus units and their definitions."""
        from pythonfmu import __version__ as pythonfmu_version

        root = super().to_xml(model_options or {})
        root.set("generationTool", f"mbdfmu companion FMU (pythonfmu {pythonfmu_version})")
        units = {v.name: v.unit for v in self.VARIABLES if v.unit}
        definitions = Element("UnitDefinitions")
        for name in sorted(set(units.values())):
            unit = SubElement(definitions, "Unit", name=name)
            exponents = base_units(name)
            if exponents:
                SubElement(unit, "BaseUnit", {k: str(e) for k, e in exponents.items()})
        root.insert(list(root).index(root.find("CoSimulation")) + 1, definitions)
        for sv in root.find("ModelVariables"):
            real = sv.find("Real")
            if real is not None and sv.get("name") in units:
                real.set("unit", units[sv.get("name")])
        return root
