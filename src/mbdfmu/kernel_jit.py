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


def _compiled(function):
    """numba's ahead-of-use compilation, cached on disk; the plain function without numba."""
    return numba.njit(cache=True, nogil=True)(function) if numba is not None else function


def available() -> bool:
    """numba is installed and not switched off by ``MBDFMU_KERNEL=numpy``."""
    return numba is not None and os.environ.get("MBDFMU_KERNEL", "auto") != "numpy"


@_compiled
def constraint_terms(q, qd, cval,
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


@_compiled
def terms(q, qd, cval, args, jac_constants, keep):
    """Psi (m,), the kept Jacobian values (on the pattern's rows/cols) and gamma without
    c''(t). q, qd with the ground's three zeros appended."""
    m = cval.shape[0]
    psi, gamma = np.empty(m), np.empty(m)
    data = np.empty(jac_constants.shape[0] + 4 * args[0].shape[0] + 6 * args[5].shape[0])
    data[:jac_constants.shape[0]] = jac_constants
    constraint_terms(q, qd, cval, args[0], args[1], args[2], args[3], args[4],
                     args[5], args[6], args[7], args[8], args[9], args[10],
                     args[11], args[12], args[13], psi, data, gamma)
    return psi, data[keep], gamma


@_compiled
def jac_mul(values, rows, cols, x, m):
    """J x from J's values on its pattern."""
    y = np.zeros(m)
    for k in range(values.shape[0]):
        y[rows[k]] += values[k] * x[cols[k]]
    return y


@_compiled
def jac_t_mul(values, rows, cols, y, n):
    """J^T y from J's values on its pattern."""
    x = np.zeros(n)
    for k in range(values.shape[0]):
        x[cols[k]] += values[k] * y[rows[k]]
    return x


@_compiled
def schur_solve(values, pattern, b, rank_tol):
    """x with (J M^-1 J^T) x = b by banded Cholesky; ok False when S is too near singular.

    S is summed over the pattern's column pairs straight into lower band storage in
    reverse Cuthill-McKee order (``JacobianPattern._plan_schur_band``): O(nonzeros) to
    assemble, O(m kd^2) to factorise, no dense J, at any size.
    """
    pair_a, pair_b, pair_minv, band_index, perm, kd = (pattern[2], pattern[3], pattern[4],
                                                       pattern[5], pattern[6], pattern[7])
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


@_compiled
def accelerations(q, qd, cval, cdd, F, minv, rank_tol, args, jac_constants, keep, pattern):
    """Eq. 14 by the Schur complement, all in one compiled call.

    Same steps as ``System.accelerations``: ``S = J M^-1 J^T``, Cholesky,
    ``lam = S^-1 (J M^-1 F - gamma)``, ``q'' = M^-1 (F - J^T lam)``. q, qd with the ground's
    three zeros appended; ``pattern`` = (rows, cols, pair_a, pair_b, pair_minv, band_index,
    perm, kd) of ``JacobianPattern``. Returns (q'', lam, ok); ok is False when S is too
    close to singular for Cholesky (the caller then takes the minimum-norm path).
    """
    m, n = cval.shape[0], F.shape[0]
    rows, cols = pattern[0], pattern[1]
    _, values, gamma = terms(q, qd, cval, args, jac_constants, keep)
    rhs = jac_mul(values, rows, cols, minv * F, m) - (gamma + cdd)
    lam, ok = schur_solve(values, pattern, rhs, rank_tol)
    return minv * (F - jac_t_mul(values, rows, cols, lam, n)), lam, ok


@_compiled
def rk4p_step(q, qd, f, h, motion, F, minv, rank_tol, tol, max_iter, args, jac_constants,
              keep, pattern):
    """One step of ``rk4p`` (classic RK4 on the index-1 form, then the mass-weighted
    projections of ``assembly.py``) for a mechanism with constant applied forces F.

    q, qd, f (= q'' at the start): (n,). ``motion`` (3, 3, m): c, c', c'' of every row at
    t, t + h/2 and t + h. Returns (q, q', q'' at t + h, status): status 0 ok, 1 a singular
    Schur complement (the caller redoes the step on the general path), 2 the position
    projection did not converge to tol in max_iter Newton iterations.
    """
    n = q.shape[0]
    m = motion.shape[2]
    rows, cols = pattern[0], pattern[1]
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
                                   rank_tol, args, jac_constants, keep, pattern)
        if not ok:
            return q, qd, f, 1
        w = 2.0 if stage < 3 else 1.0
        acc_q += w * k_q
        acc_v += w * k_v
    qn = q + h / 6.0 * acc_q
    vn = qd + h / 6.0 * acc_v
    # position projection: Newton, dq = -M^-1 J^T (J M^-1 J^T)^-1 Psi
    done = False
    for _ in range(max_iter + 1):
        qe[:n] = qn
        psi, values, _ = terms(qe, qe, motion[2, 0], args, jac_constants, keep)
        if np.max(np.abs(psi)) <= tol:
            done = True
            break
        x, ok = schur_solve(values, pattern, psi, rank_tol)
        if not ok:
            return q, qd, f, 1
        qn = qn - minv * jac_t_mul(values, rows, cols, x, n)
    if not done:
        return q, qd, f, 2
    # velocity projection onto J q' = nu
    x, ok = schur_solve(values, pattern, jac_mul(values, rows, cols, vn, m) - motion[2, 1],
                        rank_tol)
    if not ok:
        return q, qd, f, 1
    vn = vn - minv * jac_t_mul(values, rows, cols, x, n)
    qde[:n] = vn
    fn, _, ok = accelerations(qe, qde, motion[2, 0], motion[2, 2], F, minv, rank_tol,
                              args, jac_constants, keep, pattern)
    if not ok:
        return q, qd, f, 1
    return qn, vn, fn, 0


# Fields of the ``audit`` array of rk4p_steps: EnergyAudit's running state (energy_audit.py).
AUDIT_FIELDS = ("active", "e0", "v0", "kinetic_max", "potential_swing", "magnitude", "checks",
                "worst", "last_energy")


@_compiled
def rk4p_steps(q, qd, f, h, motions, F, minv, rank_tol, tol, max_iter, args, jac_constants,
               keep, pattern, mass, audit, divergence_fraction, roundoff):
    """``rk4p_step`` repeated for every row of ``motions`` (s, 3, 3, m), with the energy
    divergence check of a fixed-step method after each step (``EnergyAudit.check`` with
    factor 0, for mechanisms whose energy is 1/2 q'M q' - F.q) updating ``audit`` in place.

    Returns (q, q', q'', steps done, status): status 0 all done; 1 a singular Schur
    complement at the next step, 2 a failed projection there (see rk4p_step); 3 the energy
    check failed after the last step done; 4 a non-finite state after it.
    """
    for k in range(motions.shape[0]):
        qn, vn, fn, status = rk4p_step(q, qd, f, h, motions[k], F, minv, rank_tol, tol,
                                       max_iter, args, jac_constants, keep, pattern)
        if status != 0:
            return q, qd, f, k, status
        q, qd, f = qn, vn, fn
        if not np.isfinite(q.sum() + qd.sum() + f.sum()):
            return q, qd, f, k + 1, 4
        if audit[0] != 0.0:
            kinetic = 0.5 * np.sum(mass * qd * qd)
            energy = kinetic - np.sum(F * q)
            audit[3] = max(audit[3], kinetic)
            audit[4] = max(audit[4], abs(energy - kinetic - audit[2]))
            audit[5] = max(audit[5], abs(energy), kinetic)
            audit[8] = energy
            audit[6] += 1.0
            error = abs(energy - audit[1])
            if error > roundoff * audit[5] * audit[6]:
                allowance = divergence_fraction * max(audit[3], audit[4])
                ratio = error / allowance if allowance > 0.0 else np.inf
                audit[7] = max(audit[7], ratio)
                if ratio > 1.0:
                    return q, qd, f, k + 1, 3
    return q, qd, f, motions.shape[0], 0
