"""The constraint kernel compiled by numba: Psi, Psi_q's values and gamma, and eq. (14).

The same equations as the vectorised numpy code of ``constraints.py``, row by row (the
primitives are documented in ``joints.py``); loops are what numba compiles best. numba is
optional (``pip install "mbdfmu[jit]"``): without it, or with ``MBDFMU_KERNEL=numpy``, the
numpy kernel runs. The two are checked against each other in ``tests/test_kernel.py`` and
timed against each other in ``benchmarks/kernel.py``.

The kernel takes two named structures built once per scene: ``Primitives`` (the index
arrays of the three row primitives) and ``JacobianPlan`` (Psi_q's pattern and the plan of
the banded Schur complement, ``sparsity.JacobianPattern``).
"""

from __future__ import annotations

import math
from collections import namedtuple

import numpy as np

try:  # numba is optional; FMUs run without it
    import numba
except ImportError:  # pragma: no cover - depends on the installation
    numba = None


def jit(function):
    """numba's ahead-of-use compilation, cached on disk; the plain function without numba."""
    return numba.njit(cache=True, nogil=True)(function) if numba is not None else function


def direct(dispatcher):
    """A caller of ``dispatcher``'s compiled code that skips numba's per-call dispatch.

    numba types every argument on every call to pick a specialization; for the named
    tuples this kernel takes, that costs more than the kernel itself at small sizes. Each
    function here has exactly one specialization (the callers always pass the same types:
    C-contiguous float64/int64 arrays, read-only motion arrays; tests/test_kernel.py checks
    it), so after the first call, which compiles or loads it, its entry point is called
    directly.
    """
    if numba is None:
        return dispatcher
    entry = None

    def call(*args):
        nonlocal entry
        if entry is None:
            result = dispatcher(*args)
            if len(dispatcher.signatures) == 1:
                entry = dispatcher.overloads[dispatcher.signatures[0]].entry_point
            return result
        return entry(*args)
    return call


def jit_inline(function):
    """``jit`` for small helpers, inlined into their callers (numba's own inlining, which
    LLVM's does not always match for calls that return tuples)."""
    return (numba.njit(cache=True, nogil=True, inline="always")(function) if numba is not None
            else function)


Primitives = namedtuple("Primitives", [
    "c_rows", "c_bi", "c_bj", "c_si", "c_sj",                # coincidence: rows (k, 2), bodies, points
    "l_rows", "l_bi", "l_bj", "l_si", "l_sj", "l_u", "l_w",  # line: rows, bodies, points, axis, weight
    "a_rows", "a_bi", "a_bj", "a_w"])                        # angle: rows (k,), bodies, weight
JacobianPlan = namedtuple("JacobianPlan", [
    "constants",                  # constant entries of Psi_q's term values
    "merge", "size",              # term entry -> distinct entry (repeats summed); their number
    "keep",                       # the distinct entries kept (not ground)
    "rows", "cols",               # the kept entries' positions
    "pair_a", "pair_b", "pair_minv", "band_index", "perm", "kd"])   # banded Schur plan


@jit_inline
def _rotated(q, b, vx, vy):
    """A_b (vx, vy) for body b's angle in q: (x, y)."""
    c, s = math.cos(q[3 * b + 2]), math.sin(q[3 * b + 2])
    return c * vx - s * vy, s * vx + c * vy


@jit
def _coincidence_terms(q, qd, cval, p, psi, data, gamma, k0):
    """Coincidence rows (joints.py): psi, the 4 blocks of d(A s)/dphi from data[k0], gamma."""
    kc = p.c_rows.shape[0]
    for k in range(kc):
        i, j = p.c_bi[k], p.c_bj[k]
        aix, aiy = _rotated(q, i, p.c_si[k, 0], p.c_si[k, 1])
        ajx, ajy = _rotated(q, j, p.c_sj[k, 0], p.c_sj[k, 1])
        r0, r1 = p.c_rows[k, 0], p.c_rows[k, 1]
        psi[r0] += q[3 * i] + aix - q[3 * j] - ajx
        psi[r1] += q[3 * i + 1] + aiy - q[3 * j + 1] - ajy
        data[k0 + k] = -aiy
        data[k0 + kc + k] = aix
        data[k0 + 2 * kc + k] = ajy
        data[k0 + 3 * kc + k] = -ajx
        wi2, wj2 = qd[3 * i + 2] ** 2, qd[3 * j + 2] ** 2
        gamma[r0] += aix * wi2 - ajx * wj2
        gamma[r1] += aiy * wi2 - ajy * wj2


@jit
def _line_terms(q, qd, cval, p, psi, data, gamma, k1):
    """Line terms (joints.py), each times its weight: psi, the 6 blocks of Psi_q from
    data[k1], gamma."""
    kl = p.l_rows.shape[0]
    for k in range(kl):
        i, j = p.l_bi[k], p.l_bj[k]
        aix, aiy = _rotated(q, i, p.l_si[k, 0], p.l_si[k, 1])
        ajx, ajy = _rotated(q, j, p.l_sj[k, 0], p.l_sj[k, 1])
        ux, uy = _rotated(q, i, p.l_u[k, 0], p.l_u[k, 1])
        dx = q[3 * j] + ajx - q[3 * i] - aix
        dy = q[3 * j + 1] + ajy - q[3 * i + 1] - aiy
        row, w = p.l_rows[k], p.l_w[k]
        psi[row] += w * (ux * dx + uy * dy)
        # rot90(v) = (-v_y, v_x)
        data[k1 + k] = -w * ux
        data[k1 + kl + k] = -w * uy
        data[k1 + 2 * kl + k] = w * ((-uy * dx + ux * dy) - (-ux * aiy + uy * aix))
        data[k1 + 3 * kl + k] = w * ux
        data[k1 + 4 * kl + k] = w * uy
        data[k1 + 5 * kl + k] = w * (-ux * ajy + uy * ajx)
        wi, wj = qd[3 * i + 2], qd[3 * j + 2]
        ddx = qd[3 * j] - wj * ajy - qd[3 * i] + wi * aiy
        ddy = qd[3 * j + 1] + wj * ajx - qd[3 * i + 1] - wi * aix
        gamma[row] += w * (wi * wi * (ux * dx + uy * dy)
                           - 2.0 * wi * (-uy * ddx + ux * ddy)
                           + ux * (ajx * wj * wj - aix * wi * wi)
                           + uy * (ajy * wj * wj - aiy * wi * wi))


@jit
def constraint_terms(q, qd, cval, p, psi, data, gamma):
    """Fill psi (m,), data (Psi_q's term values, ``constraints.py``'s layout) and gamma (m,,
    without c''(t)) in place, for the ``Primitives`` p; each row sums its terms (eq. 24).

    q, qd: (3 nb + 3,) with the ground as body nb (zeros); cval: motion values c(t) per row.
    ``data`` holds the constants first; the q-dependent blocks follow them in the order
    coincidence (4 blocks of kc), line (6 blocks of kl).
    """
    kc, kl = p.c_rows.shape[0], p.l_rows.shape[0]
    k0 = data.shape[0] - 4 * kc - 6 * kl
    for r in range(gamma.shape[0]):
        gamma[r] = 0.0
        psi[r] = -cval[r]
    _coincidence_terms(q, qd, cval, p, psi, data, gamma, k0)
    _line_terms(q, qd, cval, p, psi, data, gamma, k0 + 4 * kc)
    for k in range(p.a_rows.shape[0]):
        psi[p.a_rows[k]] += p.a_w[k] * (q[3 * p.a_bj[k] + 2] - q[3 * p.a_bi[k] + 2])


@jit
def terms(q, qd, cval, p, plan):
    """Psi (m,), the kept Jacobian values (on ``plan.rows``/``plan.cols``, repeated term
    entries summed) and gamma without c''(t). q, qd with the ground's three zeros appended."""
    m = cval.shape[0]
    psi, gamma = np.empty(m), np.empty(m)
    k0 = plan.constants.shape[0]
    raw = np.empty(k0 + 4 * p.c_rows.shape[0] + 6 * p.l_rows.shape[0])
    raw[:k0] = plan.constants
    constraint_terms(q, qd, cval, p, psi, raw, gamma)
    data = np.zeros(plan.size)
    for k in range(raw.shape[0]):
        data[plan.merge[k]] += raw[k]
    return psi, data[plan.keep], gamma


@jit_inline
def pattern_product(values, out_index, in_index, x, size):
    """sum_k values[k] x[in_index[k]] into out[out_index[k]] (size,): J x with (rows, cols),
    J^T y with (cols, rows)."""
    out = np.zeros(size)
    for k in range(values.shape[0]):
        out[out_index[k]] += values[k] * x[in_index[k]]
    return out


@jit
def jac_mul(values, rows, cols, x, m):
    """J x from J's values on its pattern."""
    return pattern_product(values, rows, cols, x, m)


@jit
def jac_t_mul(values, rows, cols, y, n):
    """J^T y from J's values on its pattern."""
    return pattern_product(values, cols, rows, y, n)


@jit
def schur_solve(values, plan, b, rank_tol):
    """x with (J M^-1 J^T) x = b by banded Cholesky; ok False when S is too near singular.

    S is summed over the pattern's column pairs straight into lower band storage in
    reverse Cuthill-McKee order (``JacobianPattern._plan_schur_band``): O(nonzeros) to
    assemble, O(m kd^2) to factorise, no dense J, at any size.
    """
    pair_a, pair_b, pair_minv = plan.pair_a, plan.pair_b, plan.pair_minv
    band_index, perm, kd = plan.band_index, plan.perm, plan.kd
    m = b.shape[0]
    flat = np.zeros((kd + 1) * m)
    for p in range(pair_a.shape[0]):
        flat[band_index[p]] += values[pair_a[p]] * values[pair_b[p]] * pair_minv[p]
    L = flat.reshape(kd + 1, m)          # L[i - j, j] = S[i, j], then the factor
    dmax, dmin = 0.0, np.inf
    for j in range(m):
        s = L[0, j]
        for k in range(max(0, j - kd), j):
            s -= L[j - k, k] * L[j - k, k]
        if s <= 0.0:
            return b, False
        d = math.sqrt(s)
        L[0, j] = d
        dmax, dmin = max(dmax, d), min(dmin, d)
        for i in range(j + 1, min(m, j + kd + 1)):
            s = L[i - j, j]
            for k in range(max(0, i - kd), j):
                s -= L[i - k, k] * L[j - k, k]
            L[i - j, j] = s / d
    if not dmin > math.sqrt(rank_tol) * dmax:
        return b, False
    x = np.empty(m)
    for i in range(m):                   # L y = P b
        s = b[perm[i]]
        for k in range(max(0, i - kd), i):
            s -= L[i - k, k] * x[k]
        x[i] = s / L[0, i]
    for i in range(m - 1, -1, -1):       # L^T z = y
        s = x[i]
        for k in range(i + 1, min(m, i + kd + 1)):
            s -= L[k - i, i] * x[k]
        x[i] = s / L[0, i]
    out = np.empty(m)
    for i in range(m):                   # x = P^T z
        out[perm[i]] = x[i]
    return out, True


@jit
def accelerations(q, qd, cval, cdd, F, minv, rank_tol, p, plan):
    """Eq. (14) by the Schur complement (formulation.md, eq. 15), all in one compiled call.

    Same steps as ``dynamics.Equations.accelerations``: ``S = J M^-1 J^T``, Cholesky,
    ``lam = S^-1 (J M^-1 F - gamma)``, ``q'' = M^-1 (F - J^T lam)``. q, qd with the ground's
    three zeros appended. Returns (q'', lam, ok); ok is False when S is too close to
    singular for Cholesky (the caller then takes the minimum-norm path).
    """
    m, n = cval.shape[0], F.shape[0]
    _, values, gamma = terms(q, qd, cval, p, plan)
    rhs = jac_mul(values, plan.rows, plan.cols, minv * F, m) - (gamma + cdd)
    lam, ok = schur_solve(values, plan, rhs, rank_tol)
    return minv * (F - jac_t_mul(values, plan.rows, plan.cols, lam, n)), lam, ok


