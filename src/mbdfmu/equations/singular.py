"""Singular configurations: how far a mechanism is from one, and eq. (14) close to one.

At a singular configuration Psi_q loses rank (P2's N-four-bar when its cranks are
horizontal); near one its smallest singular value sigma is small. The Schur complement
``S = Psi_q M^-1 Psi_q^T`` of eq. (15) then has the condition number 1 / sigma^2: its
Cholesky solve loses accuracy like eps / sigma^2, and the minimum-norm fallback of
``sparsity.schur_solve`` (which drops eigenvalues of S below ``RANK_TOLERANCE``) drops the
constraint force of the direction that loses rank, an O(1) error in q'' within
sigma < sqrt(RANK_TOLERANCE) of the configuration. ``nullspace_accelerations`` solves eq.
(14) from an SVD of ``M^-1/2 Psi_q^T`` instead, whose error grows only like eps / sigma
(Golub and Van Loan, Matrix Computations, sec. 6.2 on least squares with equality
constraints); ``Equations.accelerations`` takes it wherever S is ill-conditioned.

``singularity_indicator`` measures the distance to a singular configuration in a way that
does not depend on units or masses, for the integrators' step planning near one.
"""

from __future__ import annotations

import math

import numpy as np
import scipy.linalg

from .sparsity import SparseJacobian

# Singular values of M^-1/2 Psi_q^T below this fraction of the largest are those of
# redundant rows (or of an exactly singular configuration): dropped; all others are kept,
# however small.
NULLSPACE_RANK_TOLERANCE = 1e-13

_potrf, _pbtrf = scipy.linalg.lapack.dpotrf, scipy.linalg.lapack.dpbtrf


def singularity_indicator(J) -> float:
    """Distance to a singular configuration: the smallest over the largest diagonal entry of
    the Cholesky factor of ``Psi_q D Psi_q^T``, D scaling Psi_q's columns to unit norm (so
    units and masses do not matter: a point mass with a tiny inertia does not look
    singular). It falls linearly to zero as a mechanism approaches a singular
    configuration (for P2 like the crank angle from the horizontal), is of order one away
    from them and zero with redundant constraints. ``inf`` without constraints."""
    if J.shape[0] == 0:
        return math.inf
    if isinstance(J, SparseJacobian):
        p = J.pattern
        w = np.bincount(p.cols, weights=J.data ** 2, minlength=p.n)
        scale = 1.0 / np.where(w > 0, w, 1.0)
        band = np.bincount(p.band_index,
                           weights=J.data[p.pair_a] * J.data[p.pair_b] * scale[p.cols[p.pair_a]],
                           minlength=p.band_size).reshape(p.kd + 1, p.m)
        factor, info = _pbtrf(band, lower=1)
        d = np.abs(factor[0])
    else:
        w = np.sum(J * J, axis=0)
        scale = 1.0 / np.where(w > 0, w, 1.0)
        factor, info = _potrf((J * scale) @ J.T, lower=False, clean=False)
        d = np.abs(np.diag(factor))
    if info != 0 or not np.all(np.isfinite(d)):
        return 0.0
    return float(d.min() / d.max())


def nullspace_accelerations(J: np.ndarray, minv: np.ndarray, F: np.ndarray,
                            gamma: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Eq. (14) near a singular configuration: (q'', lam).

    q'' is the acceleration closest to M^-1 F in the mass metric with Psi_q q'' = gamma,
    from the SVD ``M^-1/2 Psi_q^T = U S V^T`` (x = M^1/2 q''):
    ``x = x_F - U U^T x_F + U S^-1 V^T gamma``; lam is the minimum-norm solution of
    ``Psi_q^T lam = F - M q''``, ``V S^-1 U^T (x_F - x)``. Singular values below
    NULLSPACE_RANK_TOLERANCE of the largest are dropped (redundant rows: q'' is unique,
    lam the minimum-norm one, as the Schur complement's minimum-norm solution gives)."""
    s = np.sqrt(minv)
    U, sv, Vt = scipy.linalg.svd((J * s).T, full_matrices=False, check_finite=False)
    r = int(np.sum(sv > NULLSPACE_RANK_TOLERANCE * max(float(sv.max(initial=0.0)), 1e-300)))
    U, sv, Vt = U[:, :r], sv[:r], Vt[:r]
    x_F = s * F
    x = x_F - U @ (U.T @ x_F) + U @ ((Vt @ gamma) / sv)
    lam = Vt.T @ ((U.T @ (x_F - x)) / sv)
    return s * x, lam
