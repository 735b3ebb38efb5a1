"""Index-1 form integrated by an embedded Runge-Kutta pair, with coordinate projection.

The state y = (q, q') follows y' = (q', q''(t, q, q')) with q'' from eq. (14) (the index-1
form). After every accepted step, q is projected onto Psi(q, t) = 0 and q' onto
Psi_q q' = nu, each with the smallest mass-weighted change (``equations.projection``), which
removes the drift of the index-1 form without changing its order. The Butcher tableaux are
scipy's (``scipy.integrate.RK45`` and ``DOP853``): a method here is a tableau plus a name.
"""

from __future__ import annotations

import math

import numpy as np
from scipy.integrate import DOP853, RK45

from ..equations.projection import project_positions, project_velocities
from ..errors import SolverError
from . import c_steps
from .base import Integrator

SAFETY = 0.9       # Multiply the optimal step by this, to be likely accepted.
MIN_FACTOR = 0.2   # Minimum allowed decrease of the step after a rejection.
MAX_FACTOR = 10.0  # Maximum allowed increase of the step after an acceptance.
# Projection tolerance, relative to atol and to the mechanism's size, with a floor near
# rounding so that Newton always converges.
PROJECTION_TOL_FACTOR = 1e-2
PROJECTION_TOL_FLOOR = 1e-13
# A step rejected for its energy change is retried smaller only while that divides the
# energy error by at least 1 / ENERGY_MIN_GAIN.
ENERGY_MIN_GAIN = 0.5


def rk_stages(rhs, t: float, y: np.ndarray, h: float, A: np.ndarray, C: np.ndarray,
              f0: np.ndarray, n_stages: int) -> np.ndarray:
    """Stage derivatives K (n_stages + 1, len(y)) of an explicit Runge-Kutta tableau (A, C).

    ``rhs(t, y)`` is y' = f(t, y); ``K[0] = f0 = f(t, y)``; the last row is left for the
    caller (FSAL pairs fill it with f(t + h, y_new)). Hairer, Norsett, Wanner, Solving ODEs I,
    eq. II.1.8.
    """
    K = np.empty((n_stages + 1, y.size))
    K[0] = f0
    for s in range(1, n_stages):
        K[s] = rhs(t + C[s] * h, y + h * (K[:s].T @ A[s, :s]))
    return K


class ProjectedRK(Integrator):
    """Base of the embedded pairs: subclasses give the tableau (A, B, C, error weights)."""

    adaptive = True
    state_fields = ("f", "energy_rejected")
    A: np.ndarray
    B: np.ndarray
    C: np.ndarray
    order: int            # order of the error estimator, for the step controller
    n_stages: int

    def restart(self):
        self.f = self._rhs(self.t, self.q, self.qd)
        self.energy_rejected = None  # energy error of the last step rejected for it
        if self.h is None:
            self.h = self._initial_step()

    def _rhs(self, t, q, qd):
        qdd, _ = self.accelerations(t, q, qd)
        return np.concatenate((qd, qdd))

    def _scale(self, y, y_new):
        return self.atol + self.rtol * np.maximum(np.abs(y), np.abs(y_new))

    def _initial_step(self) -> float:
        """Hairer, Norsett and Wanner's starting step (Solving ODEs I, II.4)."""
        y = np.concatenate((self.q, self.qd))
        scale = self.atol + self.rtol * np.abs(y)
        d0 = np.sqrt(np.mean((y / scale) ** 2))
        d1 = np.sqrt(np.mean((self.f / scale) ** 2))
        h0 = 1e-6 if d0 < 1e-5 or d1 < 1e-5 else 0.01 * d0 / d1
        h0 = min(h0, self.max_step)
        n = self.q.size
        f1 = self._rhs(self.t + h0, *np.split(y + h0 * self.f, [n]))
        d2 = np.sqrt(np.mean(((f1 - self.f) / scale) ** 2)) / h0
        h1 = (max(1e-6, h0 * 1e-3) if d1 <= 1e-15 and d2 <= 1e-15
              else (0.01 / max(d1, d2)) ** (1.0 / (self.order + 1)))
        return min(100 * h0, h1, self.max_step)

    def _error_norm(self, K, h, scale):
        raise NotImplementedError

    def _rhs_y(self, t, y):
        n = self.q.size
        return self._rhs(t, y[:n], y[n:])

    def _projection_tol(self) -> float:
        """Max-norm of Psi the position projection reaches (m or rad)."""
        return (max(PROJECTION_TOL_FACTOR * self.atol, PROJECTION_TOL_FLOOR)
                * self.equations.length_scale)

    def _project(self, t_new, y_new):
        """Mass-weighted projection of y_new = (q, q') onto the constraints at t_new;
        SolverError when Newton does not converge."""
        n = self.q.size
        u = self.inputs(t_new)
        q, _ = project_positions(self.equations, t_new, y_new[:n], tol=self._projection_tol(),
                                 u=u)
        qd = project_velocities(self.equations, t_new, q, y_new[n:], u)
        self.stats.nprojections += 1
        return q, qd

    def _step_impl(self, h):
        if self.equations.ckernel is not None:     # the same step in C (c_steps.py)
            stepped = c_steps.prk_step(self, h, SAFETY, MIN_FACTOR, MAX_FACTOR, ENERGY_MIN_GAIN)
            if stepped is not None:
                return stepped
        t, n = self.t, self.q.size
        y = np.concatenate((self.q, self.qd))
        K = rk_stages(self._rhs_y, t, y, h, self.A, self.C, self.f, self.n_stages)
        y_new = y + h * (K[:-1].T @ self.B)
        K[-1] = self._rhs(t + h, y_new[:n], y_new[n:])
        if not (np.all(np.isfinite(y_new)) and np.all(np.isfinite(K[-1]))):
            return False, h * MIN_FACTOR
        err = self._error_norm(K, h, self._scale(y, y_new))
        if not err < 1.0:
            return False, h * max(MIN_FACTOR, SAFETY * err ** (-1.0 / (self.order + 1)))
        t_new = t + h
        try:
            q, qd = self._project(t_new, y_new)
        except SolverError:
            return False, h * 0.5  # a projection that fails is an error too large
        if self.audit is not None:
            # the step's energy change as a second error estimate (energy_audit.py); not
            # insisted on when a smaller step did not reduce it (a jump that does not come from
            # the step size, e.g. a projection at a singular configuration)
            energy_err = self.audit.step_error(self.equations, t_new, q, qd)
            last, self.energy_rejected = self.energy_rejected, None
            if not energy_err <= 1.0 and (last is None or energy_err < ENERGY_MIN_GAIN * last):
                self.energy_rejected = energy_err
                return False, h * max(MIN_FACTOR, SAFETY * energy_err ** (-1.0 / (self.order + 1)))
        self.q, self.qd = q, qd
        self.f = self._rhs(t_new, q, qd)
        factor = MAX_FACTOR if err == 0 else min(MAX_FACTOR, SAFETY * err ** (-1.0 / (self.order + 1)))
        return True, h * factor


class RK45P(ProjectedRK):
    """Dormand-Prince 5(4) with coordinate projection."""

    name = "rk45p"
    summary = "index-1, Dormand-Prince 5(4), adaptive, mass-weighted coordinate projection"
    A, B, C, E, n_stages, order = RK45.A, RK45.B, RK45.C, RK45.E, RK45.n_stages, 4

    def _error_norm(self, K, h, scale):
        return float(np.sqrt(np.mean((h * (K.T @ self.E) / scale) ** 2)))


class DOP853P(ProjectedRK):
    """Dormand-Prince 8(5,3) with coordinate projection: the default for smooth scenes."""

    name = "dop853p"
    summary = "index-1, Dormand-Prince 8(5,3), adaptive, mass-weighted coordinate projection"
    A, B, C, n_stages, order = DOP853.A, DOP853.B, DOP853.C, DOP853.n_stages, 7
    E3, E5 = DOP853.E3, DOP853.E5

    def _error_norm(self, K, h, scale):
        # Hairer's combined 5th/3rd order estimate, as in scipy's DOP853.
        err5 = np.linalg.norm((K.T @ self.E5) / scale) ** 2
        err3 = np.linalg.norm((K.T @ self.E3) / scale) ** 2
        if err5 == 0.0:     # also when 0.01 err3 underflows (a body held at rest): not 0 / 0
            return 0.0
        return float(abs(h) * err5 / math.sqrt((err5 + 0.01 * err3) * scale.size))
