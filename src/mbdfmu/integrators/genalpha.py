"""Generalized-alpha on the index-3 equations, with a scaled iteration matrix.

Arnold and Bruls, "Convergence of the generalized-alpha scheme for constrained mechanical
systems", Multibody Syst. Dyn. 18 (2007) 185-202, eqs. (8)-(10) and Algorithm 1: at
t_{n+1} = t_n + h the equations of motion and the position constraints hold exactly,

    M q''_{n+1} + Psi_q^T lam_{n+1} = F(t_{n+1}, q_{n+1}, q'_{n+1}),   Psi(q_{n+1}, t_{n+1}) = 0,

with Newmark's formulas on an algorithmic acceleration a,

    q_{n+1}  = q_n + h q'_n + h^2 (1/2 - beta) a_n + h^2 beta a_{n+1},
    q'_{n+1} = q'_n + h (1 - gamma) a_n + h gamma a_{n+1},
    (1 - alpha_m) a_{n+1} + alpha_m a_n = (1 - alpha_f) q''_{n+1} + alpha_f q''_n,

and Chung and Hulbert's parameters for a spectral radius rho_inf at infinite frequency
(1993, eq. 25): alpha_m = (2 rho - 1)/(rho + 1), alpha_f = rho/(rho + 1),
gamma = 1/2 + alpha_f - alpha_m, beta = (gamma + 1/2)^2 / 4. Second order; rho_inf = 1 keeps
all energy (no damping), smaller values damp the high frequencies, rho_inf = 0 the most.

Newton on (q''_{n+1}, lam_{n+1}), scaled as Negrut, Rampalli, Ottarsson, Sajdak (2007, HHT-I3,
J. Comput. Nonlinear Dynam. 2, eq. 17) and Arnold-Bruls (sec. 4): the unknowns are the
position increment dq = D dq'' and D dlam with D = beta' = h^2 beta (1 - alpha_f)/(1 - alpha_m),
the dynamic rows are multiplied by D, so the iteration matrix

    [[M + G C_t + D K_t,  Psi_q^T],     G = h gamma (1 - alpha_f)/(1 - alpha_m),
     [Psi_q,              0      ]]     K_t = d(Psi_q^T lam)/dq - dF/dq,  C_t = -dF/dq',

tends to eq. 14's matrix as h -> 0 instead of growing like 1/h^2. K_t's geometric part is
``System.constraint_hessian``; the force Jacobians are forward differences (skipped when F is
constant). ``jacobian="mass"`` keeps only [[M, Psi_q^T], [Psi_q, 0]], which suffices at small
steps.

Velocities: the index-3 scheme does not satisfy Psi_q q' = nu exactly (an O(h^2) violation
in Arnold-Bruls); here q'_{n+1} is additionally projected onto it with the smallest
kinetic-energy change (``assembly.project_velocities``), as ALI3-P does, so that outputs and
reactions see consistent velocities. The algorithmic acceleration a is kept as computed.

The iteration matrix of a mechanism at a singular configuration or with redundant
constraints is singular: the step is halved and retried, and the run stops with that reason
(use ``ali3p`` there).
"""

from __future__ import annotations

import numpy as np

from ..assembly import project_velocities
from ..errors import SolverError
from .base import Integrator
from .implicit import (NEWTON_MAX_ITER, IterationMatrix, NewtonFailure, advance_with_halving,
                       check_rate, converged, increment_converged,
                       newton_tolerance)

# Numerical damping: spectral radius at infinite frequency (1: none, 0: the most).
RHO_INF = 0.8


def genalpha_coefficients(rho_inf: float) -> tuple[float, float, float, float]:
    """(alpha_m, alpha_f, beta, gamma) of Chung and Hulbert (1993, eq. 25) for rho_inf in [0, 1]."""
    am = (2.0 * rho_inf - 1.0) / (rho_inf + 1.0)
    af = rho_inf / (rho_inf + 1.0)
    gamma = 0.5 + af - am
    return am, af, 0.25 * (gamma + 0.5) ** 2, gamma


class GeneralizedAlpha(Integrator):
    """Implicit index-3 generalized-alpha, fixed step, Newton with a scaled iteration matrix."""

    name = "genalpha"
    summary = ("index-3 generalized-alpha (Arnold-Bruls), implicit, fixed step, numerical "
               "damping rho_inf, scaled Newton matrix")
    default_step = 1e-3
    option_names = ("rho_inf", "jacobian")
    state_fields = ("a", "qdd", "lam", "matrix")

    def __init__(self, system, t0, q0, qd0, *, rho_inf: float = RHO_INF,
                 jacobian: str = "full", **common):
        if not 0.0 <= float(rho_inf) <= 1.0:
            raise SolverError(f"genalpha: rho_inf must be in [0, 1], got {rho_inf}")
        if jacobian not in ("full", "mass"):
            raise SolverError(f'genalpha: jacobian must be "full" or "mass", got "{jacobian}"')
        self.rho_inf, self.jacobian = float(rho_inf), jacobian
        self.coefficients = genalpha_coefficients(self.rho_inf)
        self.matrix = IterationMatrix()
        super().__init__(system, t0, q0, qd0, **common)

    def restart(self):
        self.qdd, self.lam = self.accelerations(self.t, self.q, self.qd)
        self.a = self.qdd.copy()
        self.matrix = IterationMatrix()

    def _step_impl(self, h):
        self.stats.nrejected += advance_with_halving(self._try_step, self.t, h, self.name)
        return True, h

    def _iteration_matrix(self, t, q, qd, J, lam, D, G):
        system, n = self.system, self.system.n
        S = np.zeros((n + system.m, n + system.m))
        S[:n, :n] = np.diag(system.mass)
        if self.jacobian == "full":
            dFdq, dFdv = system.force_jacobians(t, q, qd)
            S[:n, :n] += D * (system.constraint_hessian(q, lam) - dFdq) - G * dFdv
        S[:n, n:] = J.T
        S[n:, :n] = J
        return S

    def _try_step(self, t, h):
        """One step from (t, self.q, ...) to t + h; updates the state or raises NewtonFailure."""
        system, n = self.system, self.system.n
        am, af, beta, gamma = self.coefficients
        t1 = t + h
        D = h * h * beta * (1.0 - af) / (1.0 - am)
        G = h * gamma * (1.0 - af) / (1.0 - am)
        q_n, v_n, a_n, qdd_n = self.q, self.qd, self.a, self.qdd
        # predictor: Newmark with q''_{n+1} = q''_n (a_{n+1} then follows)
        a = (af * qdd_n - am * a_n + (1.0 - af) * qdd_n) / (1.0 - am)
        q = q_n + h * v_n + h * h * ((0.5 - beta) * a_n + beta * a)
        qd = v_n + h * ((1.0 - gamma) * a_n + gamma * a)
        qdd, lam = qdd_n.copy(), self.lam.copy()
        tol = newton_tolerance(self.atol, h, system.length_scale)
        matrix = self.matrix
        if not matrix.valid_for(h):
            matrix.lu = None
        matrix.fresh = False
        previous, size = None, np.inf
        for _ in range(NEWTON_MAX_ITER):
            self.stats.nnewton += 1
            Psi, J = system.constraints(t1, q)
            F = system.forces(t1, q, qd)
            dynamic = D * (system.mass * qdd + J.T @ lam - F)
            if not np.all(np.isfinite(dynamic)):
                raise NewtonFailure("non-finite residual")
            if converged(size, dynamic / system.mass, Psi, tol):
                break
            if matrix.lu is None:
                matrix.factor(self._iteration_matrix(t1, q, qd, J, lam, D, G), h, self.stats)
            dx = -matrix.solve(np.concatenate((dynamic, Psi)))
            size = float(np.max(np.abs(dx[:n])))
            if not np.isfinite(size):
                raise NewtonFailure("non-finite Newton increment")
            q = q + dx[:n]
            qd = qd + (G / D) * dx[:n]
            qdd = qdd + dx[:n] / D
            lam = lam + dx[n:] / D
            if increment_converged(size, previous, tol):
                break
            previous = check_rate(matrix, size, previous)
        else:
            raise NewtonFailure(f"Newton did not converge in {NEWTON_MAX_ITER} iterations "
                                f"(last increment {size:.3g}, constraint residual "
                                f"{np.max(np.abs(Psi), initial=0.0):.3g}, tolerance {tol:.3g})")
        self.a = (af * qdd_n - am * a_n + (1.0 - af) * qdd) / (1.0 - am)
        self.q, self.qdd, self.lam = q, qdd, lam
        self.qd = project_velocities(system, t1, q, qd)
        self.stats.nprojections += 1
        self.check_finite(t1, self.q, self.qd)
