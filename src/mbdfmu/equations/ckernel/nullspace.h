/*
 * nullspace.h (part of kernel.c): eq. (14) where the Schur complement S is ill-conditioned
 * (next to a singular configuration; redundant rows), as singular.py
 * nullspace_accelerations solves it, with x = M^1/2 q'' and A = M^-1/2 Psi_q^T (n x m):
 *     x = x_F - P_A x_F + (A^T)^+ g,   lam = A^+ (x_F - x),
 * P_A the orthogonal projector onto A's range. singular.py takes these from LAPACK's SVD;
 * here from a complete orthogonal decomposition (LAPACK's gelsy route; Golub and Van Loan,
 * Matrix Computations, sec. 5.4-5.5): Householder QR with column pivoting A P = Q R, its
 * rank r where |R_kk| falls to NULLSPACE_RANK_TOL of |R_00|, then the RZ factorisation
 * [R11 R12] = [T 0] Z, so A = Q1 T Z1 P^T (Q1: Q's first r columns, Z1: Z's first r rows,
 * T r x r upper triangular) and
 *     x = x_F - Q1 (Q1^T x_F - T^-T Z1 P^T g),   lam = P Z1^T T^-1 (Q1^T x_F - T^-T Z1 P^T g)
 * (Q1^T (x_F - x) is that bracket itself). Both work on A, never on S = A^T A, so the error
 * grows like eps / sigma, not eps / sigma^2, as the SVD's does: the problem's own
 * conditioning, since A's entries carry eps of round-off already. It costs a few m^2 n,
 * where a one-sided Jacobi SVD took ten-odd sweeps of 5 m^2 n each. For the
 * dense form of S only (S_(M, banded) 0); a banded scene's singular cases stay the numpy
 * path's.
 */

#define NULLSPACE_RANK_TOL 1e-13      /* singular.NULLSPACE_RANK_TOLERANCE */

/* doubles of scratch nullspace_accelerations needs (0 for a banded model) */
static I nullspace_size(const Model *M) {
    return S_(M, banded) ? 0 : S_(M, n) * S_(M, m) + 5 * S_(M, m) + 2 * S_(M, n);
}

/* The Householder reflector I - tau v v^T (v[0] = 1, v[k] = x[k * stride] / (alpha - beta)
 * after the call) that maps (alpha, x) to (beta, 0): LAPACK's dlarfg. Returns tau. */
static double reflector(double *alpha, double *x, I len, I stride) {
    double ss = 0.0;                /* A's entries are O(1) to O(1e3): no scaling needed */
    for (I k = 0; k < len; k++) ss += x[k * stride] * x[k * stride];
    if (ss == 0.0) return 0.0;
    double a = *alpha, beta = -copysign(sqrt(a * a + ss), a);
    for (I k = 0; k < len; k++) x[k * stride] /= a - beta;
    *alpha = beta;
    return (beta - a) / beta;
}

/* A P = Q R in place (A: n x m, column k at A + k n; Q's reflectors below R's diagonal,
 * their tau in tau), P in perm, stopped at the rank: returned. */
static I pivoted_qr(double *A, I n, I m, I *perm, double *tau, double *norms) {
    I steps = n < m ? n : m;
    double first = 0.0;
    for (I k = 0; k < m; k++) perm[k] = k;
    for (I k = 0; k < steps; k++) {
        I p = k;
        for (I j = k; j < m; j++) {        /* squared norms below row k, afresh (no drift) */
            double s = 0.0;
            for (I i = k; i < n; i++) s += A[j * n + i] * A[j * n + i];
            norms[j] = s;
            if (s > norms[p]) p = j;
        }
        if (k == 0) first = norms[p];
        if (!(norms[p] > NULLSPACE_RANK_TOL * NULLSPACE_RANK_TOL * first)) return k;
        if (p != k) {
            for (I i = 0; i < n; i++) {
                double t = A[k * n + i]; A[k * n + i] = A[p * n + i]; A[p * n + i] = t;
            }
            I t = perm[k]; perm[k] = perm[p]; perm[p] = t;
        }
        double *col = A + k * n;
        tau[k] = reflector(col + k, col + k + 1, n - k - 1, 1);
        for (I j = k + 1; j < m; j++) {    /* H_k on the columns right of k */
            double *c = A + j * n, s = c[k];
            for (I i = k + 1; i < n; i++) s += col[i] * c[i];
            s *= tau[k];
            c[k] -= s;
            for (I i = k + 1; i < n; i++) c[i] -= s * col[i];
        }
    }
    return steps;
}

/* [R11 R12] = [T 0] Z in place (R's first r rows in A; rows from the bottom up, each
 * reflector on column i and columns r..m-1, its vector left in row i's R12 part, tau in
 * ztau): LAPACK's tzrzf. Z = H_0 ... H_{r-1}. */
static void rz_factor(double *A, I n, I m, I r, double *ztau) {
    for (I i = r - 1; i >= 0; i--) {
        if (r == m) { ztau[i] = 0.0; continue; }
        ztau[i] = reflector(A + i * n + i, A + r * n + i, m - r, n);
        for (I k = 0; k < i; k++) {        /* rows above: columns i and r..m-1 */
            double s = A[i * n + k];
            for (I j = r; j < m; j++) s += A[j * n + k] * A[j * n + i];
            s *= ztau[i];
            A[i * n + k] -= s;
            for (I j = r; j < m; j++) A[j * n + k] -= s * A[j * n + i];
        }
    }
}

/* H_i y (y: m) for rz_factor's reflector i: (1 at i, row i's R12 part at r..m-1). */
static void rz_apply(const double *A, I n, I m, I r, const double *ztau, I i, double *y) {
    double s = y[i];
    for (I j = r; j < m; j++) s += A[j * n + i] * y[j];
    s *= ztau[i];
    y[i] -= s;
    for (I j = r; j < m; j++) y[j] -= s * A[j * n + i];
}

/* H_k y (y: n) for pivoted_qr's reflector k (1 at k, column k's part below its diagonal). */
static void qr_apply(const double *A, I n, const double *tau, I k, double *y) {
    const double *col = A + k * n;
    double s = y[k];
    for (I i = k + 1; i < n; i++) s += col[i] * y[i];
    s *= tau[k];
    y[k] -= s;
    for (I i = k + 1; i < n; i++) y[i] -= s * col[i];
}

/* q'' (n) and lam (m) with Psi_q q'' = g in the mass metric closest to M^-1 F; Psi_q's
 * values in `values`; w: nullspace_size(M) doubles. ST_SINGULAR where the numpy path must
 * answer (a banded model, values that are not finite: it says why). */
static int nullspace_accelerations(const Model *M, const double *values, const double *F,
                                   const double *g, double *qdd, double *lam, double *w) {
    I n = S_(M, n), m = S_(M, m);
    if (S_(M, banded) || !all_finite_values(values, S_(M, nkeep)) || !all_finite_values(F, n) ||
            !all_finite_values(g, m))
        return ST_SINGULAR;
    double *A = w, *tau = A + n * m, *ztau = tau + m, *norms = ztau + m, *h = norms + m,
           *y = h + m, *sq = y + m, *x = sq + n;
    I perm[m];                          /* m < BANDED_MIN_ROWS here: small on the stack */
    for (I k = 0; k < n; k++) sq[k] = sqrt(M->minv[k]);                  /* M^-1/2 */
    memset(A, 0, (size_t)(n * m) * sizeof(double));
    for (I k = 0; k < S_(M, nkeep); k++)
        A[S_(M, rows)[k] * n + S_(M, cols)[k]] += values[k] * sq[S_(M, cols)[k]];
    I r = pivoted_qr(A, n, m, perm, tau, norms);
    rz_factor(A, n, m, r, ztau);
    for (I k = 0; k < n; k++) x[k] = sq[k] * F[k];                       /* x_F */
    for (I k = 0; k < m; k++) h[k] = g[perm[k]];                          /* P^T g */
    for (I i = r - 1; i >= 0; i--) rz_apply(A, n, m, r, ztau, i, h);      /* Z h */
    for (I i = 0; i < r; i++) {                                           /* T^-T (Z h)_1:r */
        double s = h[i];
        for (I k = 0; k < i; k++) s -= A[i * n + k] * h[k];
        h[i] = s / A[i * n + i];
    }
    for (I k = 0; k < n; k++) qdd[k] = x[k];                              /* Q^T x_F */
    for (I k = 0; k < r; k++) qr_apply(A, n, tau, k, qdd);
    for (I i = 0; i < r; i++) y[i] = qdd[i] - h[i];                       /* the bracket */
    for (I k = 0; k < n; k++) qdd[k] = k < r ? y[k] : 0.0;                /* Q1 bracket */
    for (I k = r - 1; k >= 0; k--) qr_apply(A, n, tau, k, qdd);
    for (I k = 0; k < n; k++) qdd[k] = sq[k] * (x[k] - qdd[k]);           /* M^-1/2 x */
    for (I i = r - 1; i >= 0; i--) {                                      /* T^-1 bracket */
        double s = y[i];
        for (I k = i + 1; k < r; k++) s -= A[k * n + i] * y[k];
        y[i] = s / A[i * n + i];
    }
    for (I k = r; k < m; k++) y[k] = 0.0;
    for (I i = 0; i < r; i++) rz_apply(A, n, m, r, ztau, i, y);           /* Z^T (y; 0) */
    for (I k = 0; k < m; k++) lam[perm[k]] = y[k];                        /* P */
    return ST_OK;
}
