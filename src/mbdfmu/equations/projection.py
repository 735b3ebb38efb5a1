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
from .sparsity import RANK_TOLERANCE, schur_solve

# Newton iterations allowed when assembling from rough estimates, and while projecting.
ASSEMBLY_MAX_ITER = 60
PROJECTION_MAX_ITER = 8
# Residual (relative to the mechanism's length scale) at which positions count as assembled.
ASSEMBLY_TOL = 1e-12
# A velocity changed by more than this (relative to max(1, |v|)) is reported as changed.
VELOCITY_CHANGE_TOL = 1e-9
# Each coordinate's scene key, component (None: a scalar) and unit: positions, velocities.
POSITION_KEYS = (("position", 0, "m"), ("position", 1, "m"), ("angle", None, "rad"))
VELOCITY_KEYS = (("velocity", 0, "m/s"), ("velocity", 1, "m/s"), ("angular_velocity", None, "rad/s"))


def project_positions(system: Equations, t: float, q: np.ndarray, *, tol: float,
                      max_iter: int = PROJECTION_MAX_ITER,
                      u: InputValues | None = None) -> tuple[np.ndarray, int]:
    """Closest q (mass-weighted) with Psi(q, t) = 0; returns (q, iterations).

    Raises SolverError when Newton does not converge to ``tol`` (max-norm of Psi).
    """
    q = q.copy()
    for it in range(max_iter + 1):
        Psi, J = system.constraints(t, q, u=u, sparse=True)
        if not np.all(np.isfinite(Psi)):
            raise SolverError("non-finite constraint residual while projecting positions", t)
        err = np.max(np.abs(Psi)) if Psi.size else 0.0
        if err <= tol:
            return q, it
        if it == max_iter:
            break
        q -= system.minv * (J.T @ schur_solve(J, system.minv, Psi))
    worst = int(np.argmax(np.abs(Psi)))
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
    return (np.array([[*b.position, b.angle] for b in bodies], dtype=float).ravel(),
            np.array([[*b.velocity, b.angular_velocity] for b in bodies], dtype=float).ravel())


def assemble(system: Equations, t: float = 0.0,
             u: InputValues | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Consistent (q, q') at time t from the scene's estimates; AssemblyError if impossible."""
    scene = system.scene
    q, qd = initial_estimates(system)
    tol = ASSEMBLY_TOL * system.length_scale
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
    lines = []
    for k, body in enumerate(system.scene.bodies):
        for c in range(3):
            i = 3 * k + c
            for keys, old, new, stage in ((POSITION_KEYS, q0[i], q[i], "assembly"),
                                          (VELOCITY_KEYS, qd0[i], qd[i], "the velocity projection")):
                name, index, unit = keys[c]
                limit = (ASSEMBLY_TOL * system.length_scale if keys is POSITION_KEYS
                         else VELOCITY_CHANGE_TOL * max(1.0, abs(old), abs(new)))
                if body.gave(name) and abs(new - old) > limit:
                    label = name if index is None else f"{name}[{index}]"
                    lines.append(f'body "{body.name}": {label} = {old:.6g} {unit} as given, '
                                 f"{new:.6g} after {stage} (changed by {new - old:+.3g}): the "
                                 "joints and drivers allow no other")
    return lines
