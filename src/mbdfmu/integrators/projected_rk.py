"""Index-1 form integrated by an embedded Runge-Kutta pair, with coordinate projection.

The state y = (q, q') follows y' = (q', q''(t, q, q')) with q'' from eq. (14) (the index-1
form). After every accepted step, q is projected onto Psi(q, t) = 0 and q' onto
Psi_q q' = nu, each with the smallest mass-weighted change (``equations.projection``), which
removes the drift of the index-1 form without changing its order. The Butcher tableaux and
interpolants are scipy's (``scipy.integrate.RK45`` and ``DOP853``; the tableaux as data in
``tableaux.py``, which an FMU imports without scipy.integrate): a method here is a
tableau, its error estimate, its dense output and a name.

Step control (Hairer, Norsett and Wanner, Solving ODEs I, sec. II.4) with two additions:

* it aims at ``local_tolerance`` times rtol and atol per step, so that the error at the
  end of a run, which adds up the errors of its steps, is of the order of rtol (the
  tolerances a user gives are meant for the result, not for one step);
* a step's energy change is a second error estimate (``energy_audit.py``); an energy error
  that does not fall when the step is retried smaller comes from the projection, not the
  step size (the conditioning next to a singular configuration): accepted while it stays
  within what the whole run may drift, and otherwise the run stops, since a jump that
  large is a projection onto another branch (the velocity projected onto the other
  branch's tangent loses energy), never to be accepted.

Singular configurations: ``singular_zone.py`` plans the steps across them; near one the
error estimate counts only its part along the constraints (``_tangent``). Outputs between
steps come from dense output (``dense_output.py``), projected like the steps' ends.
"""

from __future__ import annotations

import math

import numpy as np

from ..equations.projection import PROJECTION_MAX_ITER, project_positions, project_velocities
from ..equations.sparsity import schur_solve
from ..errors import SolverError
from . import c_steps, dense_output, singular_zone, starting_step
from .adaptive import ERR_OLD_MIN, AdaptiveStepping, accepted_step, rejected_step
from .base import Integrator, OutputPoint
from . import tableaux
from .energy_audit import ENERGY_STEP_FACTOR, ENERGY_TOL_FACTOR

SAFETY = 0.9       # Multiply the optimal step by this, to be likely accepted.
MIN_FACTOR = 0.2   # Minimum allowed decrease of the step after a rejection.
MAX_FACTOR = 10.0  # Maximum allowed increase of the step after an acceptance.
# The PI controller's beta (adaptive.py), Hairer's stabilisation parameter: his DOPRI5
# code's default; his DOP853 code defaults to 0 (the I controller), but with 0.04 dop853p
# takes fewer evaluations for the same error on the bench's long runs (docs/performance_history.md).
PI_BETA = 0.04
# Projection tolerance, relative to atol and to the mechanism's size, with a floor near
# rounding so that Newton always converges; atol above PROJECTION_ATOL_MAX (a loose
# fixed-step accuracy) does not loosen it: a loose projection near a singular configuration
# would put the state on the other branch.
PROJECTION_TOL_FACTOR = 1e-2
PROJECTION_TOL_FLOOR = 1e-13
PROJECTION_ATOL_MAX = 1e-8
# A step rejected for its energy change is retried smaller while that divides the energy
# error by at least 1 / ENERGY_MIN_GAIN; when it does not, the energy error is not the
# step size's: accepted while it is within what the whole run may drift (the energy
# audit's allowance; in units of ``EnergyAudit.step_error``), else the run stops.
ENERGY_MIN_GAIN = 0.5
ENERGY_JUMP_LIMIT = ENERGY_TOL_FACTOR / ENERGY_STEP_FACTOR


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


def projection_tol(integrator) -> float:
    """Max-norm of Psi (m or rad) the position projections of a method reach."""
    return (max(PROJECTION_TOL_FACTOR * min(integrator.atol, PROJECTION_ATOL_MAX),
                PROJECTION_TOL_FLOOR) * integrator.equations.length_scale)


class ProjectedRK(AdaptiveStepping, Integrator):
    """Base of the embedded pairs: subclasses give the tableau (A, B, C, error weights)."""

    adaptive = True
    dense_output = True
    local_tolerance = 1e-2   # the step control's target, times rtol and atol, per step
    interpolant: str | None = None     # dense output: a key of ckernel.DENSE_KINDS
    state_fields = ("f", "energy_rejected", "dense", "zone", "err_old")
    beta = PI_BETA
    alpha: float          # the PI controller's exponent of the error (Hairer's)
    err_old = ERR_OLD_MIN   # the controller's memory: the last kept accepted step's error
    err_step = 0.0        # the error of the step just accepted
    A: np.ndarray
    B: np.ndarray
    C: np.ndarray
    order: int            # order of the error estimator, for the step controller
    n_stages: int
    # y' at a trial's unprojected end feeds the error estimate where its weight is not 0,
    # the dense output and a watch; an advance that needs none skips it (_advance_adaptive)
    error_reads_end, skip_end = True, False

    def _advance_adaptive(self, t_target, dense):
        self.skip_end = not (dense or self.error_reads_end or self.watch is not None
                             or self.equations.sliding)
        try:
            super()._advance_adaptive(t_target, dense)
        finally:
            self.skip_end = False

    def restart(self):
        started = starting_step.start_in_c(self) if type(self)._rhs is ProjectedRK._rhs else None
        if started is None:
            started = (self._rhs(self.t, self.q, self.qd),
                       singular_zone.indicator(self, self.t, self.q))
        self.f = started[0]
        self.energy_rejected = None  # energy error of the last step rejected for it
        self.dense = None            # the last step, for outputs inside it
        self.zone = singular_zone.SingularZone()
        self.zone.indicator = started[1]
        if self.h is None:
            self.h = self._initial_step()
            self.err_old = ERR_OLD_MIN

    def _error_kept(self):
        self.err_old = max(self.err_step, ERR_OLD_MIN)

    def _rhs(self, t, q, qd):
        qdd, _ = self.accelerations(t, q, qd)
        return np.concatenate((qd, qdd))

    def _rhs_y(self, t, y):
        n = self.q.size
        return self._rhs(t, y[:n], y[n:])

    def _scale(self, y, y_new):
        return self.local_tolerance * (self.atol + self.rtol * np.maximum(np.abs(y), np.abs(y_new)))

    def _initial_step(self) -> float:
        return starting_step.initial_step(self)

    def _error_norm(self, K, h, scale, tangent=None):
        raise NotImplementedError

    def _tangent(self, t, q):
        """x -> its part along the constraints at (t, q) in the mass metric,
        x - M^-1 J^T (J M^-1 J^T)^+ J x, for the (dq, dq') halves of an error estimate: what
        the projection after the step keeps."""
        n, minv = self.q.size, self.equations.minv
        _, J = self.constraints(t, q, sparse=True)

        def tangent(v):
            out = np.empty_like(v)
            for half in (slice(0, n), slice(n, 2 * n)):
                out[half] = v[half] - minv * (J.T @ schur_solve(J, minv, J @ v[half]))
            return out
        return tangent

    def _projection_tol(self) -> float:
        return projection_tol(self)

    def _project(self, t_new, y_new):
        """Mass-weighted projection of y_new = (q, q') onto the constraints at t_new;
        SolverError when Newton does not converge."""
        n, eq = self.q.size, self.equations
        u = self.inputs(t_new)
        if eq.ckernel is not None:      # None: the numpy path's case (it says why)
            done = eq.ckernel.project(y_new[:n], y_new[n:], eq.motion_values(t_new, u),
                                      projection_tol(self), PROJECTION_MAX_ITER)
            if done is not None:
                self.stats.nprojections += 1
                return done
        q, _ = project_positions(eq, t_new, y_new[:n], tol=projection_tol(self), u=u)
        qd = project_velocities(self.equations, t_new, q, y_new[n:], u)
        self.stats.nprojections += 1
        return q, qd

    def _plan_step(self, h, landing, proposal):
        return singular_zone.plan(self, self.zone, h, landing, proposal)

    def _steps_in_c(self, t_target, dense, rejections):
        cls = type(self)
        if not (cls._step_impl is ProjectedRK._step_impl and
                cls._plan_step is ProjectedRK._plan_step and c_steps.prk_runs(self)):
            return None
        status, rejections = c_steps.prk_run(self, t_target, dense, rejections,
                                             (SAFETY, MIN_FACTOR, MAX_FACTOR),
                                             (ENERGY_MIN_GAIN, ENERGY_JUMP_LIMIT))
        if status == c_steps.RUN_FAILED:
            self._step_size_failed()
        if status == c_steps.RUN_ENERGY:
            self._after_step()                 # says why
        return rejections, status == c_steps.RUN_PYTHON

    def _step_impl(self, h):
        t0, c0 = self.t, self.zone.indicator
        ok, h_next, state = self._attempt(h, c0)
        if not ok:
            return False, h_next
        q, qd, f, c1, dense = state
        retry = singular_zone.after_step(self.zone, t0, h, c0, c1)
        if retry is not None:
            return False, retry
        self.q, self.qd, self.f, self.dense = q, qd, f, dense
        self.zone.indicator = c1
        return True, h_next

    def _attempt(self, h, c0):
        """One step of size h from the current state: (accepted, h_next, state)."""
        if self.equations.ckernel is not None:
            stepped = c_steps.prk_attempt(self, h, c0, SAFETY, MIN_FACTOR, MAX_FACTOR)
            if stepped is not None:      # else a case the kernel hands back: in Python
                return stepped
        t, n = self.t, self.q.size
        y = np.concatenate((self.q, self.qd))
        K = rk_stages(self._rhs_y, t, y, h, self.A, self.C, self.f, self.n_stages)
        y_new = y + h * (K[:-1].T @ self.B)
        K[-1] = 0.0 if self.skip_end else self._rhs_y(t + h, y_new)
        if not (np.all(np.isfinite(y_new)) and np.all(np.isfinite(K[-1]))):
            return False, h * MIN_FACTOR, None
        t_new = t + h
        c1 = singular_zone.indicator(self, t_new, y_new[:n])
        near = min(c0, c1) < singular_zone.NEAR_ZONE
        err = self._error_norm(K, h, self._scale(y, y_new),
                               self._tangent(t_new, y_new[:n]) if near else None)
        if not err < 1.0:
            return False, rejected_step(h, err, self.alpha, SAFETY, MIN_FACTOR), None
        try:
            q, qd = self._project(t_new, y_new)
        except SolverError:
            return False, h * 0.5, None   # a projection that fails is an error too large
        rejected = self._energy_rejects(t_new, q, qd, h)
        if rejected is not None:
            return False, rejected, None
        f = self._rhs(t_new, q, qd)
        dense = None if self.skip_end else dense_output.DenseStep(t, h, y, y_new, K)
        self.err_step = err
        return True, accepted_step(h, err, self.err_old, self.alpha, self.beta, SAFETY,
                                   MAX_FACTOR), (q, qd, f, c1, dense)

    def _energy_rejects(self, t_new, q, qd, h) -> float | None:
        """The step's energy change as a second error estimate: None to accept, else the
        step to retry with (see the module docstring)."""
        if self.audit is None:
            return None
        energy_err = self.audit.step_error(self.equations, t_new, q, qd)
        last, self.energy_rejected = self.energy_rejected, None
        if energy_err <= 1.0:
            return None
        if last is None or energy_err < ENERGY_MIN_GAIN * last:
            self.energy_rejected = energy_err
            return rejected_step(h, energy_err, self.alpha, SAFETY, MIN_FACTOR)
        if energy_err <= ENERGY_JUMP_LIMIT:
            return None
        jump = abs(self.equations.total_energy(q, qd) - self.audit.last_energy)
        raise SolverError(
            f"{self.name}: the energy jumps by {jump:.3g} J in a step however small "
            f"({energy_err:.3g} times what rtol = {self.rtol:g}, atol = {self.atol:g} allow a "
            "step): the projection put the state on another branch" + self.singularity_hint(),
            self.t)

    def _output_at(self, t: float) -> OutputPoint:
        """The state at t inside the last step: its interpolant, projected (the
        interpolant itself where the projection does not converge, next to a singular
        configuration)."""
        if t >= self.t:
            return None
        step = self.dense
        if step is None or not step.contains(t):
            raise SolverError(f"{self.name}: no step holds the output time {t:.9g} s", self.t)
        if self.load_dense_output(t):
            # the C kernel's: what an FMU's wrapper serves by itself (ckernel/dense.h)
            done = self.equations.ckernel.dense_state(t)
            if done is not None:
                self.stats.nprojections += 1
                return OutputPoint(t, *done)
        if step.coefficients is None:
            step.coefficients = self._interpolant(step)
        y = self._interpolated(step, (t - step.t_old) / step.h)
        try:
            q, qd = self._project(t, y)
        except SolverError:
            n = self.q.size
            q, qd = y[:n], y[n:]
        return OutputPoint(t, q, qd)

    def load_dense_output(self, t: float) -> bool:
        """Put the last step's dense output, with the inputs at t held over it, into the C
        kernel (``Kernel.load_dense``); False without a kernel, an interpolant or a step."""
        eq, step = self.equations, self.dense
        if eq.ckernel is None or self.interpolant is None or step is None:
            return False
        if step.coefficients is None:
            step.coefficients = self._interpolant(step)
        u = self.inputs(t)
        eq.ckernel.load_dense(self.interpolant, step, eq.motion_values(t, u), u.forces,
                              projection_tol(self), PROJECTION_MAX_ITER)
        return True

    def _interpolant(self, step):
        raise NotImplementedError

    def _interpolated(self, step, x):
        raise NotImplementedError


class RK45P(ProjectedRK):
    """Dormand-Prince 5(4) with coordinate projection."""

    name = "rk45p"
    summary = "index-1, Dormand-Prince 5(4), adaptive, mass-weighted coordinate projection"
    A, B, C, E, P = (tableaux.RK45_A, tableaux.RK45_B, tableaux.RK45_C, tableaux.RK45_E,
                     tableaux.RK45_P)
    n_stages, order = tableaux.RK45_STAGES, 4
    # the I controller: with PI_BETA and Hairer's DOPRI5 alpha, more evaluations for the
    # same error at tight tolerances, and P2 N = 2 stopping at rtol 1e-8 next to a
    # singular crossing (docs/performance_history.md)
    beta = 0.0
    alpha = 1.0 / (order + 1)
    interpolant = "rk45"

    def _error_norm(self, K, h, scale, tangent=None):
        e = h * (K.T @ self.E)
        if tangent is not None:
            e = tangent(e)
        return float(np.sqrt(np.mean((e / scale) ** 2)))

    def _interpolant(self, step):
        # with the C kernel its function, which the FMU wrapper's dense runs call too
        kernel = self.equations.ckernel
        if kernel is not None:
            return kernel.rk45_dense(step.K, self.P)
        return dense_output.rk45_interpolant(step, self.P)

    def _interpolated(self, step, x):
        return dense_output.rk45_value(step, x)


class DOP853P(ProjectedRK):
    """Dormand-Prince 8(5,3) with coordinate projection: the default for smooth scenes."""

    name = "dop853p"
    summary = "index-1, Dormand-Prince 8(5,3), adaptive, mass-weighted coordinate projection"
    A, B, C = tableaux.DOP853_A, tableaux.DOP853_B, tableaux.DOP853_C
    n_stages, order = tableaux.DOP853_STAGES, 7
    alpha = 1.0 / (order + 1) - 0.2 * PI_BETA       # Hairer's DOP853
    E3, E5 = tableaux.DOP853_E3, tableaux.DOP853_E5
    error_reads_end = bool(E3[-1] or E5[-1])        # both 0: Hairer's estimate skips it
    interpolant = "dop853"

    def _error_norm(self, K, h, scale, tangent=None):
        # Hairer's combined 5th/3rd order estimate, as in scipy's DOP853.
        e5, e3 = K.T @ self.E5, K.T @ self.E3
        if tangent is not None:
            e5, e3 = tangent(e5), tangent(e3)
        err5 = np.linalg.norm(e5 / scale) ** 2
        err3 = np.linalg.norm(e3 / scale) ** 2
        if err5 == 0.0:     # also when 0.01 err3 underflows (a body held at rest): not 0 / 0
            return 0.0
        return float(abs(h) * err5 / math.sqrt((err5 + 0.01 * err3) * scale.size))

    def _interpolant(self, step):
        kernel = self.equations.ckernel
        if kernel is not None:      # the wrapper's dense runs build it by the same function
            times = step.t_old + tableaux.DOP853_C_EXTRA * step.h
            us = [self.inputs(t) for t in times]
            motions = self.equations.constraint_set.motion_block(times, us).reshape(
                len(times), -1)     # each row (c, c', c'') at its time: motion_values
            F = kernel.dop853_dense(step.K, step.y_old, step.y_new, step.h,
                                    tableaux.DOP853_A_EXTRA, tableaux.DOP853_D, motions,
                                    [u.forces if len(u.forces) else [0.0] for u in us])
            if F is not None:
                self.stats.naccel += len(times)
                return F
        return dense_output.dop853_interpolant(step, self._rhs_y)

    def _interpolated(self, step, x):
        return dense_output.dop853_value(step, x)

