"""The constraint kernel compiled by numba: Psi, Psi_q's values and gamma in one call.

The same equations as ``System.constraints``' vectorised numpy code, row by row (the
primitives are documented in ``system.py``); loops are what numba compiles best. numba is
optional (``pip install "mbdfmu[jit]"``): without it, or with ``MBDFMU_KERNEL=numpy``, the
numpy kernel runs. The two are checked against each other in ``tests/test_kernel.py`` and
timed against each other in ``benchmarks/kernel.py``.
"""

from __future__ import annotations

import math
import os

import numpy as np

try:  # numba is optional; FMUs run without it
    import numba
except ImportError:  # pragma: no cover - depends on the installation
    numba = None


def available() -> bool:
    """numba is installed and not switched off by ``MBDFMU_KERNEL=numpy``."""
    return numba is not None and os.environ.get("MBDFMU_KERNEL", "auto") != "numpy"


def constraint_terms(q, qd, with_v, cval,
                     c_rows, c_bi, c_bj, c_si, c_sj,
                     l_rows, l_bi, l_bj, l_si, l_sj, l_u,
                     a_rows, a_bi, a_bj,
                     psi, data, gamma):
    """Fill psi (m,), data (the Jacobian values, System's layout) and gamma (m,) in place.

    q, qd: (3 nb,) with the ground as body nb (zeros); cval: motion values c(t) per row.
    ``data`` holds the constants first; the q-dependent blocks follow them in the order
    coincidence (4 blocks of kc), line (6 blocks of kl).
    """
    kc, kl = c_rows.shape[0], l_rows.shape[0]
    k0 = data.shape[0] - 4 * kc - 6 * kl
    for r in range(gamma.shape[0]):
        gamma[r] = 0.0
    for k in range(kc):
        i, j = c_bi[k], c_bj[k]
        ci, si_ = math.cos(q[3 * i + 2]), math.sin(q[3 * i + 2])
        cj, sj_ = math.cos(q[3 * j + 2]), math.sin(q[3 * j + 2])
        aix = ci * c_si[k, 0] - si_ * c_si[k, 1]
        aiy = si_ * c_si[k, 0] + ci * c_si[k, 1]
        ajx = cj * c_sj[k, 0] - sj_ * c_sj[k, 1]
        ajy = sj_ * c_sj[k, 0] + cj * c_sj[k, 1]
        r0, r1 = c_rows[k, 0], c_rows[k, 1]
        psi[r0] = q[3 * i] + aix - q[3 * j] - ajx - cval[r0]
        psi[r1] = q[3 * i + 1] + aiy - q[3 * j + 1] - ajy - cval[r1]
        data[k0 + k] = -aiy
        data[k0 + kc + k] = aix
        data[k0 + 2 * kc + k] = ajy
        data[k0 + 3 * kc + k] = -ajx
        if with_v:
            wi2, wj2 = qd[3 * i + 2] ** 2, qd[3 * j + 2] ** 2
            gamma[r0] = aix * wi2 - ajx * wj2
            gamma[r1] = aiy * wi2 - ajy * wj2
    k1 = k0 + 4 * kc
    for k in range(kl):
        i, j = l_bi[k], l_bj[k]
        ci, si_ = math.cos(q[3 * i + 2]), math.sin(q[3 * i + 2])
        cj, sj_ = math.cos(q[3 * j + 2]), math.sin(q[3 * j + 2])
        aix = ci * l_si[k, 0] - si_ * l_si[k, 1]
        aiy = si_ * l_si[k, 0] + ci * l_si[k, 1]
        ajx = cj * l_sj[k, 0] - sj_ * l_sj[k, 1]
        ajy = sj_ * l_sj[k, 0] + cj * l_sj[k, 1]
        ux = ci * l_u[k, 0] - si_ * l_u[k, 1]
        uy = si_ * l_u[k, 0] + ci * l_u[k, 1]
        dx = q[3 * j] + ajx - q[3 * i] - aix
        dy = q[3 * j + 1] + ajy - q[3 * i + 1] - aiy
        row = l_rows[k]
        psi[row] = ux * dx + uy * dy - cval[row]
        # rot90(v) = (-v_y, v_x)
        data[k1 + k] = -ux
        data[k1 + kl + k] = -uy
        data[k1 + 2 * kl + k] = (-uy * dx + ux * dy) - (-ux * aiy + uy * aix)
        data[k1 + 3 * kl + k] = ux
        data[k1 + 4 * kl + k] = uy
        data[k1 + 5 * kl + k] = -ux * ajy + uy * ajx
        if with_v:
            wi, wj = qd[3 * i + 2], qd[3 * j + 2]
            ddx = qd[3 * j] - wj * ajy - qd[3 * i] + wi * aiy
            ddy = qd[3 * j + 1] + wj * ajx - qd[3 * i + 1] - wi * aix
            gamma[row] = (wi * wi * (ux * dx + uy * dy)
                          - 2.0 * wi * (-uy * ddx + ux * ddy)
                          + ux * (ajx * wj * wj - aix * wi * wi)
                          + uy * (ajy * wj * wj - aiy * wi * wi))
    for k in range(a_rows.shape[0]):
        row = a_rows[k]
        psi[row] = q[3 * a_bj[k] + 2] - q[3 * a_bi[k] + 2] - cval[row]


if numba is not None:
    constraint_terms_compiled = numba.njit(cache=True, nogil=True)(constraint_terms)
else:  # pragma: no cover
    constraint_terms_compiled = None


def accelerations_dense(q, qd, cval, cdd, F, minv, rank_tol, args, jac_constants, flat,
                        keep, m, n):
    """Eq. 14 by the Schur complement for a small mechanism, all in one compiled call.

    Same steps as ``System.accelerations`` (dense path): ``S = J M^-1 J^T``, Cholesky,
    ``lam = S^-1 (J M^-1 F - gamma)``, ``q'' = M^-1 (F - J^T lam)``. Returns
    (q'', lam, ok); ok is False when S is too close to singular for Cholesky (the caller
    then takes the minimum-norm path).
    """
    psi, gamma = np.empty(m), np.empty(m)
    data = np.empty(jac_constants.shape[0] + 4 * args[0].shape[0] + 6 * args[5].shape[0])
    data[:jac_constants.shape[0]] = jac_constants
    constraint_terms_compiled(q, qd, True, cval, args[0], args[1], args[2], args[3], args[4],
                              args[5], args[6], args[7], args[8], args[9], args[10],
                              args[11], args[12], args[13], psi, data, gamma)
    J = np.zeros(m * n)
    for k in range(keep.shape[0]):
        J[flat[k]] = data[keep[k]]
    J = J.reshape(m, n)
    JMi = J * minv
    S = JMi @ J.T
    b = JMi @ F - (gamma + cdd)
    # Cholesky S = L L^T, in place in the lower triangle
    dmax, dmin = 0.0, np.inf
    for j in range(m):
        s = S[j, j]
        for k in range(j):
            s -= S[j, k] * S[j, k]
        if s <= 0.0:
            return np.zeros(n), np.zeros(m), False
        d = math.sqrt(s)
        S[j, j] = d
        dmax, dmin = max(dmax, d), min(dmin, d)
        for i in range(j + 1, m):
            s = S[i, j]
            for k in range(j):
                s -= S[i, k] * S[j, k]
            S[i, j] = s / d
    if not dmin > math.sqrt(rank_tol) * dmax:
        return np.zeros(n), np.zeros(m), False
    lam = b.copy()
    for i in range(m):                   # L y = b
        s = lam[i]
        for k in range(i):
            s -= S[i, k] * lam[k]
        lam[i] = s / S[i, i]
    for i in range(m - 1, -1, -1):       # L^T x = y
        s = lam[i]
        for k in range(i + 1, m):
            s -= S[k, i] * lam[k]
        lam[i] = s / S[i, i]
    return minv * (F - J.T @ lam), lam, True


if numba is not None:
    accelerations_dense_compiled = numba.njit(cache=True, nogil=True)(accelerations_dense)
else:  # pragma: no cover
    accelerations_dense_compiled = None
