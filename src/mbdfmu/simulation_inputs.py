"""The inputs of a ``Simulation``: values held until set again, Taylor polynomials from
input derivatives, sampled driver positions and signals (``signals.py``), by name.

A mixin of ``Simulation`` (like ``integrators.adaptive.AdaptiveStepping`` of the adaptive
methods): it reads and sets the simulation's ``equations``, ``input_names``, ``t``,
``_drivers``, ``_forces`` (the signal of each input item), ``_held`` (the inputs while all
are held), ``_cache``, ``_inputs_changed`` (the method restarts before the next step:
``Simulation._reinitialize``) and ``_motion_changed`` (a driver's input among them: the state
is re-projected first).
"""

from __future__ import annotations

import math

import numpy as np

from .errors import InputError
from .model.variables import InputValues
from .signals import Held, SampledDriver, TaylorInput, known_ahead


class SimulationInputs:
    """Setting and reading a simulation's inputs (see the module docstring)."""

    def inputs_at(self, t: float) -> InputValues:
        """The input values at time t, as the equations take them."""
        layout = self.equations.layout
        if not self._drivers and not self._forces:
            return self.equations.no_inputs
        if self._held is not None:       # every input held: the same values at any t
            return self._held
        motions = np.array([self._drivers[n](t) for n in layout.drivers], dtype=float)
        forces = [np.atleast_1d(np.asarray(self._forces[n](t), dtype=float))
                  for n in layout.forces]
        values = InputValues(motions.reshape(-1, 3),
                             np.concatenate(forces) if forces else np.zeros(0))
        if not self._drivers and all(type(f) is Held for f in self._forces.values()):
            self._held = values
        return values

    def _split(self, name: str) -> tuple[str, str]:
        if name not in self.input_names:
            hint = (f"; this scene's inputs: {', '.join(self.input_names)}" if self.input_names
                    else "; this scene has no inputs")
            raise InputError(f'unknown input "{name}"{hint}')
        item, _, field = name.rpartition(".")
        return item, field

    def set_input(self, name: str, value: float) -> None:
        """Set an input at the current time; it holds until set again."""
        item, field = self._split(name)
        value = float(value)
        if not math.isfinite(value):
            raise InputError(f'input "{name}" is not finite ({value})')
        if item in self._drivers:
            driver = self._drivers[item]
            if not isinstance(driver, SampledDriver):
                driver = self._drivers[item] = SampledDriver(driver(self.t)[0])
            driver.set(self.t, **{field: value})
            self._motion_changed = True
        else:
            fields = self.equations.layout.fields[item]
            values = np.array(self._forces[item](self.t), dtype=float)
            values[fields.index(field)] = value
            self._forces[item] = Held(values)
        self._inputs_changed = True
        self._cache = self._held = None

    def set_input_derivative(self, name: str, order: int, value: float) -> None:
        """The ``order``-th time derivative (1 or more) of an input at the current time: the
        input then follows its Taylor polynomial until set again (``set_input`` holds it).

        A force component takes any order; a driver's position takes 1 (its velocity) and
        2 (its acceleration), its velocity 1 (the acceleration): the driver's motion over a
        step is the quadratic ``p + v tau + a tau^2 / 2`` (``signals.SampledDriver``)."""
        item, field = self._split(name)
        value = float(value)
        if not math.isfinite(value):
            raise InputError(f'derivative {order} of input "{name}" is not finite ({value})')
        if item in self._drivers:
            slot = {("position", 1): "velocity", ("position", 2): "acceleration",
                    ("velocity", 1): "acceleration"}.get((field, order))
            if slot is None:
                raise InputError(f'input "{name}": a driver\'s motion is quadratic over a '
                                 f"step; derivative {order} of its {field} cannot be followed")
            driver = self._drivers[item]
            if not isinstance(driver, SampledDriver):
                driver = self._drivers[item] = SampledDriver(driver(self.t)[0])
            driver.set(self.t, **{slot: value})
            self._motion_changed = True
        else:
            signal = self._forces[item]
            if not (isinstance(signal, TaylorInput) and signal.t0 == self.t):
                signal = self._forces[item] = TaylorInput(self.t, signal(self.t))
            signal.set_derivative(self.equations.layout.fields[item].index(field), order, value)
        self._inputs_changed = True
        self._cache = self._held = None

    def set_input_signal(self, item: str, signal) -> None:
        """Drive a force item or a driver with a function of time (see ``signals``)."""
        if item in self._drivers:
            self._drivers[item] = signal
            self._motion_changed = True
        elif item in self._forces:
            self._forces[item] = signal
        else:
            raise InputError(f'"{item}" is not an input-driven driver or force of this scene')
        self._inputs_changed = True
        self._cache = self._held = None

    def inputs_known_ahead(self) -> bool:
        """Whether the inputs beyond now are known (``signals.known_ahead``)."""
        return known_ahead([*self._drivers.values(), *self._forces.values()])
