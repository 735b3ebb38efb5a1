"""Classic fixed-step Runge-Kutta 4 on the index-1 form, with coordinate projection.

The state y = (q, q') follows y' = (q', q''(t, q, q')) with q'' from the seed's eq. (14);
after every step q is projected onto Psi(q, t) = 0 and q' onto Psi_q q' = nu with the
smallest mass-weighted change (``assembly.project_positions`` / ``project_velocities``),
exactly as the adaptive pairs of ``projected_rk.py`` do (Hairer, Lubich, Roche 1989; Hairer
and Wanner, Solving ODEs II, sec. VII.2). No error control: the step sets the accuracy
(global error O(h^4)); divergence, a projection that fails and a non-finite state raise.
"""

from __future__ import annotations

import math

import numpy as np

from .. import kernel_jit
from ..assembly import PROJECTION_MAX_ITER
from ..errors import SolverError
from .energy_audit import ENERGY_DIVERGENCE_FRACTION, ENERGY_ROUNDOFF
from .projected_rk import PROJECTION_TOL_FACTOR, PROJECTION_TOL_FLOOR, ProjectedRK, rk_stages

# The classic tableau (Kutta 1901; Hairer, Norsett, Wanner I, Table II.1.1).
RK4_A = np.array([[0.0, 0.0, 0.0, 0.0],
                  [0.5, 0.0, 0.0, 0.0],
                  [0.0, 0.5, 0.0, 0.0],
                  [0.0, 0.0, 1.0, 0.0]])
RK4_B = np.array([1.0, 2.0, 2.0, 1.0]) / 6.0
RK4_C = np.array([0.0, 0.5, 0.5, 1.0])


def rk4_step(rhs, t: float, y: np.ndarray, h: float, f0: np.ndarray) -> np.ndarray:
    """One classic RK4 step of y' = rhs(t, y) from (t, y) with f0 = rhs(t, y); returns y(t+h)."""
    K = rk_stages(rhs, t, y, h, RK4_A, RK4_C, f0, 4)
    return y + h * (K[:-1].T @ RK4_B)


class RK4P(ProjectedRK):
    """Classic RK4, fixed step, with mass-weighted coordinate projection after each step.

    Mechanisms whose applied forces are constant (``System.fused_steps``: numba kernel,
    gravity, constant torques, constant forces at centres of mass) run whole sequences of steps compiled in one call
    (``kernel_jit.rk4p_steps``), with the same time grid, projections and checks.
    """

    name = "rk4p"
    summary = "index-1, classic Runge-Kutta 4, fixed step, mass-weighted coordinate projection"
    adaptive = False
    default_step = 1e-3

    def _step_impl(self, h):
        t, t_new = self.t, self.t + h
        y_new = rk4_step(self._rhs_y, t, np.concatenate((self.q, self.qd)), h, self.f)
        self.check_finite(t_new, y_new)
        try:
            q, qd = self._project(t_new, y_new)
        except SolverError as exc:
            reason = str(exc).split(": ", 1)[1] if exc.t is not None else str(exc)
            raise SolverError(f"{self.name}: step {h:.3g} s too large, {reason}", t_new) from None
        f = self._rhs(t_new, q, qd)
        self.check_finite(t_new, f)
        self.q, self.qd, self.f = q, qd, f
        return True, h

    def _advance_fixed(self, t_target: float) -> None:
        """The base class's loop, with runs of steps compiled in one call when possible."""
        if not self.system.fused_steps:
            return super()._advance_fixed(t_target)
        t0 = self.t
        n = max(1, math.ceil((t_target - t0) / self.h - 1e-9))
        h = (t_target - t0) / n
        k = 0
        while k < n:
            done, status = self._compiled_steps(t0, h, k, n)
            k += done
            self.t = t0 + k * h if k < n else t_target
            self.stats.nsteps += done
            if status in (3, 4):          # the check after the last step failed: say why
                self.check_finite(self.t, self.q, self.qd, self.f)
                self._after_step()
            elif status in (1, 2):
                # a singular Schur complement (minimum-norm solves) or a failed projection
                # (its message names the constraint): this step on the general path
                self._step_impl(h)
                k += 1
                self.t = t0 + k * h if k < n else t_target
                self.stats.nsteps += 1
                self._after_step()

    def _compiled_steps(self, t0: float, h: float, k: int, n: int) -> tuple[int, int]:
        """Steps k..n-1 of the grid t0 + j h in one compiled call; (steps done, status of
        ``kernel_jit.rk4p_steps``). The energy audit's running state goes in and out."""
        audit = self.audit
        state = np.zeros(len(kernel_jit.AUDIT_FIELDS))
        if audit is not None:
            state[:] = [1.0] + [getattr(audit, name) for name in kernel_jit.AUDIT_FIELDS[1:]]
        tol = max(PROJECTION_TOL_FACTOR * self.atol, PROJECTION_TOL_FLOOR) * self.system.length_scale
        size = self.q.size
        q, qd, qdd, done, status = self.system.rk4p_steps(
            t0 + h * np.arange(k, n), self.q, self.qd, self.f[size:], h, state, tol=tol,
            max_iter=PROJECTION_MAX_ITER, divergence_fraction=ENERGY_DIVERGENCE_FRACTION,
            roundoff=ENERGY_ROUNDOFF)
        if audit is not None:
            for name, value in zip(kernel_jit.AUDIT_FIELDS[1:], state[1:]):
                setattr(audit, name, int(value) if name == "checks" else float(value))
            if status == 3:               # _after_step checks this state again: count it once
                audit.checks -= 1
        self.q, self.qd, self.f = q, qd, np.concatenate((qd, qdd))
        self.stats.naccel += 4 * done
        self.stats.nprojections += done
        return done, status
