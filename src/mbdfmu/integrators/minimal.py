"""Minimal coordinates by coordinate partitioning, integrated by Dormand-Prince 8(5,3).

Wehage and Haug (1982), "Generalized coordinate partitioning for dimension reduction in
analysis of constrained dynamic systems", J. Mech. Design 104, 247-255: QR with column
pivoting of Psi_q splits q into ``rank`` dependent coordinates, whose block of Psi_q is
well conditioned, and ``n - rank`` independent ones z (body angles preferred, as
``analysis/operating.py`` does). Only (z, z') are integrated, with the embedded pair's
error control on them alone; at every stage and at the step's end the dependent
coordinates are solved from Psi(q, t) = 0 and Psi_q q' = nu with (z, z') held, by Newton
started from the tableau's own values (eqs. 18-19 with zero weight on z: the C kernel's
projections, ``mbd_mc_trial``, or the dense Newton here), and q'' comes from eq. (14). The
constraints then hold at every stage, not only after the step, and nothing is projected
after the fact. Before each step the partition is checked: when its dependent block's
conditioning has fallen REPARTITION_RATIO below that of Psi_q itself (the chosen
coordinates are about to stop determining the others), it is chosen again at the current
state; y' = (q', q'') is the same in any partition, so the step goes on.
"""

from __future__ import annotations

import numpy as np
import scipy.linalg

from ..errors import SolverError
from ..equations.projection import PROJECTION_MAX_ITER
from . import c_steps, dense_output
from .projected_rk import ENERGY_MIN_GAIN, MAX_FACTOR, MIN_FACTOR, SAFETY, DOP853P

# Weight of the angle columns of Psi_q in the pivoting: angles stay independent when the
# choice is otherwise equal (a crank's angle names a four-bar's degree of freedom).
ANGLE_WEIGHT = 0.1
# Rank decisions on the pivoted R diagonal, relative to its largest entry.
RANK_RTOL = 1e-9
# A partition is taken when its dependent block's smallest over largest singular value is at
# least this fraction of Psi_q's own, and re-chosen when that ratio falls to this fraction
# of its value when chosen.
REPARTITION_RATIO = 1e-2
# Constraint rows up to which the partition is checked after every accepted step.
CHECK_ROWS = 60


def choose_partition(J: np.ndarray) -> np.ndarray:
    """The independent coordinates (bool, n) for the constraint Jacobian J (m, n)."""
    m, n = J.shape
    independent = np.ones(n, dtype=bool)
    if m == 0:
        return independent
    weighted = J.copy()
    weighted[:, 2::3] *= ANGLE_WEIGHT
    for matrix in (weighted, J):
        _, R, pivots = scipy.linalg.qr(matrix, mode="economic", pivoting=True)
        d = np.abs(np.diag(R))
        rank = int(np.sum(d > RANK_RTOL * d[0])) if d.size and d[0] > 0 else 0
        chosen = np.ones(n, dtype=bool)
        chosen[pivots[:rank]] = False
        if _block_conditioning(J, chosen) >= REPARTITION_RATIO * _conditioning(J):
            return chosen
        independent = chosen
    return independent


def _conditioning(J: np.ndarray) -> float:
    """Smallest over largest of J's nonzero singular values (as many as its rank)."""
    sv = np.linalg.svd(J, compute_uv=False)
    rank = int(np.sum(sv > RANK_RTOL * sv[0])) if sv.size and sv[0] > 0 else 0
    return float(sv[rank - 1] / sv[0]) if rank else 1.0


def _block_conditioning(J: np.ndarray, independent: np.ndarray) -> float:
    """Smallest over largest singular value of J's dependent block (m, rank)."""
    sv = np.linalg.svd(J[:, ~independent], compute_uv=False)
    return float(sv[-1] / sv[0]) if sv.size and sv[0] > 0 else 1.0


class MinimalCoordinates(DOP853P):
    """Dormand-Prince 8(5,3) on the independent coordinates; dependent ones by Newton."""

    error_reads_end = True      # its trials evaluate their end as a stage of their own
    name = "minimal"
    summary = ("minimal coordinates: coordinate partitioning (re-chosen when its block loses "
               "rank), Dormand-Prince 8(5,3) on the independent ones, dependent ones by Newton")
    state_fields = DOP853P.state_fields + ("independent", "chosen_conditioning")
    # Its own step (below) keeps the controller's step (no singular-zone plans); outputs
    # come from DOP853's dense output of its stages (full coordinates, the dependent ones
    # solved at each stage), so output times do not cut its steps: landing next to a
    # singular configuration put it on the other branch. Like the projected pairs it aims
    # at rtol / 100 per step: at rtol per step its errors on P2 added up over the steps
    # to 100 to 180 times rtol (docs/accuracy.md).
    local_tolerance = DOP853P.local_tolerance
    # The I controller (adaptive.py): with dop853p's PI_BETA its P2 N = 2 run at rtol 1e-10
    # ends beyond the bench's line for a silently wrong result, where it ended just inside
    # it before (docs/performance_history.md, "dop853p's PI controller").
    beta, alpha = 0.0, 1.0 / (DOP853P.order + 1)

    @property
    def dense_output(self) -> bool:
        """With independent coordinates only: without them (drivers prescribe the motion)
        nothing controls the step, and outputs come from landing on them."""
        return bool(self.independent.any())

    def _plan_step(self, h, landing, proposal):
        return h

    def restart(self):
        self._choose()
        super().restart()

    def _choose(self) -> None:
        _, J = self.constraints(self.t, self.q)
        self.independent = choose_partition(J)
        self.chosen_conditioning = _block_conditioning(J, self.independent) if J.size else 1.0

    def _check_partition(self) -> None:
        if self.equations.m == 0:
            return
        _, J = self.constraints(self.t, self.q)
        if _block_conditioning(J, self.independent) < REPARTITION_RATIO * self.chosen_conditioning:
            self._choose()

    def _step_impl(self, h):
        t0, y0 = self.t, np.concatenate((self.q, self.qd))
        stepped, self.stages = None, None
        if self.equations.ckernel is not None:
            stepped = c_steps.mc_step(self, h, SAFETY, MIN_FACTOR, MAX_FACTOR, ENERGY_MIN_GAIN)
            k = self.equations.ckernel.buf.K
            self.stages = k[:(self.n_stages + 1) * y0.size].reshape(-1, y0.size).copy()
        accepted, h_next = stepped if stepped is not None else self._python_step(h)
        if accepted:       # the stages' last row: y' at the accepted end
            self.stages[-1] = self.f
            y1 = np.concatenate((self.q, self.qd))
            self.dense = dense_output.DenseStep(t0, h, y0, y1, self.stages)
        failed = self.trial_status == c_steps.ckernel.PROJECTION      # a Newton solve
        if failed or (accepted and self.equations.m <= CHECK_ROWS):
            self._check_partition()
        return accepted, h_next

    # ------------------------------------------------------------ the step without C

    def _recover(self, t: float, y: np.ndarray) -> np.ndarray:
        """y = (q, q') with the dependent coordinates solved at t, (z, z') held."""
        n, u = self.q.size, self.inputs(t)
        q, qd = y[:n].copy(), y[n:].copy()
        dep = ~self.independent
        tol = self._projection_tol()
        for _ in range(PROJECTION_MAX_ITER + 1):
            Psi, J = self.equations.constraints(t, q, u=u)
            if not np.all(np.isfinite(Psi)):
                raise SolverError("the dependent coordinates became non-finite", t)
            if Psi.size == 0 or np.max(np.abs(Psi)) <= tol:
                break
            q[dep] -= np.linalg.lstsq(J[:, dep], Psi, rcond=None)[0]
        else:
            raise SolverError("Newton on the dependent coordinates did not converge", t)
        if Psi.size:
            _, J, nu, _ = self.equations.constraints(t, q, qd, u)
            qd[dep] += np.linalg.lstsq(J[:, dep], nu - J @ qd, rcond=None)[0]
        return np.concatenate((q, qd))

    def _python_step(self, h):
        t, n, ns = self.t, self.q.size, self.n_stages
        y = np.concatenate((self.q, self.qd))
        K = np.empty((ns + 1, y.size))
        K[0] = self.f
        counted = self.stats.naccel        # decide() counts the evaluations, as in C
        try:
            for s in range(1, ns + 1):
                combined = y + h * (K[:s].T @ (self.A[s, :s] if s < ns else self.B))
                ys = self._recover(t + (self.C[s] if s < ns else 1.0) * h, combined)
                K[s] = self._rhs_y(t + (self.C[s] if s < ns else 1.0) * h, ys)
        except SolverError:
            self.stats.naccel = counted
            return c_steps.decide(self, h, c_steps.ckernel.PROJECTION, 0.0, None, None,
                                  SAFETY, MIN_FACTOR, MAX_FACTOR, ENERGY_MIN_GAIN)
        self.stats.naccel = counted
        status = c_steps.ckernel.OK
        if not (np.all(np.isfinite(ys)) and np.all(np.isfinite(K[-1]))):
            status = c_steps.ckernel.NOT_FINITE
        kept = np.concatenate((self.independent, self.independent))
        err = self._error_norm(K[:, kept], h, self._scale(y, ys)[kept]) if kept.any() else 0.0
        if status == c_steps.ckernel.OK and not err < 1.0:
            status = c_steps.ckernel.ERROR_NORM
        self.stages = K
        return c_steps.decide(self, h, status, err, ys, K[-1].copy(), SAFETY, MIN_FACTOR,
                              MAX_FACTOR, ENERGY_MIN_GAIN, end_evaluated=True)
