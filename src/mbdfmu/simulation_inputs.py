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


class InputsAt:
    """A simulation's ``inputs_at``, as its integrator calls it (``inputs(t)``), with
    ``forces_at(times)`` beside it (``SimulationInputs.forces_at``)."""

    __slots__ = ("sim",)

    def __init__(self, sim: "SimulationInputs"):
        self.sim = sim

    def __call__(self, t: float) -> InputValues:
        return self.sim.inputs_at(t)

    def forces_at(self, times) -> np.ndarray | None:
        return self.sim.forces_at(times)


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

    def forces_at(self, times) -> np.ndarray | None:
        """The force inputs at each of ``times`` in one evaluation, (len(times), nf): the
        doubles of ``inputs_at(t).forces`` at each (a step's stage times, for the C
        kernel). None where a driver takes its motion from the inputs or a force input is
        neither held nor a Taylor polynomial: ``inputs_at`` at each time then."""
        signals = [self._forces[n] for n in self.equations.layout.forces]
        if self._drivers or not all(type(f) in (Held, TaylorInput) for f in signals):
            return None
        times = np.asarray(times, dtype=float)
        return np.hstack([f.at_times(times) for f in signals]) if signals else \
            np.zeros((len(times), 0))

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
            self._forces[item] = self._force_set(item, field, value)
        self._inputs_changed = True
        self._cache = self._held = None

    def _force_set(self, item: str, field: str, value: float):
        """The signal of force ``item`` once ``field`` is set to ``value`` now: held, but for
        the components that follow their Taylor polynomial (derivatives set and not yet
        replaced: a master may set a component's value and derivatives, then the next's)."""
        index = self.equations.layout.fields[item].index(field)
        signal = self._forces[item]
        if isinstance(signal, TaylorInput):
            signal = signal.rebased(self.t)
            signal.coefficients[:, index] = 0.0
            signal.coefficients[0, index] = value
            if signal.coefficients[1:].any():
                return signal
            return Held(signal.coefficients[0])
        values = np.array(signal(self.t), dtype=float)
        values[index] = value
        return Held(values)

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
                # the components not set again follow their polynomials on
                signal = self._forces[item] = signal.rebased(self.t) if isinstance(
                    signal, TaylorInput) else TaylorInput(self.t, signal(self.t))
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
