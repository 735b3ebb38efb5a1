"""A running check of the energy balance: the integrators' own guard against silent errors.

In a scene whose energy is conserved (``Equations.nonconservative_reason() is None``) the
total energy ``E = T + V`` (``Equations.total_energy``) must stay at its initial value.
Every method checks it after every accepted step (a dense check, not only at output times)
against a budget relative to the energy in motion, ``scale = max(max T, max |V - V0|)``:

* adaptive methods: ``ENERGY_TOL_FACTOR`` times the energy change that errors at the
  tolerances would make, ``sum |F_i| (atol + rtol |q_i|) + |M_i q'_i| (atol + rtol |q'_i|)``
  (largest so far; dE = -F.dq + M q'.dq'). Local error control bounds the error of each
  step, not the sum over many steps; smooth scenes stay well within the factor
  (tests/test_integrators.py pins it). A fast transient that the step control skims over,
  or a singular crossing taken on the wrong branch, shows up here, and the run stops with
  that reason instead of returning an answer that is wrong by far more than the
  tolerances. It is a gross-error detector, not a global error bound;
* fixed-step methods (no error control) the same, with their stated accuracy
  (``stated_accuracy.py``) as the tolerances: a loose one by default, so a numerically
  damped method such as generalized-alpha, which removes energy by design, is not stopped
  for damping what its step does not resolve; never more than
  ``ENERGY_DIVERGENCE_FRACTION * scale`` (divergence).

Adaptive methods also use the energy as an error estimate of each step: a step whose own
energy change exceeds ENERGY_STEP_FACTOR of what the tolerances allow is rejected and retried
smaller (``step_error``); docs/accuracy.md shows what that does on the light cart-pole.
The check costs an energy and a force evaluation per step. Scenes with drivers, inputs or
dampers are not checked (their energy balance needs the work of those, not tracked here).
"""

from __future__ import annotations

from dataclasses import dataclass, fields

import numpy as np

from ..plain import Plain


# An adaptive step whose own energy change exceeds this fraction of what the tolerances
# allow is rejected and retried smaller (an error estimate of its own, see the docstring);
# larger values let the light cart-pole's spike through, smaller ones cost smooth scenes
# many rejections (docs/accuracy.md).
ENERGY_STEP_FACTOR = 0.05
# An adaptive run may drift in energy by this many times what its tolerances allow
# (rtol of the energy in motion plus atol converted to joules); see the module docstring.
ENERGY_TOL_FACTOR = 10.0
# A fixed-step run whose energy error reaches this fraction of the energy in motion diverged.
ENERGY_DIVERGENCE_FRACTION = 1.0
# Round-off allowance per step, relative to the largest |E| seen (potentials have arbitrary
# datums); the run's allowance grows with the number of steps checked.
ENERGY_ROUNDOFF = 1e-13


@dataclass
class EnergyAudit(Plain):
    """Initial energy and the largest energies seen; ``check`` reports a broken balance."""

    method: str
    rtol: float            # the tolerances of (q, q') ...
    atol: float
    factor: float          # ... times this bound |E - E0| (0: divergence check only)
    what: str              # how the budget was set, for the message
    fixed_step: bool       # a fixed-step method's (the message's advice differs)
    e0: float
    v0: float
    kinetic_max: float = 0.0
    potential_swing: float = 0.0
    magnitude: float = 0.0
    tolerance_joules: float = 0.0  # largest energy change the tolerances allow, seen so far
    last_energy: float = 0.0       # at the last accepted step
    checks: int = 0                # accepted steps checked
    worst: float = 0.0     # largest |E - E0| / allowance seen

    @classmethod
    def start(cls, equations, q, qd, *, method: str, rtol: float, atol: float, factor: float,
              what: str, fixed_step: bool = False):
        """An audit of ``equations`` from (q, q'), or None when its energy is not conserved."""
        if equations.nonconservative_reason() is not None:
            return None
        e0 = equations.total_energy(q, qd)
        t0 = equations.kinetic_energy(qd)
        audit = cls(method, rtol, atol, factor, what, fixed_step, e0, e0 - t0)
        audit.kinetic_max, audit.magnitude, audit.last_energy = t0, abs(e0), e0
        return audit

    def joules(self, equations, t: float, q: np.ndarray, qd: np.ndarray) -> float:
        """The energy change errors at the tolerances would make: dE = -F.dq + M q'.dq'."""
        F, p = equations.forces(t, q, qd), equations.mass * qd
        return (float(np.abs(F) @ (self.atol + self.rtol * np.abs(q)))
                + float(np.abs(p) @ (self.atol + self.rtol * np.abs(qd))))

    def step_error(self, equations, t: float, q: np.ndarray, qd: np.ndarray) -> float:
        """A proposed step's energy change over ENERGY_STEP_FACTOR times what the tolerances
        allow at its end: above 1, the step should be rejected."""
        change = abs(equations.total_energy(q, qd) - self.last_energy)
        if change <= 10 * ENERGY_ROUNDOFF * self.magnitude:
            return 0.0
        allowed = ENERGY_STEP_FACTOR * self.joules(equations, t, q, qd)
        return change / allowed if allowed > 0 else np.inf

    def check(self, equations, t: float, q: np.ndarray, qd: np.ndarray) -> str | None:
        """None while the balance holds; otherwise the reason (without the time)."""
        kinetic = equations.kinetic_energy(qd)
        energy = equations.total_energy(q, qd)
        if not np.isfinite(energy):
            return f"{self.method}: the energy became non-finite (the method diverged)"
        self.kinetic_max = max(self.kinetic_max, kinetic)
        self.potential_swing = max(self.potential_swing, abs(energy - kinetic - self.v0))
        self.magnitude = max(self.magnitude, abs(energy), kinetic)
        self.last_energy = energy
        scale = max(self.kinetic_max, self.potential_swing)
        if self.factor:
            # dE = -F . dq + (M q') . dq' for errors dq, dq' at the tolerances
            self.tolerance_joules = max(self.tolerance_joules, self.joules(equations, t, q, qd))
            allowance = min(self.factor * self.tolerance_joules, ENERGY_DIVERGENCE_FRACTION * scale)
        else:
            allowance = ENERGY_DIVERGENCE_FRACTION * scale
        error = abs(energy - self.e0)
        self.checks += 1
        if error <= ENERGY_ROUNDOFF * self.magnitude * self.checks:
            return None
        ratio = error / allowance if allowance > 0 else np.inf
        self.worst = max(self.worst, ratio)
        if ratio <= 1.0:
            return None
        if allowance >= ENERGY_DIVERGENCE_FRACTION * scale:
            advice = "the solution has diverged; use a smaller step"
        elif self.fixed_step:
            advice = ("the step is too large for that accuracy; use a smaller step (the error "
                      "falls like a power of it), a larger rtol, or another method")
        else:
            advice = ("the step-size control did not resolve a fast transient or a singular "
                      "crossing; use a smaller rtol or another method")
        return (f"{self.method}: energy balance broken by {error:.3g} J ({error / scale:.2g} of "
                f"the {scale:.3g} J in motion; {self.what} allow {allowance:.2g} J): {advice}")


EnergyAudit.plain_fields = tuple(f.name for f in fields(EnergyAudit))
EnergyAudit.flat_fields = True
