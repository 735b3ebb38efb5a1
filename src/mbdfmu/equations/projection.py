"""Projections onto the constraints, consistent initial conditions and the rank of Psi_q.

Positions are corrected by Newton's method with the smallest mass-weighted change,
``dq = -M^-1 Psi_q^T (Psi_q M^-1 Psi_q^T)^+ Psi`` (formulation.md, eq. 18); velocities are
projected onto ``Psi_q q' = nu`` with the smallest change in kinetic energy (eq. 19). The
same two projections assemble a scene from estimates and keep the index-1 integrators on
the constraint manifold (coordinate projection).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.linalg

from ..errors import AssemblyError, SolverError
from ..model.variables import InputValues
from .dynamics import Equations
from .planar import stacked
from .sparsity import RANK_TOLERANCE, schur_solve

# Newton iterations allowed when assembling from rough estimates, and while projecting.
ASSEMBLY_MAX_ITER = 60
PROJECTION_MAX_ITER = 8
# Residual (relative to the mechanism's length scale) at which positions count as assembled.
ASSEMBLY_TOL = 1e-12
# A constraint residual this small (relative to the mechanism's size) is rounding: the
# Newton increment it gives measures the conditioning, not the distance to the constraints.
ROUNDOFF_RESIDUAL = 1e-14
# A velocity changed by more than this (relative to max(1, |v|)) is reported as changed.
VELOCITY_CHANGE_TOL = 1e-9
# Each coordinate's scene key, component (None: a scalar) and unit: positions, velocities.
POSITION_KEYS = (("position", 0, "m"), ("position", 1, "m"), ("angle", None, "rad"))
VELOCITY_KEYS = (("velocity", 0, "m/s"), ("velocity", 1, "m/s"), ("angular_velocity", None, "rad/s"))


def project_positions(system: Equations, t: float, q: np.ndarray, *, tol: float,
                      max_iter: int = PROJECTION_MAX_ITER,
                      u: InputValues | None = None) -> tuple[np.ndarray, int]:
    """Closest q (mass-weighted) with Psi(q, t) = 0; returns (q, iterations).

    Converged when Psi and the last Newton increment are both below ``tol`` (max-norms):
    near a singular configuration |Psi| <= tol alone leaves q off by up to tol / sigma
    (sigma the smallest singular value of Psi_q) along the direction that loses rank,
    towards the other branch. An increment made of the rounding of Psi (a residual at
    ROUNDOFF_RESIDUAL of the mechanism's size) cannot shrink further and also ends the
    iteration. Scenes with end stops or friction (events hold rows of their joints) stop on
    Psi alone: the extra increment moved the states the events hold (crane_stop came to
    rest off its closed form). Raises SolverError when Newton does not get there in
    ``max_iter``.
    """
    q = q.copy()
    if system.m == 0:
        return q, 0
    held_rows = system.has_events
    err = np.inf
    for it in range(max_iter + 1):
        Psi, J = system.constraints(t, q, u=u, sparse=True)
        if not np.all(np.isfinite(Psi)):
            raise SolverError("non-finite constraint residual while projecting positions", t)
        err = float(np.max(np.abs(Psi)))
        if err <= tol and held_rows:
            return q, it      # Psi alone: see the docstring
        if err > tol and it == max_iter:
            break
        dq = system.minv * (J.T @ schur_solve(J, system.minv, Psi))
        q -= dq
        if err <= tol and (float(np.max(np.abs(dq))) <= tol
                           or err <= ROUNDOFF_RESIDUAL * system.length_scale):
            return q, it + 1
    worst = int(np.argmax(np.abs(Psi)))
    if err <= tol:
        raise SolverError(f"position projection did not converge: its Newton increment is still "
                          f"{float(np.max(np.abs(dq))):.3g} after {max_iter} iterations (a "
                          "singular configuration)", t)
    raise SolverError(f"position projection did not converge: {system.row_labels[worst]} "
                      f"violated by {err:.3g} after {max_iter} iterations", t)


def project_velocities(system: Equations, t: float, q: np.ndarray, qd: np.ndarray,
                       u: InputValues | None = None) -> np.ndarray:
    """Closest q' in kinetic energy with Psi_q q' = nu."""
    if system.m == 0:
        return qd.copy()
    _, J, nu, _ = system.constraints(t, q, qd, u, sparse=True)
    return qd - system.minv * (J.T @ schur_solve(J, system.minv, J @ qd - nu))


@dataclass(frozen=True)
class RankReport:
    """Degrees of freedom and redundant constraint rows at one configuration."""

    dof: int
    rank: int
    redundant: tuple[str, ...]


def rank_report(system: Equations, t: float, q: np.ndarray) -> RankReport:
    """Rank of Psi_q by QR with column pivoting on Psi_q^T: rows left out are redundant."""
    if system.m == 0:
        return RankReport(system.n, 0, ())
    _, J = system.constraints(t, q)
    _, R, perm = scipy.linalg.qr(J.T, mode="economic", pivoting=True)
    d = np.abs(np.diag(R))
    rank = int(np.sum(d > RANK_TOLERANCE ** 0.5 * max(d.max(), 1e-300)))
    redundant = tuple(system.row_labels[k] for k in sorted(perm[rank:]))
    return RankReport(system.n - rank, rank, redundant)


def initial_estimates(system: Equations) -> tuple[np.ndarray, np.ndarray]:
    """(q, q') as the scene gives them, before assembly."""
    bodies = system.scene.bodies
    return (stacked([(*b.position, b.angle) for b in bodies], 3).ravel(),
            stacked([(*b.velocity, b.angular_velocity) for b in bodies], 3).ravel())


def assemble(system: Equations, t: float = 0.0, u: InputValues | None = None, *,
             estimates: tuple[np.ndarray, np.ndarray] | None = None
             ) -> tuple[np.ndarray, np.ndarray]:
    """Consistent (q, q') at time t from the scene's estimates (``initial_estimates``, or
    those given); AssemblyError if impossible."""
    scene = system.scene
    q, qd = initial_estimates(system) if estimates is None else estimates
    tol = ASSEMBLY_TOL * system.length_scale
    kernel = getattr(system, "ckernel", None)
    if kernel is not None:      # the same Newton iteration in C; None: the numpy path's case
        done = kernel.project(q, qd, system.motion_values(t, u), tol, ASSEMBLY_MAX_ITER)
        if done is not None:
            return done
    try:
        q, _ = project_positions(system, t, q, tol=tol, max_iter=ASSEMBLY_MAX_ITER, u=u)
    except SolverError:
        Psi, _ = system.constraints(t, q, u=u)
        report = rank_report(system, t, q)
        worst = int(np.argmax(np.abs(Psi)))
        what = (f"{system.row_labels[worst]} stays violated by {abs(Psi[worst]):.3g}")
        if report.redundant:
            what += (" (the constraints are redundant and inconsistent: "
                     + ", ".join(report.redundant) + " repeat others)")
        raise AssemblyError(f"{scene.source}: cannot be assembled at t = {t:g}: {what}") from None
    return q, project_velocities(system, t, q, qd, u)


def assembly_changes(system: Equations, given: tuple[np.ndarray, np.ndarray],
                     assembled: tuple[np.ndarray, np.ndarray]) -> list[str]:
    """One line for each value the scene gave that assembly changed: a position beyond the
    assembly tolerance, or a velocity the projection onto the velocity constraints changed
    (``given`` and ``assembled`` are (q, q') pairs). Values the scene left to their
    defaults are not reported."""
    q0, qd0 = given
    q, qd = assembled
    dq, dqd = np.abs(q - q0), np.abs(qd - qd0)
    tol = ASSEMBLY_TOL * system.length_scale
    if dq.max(initial=0.0) <= tol and dqd.max(initial=0.0) <= VELOCITY_CHANGE_TOL:
        return []       # nothing beyond its limit (a velocity's is at least this): the usual case
    moved = dq > tol
    sped = dqd > VELOCITY_CHANGE_TOL * np.maximum(
        1.0, np.maximum(np.abs(qd0), np.abs(qd)))
    lines = []
    for i in np.flatnonzero(moved | sped).tolist():     # the values beyond their limit
        k, c = divmod(i, 3)
        body = system.scene.bodies[k]
        for keys, old, new, stage, beyond in (
                (POSITION_KEYS, q0[i], q[i], "assembly", moved[i]),
                (VELOCITY_KEYS, qd0[i], qd[i], "the velocity projection", sped[i])):
            name, index, unit = keys[c]
            if beyond and body.gave(name):
                label = name if index is None else f"{name}[{index}]"
                lines.append(f'body "{body.name}": {label} = {old:.6g} {unit} as given, '
                             f"{new:.6g} after {stage} (changed by {new - old:+.3g}): the "
                             "joints and drivers allow no other")
    return lines
