"""Classic fixed-step Runge-Kutta 4 on the index-1 form, with coordinate projection.

The state y = (q, q') follows y' = (q', q''(t, q, q')) with q'' from eq. (14); after every
step q is projected onto Psi(q, t) = 0 and q' onto Psi_q q' = nu with the smallest
mass-weighted change (``equations.projection``, formulation.md eqs. 18-19),
exactly as the adaptive pairs of ``projected_rk.py`` do (Hairer, Lubich, Roche 1989; Hairer
and Wanner, Solving ODEs II, sec. VII.2). No error control: the step sets the accuracy
(global error O(h^4)); divergence, a projection that fails and a non-finite state raise.
"""

from __future__ import annotations


import numpy as np

from ..equations.projection import PROJECTION_MAX_ITER, ROUNDOFF_RESIDUAL
from ..equations.sparsity import RANK_TOLERANCE
from ..errors import SolverError
from . import c_steps, rk4p_c
from .energy_audit import ENERGY_DIVERGENCE_FRACTION, ENERGY_ROUNDOFF
from .projected_rk import ProjectedRK, projection_tol, rk_stages

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

    Mechanisms whose applied forces never change run whole sequences of steps compiled in
    one call when the numba kernel is in use (``rk4p_compiled.py``), with the same time
    grid, projections and checks.
    """

    name = "rk4p"
    summary = "index-1, classic Runge-Kutta 4, fixed step, mass-weighted coordinate projection"
    adaptive = False
    dense_output = False
    default_step = 1e-3
    orders = (4, 4)
    carry_velocity_error = True

    def _step_impl(self, h):
        t, t_new = self.t, self.t + h
        y_new = rk4_step(self._rhs_y, t, np.concatenate((self.q, self.qd)), h, self.f)
        self.check_finite(t_new, y_new)
        try:
            q, qd = self._project(t_new, y_new)
        except SolverError as exc:
            raise SolverError(f"{self.name}: step {h:.3g} s too large, {exc.reason}",
                              t_new) from None
        f = self._rhs(t_new, q, qd)
        self.check_finite(t_new, f)
        self.q, self.qd, self.f = q, qd, f
        return True, h

    def _advance_fixed(self, t_target):
        """The base class's loop, in the C kernel with its checks when it can take it."""
        if not rk4p_c.advance_fixed(self, t_target):
            super()._advance_fixed(t_target)

    def check_step(self, h):
        """A step of the step-doubling check, compiled when the run's steps are (a Python
        step costs about twenty of them); on the Python path when the compiled one hands it
        back."""
        if self.equations.ckernel is not None and self.equations.m > 0:
            if c_steps.rk4p_check_step(self, h):
                return
        elif self.compiled_steps:
            from .rk4p_compiled import StepStatus
            done, status = self._compiled_steps(self.t, h, 0, 1)
            if done == 1 and status in (StepStatus.DONE, StepStatus.ENERGY):
                return
        self._step_impl(h)

    @property
    def compiled_steps(self) -> bool:
        """Whole runs of steps can be compiled: the numba kernel, constraints, and applied
        forces that never change."""
        eq = self.equations
        return eq.kernel == "numba" and eq.m > 0 and eq.applied.is_constant

    def _fixed_run(self, t0, h, k, stop, n, t_target):
        """The base class's run of steps, compiled in one call when possible; one C call a
        step when the events watch each step."""
        in_c = self.equations.ckernel is not None and self.equations.m > 0
        if self.watch_each_step:
            return rk4p_c.watched_run(self, t0, h, k, stop, n, t_target) if in_c else \
                super()._fixed_run(t0, h, k, stop, n, t_target)
        if in_c:
            return c_steps.rk4p_run(self, t0, h, k, stop, n, t_target)   # the C kernel
        if not self.compiled_steps:
            return super()._fixed_run(t0, h, k, stop, n, t_target)
        from .rk4p_compiled import StepStatus   # numba only when the compiled path runs
        while k < stop:
            done, status = self._compiled_steps(t0, h, k, stop)
            k += done
            self.t = t0 + k * h if k < n else t_target
            self.stats.nsteps += done
            if status in (StepStatus.ENERGY, StepStatus.NOT_FINITE):
                self.check_finite(self.t, self.q, self.qd, self.f)   # say why
                self._after_step()
            elif status in (StepStatus.SINGULAR, StepStatus.PROJECTION):
                # minimum-norm solves, or a failed projection whose message names the
                # constraint: this step on the general path
                k = super()._fixed_run(t0, h, k, k + 1, n, t_target)
            if self.limit is not None:
                self.limit.check(self.stats, self.t, t_target)
        return stop

    def _stage_motions(self, times: np.ndarray, h: float) -> np.ndarray:
        """c, c', c'' of every row at t, t + h/2 and t + h for each step start t, read-only
        (one compiled signature)."""
        eq = self.equations
        if not eq.scene.drivers:     # the motions never change: one block for every step
            block = np.array([eq.motion_values(0.0)] * 3)
            motions = np.repeat(block[None], len(times), axis=0)
        else:
            motions = np.array([[eq.motion_values(t + a, self.inputs(t + a))
                                 for a in (0.0, 0.5 * h, h)] for t in times])
        motions.flags.writeable = False
        return motions

    def _compiled_steps(self, t0: float, h: float, k: int, n: int):
        """Steps k..n-1 of the grid t0 + j h in one compiled call; (steps done, status). The
        energy audit's running state goes in and out."""
        from .rk4p_compiled import AUDIT_ATTRIBUTES, AuditField, StepStatus, rk4p_steps
        audit, eq = self.audit, self.equations
        state = np.zeros(len(AuditField))
        if audit is not None:
            state[AuditField.ACTIVE] = 1.0
            for field, attribute in AUDIT_ATTRIBUTES.items():
                state[field] = getattr(audit, attribute)
        size = self.q.size
        c = eq.constraint_set
        q, qd, qdd, done, status = rk4p_steps(
            self.q, self.qd, self.f[size:], h, self._stage_motions(t0 + h * np.arange(k, n), h),
            eq.applied.constant, eq.minv, RANK_TOLERANCE, projection_tol(self),
            ROUNDOFF_RESIDUAL * eq.length_scale, PROJECTION_MAX_ITER, c.primitives, c.plan,
            eq.mass, state,
            ENERGY_DIVERGENCE_FRACTION, ENERGY_ROUNDOFF)
        status = StepStatus(status)
        if audit is not None:
            for field, attribute in AUDIT_ATTRIBUTES.items():
                value = state[field]
                setattr(audit, attribute, int(value) if field == AuditField.CHECKS else float(value))
            if status == StepStatus.ENERGY:   # _after_step checks this state again: count it once
                audit.checks -= 1
        self.q, self.qd, self.f = q, qd, np.concatenate((qd, qdd))
        self.stats.naccel += 4 * done
        self.stats.nprojections += done
        return done, status
