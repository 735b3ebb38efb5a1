/*
 * nullspace.h (part of kernel.c): eq. (14) where the Schur complement S is ill-conditioned
 * (next to a singular configuration), as singular.py nullspace_accelerations solves it:
 * from the SVD M^-1/2 Psi_q^T = U Sigma V^T (x = M^1/2 q''),
 *     x = x_F - U U^T x_F + U Sigma^-1 V^T g,   lam = V Sigma^-1 U^T (x_F - x),
 * singular values below NULLSPACE_RANK_TOL of the largest dropped. The SVD is one-sided
 * Jacobi (Hestenes): it rotates pairs of A's columns until they are orthogonal, so it
 * works on A itself, never on S = A^T A, and keeps the accuracy of the small singular
 * values that forming S would square away (Demmel and Veselic, "Jacobi's method is more
 * accurate than QR", SIAM J. Matrix Anal. Appl. 13, 1992). For the dense form of S only
 * (S_(M, banded) 0); a banded scene's singular cases stay the numpy path's.
 */

#define NULLSPACE_RANK_TOL 1e-13      /* singular.NULLSPACE_RANK_TOLERANCE */
#define SVD_SWEEPS 60
/* columns whose cosine is below this are orthogonal to round-off: not rotated */
#define SVD_ORTHOGONAL 1e-15

/* doubles of scratch nullspace_accelerations needs (0 for a banded model) */
static I nullspace_size(const Model *M) {
    return S_(M, banded) ? 0 : S_(M, n) * S_(M, m) + S_(M, m) * S_(M, m) + S_(M, m) + 2 * S_(M, n);
}

/* A (n x m, column k at A + k n) -> A V (orthogonal columns: U Sigma), V (m x m, column k
 * at V + k m) the product of the rotations. */
static void one_sided_jacobi(double *A, I n, I m, double *V) {
    for (I i = 0; i < m * m; i++) V[i] = 0.0;
    for (I i = 0; i < m; i++) V[i * m + i] = 1.0;
    for (int sweep = 0; sweep < SVD_SWEEPS; sweep++) {
        int rotated = 0;
        for (I p = 0; p + 1 < m; p++)
            for (I q = p + 1; q < m; q++) {
                double *ap = A + p * n, *aq = A + q * n, alpha = 0.0, beta = 0.0, gamma = 0.0;
                for (I k = 0; k < n; k++) {
                    alpha += ap[k] * ap[k];
                    beta += aq[k] * aq[k];
                    gamma += ap[k] * aq[k];
                }
                if (!(fabs(gamma) > SVD_ORTHOGONAL * sqrt(alpha * beta))) continue;
                rotated = 1;
                /* the rotation that zeroes the pair's inner product, its smaller angle */
                double zeta = (beta - alpha) / (2.0 * gamma);
                double t = (zeta >= 0.0 ? 1.0 : -1.0) / (fabs(zeta) + sqrt(1.0 + zeta * zeta));
                double c = 1.0 / sqrt(1.0 + t * t), s = c * t;
                for (I k = 0; k < n; k++) {
                    double a = ap[k], b = aq[k];
                    ap[k] = c * a - s * b;
                    aq[k] = s * a + c * b;
                }
                double *vp = V + p * m, *vq = V + q * m;
                for (I k = 0; k < m; k++) {
                    double a = vp[k], b = vq[k];
                    vp[k] = c * a - s * b;
                    vq[k] = s * a + c * b;
                }
            }
        if (!rotated) break;
    }
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
    double *A = w, *V = A + n * m, *sv = V + m * m, *xF = sv + m, *x = xF + n;
    for (I k = 0; k < n; k++) x[k] = sqrt(M->minv[k]);                   /* M^-1/2 */
    memset(A, 0, (size_t)(n * m) * sizeof(double));
    for (I k = 0; k < S_(M, nkeep); k++)
        A[S_(M, rows)[k] * n + S_(M, cols)[k]] += values[k] * x[S_(M, cols)[k]];
    for (I k = 0; k < n; k++) xF[k] = x[k] * F[k];
    one_sided_jacobi(A, n, m, V);
    double largest = 0.0;
    for (I r = 0; r < m; r++) {
        double ss = 0.0;
        for (I k = 0; k < n; k++) ss += A[r * n + k] * A[r * n + k];
        sv[r] = sqrt(ss);
        largest = fmax(largest, sv[r]);
    }
    double cut = NULLSPACE_RANK_TOL * fmax(largest, 1e-300);
    for (I r = 0; r < m; r++)                       /* A's columns -> U's */
        if (sv[r] > cut) for (I k = 0; k < n; k++) A[r * n + k] /= sv[r];
    /* qdd holds M^-1/2 until the end; x = x_F - U (U^T x_F - Sigma^-1 V^T g) */
    for (I k = 0; k < n; k++) { qdd[k] = x[k]; x[k] = xF[k]; }
    for (I r = 0; r < m; r++) {
        if (!(sv[r] > cut)) continue;
        const double *u = A + r * n, *v = V + r * m;
        double ux = 0.0, vg = 0.0;
        for (I k = 0; k < n; k++) ux += u[k] * xF[k];
        for (I k = 0; k < m; k++) vg += v[k] * g[k];
        double c = vg / sv[r] - ux;
        for (I k = 0; k < n; k++) x[k] += c * u[k];
    }
    for (I k = 0; k < m; k++) lam[k] = 0.0;
    for (I r = 0; r < m; r++) {                     /* lam = V Sigma^-1 U^T (x_F - x) */
        if (!(sv[r] > cut)) continue;
        const double *u = A + r * n, *v = V + r * m;
        double c = 0.0;
        for (I k = 0; k < n; k++) c += u[k] * (xF[k] - x[k]);
        c /= sv[r];
        for (I k = 0; k < m; k++) lam[k] += c * v[k];
    }
    for (I k = 0; k < n; k++) qdd[k] *= x[k];
    return ST_OK;
}
