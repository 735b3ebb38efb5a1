"""A running check of the energy balance: the integrators' own guard against silent errors.

In a scene whose energy is conserved (``System.nonconservative_reason() is None``) the total
energy ``E = T + V`` (``System.total_energy``) must stay at its initial value. Every method
checks it after every accepted step (a dense check, not only at output times) against a
budget relative to the energy in motion, ``scale = max(max T, max |V - V0|)`` so far:

* adaptive methods: ``ENERGY_TOL_FACTOR * rtol * scale``. Local error control bounds the
  error of each step, not the sum over many steps; a fast transient that the step control
  skims over (the light cart-pole's one-microsecond spike, a singular crossing taken on the
  wrong branch) shows up here, and the run stops with that reason instead of returning an
  answer that is wrong by far more than rtol;
* fixed-step methods (no error control): ``ENERGY_DIVERGENCE_FRACTION * scale``: only
  divergence, since a fixed step is the user's statement of the accuracy wanted (and a
  numerically damped method such as generalized-alpha removes energy by design).

The check costs one energy evaluation per step. Scenes with drivers, inputs or dampers are
not checked (their energy balance needs the work of those, which is not tracked here).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..errors import SolverError

# An adaptive run may drift in energy by this many times rtol (relative to the energy in
# motion). Smooth scenes stay below 0.5 rtol (measured: pendulum, rod pendulum, double
# pendulum with rk45p and dop853p at rtol 1e-4..1e-8).
ENERGY_TOL_FACTOR = 10.0
# A fixed-step run whose energy error reaches this fraction of the energy in motion diverged.
ENERGY_DIVERGENCE_FRACTION = 1.0
# Round-off allowance, relative to the largest |E| seen (potentials have arbitrary datums).
ENERGY_ROUNDOFF = 1e-12


@dataclass
class EnergyAudit:
    """Initial energy and the largest energies seen; ``check`` raises on a broken balance."""

    method: str
    budget: float          # allowed |E - E0| / scale
    what: str              # how the budget was set, for the message
    e0: float
    v0: float
    kinetic_max: float = 0.0
    potential_swing: float = 0.0
    magnitude: float = 0.0
    worst: float = 0.0     # largest |E - E0| / scale seen

    @classmethod
    def start(cls, system, q, qd, *, method: str, budget: float, what: str):
        """An audit of ``system`` from (q, q'), or None when its energy is not conserved."""
        if system.nonconservative_reason() is not None:
            return None
        e0 = system.total_energy(q, qd)
        t0 = system.kinetic_energy(qd)
        audit = cls(method, budget, what, e0, e0 - t0)
        audit.kinetic_max, audit.magnitude = t0, abs(e0)
        return audit

    def check(self, system, t: float, q: np.ndarray, qd: np.ndarray) -> None:
        kinetic = system.kinetic_energy(qd)
        energy = system.total_energy(q, qd)
        if not np.isfinite(energy):
            raise SolverError(f"{self.method}: the energy became non-finite (the method diverged)", t)
        self.kinetic_max = max(self.kinetic_max, kinetic)
        self.potential_swing = max(self.potential_swing, abs(energy - kinetic - self.v0))
        self.magnitude = max(self.magnitude, abs(energy), kinetic)
        scale = max(self.kinetic_max, self.potential_swing)
        error = abs(energy - self.e0)
        if error <= ENERGY_ROUNDOFF * self.magnitude:
            return
        relative = error / scale if scale > 0 else np.inf
        self.worst = max(self.worst, relative)
        if relative > self.budget:
            raise SolverError(
                f"{self.method}: energy balance broken by {error:.3g} J ({relative:.2g} of the "
                f"{scale:.3g} J in motion; {self.what} allows {self.budget:.2g}): "
                + ("the step-size control did not resolve a fast transient or a singular "
                   "crossing; use a smaller rtol or another method"
                   if self.budget < ENERGY_DIVERGENCE_FRACTION else
                   "the solution has diverged; use a smaller step"), t)
