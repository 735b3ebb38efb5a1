"""The explicit second-order Taylor step of the formulation, without any stabilisation.

    q_{n+1}  = q_n + h q'_n + h^2/2 q''_n,      q'_{n+1} = q'_n + h q''_n,

with q'' and lam from eq. (14) at (t_n, q_n, q'_n) (formulation.md, eq. 21). Nothing pulls
the state back to the constraints, so position and velocity errors grow: it is the baseline
the stabilised methods are charted against.
"""

from __future__ import annotations

from .base import Integrator


class Taylor(Integrator):
    name = "taylor"
    summary = "explicit 2nd-order Taylor step (formulation eq. 21), fixed step, no stabilisation"
    default_step = 1e-4
    orders = (2, 1)       # q gains h^2/2 q'', q' only h q'': local errors O(h^3), O(h^2)
    carry_velocity_error = True

    def _step_impl(self, h):
        qdd, _ = self.accelerations(self.t, self.q, self.qd)
        q = self.q + h * self.qd + 0.5 * h * h * qdd
        qd = self.qd + h * qdd
        self.check_finite(self.t + h, q, qd)
        self.check_drift(self.t + h, q)
        self.q, self.qd = q, qd
        return True, h
