"""Classic fixed-step Runge-Kutta 4 on the index-1 form, with coordinate projection.

The state y = (q, q') follows y' = (q', q''(t, q, q')) with q'' from the seed's eq. (14);
after every step q is projected onto Psi(q, t) = 0 and q' onto Psi_q q' = nu with the
smallest mass-weighted change (``assembly.project_positions`` / ``project_velocities``),
exactly as the adaptive pairs of ``projected_rk.py`` do (Hairer, Lubich, Roche 1989; Hairer
and Wanner, Solving ODEs II, sec. VII.2). No error control: the step sets the accuracy
(global error O(h^4)); divergence, a projection that fails and a non-finite state raise.
"""

from __future__ import annotations

import numpy as np

from ..errors import SolverError
from .projected_rk import ProjectedRK, rk_stages

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
