"""Whole runs of ``rk4p`` steps compiled in one numba call, the energy check included.

For a mechanism whose applied forces never change (gravity, constant torques, constant
forces at centres of mass: ``AppliedForces.is_constant``) and the numba kernel, a run of
fixed steps needs nothing from Python between steps: the driver motions at every stage are
known beforehand. ``rk4p_steps`` does classic RK4 on the index-1 form, the mass-weighted
projections (formulation.md, eqs. 18-19) and ``EnergyAudit.check`` after each step, the
same arithmetic as the Python path of ``rk4p.py``.
"""

from __future__ import annotations

from enum import IntEnum

import numpy as np

from ..equations.compiled import (accelerations, jac_mul, jac_t_mul, jit, jit_inline,
                                  schur_solve, terms)


class StepStatus(IntEnum):
    """How a compiled run ended."""

    DONE = 0          # every step taken
    SINGULAR = 1      # a singular Schur complement at the next step: redo it on the general path
    PROJECTION = 2    # the position projection did not converge there: redo it (says why)
    ENERGY = 3        # the energy check failed after the last step taken
    NOT_FINITE = 4    # a non-finite state after the last step taken


class AuditField(IntEnum):
    """Slots of the energy check's running state (``EnergyAudit``'s attributes)."""

    ACTIVE = 0
    E0 = 1
    V0 = 2
    KINETIC_MAX = 3
    POTENTIAL_SWING = 4
    MAGNITUDE = 5
    CHECKS = 6
    WORST = 7
    LAST_ENERGY = 8
    RTOL = 9
    ATOL = 10
    FACTOR = 11
    TOLERANCE_JOULES = 12


AUDIT_ATTRIBUTES = {f: f.name.lower() for f in AuditField if f != AuditField.ACTIVE}


@jit_inline
def _project_positions(qe, qn, c, minv, rank_tol, tol, roundoff, max_iter, p, plan):
    """Newton, dq = -M^-1 J^T (J M^-1 J^T)^-1 Psi, stopping as ``rk4p_step`` says; returns
    (q, DONE / SINGULAR / PROJECTION). ``qe`` is the extended work array."""
    n = qn.shape[0]
    for it in range(max_iter + 1):
        qe[:n] = qn
        psi, values, _ = terms(qe, qe, c, p, plan)
        err = np.max(np.abs(psi))
        if err > tol and it == max_iter:
            break
        x, ok = schur_solve(values, plan, psi, rank_tol)
        if not ok:
            return qn, StepStatus.SINGULAR
        dq = minv * jac_t_mul(values, plan.rows, plan.cols, x, n)
        qn = qn - dq
        if err <= tol and (np.max(np.abs(dq)) <= tol or err <= roundoff):
            return qn, StepStatus.DONE
    return qn, StepStatus.PROJECTION


@jit
def rk4p_step(q, qd, f, h, motion, F, minv, rank_tol, tol, roundoff, max_iter, p, plan):
    """One step of ``rk4p`` for a mechanism with constant applied forces F.

    q, qd, f (= q'' at the start): (n,). ``motion`` (3, 3, m): c, c', c'' of every row at
    t, t + h/2 and t + h. The position projection stops as
    ``projection.project_positions`` does (Psi and the Newton increment below ``tol``, or
    Psi below ``roundoff``). Returns (q, q', q'' at t + h, status) with status DONE,
    SINGULAR or PROJECTION.
    """
    n = q.shape[0]
    m = motion.shape[2]
    z = np.zeros(3)
    qe, qde = np.concatenate((q, z)), np.concatenate((qd, z))
    acc_q, acc_v = qd.copy(), f.copy()          # sum of b_i k_i (times 6)
    k_q, k_v = qd, f
    for stage in range(1, 4):
        a = 0.5 * h if stage < 3 else h
        row = 1 if stage < 3 else 2
        qe[:n] = q + a * k_q
        qde[:n] = qd + a * k_v
        k_q = qde[:n].copy()
        k_v, _, ok = accelerations(qe, qde, motion[row, 0], motion[row, 2], F, minv,
                                   rank_tol, p, plan)
        if not ok:
            return q, qd, f, StepStatus.SINGULAR
        w = 2.0 if stage < 3 else 1.0
        acc_q += w * k_q
        acc_v += w * k_v
    qn = q + h / 6.0 * acc_q
    vn = qd + h / 6.0 * acc_v
    qn, status = _project_positions(qe, qn, motion[2, 0], minv, rank_tol, tol, roundoff,
                                    max_iter, p, plan)
    if status != StepStatus.DONE:
        return q, qd, f, status
    qe[:n] = qn
    _, values, _ = terms(qe, qe, motion[2, 0], p, plan)
    # velocity projection onto J q' = nu
    x, ok = schur_solve(values, plan, jac_mul(values, plan.rows, plan.cols, vn, m)
                        - motion[2, 1], rank_tol)
    if not ok:
        return q, qd, f, StepStatus.SINGULAR
    vn = vn - minv * jac_t_mul(values, plan.rows, plan.cols, x, n)
    qde[:n] = vn
    fn, _, ok = accelerations(qe, qde, motion[2, 0], motion[2, 2], F, minv, rank_tol, p, plan)
    if not ok:
        return q, qd, f, StepStatus.SINGULAR
    return qn, vn, fn, StepStatus.DONE


@jit_inline
def _energy_check(q, qd, F, mass, audit, divergence_fraction, roundoff):
    """``EnergyAudit.check`` for energies 1/2 q'M q' - F.q; updates ``audit`` in place and
    returns False when the balance is broken."""
    kinetic = 0.5 * np.sum(mass * qd * qd)
    energy = kinetic - np.sum(F * q)
    audit[AuditField.KINETIC_MAX] = max(audit[AuditField.KINETIC_MAX], kinetic)
    audit[AuditField.POTENTIAL_SWING] = max(audit[AuditField.POTENTIAL_SWING],
                                            abs(energy - kinetic - audit[AuditField.V0]))
    audit[AuditField.MAGNITUDE] = max(audit[AuditField.MAGNITUDE], abs(energy), kinetic)
    audit[AuditField.LAST_ENERGY] = energy
    scale = max(audit[AuditField.KINETIC_MAX], audit[AuditField.POTENTIAL_SWING])
    allowance = divergence_fraction * scale
    if audit[AuditField.FACTOR] != 0.0:
        rtol, atol = audit[AuditField.RTOL], audit[AuditField.ATOL]
        joules = (np.sum(np.abs(F) * (atol + rtol * np.abs(q)))
                  + np.sum(np.abs(mass * qd) * (atol + rtol * np.abs(qd))))
        audit[AuditField.TOLERANCE_JOULES] = max(audit[AuditField.TOLERANCE_JOULES], joules)
        allowance = min(audit[AuditField.FACTOR] * audit[AuditField.TOLERANCE_JOULES],
                        allowance)
    audit[AuditField.CHECKS] += 1.0
    error = abs(energy - audit[AuditField.E0])
    if error <= roundoff * audit[AuditField.MAGNITUDE] * audit[AuditField.CHECKS]:
        return True
    ratio = error / allowance if allowance > 0.0 else np.inf
    audit[AuditField.WORST] = max(audit[AuditField.WORST], ratio)
    return ratio <= 1.0


@jit
def rk4p_steps(q, qd, f, h, motions, F, minv, rank_tol, tol, residual_roundoff, max_iter, p,
               plan, mass, audit, divergence_fraction, roundoff):
    """``rk4p_step`` for every row of ``motions`` (s, 3, 3, m), with the energy check
    after each step when ``audit[ACTIVE]``.

    Returns (q, q', q'', steps done, status): DONE; SINGULAR or PROJECTION at the next
    step; ENERGY or NOT_FINITE after the last step done.
    """
    for k in range(motions.shape[0]):
        qn, vn, fn, status = rk4p_step(q, qd, f, h, motions[k], F, minv, rank_tol, tol,
                                       residual_roundoff, max_iter, p, plan)
        if status != StepStatus.DONE:
            return q, qd, f, k, status
        q, qd, f = qn, vn, fn
        if not np.isfinite(q.sum() + qd.sum() + f.sum()):
            return q, qd, f, k + 1, StepStatus.NOT_FINITE
        if audit[AuditField.ACTIVE] != 0.0 and not _energy_check(
                q, qd, F, mass, audit, divergence_fraction, roundoff):
            return q, qd, f, k + 1, StepStatus.ENERGY
    return q, qd, f, motions.shape[0], StepStatus.DONE
