"""ALI3-P: augmented Lagrangian index-3 formulation with velocity and acceleration projections.

Bayo and Ledesma, "Augmented Lagrangian and mass-orthogonal projection methods for
constrained multibody dynamics", Nonlinear Dynamics 9 (1996) 113-130; Cuadrado, Cardenal and
Bayo, "Modeling and solution methods for efficient real-time simulation of multibody
dynamics", Multibody Syst. Dyn. 1 (1997) 259-280 (ALI3-P, their sec. 4).

Equations of motion with a penalty alpha on the constraints and iterated multipliers:

    M q'' + Psi_q^T (lam* + alpha Psi) = F,      lam*_{i+1} = lam*_i + alpha Psi_{i+1},

discretised with the trapezoidal rule, q'_{n+1} = 2/h (q_{n+1} - q_n) - q'_n and
q''_{n+1} = 4/h^2 (q_{n+1} - q_n) - 4/h q'_n - q''_n. Bayo's iteration solves, per Newton
step, ``f_q dq = -f`` with f = h^2/4 (M q'' + Psi_q^T (lam* + alpha Psi) - F) and

    f_q = M + h/2 C + h^2/4 (Psi_q^T alpha Psi_q + K),   C = -dF/dq',  K = H(lam) - dF/dq,

H being the geometric stiffness (``Equations.constraint_hessian``). Here the same iteration is
computed in its augmented (quasi-definite) form, eq. (AL) below, which eliminating dmu turns
back into Bayo's f_q and his multiplier update (with Psi_{i+1} linearised):

    [[M + h/2 C + h^2/4 K,  Psi_q^T], [dq ],     [h^2/4 (M q'' + Psi_q^T lam - F)]
     [Psi_q,               -1/P   I]] [dmu]  = - [Psi                            ],   (AL)

    lam += 4/h^2 dmu,   P = alpha h^2 / 4.

Why: the condensed f_q with the large penalty that singular configurations need
(P s^2 >> M for a Jacobian singular value s) swamps M in round-off, while the augmented
matrix keeps M and Psi_q apart; it is non-singular for every P > 0 however Psi_q loses rank
(a quasi-definite matrix), so the method passes singular configurations (P2's N-four-bar
when its cranks are horizontal) and redundant constraints (the parallelogram's third crank).
The iteration converges by the factor 1 / (1 + P s^2 / M) per step in the direction that
loses rank, and the trapezoidal equations then hold exactly (Psi = 0 to the tolerance).

Projections (Bayo and Ledesma's mass-orthogonal projections): after convergence q' and q''
from the trapezoidal rule are projected onto Psi_q q' = nu and Psi_q q'' = gamma with the
smallest change in the mass metric, ``x - M^-1 Psi_q^T (Psi_q M^-1 Psi_q^T)^+ (Psi_q x - rhs)``,
minimum-norm at singular configurations (``sparsity.spd_solver``). Cuadrado et al. weight the
projections with f_q instead, which needs no extra factorisation in their sparse code; with
a diagonal M the mass metric costs one small Cholesky and is exact.

The penalty: ``alpha`` (N/m on the position rows) if given; by default P = PENALTY_RATIO *
max_i (M_ii / (Psi_q^T Psi_q)_ii) at the start, i.e. alpha = 4 P / h^2.
"""

from __future__ import annotations

import numpy as np

from ..equations.sparsity import spd_solver
from .base import Option, number_in
from .implicit_c import CompiledNewton, attempt
from .implicit_control import STEP_CONTROL, StepControl
from .newton import ImplicitMethod, IterationMatrix, newton_iterate, newton_tolerances

# How much the penalty outweighs the largest mass (per unit of constraint gradient): large,
# so that the iteration converges fast where the Jacobian nearly loses rank (1e10: a singular
# value 1e-5 still gives a contraction of 1/2 per iteration). In the few steps nearest a
# singular configuration Psi is at the positions' rounding while the rank-loss coordinate
# is still off by about eps / s, and only the penalty holds that coordinate on its branch:
# a weaker one left it where the predictor put it, and every crossing left an energy error
# that did not shrink like h^2 (docs/accuracy.md). The augmented form keeps this harmless
# for round-off.
PENALTY_RATIO = 1e10


def mass_projector(equations, J: np.ndarray):
    """The projection x -> x - M^-1 J^T (J M^-1 J^T)^+ (J x - rhs) (n,): the closest point to
    x in the mass metric on J x = rhs; minimum-norm where J loses rank. J M^-1 J^T is
    factorised once for the velocity and the acceleration projection."""
    if J.shape[0] == 0:
        return lambda x, rhs: x
    JMi = J * equations.minv
    solve = spd_solver(JMi @ J.T)
    return lambda x, rhs: x - JMi.T @ solve(J @ x - rhs)


class ALI3P(CompiledNewton, StepControl, ImplicitMethod):
    """Augmented Lagrangian index-3 with projections (trapezoidal rule, fixed step or step
    control, ``implicit_control.py``)."""

    name = "ali3p"
    summary = ("augmented Lagrangian index-3 with mass-orthogonal projections (ALI3-P), "
               "trapezoidal, fixed step or step_control = \"adaptive\"; passes singular and "
               "redundant constraints")
    default_step = 1e-3
    options = (Option("alpha", "a positive number (N/m)", number_in(0.0, np.inf, low_open=True)),
               STEP_CONTROL)

    def __init__(self, equations, t0, q0, qd0, *, alpha: float | None = None,
                 step_control: str = "fixed", **common):
        self.alpha_option = None if alpha is None else float(alpha)
        self.adaptive = step_control == "adaptive"
        self.matrix = IterationMatrix()
        super().__init__(equations, t0, q0, qd0, **common)
        self.penalty_base = self._penalty_base()

    def _penalty_base(self) -> float:
        """P = PENALTY_RATIO * max_i M_ii / (Psi_q^T Psi_q)_ii over the constrained coordinates."""
        if self.equations.m == 0:
            return 1.0
        _, J = self.constraints(self.t, self.q)
        weight = np.sum(J * J, axis=0)
        used = weight > 0
        if not used.any():
            return 1.0
        return PENALTY_RATIO * float(np.max(self.equations.mass[used] / weight[used]))

    def alpha(self, h: float) -> float:
        """The penalty alpha (Bayo's) used with step h: 4 P / h^2."""
        if self.alpha_option is not None:
            return self.alpha_option
        return 4.0 * self.penalty_base / (h * h)

    def _augmented_matrix(self, t, q, qd, J, lam, h, P):
        """The matrix of eq. (AL), (n + m) square."""
        eq = self.equations
        K = np.diag(eq.mass) + (0.25 * h * h) * eq.constraint_hessian(q, lam)
        if eq.forces_depend_on_state():
            dFdq, dFdv = eq.force_jacobians(t, self._unwrapped(q), qd, self.inputs(t))
            K = K - (0.5 * h * dFdv + 0.25 * h * h * dFdq)
        return self.saddle_matrix(K, J, -np.eye(eq.m) / P)

    def _attempt(self, t, h) -> dict:
        """One step to t + h, not yet taken (``_commit`` takes it); raises NewtonFailure."""
        x = attempt(self, t, h)         # in the C kernel where it covers the case
        if x is not None:
            return x
        eq, n = self.equations, self.equations.n
        t1 = t + h
        P = 0.25 * h * h * self.alpha(h)
        q_n, v_n, a_n = self.qw, self.qd, self.qdd

        # Newton's unknown is the step's increment (module ``newton``) as its Taylor
        # predictor plus a correction c: the rates from c, not from dq (whose rounding,
        # times 2 / h, would be a velocity error of every step)
        predictor, v_pred = h * v_n + 0.5 * h * h * a_n, v_n + h * a_n

        def rates(c):
            """q' and q'' of the trapezoidal rule for the correction c of the increment."""
            return v_pred + (2.0 / h) * c, a_n + (4.0 / (h * h)) * c

        x = {"c": np.zeros_like(q_n), "lam": self.lam.copy()}

        def evaluate():
            x["dq"] = predictor + x["c"]
            x["q"] = q_n + x["dq"]
            x["qd"], qdd = rates(x["c"])
            Psi, x["J"] = self.constraints(t1, x["q"])
            F = self.forces(t1, self._unwrapped(x["q"]), x["qd"])
            return (0.25 * h * h) * (eq.mass * qdd + x["J"].T @ x["lam"] - F), Psi

        def apply(dx):
            x["c"] = x["c"] + dx[:n]
            x["lam"] = x["lam"] + (4.0 / (h * h)) * dx[n:]

        tols = newton_tolerances(self.atol, h, eq.length_scale, q_n, 0.25 * h * h, a_n)
        newton_iterate(evaluate, lambda: (self._augmented_matrix(t1, x["q"], x["qd"], x["J"],
                                                                x["lam"], h, P), x["J"]),
                       apply, self.matrix, h, tols, eq.mass, eq.length_scale, self.stats,
                       count_multipliers=False)
        x["dq"] = predictor + x["c"]
        q = q_n + x["dq"]
        qd, qdd = rates(x["c"])
        # mass-orthogonal projections of q' and q'' (Bayo and Ledesma 1996)
        u = self.inputs(t1)
        _, J, nu, _ = eq.constraints(t1, q, qd, u)
        project = mass_projector(eq, J)
        qd = project(qd, nu)
        _, _, _, gamma = eq.constraints(t1, q, qd, u)
        x["qd"], x["qdd"], x["t1"] = qd, project(qdd, gamma), t1
        return x

    def _local_error(self, x: dict, h: float) -> np.ndarray:
        """The trapezoidal rule's local position error, -h^3 q^(3) / 12, with
        h q^(3) ~ q''_{n+1} - q''_n."""
        return (h * h / 12.0) * (x["qdd"] - self.qdd)

    def _commit(self, x: dict) -> None:
        q = self.qw + x["dq"]
        self.stats.nprojections += 1
        self.check_finite(x["t1"], q, x["qd"], x["qdd"])
        self.qd, self.qdd, self.lam = x["qd"], x["qdd"], x["lam"]
        self._set_positions(q)
