/*
 * solve.h (part of kernel.c): (J M^-1 J^T) x = b as sparsity.py solves it.
 *
 * Below BANDED_MIN_ROWS rows (S_(M, banded) 0) numpy factorises S dense by Cholesky in the
 * rows' own order (solve_spd's potrf), above it in band storage in reverse Cuthill-McKee
 * order (JacobianPattern.schur_solve's pbtrf); either is trusted when its pivots say S is
 * well conditioned (_well_conditioned). Here the band answers first at any size (the
 * same numbers to round-off, cheaper; factorised as L D L^T, band_cholesky_inv), the dense
 * form where the band's pivots are not. Otherwise the minimum-norm least-squares solution:
 * dense, by Cholesky with diagonal pivoting stopped at rank_tol times the first pivot
 * (pivoted_min_norm: lstsq's cut-off on the eigenvalues of symmetric S, as the pivots
 * reveal them); banded, iterated Tikhonov regularisation (JacobianPattern._min_norm). With
 * S_(M, min_norm) 0 the minimum-norm cases are handed back (ST_SINGULAR) to the numpy path.
 */

#define TIKHONOV_STEPS 3

/* Cholesky of the band L[d * m + j] = S[j + d, j] in place; pivots' range in *dmin, *dmax;
 * 0 when S is not positive definite. The range is kept in locals: fmax's calls (not inlined
 * without fast math) made the pivot's division wait on the stack instead of beside the next
 * column's sums. */
static int band_cholesky(double *L, I m, I kd, double *dmin, double *dmax) {
    double lo = INFINITY, hi = 0.0;
    for (I j = 0; j < m; j++) {
        double s = L[j];
        for (I k = (j - kd > 0 ? j - kd : 0); k < j; k++) s -= L[(j - k) * m + k] * L[(j - k) * m + k];
        if (!(s > 0.0)) return 0;
        double d = sqrt(s), inv = 1.0 / d;   /* one division per column, not per entry */
        L[j] = d;
        hi = d > hi ? d : hi;
        lo = d < lo ? d : lo;
        I end = j + kd + 1 < m ? j + kd + 1 : m;
        for (I i = j + 1; i < end; i++) {
            double t = L[(i - j) * m + j];
            for (I k = (i - kd > 0 ? i - kd : 0); k < j; k++) t -= L[(i - k) * m + k] * L[(j - k) * m + k];
            L[(i - j) * m + j] = t * inv;
        }
    }
    *dmin = lo;
    *dmax = hi;
    return 1;
}

/* S = L D L^T of the band in place, for band_substitute_inv: off the diagonal the
 * unscaled columns W = L D (L[d * m + j] = W[j + d, j]), on it 1 / D; 0 when S is not
 * positive definite; *dmin, *dmax: the range of sqrt(D), the pivots of S's Cholesky factor.
 * Right-looking (each column, once final, updates the columns after it) and without square
 * roots: a column's pivot waits on one division and one update of the column before it,
 * where the dot-product form of a Cholesky factor waits on a square root, a division and a
 * chain of kd products for every entry (the same sums in another order). A kernel built
 * for one scene runs its header's straight-line form instead (schur_factor). */
__attribute__((unused))
static int band_cholesky_inv(double *L, I m, I kd, double *dmin, double *dmax) {
    double lo = INFINITY, hi = 0.0;
    for (I j = 0; j < m; j++) {
        double d = L[j];
        if (!(d > 0.0)) return 0;
        hi = d > hi ? d : hi;
        lo = d < lo ? d : lo;
        double inv = 1.0 / d;
        I end = j + kd + 1 < m ? j + kd + 1 : m;
        for (I i = j + 1; i < end; i++) {          /* S[i, l] -= W[i, j] W[l, j] / D_j */
            double u = L[(i - j) * m + j] * inv;
            for (I l = j + 1; l <= i; l++) L[(i - l) * m + l] -= u * L[(l - j) * m + j];
        }
        L[j] = inv;
    }
    *dmin = sqrt(lo);
    *dmax = sqrt(hi);
    return 1;
}

/* S x = y in place by band_cholesky_inv's factor: z = D^-1 L^-1 y forward, then
 * x = z - D^-1 W^T x backward (L^T = D^-1 W^T), each entry, once final, updating the
 * entries after it (a chain of one product per row, not of kd). */
__attribute__((unused))
static void band_substitute_inv(const double *L, I m, I kd, double *y) {
    for (I i = 0; i < m; i++) {
        double z = y[i] * L[i];
        y[i] = z;
        I end = i + kd + 1 < m ? i + kd + 1 : m;
        for (I k = i + 1; k < end; k++) y[k] -= L[(k - i) * m + i] * z;
    }
    for (I i = m - 1; i > 0; i--) {
        double x = y[i];
        for (I k = (i - kd > 0 ? i - kd : 0); k < i; k++) y[k] -= (L[k] * L[(i - k) * m + k]) * x;
    }
}

/* Cholesky S = U^T U of a dense m x m S in place in the rows' order (potrf 'U': U's rows
 * kept in U); pivots' range in *dmin, *dmax; 0 when S is not positive definite. */
static int dense_cholesky(double *U, I m, double *dmin, double *dmax) {
    *dmax = 0.0;
    *dmin = INFINITY;
    for (I j = 0; j < m; j++) {
        double s = U[j * m + j];
        for (I k = 0; k < j; k++) s -= U[k * m + j] * U[k * m + j];
        if (!(s > 0.0)) return 0;
        double d = sqrt(s);
        U[j * m + j] = d;
        if (d > *dmax) *dmax = d;        /* d > 0: fmax's answer without its call */
        if (d < *dmin) *dmin = d;
        for (I i = j + 1; i < m; i++) {
            double t = U[j * m + i];
            for (I k = 0; k < j; k++) t -= U[k * m + j] * U[k * m + i];
            U[j * m + i] = t / d;
        }
    }
    return 1;
}

/* L L^T y = y in place for a band factor. The reciprocal of each pivot does not depend on
 * y, so its division runs beside the substitution's chain instead of on it. */
static void band_substitute(const double *L, I m, I kd, double *y) {
    for (I i = 0; i < m; i++) {
        double s = y[i], inv = 1.0 / L[i];
        for (I k = (i - kd > 0 ? i - kd : 0); k < i; k++) s -= L[(i - k) * m + k] * y[k];
        y[i] = s * inv;
    }
    for (I i = m - 1; i >= 0; i--) {
        double s = y[i], inv = 1.0 / L[i];
        I end = i + kd + 1 < m ? i + kd + 1 : m;
        for (I k = i + 1; k < end; k++) s -= L[(k - i) * m + i] * y[k];
        y[i] = s * inv;
    }
}

/* U^T U x = b in place (x: b on entry) for dense_cholesky's U (m x m). */
static void dense_substitute(const double *U, I m, double *x) {
    for (I i = 0; i < m; i++) {                 /* U^T y = b */
        double s = x[i];
        for (I k = 0; k < i; k++) s -= U[k * m + i] * x[k];
        x[i] = s / U[i * m + i];
    }
    for (I i = m - 1; i >= 0; i--) {            /* U x = y */
        double s = x[i];
        for (I k = i + 1; k < m; k++) s -= U[i * m + k] * x[k];
        x[i] = s / U[i * m + i];
    }
}

/* Minimum-norm least-squares x of S x = b for symmetric positive semi-definite S (m x m,
 * destroyed; T: m x m scratch): Cholesky with diagonal pivoting (LAPACK's pstrf),
 * P S P^T = L L^T, stopped where the largest pivot left is at or below rank_tol times the
 * first (S's largest diagonal, within a factor m of its largest eigenvalue: lstsq's
 * cut-off on the eigenvalues of symmetric S, as the pivots reveal them); rank r. With
 * G = P^T L (m x r, full column rank), S = G G^T and S^+ = G (G^T G)^-2 G^T, and G^T G =
 * L^T L = T has S's nonzero eigenvalues, so x = G T^-1 T^-1 G^T b is no worse conditioned
 * than S. About m^3 / 2 operations, where an eigen-decomposition by Jacobi rotations took
 * ten-odd sweeps of 6 m^3 each. 0 where T is not positive definite (not expected). */
static int pivoted_min_norm(double rank_tol, double *S, I m, const double *b, double *x,
                            double *T) {
    I piv[m], r = 0;                    /* m < BANDED_MIN_ROWS here: small on the stack */
    double first = 0.0, c[m];
    for (I i = 0; i < m; i++) piv[i] = i;
    for (I k = 0; k < m; k++, r++) {    /* the trailing block kept whole (both triangles) */
        I p = k;
        for (I i = k + 1; i < m; i++) if (S[i * m + i] > S[p * m + p]) p = i;
        double pivot = S[p * m + p];
        if (k == 0) first = pivot;
        if (!(pivot > rank_tol * first)) break;
        if (p != k) {                   /* rows, then columns, k and p */
            for (I j = 0; j < m; j++) {
                double t = S[k * m + j]; S[k * m + j] = S[p * m + j]; S[p * m + j] = t;
            }
            for (I i = 0; i < m; i++) {
                double t = S[i * m + k]; S[i * m + k] = S[i * m + p]; S[i * m + p] = t;
            }
            I t = piv[k]; piv[k] = piv[p]; piv[p] = t;
        }
        double d = sqrt(pivot);
        S[k * m + k] = d;
        for (I i = k + 1; i < m; i++) S[i * m + k] /= d;
        for (I i = k + 1; i < m; i++)
            for (I j = k + 1; j <= i; j++) {
                double v = S[i * m + j] - S[i * m + k] * S[j * m + k];
                S[i * m + j] = v;
                S[j * m + i] = v;
            }
    }
    /* L[i][a] = S[i * m + a] for i >= a, a < r */
    for (I a = 0; a < r; a++)                   /* T = L^T L (rows of U kept: i <= j) */
        for (I e = a; e < r; e++) {
            double s = 0.0;
            for (I i = e; i < m; i++) s += S[i * m + a] * S[i * m + e];
            T[a * r + e] = s;
        }
    for (I a = 0; a < r; a++) {                 /* c = L^T P b */
        double s = 0.0;
        for (I i = a; i < m; i++) s += S[i * m + a] * b[piv[i]];
        c[a] = s;
    }
    double dmin, dmax;
    if (r > 0) {
        if (!dense_cholesky(T, r, &dmin, &dmax)) return 0;
        dense_substitute(T, r, c);
        dense_substitute(T, r, c);
    }
    for (I i = 0; i < m; i++) {                 /* x = P^T L c */
        double s = 0.0;
        for (I a = 0; a < r && a <= i; a++) s += S[i * m + a] * c[a];
        x[piv[i]] = s;
    }
    return 1;
}

static int dense_solve(const Model *M, const double *values, const double *b, double *x,
                       double *work, I min_norm) {
    I m = S_(M, m);
    double *S = work, *U = work + m * m;
    memset(S, 0, (size_t)(m * m) * sizeof(double));
    for (I p = 0; p < S_(M, npairs); p++) {
        I ra = S_(M, rows)[S_(M, pair_a)[p]], rb = S_(M, rows)[S_(M, pair_b)[p]];
        double w = values[S_(M, pair_a)[p]] * values[S_(M, pair_b)[p]] * M->pair_minv[p];
        S[ra * m + rb] += w;
        if (ra != rb) S[rb * m + ra] += w;
    }
    double dmax, dmin;
    memcpy(U, S, (size_t)(m * m) * sizeof(double));
    int ok = dense_cholesky(U, m, &dmin, &dmax);
    if (ok && dmin > sqrt(M->rank_tol) * dmax) {
        memcpy(x, b, (size_t)m * sizeof(double));
        dense_substitute(U, m, x);
        return ST_OK;
    }
    if (!min_norm || !all_finite_values(S, m * m) || !all_finite_values(b, m)) return ST_SINGULAR;
    return pivoted_min_norm(M->rank_tol, S, m, b, x, U) ? ST_OK : ST_SINGULAR;
}

/* S = Psi_q M^-1 Psi_q^T in band storage (S[i, j] at L[(i - j) m + j], i >= j, in the
 * band's order) from Psi_q's values, each entry summed over its pairs in their order. */
static void schur_band(const Model *M, const double *values, double *L) {
#ifdef MBD_SCENE
    sc_assemble(values, M->pair_minv, L);
#else
    memset(L, 0, (size_t)((S_(M, kd) + 1) * S_(M, m)) * sizeof(double));
    for (I p = 0; p < S_(M, npairs); p++)
        L[S_(M, band_index)[p]] += values[S_(M, pair_a)[p]] * values[S_(M, pair_b)[p]]
                                   * M->pair_minv[p];
#endif
}

/* band_cholesky_inv and band_substitute_inv of S's band; for one scene the header's
 * straight-line code, the same operations in the same order less those on entries its
 * pattern keeps at zero (x - u 0 = x: the same doubles). */
static int schur_factor(const Model *M, double *L, double *dmin, double *dmax) {
#ifdef MBD_SCENE
    (void)M;
    return sc_factor(L, dmin, dmax);
#else
    return band_cholesky_inv(L, S_(M, m), S_(M, kd), dmin, dmax);
#endif
}

static void schur_substitute(const Model *M, const double *L, double *y) {
#ifdef MBD_SCENE
    (void)M;
    sc_substitute(L, y);
#else
    band_substitute_inv(L, S_(M, m), S_(M, kd), y);
#endif
}

static int banded_solve(const Model *M, const double *values, const double *b, double *x,
                        double *work, double *tmp, int *kept, I min_norm) {
    I m = S_(M, m), kd = S_(M, kd), size = (kd + 1) * m;
    double *band = work, *L = work + size, dmin, dmax;
    schur_band(M, values, band);
    memcpy(L, band, (size_t)size * sizeof(double));
    if (schur_factor(M, L, &dmin, &dmax) && dmin > sqrt(M->rank_tol) * dmax) {
        for (I i = 0; i < m; i++) tmp[i] = b[S_(M, perm)[i]];
        schur_substitute(M, L, tmp);
        for (I i = 0; i < m; i++) x[S_(M, perm)[i]] = tmp[i];
        *kept = 1;
        return ST_OK;
    }
    if (!min_norm || !all_finite_values(band, size) || !all_finite_values(b, m)) return ST_SINGULAR;
    double eps = 0.0;                               /* iterated Tikhonov (_min_norm) */
    for (I j = 0; j < m; j++) eps = fmax(eps, fabs(band[j]));
    eps = M->rank_tol * (eps > 0.0 ? eps : 1.0);
    memcpy(L, band, (size_t)size * sizeof(double));
    for (I j = 0; j < m; j++) L[j] += eps;
    if (!band_cholesky(L, m, kd, &dmin, &dmax)) return ST_SINGULAR;
    double *xp = tmp + m, *r = tmp + 2 * m;
    for (I i = 0; i < m; i++) xp[i] = 0.0;
    for (int it = 0; it < TIKHONOV_STEPS; it++) {
        for (I i = 0; i < m; i++) r[i] = b[S_(M, perm)[i]];
        for (I j = 0; j < m; j++) {                 /* r -= S xp (band storage) */
            r[j] -= band[j] * xp[j];
            for (I d = 1; d <= kd && j + d < m; d++) {
                r[j + d] -= band[d * m + j] * xp[j];
                r[j] -= band[d * m + j] * xp[j + d];
            }
        }
        band_substitute(L, m, kd, r);
        for (I i = 0; i < m; i++) xp[i] += r[i];
    }
    for (I i = 0; i < m; i++) x[S_(M, perm)[i]] = xp[i];
    return ST_OK;
}

/* x with (J M^-1 J^T) x = b: ST_OK, or ST_SINGULAR where the numpy path must answer.
 * Below BANDED_MIN_ROWS the band (cheaper at any size) answers where its pivots are
 * well conditioned, and the dense form decides only where they are not. */
static int schur_solve_mode(const Model *M, const double *values, const double *b, double *x,
                            double *work, double *tmp, int *kept, I min_norm) {
    *kept = 0;
    if (S_(M, banded)) return banded_solve(M, values, b, x, work, tmp, kept, min_norm);
    I m = S_(M, m);
    double *L = work, dmin, dmax;
    schur_band(M, values, L);
    if (schur_factor(M, L, &dmin, &dmax) && dmin > sqrt(M->rank_tol) * dmax) {
        for (I i = 0; i < m; i++) tmp[i] = b[S_(M, perm)[i]];
        schur_substitute(M, L, tmp);
        for (I i = 0; i < m; i++) x[S_(M, perm)[i]] = tmp[i];
        *kept = 1;
        return ST_OK;
    }
    return dense_solve(M, values, b, x, work, min_norm);
}

/* schur_solve_mode with the minimum-norm cases as S_(M, min_norm) says (eq. (14) asks for none:
 * it takes the null-space form instead, nullspace.h). */
static int schur_solve_keeping(const Model *M, const double *values, const double *b, double *x,
                               double *work, double *tmp, int *kept) {
    return schur_solve_mode(M, values, b, x, work, tmp, kept, S_(M, min_norm));
}

static int schur_solve(const Model *M, const double *values, const double *b, double *x,
                       double *work, double *tmp) {
    int kept;
    return schur_solve_keeping(M, values, b, x, work, tmp, &kept);
}

/* x with (J M^-1 J^T) x = b by the band factor the last schur_solve_keeping left in work
 * (it said *kept): the same J, so the same factor, without factorising again. */
static void schur_again(const Model *M, const double *b, double *x, const double *work,
                        double *tmp) {
    I m = S_(M, m), kd = S_(M, kd);
    const double *L = S_(M, banded) ? work + (kd + 1) * m : work;
    for (I i = 0; i < m; i++) tmp[i] = b[S_(M, perm)[i]];
    schur_substitute(M, L, tmp);
    for (I i = 0; i < m; i++) x[S_(M, perm)[i]] = tmp[i];
}
