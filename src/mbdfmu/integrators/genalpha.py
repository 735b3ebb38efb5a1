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
``Equations.constraint_hessian``; the force Jacobians are forward differences (skipped when F is
constant). ``jacobian="mass"`` keeps only [[M, Psi_q^T], [Psi_q, 0]], which suffices at small
steps.

Velocities: the index-3 scheme does not satisfy Psi_q q' = nu exactly (an O(h^2) violation
in Arnold-Bruls); here q'_{n+1} is additionally projected onto it with the smallest
kinetic-energy change (``equations.projection.project_velocities``), as ALI3-P does, so that outputs and
reactions see consistent velocities. The algorithmic acceleration a is kept as computed.

The iteration matrix of a mechanism at a singular configuration or with redundant
constraints is singular: the step is halved and retried, and the run stops with that reason
(use ``ali3p`` there).
"""

from __future__ import annotations

import numpy as np

from ..equations.projection import project_velocities
from .base import Option, number_in
from .implicit_c import CompiledNewton, attempt
from .implicit_control import STEP_CONTROL, StepControl
from .newton import ImplicitMethod, IterationMatrix, newton_iterate, newton_tolerances

# Numerical damping: spectral radius at infinite frequency (1: none, 0: the most).
RHO_INF = 0.8
# ... with step control: a stiff spring's oscillation must die out within a few steps where
# h w is 1 to 10, or the controller cuts the step to resolve it (measured on a 1e8 N/m spring
# on 1 kg: 0.8 took 10 times the steps of 0.5 there, 0.5 as many as at 1e10 and 1e12).
RHO_INF_ADAPTIVE = 0.5


def genalpha_coefficients(rho_inf: float) -> tuple[float, float, float, float]:
    """(alpha_m, alpha_f, beta, gamma) of Chung and Hulbert (1993, eq. 25) for rho_inf in [0, 1]."""
    am = (2.0 * rho_inf - 1.0) / (rho_inf + 1.0)
    af = rho_inf / (rho_inf + 1.0)
    gamma = 0.5 + af - am
    return am, af, 0.25 * (gamma + 0.5) ** 2, gamma


class GeneralizedAlpha(CompiledNewton, StepControl, ImplicitMethod):
    """Implicit index-3 generalized-alpha, fixed step or step control
    (``implicit_control.py``), Newton with a scaled iteration matrix."""

    name = "genalpha"
    summary = ("index-3 generalized-alpha (Arnold-Bruls), implicit, fixed step or "
               "step_control = \"adaptive\", numerical damping rho_inf, scaled Newton matrix")
    default_step = 1e-3
    options = (Option("rho_inf", "a number in [0, 1]", number_in(0.0, 1.0)),
               Option("jacobian", '"full" or "mass"', lambda v: v in ("full", "mass")),
               STEP_CONTROL)
    state_fields = ImplicitMethod.state_fields + ("a",)

    def __init__(self, equations, t0, q0, qd0, *, rho_inf: float | None = None,
                 jacobian: str = "full", step_control: str = "fixed", **common):
        self.adaptive = step_control == "adaptive"
        if rho_inf is None:
            rho_inf = RHO_INF_ADAPTIVE if self.adaptive else RHO_INF
        self.rho_inf, self.jacobian = float(rho_inf), jacobian
        self.coefficients = genalpha_coefficients(self.rho_inf)
        self.matrix = IterationMatrix()
        super().__init__(equations, t0, q0, qd0, **common)

    def restart(self):
        super().restart()
        self.a = self.qdd.copy()

    def step_change(self, ratio: float):
        """The next step is ``ratio`` times the last one: a approximates q'' at
        t_n + (alpha_m - alpha_f) h (``_local_error``), so its offset from q''_n scales with h
        (else the step change leaves an O(h) error in a). Returns what ``restore_history``
        takes back."""
        kept = self.a
        self.a = self.qdd + ratio * (self.a - self.qdd)
        return kept

    def restore_history(self, kept) -> None:
        self.a = kept

    def _iteration_matrix(self, t, q, qd, J, lam, D, G):
        eq = self.equations
        K = np.diag(eq.mass)
        if self.jacobian == "full":
            dFdq, dFdv = eq.force_jacobians(t, self._unwrapped(q), qd, self.inputs(t))
            K = K + D * (eq.constraint_hessian(q, lam) - dFdq) - G * dFdv
        return self.saddle_matrix(K, J)

    def _attempt(self, t, h) -> dict:
        """One step from (t, self.q, ...) to t + h, not yet taken (``_commit`` takes it);
        raises NewtonFailure. Newton's unknown is the position increment dq of the step
        (module ``newton``)."""
        x = attempt(self, t, h)         # in the C kernel where it covers the case
        if x is not None:
            return x
        eq, n = self.equations, self.equations.n
        am, af, beta, gamma = self.coefficients
        t1 = t + h
        D = h * h * beta * (1.0 - af) / (1.0 - am)
        G = h * gamma * (1.0 - af) / (1.0 - am)
        q_n, v_n, a_n, qdd_n = self.qw, self.qd, self.a, self.qdd
        # predictor: Newmark with q''_{n+1} = q''_n (a_{n+1} then follows)
        a = (af * qdd_n - am * a_n + (1.0 - af) * qdd_n) / (1.0 - am)
        x = {"dq": h * v_n + h * h * ((0.5 - beta) * a_n + beta * a),
             "qd": v_n + h * ((1.0 - gamma) * a_n + gamma * a),
             "qdd": qdd_n.copy(), "lam": self.lam.copy()}

        def evaluate():
            x["q"] = q_n + x["dq"]
            Psi, x["J"] = self.constraints(t1, x["q"])
            F = self.forces(t1, self._unwrapped(x["q"]), x["qd"])
            return D * (eq.mass * x["qdd"] + x["J"].T @ x["lam"] - F), Psi

        def apply(dx):
            x["dq"] = x["dq"] + dx[:n]
            x["qd"] = x["qd"] + (G / D) * dx[:n]
            x["qdd"] = x["qdd"] + dx[:n] / D
            x["lam"] = x["lam"] + dx[n:] / D

        tols = newton_tolerances(self.atol, h, eq.length_scale, q_n, D, qdd_n)
        newton_iterate(evaluate, lambda: (self._iteration_matrix(t1, x["q"], x["qd"], x["J"],
                                                                x["lam"], D, G), x["J"]),
                       apply, self.matrix, h, tols, eq.mass, eq.length_scale, self.stats)
        x["a"] = (af * qdd_n - am * a_n + (1.0 - af) * x["qdd"]) / (1.0 - am)
        x["t1"] = t1
        return x

    def _local_error(self, x: dict, h: float) -> np.ndarray:
        """The step's local position error h^3 q^(3) (beta + (alpha_m - alpha_f) / 2 - 1/6),
        with h q^(3) ~ a_{n+1} - a_n: a_n approximates q'' at t_n + (alpha_m - alpha_f) h,
        and Newmark's position formula then differs from Taylor's by that term."""
        am, af, beta, _ = self.coefficients
        return abs(beta + 0.5 * (am - af) - 1.0 / 6.0) * h * h * (x["a"] - self.a)

    def _commit(self, x: dict) -> None:
        eq, t1 = self.equations, x["t1"]
        q = self.qw + x["dq"]
        self.a, self.qdd, self.lam = x["a"], x["qdd"], x["lam"]
        u, qd = self.inputs(t1), None
        if self.c_newton is not None:     # the kernel's, as its runs of steps commit
            qd = self.c_newton.kernel.project_velocities(q, x["qd"], eq.motion_values(t1, u))
        self.qd = qd if qd is not None else project_velocities(eq, t1, q, x["qd"], u)
        self._set_positions(q)
        self.stats.nprojections += 1
        self.check_finite(t1, self.q, self.qd)
