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

from ..assembly import PROJECTION_MAX_ITER
from ..errors import SolverError
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
    """Classic RK4, fixed step, with mass-weighted coordinate projection after each step."""

    name = "rk4p"
    summary = "index-1, classic Runge-Kutta 4, fixed step, mass-weighted coordinate projection"
    adaptive = False
    default_step = 1e-3

    def _step_impl(self, h):
        if self.system.fused_steps:
            done = self._fused_step(h)
            if done:
                return True, h
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

    def _fused_step(self, h) -> bool:
        """The same step compiled in one call (``kernel_jit.rk4p_step``); False to redo it
        on the general path (a singular Schur complement needs the minimum-norm solve)."""
        tol = max(PROJECTION_TOL_FACTOR * self.atol, PROJECTION_TOL_FLOOR) * self.system.length_scale
        n = self.q.size
        q, qd, qdd, status = self.system.rk4p_step(self.t, self.q, self.qd, self.f[n:], h,
                                                   tol=tol, max_iter=PROJECTION_MAX_ITER)
        if status == 1:
            return False
        if status == 2:
            raise SolverError(f"{self.name}: step {h:.3g} s too large, position projection "
                              f"did not converge in {PROJECTION_MAX_ITER} iterations", self.t + h)
        if not math.isfinite(q.sum() + qd.sum() + qdd.sum()):   # one reduction for all three
            self.check_finite(self.t + h, q, qd, qdd)
        self.q, self.qd, self.f = q, qd, np.concatenate((qd, qdd))
        self.stats.naccel += 4
        self.stats.nprojections += 1
        return True
