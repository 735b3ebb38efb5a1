"""Implicit coupling: each macro step is iterated, with rollback, until the connected
outputs at t + h agree with the values the inputs were given for t + h (an
interface-Jacobian Newton iteration, as in Kuebler and Schiehlen's and Sicklinger et al.'s
implicit co-simulation).

Over a step every input ramps linearly from its source's output at t to the iterate ``Y``
for t + h (input derivatives of order 1, ``canInterpolateInputs``; a target that cannot
interpolate holds ``Y``). One evaluation ``G(Y)`` restores every instance to its state at
t (``fmi2SetFMUstate``), sets those ramps and steps all instances (in parallel, as
Jacobi); the step is accepted when ``Y - G(Y)`` is within ``TOLERANCE`` of each output's
scale. Newton's update uses the interface Jacobian ``I - dG/dY``: its columns are central
finite differences of ``G`` (one pair of evaluations per output that feeds an instance
with inputs; outputs of instances without inputs do not depend on Y), computed at the
first iteration of a step, then corrected after each iteration by Broyden's update with
the secant just taken (the step's nonlinearity), and recomputed only when the residual
is not halved. Converged, the coupling is the trapezoidal rule's: second order and stable
for stiff couplings at any step where each FMU is (the hydraulic crane at 50 ms, where
Jacobi fails from 2 ms).

With ``jacobian="directional"`` the interface Jacobian comes instead from the FMUs'
directional derivatives at t (``interface_jacobian.py``): one linearization per macro step,
no extra steps; the iteration then converges more slowly than with the differences, and
where it converges slowly (the residual not halved) the step goes on with the differences
(``stats["fallbacks"]``).

The first guess is the outputs' Taylor extrapolation to t + h when the sources give
output derivatives, else the outputs at t.
"""

from __future__ import annotations

import numpy as np

from . import interface_jacobian
from .settings import Refused

# Converged when every |Y - G(Y)| <= TOLERANCE * (scale of that output).
TOLERANCE = 1e-8
MAX_ITERATIONS = 12
# Relative perturbation of the finite-difference columns (times the output's scale).
PERTURBATION = 1e-6


class Implicit:
    """Iterated macro steps with interface Jacobians and rollback."""

    name = "implicit"

    def __init__(self, scenario, jacobian: str = "differences"):
        self.scenario = scenario
        self.directional = jacobian == "directional"
        self.checked = False
        self.sources = list(dict.fromkeys(c.source for c in scenario.connections))

    def scales(self, system, y0) -> np.ndarray:
        nominal = self.scenario.variable_step.nominal
        return np.array([max(abs(v), system.nominal.get(s, 0.0), nominal.get(s, 0.0), 1e-12)
                         for s, v in zip(self.sources, y0)])

    def evaluate(self, system, saved, t, h, y0, guess) -> np.ndarray:
        """G(guess): every instance from its state at t, inputs ramping to ``guess``."""
        system.set_states(saved)
        end = dict(zip(self.sources, guess))
        for m in system.members:
            pairs = system.inputs_of[m]
            member = system.members[m]
            names = [dst for dst, _ in pairs]
            if system.extrapolation.interpolates[m]:
                member.set(names, [y0[self.sources.index(src)] for _, src in pairs])
                member.set_derivatives(names, [1] * len(pairs),
                                       [(end[src] - y0[self.sources.index(src)]) / h
                                        for _, src in pairs])
            else:
                member.set(names, [end[src] for _, src in pairs])
            for dst, src in pairs:
                system.used[f"{m}.{dst}"] = end[src]
        for m in system.members:
            system.step_member(m, t, h, derivatives=False)
        return np.array([system.out[s] for s in self.sources])

    def jacobian(self, system, saved, t, h, y0, guess, scale, directional) -> np.ndarray:
        """I - dG/dY by central differences (columns of outputs that feed nothing that
        steps with inputs are unit columns), or from directional derivatives at t."""
        if directional:
            if not self.checked:
                interface_jacobian.check_members(system)
                self.checked = True
            system.set_states(saved)         # the linearization point: every instance at t
            return interface_jacobian.interface_jacobian(system, self.sources, h)
        n = len(self.sources)
        jac = np.eye(n)
        driven = {m for m in system.members if system.inputs_of[m]}
        feeds = [any(c.source == s and c.target_instance in driven
                     for c in self.scenario.connections) for s in self.sources]
        for j in range(n):
            if not feeds[j]:
                continue
            d = PERTURBATION * scale[j]
            plus, minus = guess.copy(), guess.copy()
            plus[j] += d
            minus[j] -= d
            column = (self.evaluate(system, saved, t, h, y0, plus)
                      - self.evaluate(system, saved, t, h, y0, minus)) / (2 * d)
            jac[:, j] -= column
        system.counters["jacobians"] = system.counters.get("jacobians", 0) + 1
        return jac

    def step(self, system, t: float, h: float, first: bool = False) -> None:
        system.begin_step()
        y0 = np.array([system.out[s] for s in self.sources])
        deriv = system.extrapolation.start
        guess = np.array([y + h * (deriv.get(s) or [0.0])[0] for s, y in zip(self.sources, y0)])
        scale = self.scales(system, y0)
        saved = system.get_states()
        try:
            jac, previous, change, last = None, np.inf, None, None
            for _ in range(MAX_ITERATIONS):
                residual = guess - self.evaluate(system, saved, t, h, y0, guess)
                system.counters["iterations"] = system.counters.get("iterations", 0) + 1
                size = float(np.max(np.abs(residual) / scale))
                if size <= TOLERANCE:
                    break
                if change is not None:
                    # Broyden's update with the secant just taken: the Jacobian of the
                    # nonlinear step, not only at t (the motor + crank at 50 ms contracts
                    # by 0.43 per iteration without it)
                    jac = jac + np.outer(residual - last - jac @ change, change) \
                        / float(change @ change)
                if jac is None:
                    jac = self.jacobian(system, saved, t, h, y0, guess, scale, self.directional)
                elif size > 0.5 * previous:
                    # slow: the differences of whole steps (the linearized step's Jacobian
                    # would not change); counted apart
                    jac = self.jacobian(system, saved, t, h, y0, guess, scale, False)
                    if self.directional:
                        system.counters["fallbacks"] = system.counters.get("fallbacks", 0) + 1
                previous, last = size, residual
                change = -np.linalg.solve(jac, residual)
                guess = guess + change
            else:
                raise Refused("(implicit coupling)", 2, f"the interface iteration did not "
                              f"converge in {MAX_ITERATIONS} iterations (residual {size:.3g} "
                              "of the outputs' scale)", "discard")
        finally:
            system.free_states(saved)
        # the instances stand at t + h with the converged inputs; derivatives of the
        # outputs there for the next step's first guess
        for m in system.members:
            system.read_outputs(m, t + h)
