"""Baumgarte's stabilisation of the index-1 form, fixed-step classic RK4.

The acceleration equation Psi_q q'' = gamma of eq. (14) is replaced by
(Baumgarte 1972, Comput. Methods Appl. Mech. Eng. 1, eq. 12; Nikravesh, Computer-Aided
Analysis of Mechanical Systems, sec. 13.4)

    Psi_q q'' = gamma - 2 alpha (Psi_q q' - nu) - beta^2 Psi,

so that the constraint violation obeys e'' + 2 alpha e' + beta^2 e = 0 instead of e'' = 0:
drift is damped, not removed. The state is integrated with the classic RK4 step (the same
kernel as ``rk4p``, without projection): fourth order, so the drift fed into the violation
dynamics is O(h^4) per unit time.

Choosing alpha and beta (units 1/s). They set the violation dynamics, eigenvalues
``-alpha +- sqrt(alpha^2 - beta^2)``; alpha = beta is critical damping. They must scale with
the step: alpha h and beta h of order 0.1 damp a violation within ~10 steps while keeping
those eigenvalues well inside RK4's stability interval (|lambda h| < 2.78 on the real axis).
Too small (alpha h, beta h -> 0) and the method drifts like the unstabilised index-1 form
(alpha = beta = 0 is exactly that); too large (alpha h or beta^2 h^2 beyond ~1.4 - 2.8) and
the stabilisation itself is unstable and the run diverges. There is no choice that is
right for every step: the default follows the step, ``alpha = beta = BAUMGARTE_RATE_STEP / h``.
"""

from __future__ import annotations

import numpy as np

from .base import Integrator, Option, number_in
from .rk4p import rk4_step

# Default alpha h = beta h: a violation is damped within about ten steps, far inside RK4's
# stability interval.
BAUMGARTE_RATE_STEP = 0.1


class Baumgarte(Integrator):
    """Index-1 form with Baumgarte stabilisation (alpha, beta in 1/s), fixed-step RK4."""

    name = "baumgarte"
    summary = "index-1 with Baumgarte stabilisation (alpha, beta), classic RK4, fixed step"
    default_step = 1e-3
    orders = (4, 4)       # classic RK4 on (q, q')
    carry_velocity_error = True
    options = (Option("alpha", "a number >= 0 (1/s)", number_in(0.0, float("inf"))),
               Option("beta", "a number >= 0 (1/s)", number_in(0.0, float("inf"))))
    state_fields = ("f",)

    def __init__(self, equations, t0, q0, qd0, *, alpha: float | None = None,
                 beta: float | None = None, **common):
        h = common["step"]
        self.alpha = float(alpha) if alpha is not None else BAUMGARTE_RATE_STEP / h
        self.beta = float(beta) if beta is not None else BAUMGARTE_RATE_STEP / h
        super().__init__(equations, t0, q0, qd0, **common)

    def restart(self):
        self.f = self._rhs(self.t, np.concatenate((self.q, self.qd)))

    def _rhs(self, t, y):
        q, qd = np.split(y, [self.q.size])
        self.stats.naccel += 1
        qdd, _ = self.equations.accelerations(t, q, qd, self.inputs(t),
                                              baumgarte=(self.alpha, self.beta))
        return np.concatenate((qd, qdd))

    def _step_impl(self, h):
        t_new = self.t + h
        y_new = rk4_step(self._rhs, self.t, np.concatenate((self.q, self.qd)), h, self.f)
        self.check_finite(t_new, y_new)
        q, qd = np.split(y_new, [self.q.size])
        self.check_drift(t_new, q)
        f = self._rhs(t_new, y_new)
        self.check_finite(t_new, f)
        self.q, self.qd, self.f = q, qd, f
        return True, h
