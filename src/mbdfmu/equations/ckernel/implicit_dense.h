/*
 * implicit_dense.h (part of implicit.h): genalpha's and ali3p's iteration matrix
 * [[K, Psi_q^T], [Psi_q, -E]] assembled whole and factorised by a dense LU with partial
 * pivoting (LAPACK's dgetrf, what the Python step calls), for the mechanisms whose K the
 * banded Schur complement cannot take: line rows (translational and slot joints: their
 * geometric stiffness couples a body's position and angle, and two bodies' angles) and
 * forces of the state between two moving bodies. K as the Python step builds it
 * (genalpha.py _iteration_matrix, ali3p.py _augmented_matrix):
 *
 *     K = diag(M) + c_h H(lam) - cq dF/dq - cv dF/dq'
 *
 * H: constraints.py ConstraintSet.hessian (coincidence and line rows); dF: forces.py
 * AppliedForces.jacobians (forward differences, one coordinate at a time). Only the solve
 * differs from the banded path: the Newton iteration, its tests and the kept matrix's
 * validity are implicit.h's. The factors follow the banded layout in `kept`
 * (mbd_implicit_dense_kept_size): the LU ((n + m)^2, row-major) then its pivots.
 */

/* A matrix just factorised at the iterate: kept for step h, with E = e I and the
 * singularity indicator of its Psi_q (values v); both solvers' end. */
static int kept_valid(const Model *M, Scratch *s, double *kept, const double *v, double h,
                      double e) {
    kept[KEPT_VALID] = 1.0;
    kept[KEPT_H] = h;
    kept[KEPT_FRESH] = 1.0;
    kept[KEPT_E] = e;
    kept[KEPT_INDICATOR] = S_(M, m) ? indicator_of(M, s, v) : INFINITY;
    return ST_OK;
}

I mbd_implicit_dense_kept_size(const Model *M) {
    I size = S_(M, n) + S_(M, m);
    return mbd_implicit_kept_size(M) + size * size + size;
}

static double *dense_factors(const Model *M, const double *kept) {
    return (double *)kept + mbd_implicit_kept_size(M);
}

/* A[i][j] += c at (i, j) of K (row stride N) when both are moving bodies' coordinates. */
static inline void k_add(double *A, I N, I n, I i, I j, double c) {
    if (i < n && j < n) A[i * N + j] += c;
}

/* A's K block += c_h d(Psi_q^T lam)/dq at the iterate (qe, s->cs from evaluate()):
 * constraints.py hessian and _line_hessian, term for term. */
static void add_hessian(const Model *M, Scratch *s, const double *lam, double c_h, double *A,
                        I N) {
    I n = S_(M, n), nb = S_(M, nb);
    const double *cs = s->cs, *sn = s->cs + nb + 1, *qe = s->qe;
    for (I k = 0; k < S_(M, kc); k++) {
        I i = S_(M, c_bi)[k], j = S_(M, c_bj)[k];
        I r0 = S_(M, c_rows)[2 * k], r1 = S_(M, c_rows)[2 * k + 1];
        double aix, aiy, ajx, ajy;
        rotated(cs, sn, i, M->c_si[2 * k], M->c_si[2 * k + 1], &aix, &aiy);
        rotated(cs, sn, j, M->c_sj[2 * k], M->c_sj[2 * k + 1], &ajx, &ajy);
        k_add(A, N, n, 3 * i + 2, 3 * i + 2, -c_h * (aix * lam[r0] + aiy * lam[r1]));
        k_add(A, N, n, 3 * j + 2, 3 * j + 2, c_h * (ajx * lam[r0] + ajy * lam[r1]));
    }
    for (I k = 0; k < S_(M, kl); k++) {
        I i = S_(M, l_bi)[k], j = S_(M, l_bj)[k], pi = 3 * i + 2, pj = 3 * j + 2;
        double aix, aiy, ajx, ajy, ux, uy, m1 = c_h * lam[S_(M, l_rows)[k]] * M->l_w[k];
        rotated(cs, sn, i, M->l_si[2 * k], M->l_si[2 * k + 1], &aix, &aiy);
        rotated(cs, sn, j, M->l_sj[2 * k], M->l_sj[2 * k + 1], &ajx, &ajy);
        rotated(cs, sn, i, M->l_u[2 * k], M->l_u[2 * k + 1], &ux, &uy);
        double dx = qe[3 * j] + ajx - qe[3 * i] - aix, dy = qe[3 * j + 1] + ajy - qe[3 * i + 1] - aiy;
        double ru[2] = {-uy, ux}, uasj = ux * ajx + uy * ajy;
        for (I axis = 0; axis < 2; axis++) {
            I xi = 3 * i + axis, xj = 3 * j + axis;
            k_add(A, N, n, xi, pi, -m1 * ru[axis]);
            k_add(A, N, n, pi, xi, -m1 * ru[axis]);
            k_add(A, N, n, xj, pi, m1 * ru[axis]);
            k_add(A, N, n, pi, xj, m1 * ru[axis]);
        }
        k_add(A, N, n, pi, pi, -m1 * (ux * (dx + aix) + uy * (dy + aiy)));
        k_add(A, N, n, pi, pj, m1 * uasj);
        k_add(A, N, n, pj, pi, m1 * uasj);
        k_add(A, N, n, pj, pj, -m1 * uasj);
    }
}

/* A's K block -= cq dF/dq + cv dF/dq' by forward differences at (q, qd) (F0 there);
 * w: 2 n scratch. */
static int add_force_jacobians(const Model *M, const Implicit *p, const double *q,
                               const double *qd, const double *uf, const double *F0, double cq,
                               double cv, double *A, I N, double *w) {
    I n = S_(M, n);
    double *xp = w, *Fp = w + n;
    for (int which = 0; which < 2; which++) {
        const double *x = which ? qd : q;
        double c = which ? cv : cq;
        if (c == 0.0) continue;
        memcpy(xp, x, (size_t)n * sizeof(double));
        for (I k = 0; k < n; k++) {
            double delta = p->fd_step * fmax(1.0, fabs(x[k]));
            xp[k] = x[k] + delta;
            int st = which ? forces(M, q, xp, uf, Fp) : forces(M, xp, qd, uf, Fp);
            if (st != ST_OK) return st;
            xp[k] = x[k];
            for (I r = 0; r < n; r++) A[r * N + k] -= c * ((Fp[r] - F0[r]) / delta);
        }
    }
    return ST_OK;
}

/* LU with partial pivoting in place (A = P L U, row-major), piv[k]: the row swapped with
 * k; *pmin, *pmax: the smallest and largest |U_kk|. */
static void saddle_lu(double *A, I N, double *piv, double *pmin, double *pmax) {
    *pmin = INFINITY;
    *pmax = 0.0;
    for (I k = 0; k < N; k++) {
        I best = k;
        for (I i = k + 1; i < N; i++)
            if (fabs(A[i * N + k]) > fabs(A[best * N + k])) best = i;
        piv[k] = (double)best;
        if (best != k)
            for (I j = 0; j < N; j++) {
                double t = A[k * N + j];
                A[k * N + j] = A[best * N + j];
                A[best * N + j] = t;
            }
        double d = A[k * N + k];
        *pmin = fmin(*pmin, fabs(d));
        *pmax = fmax(*pmax, fabs(d));
        if (d == 0.0) continue;
        for (I i = k + 1; i < N; i++) {
            double l = A[i * N + k] / d;
            A[i * N + k] = l;
            if (l != 0.0)
                for (I j = k + 1; j < N; j++) A[i * N + j] -= l * A[k * N + j];
        }
    }
}

/* factor_matrix's dense case: the saddle matrix at the iterate into the kept LU (values:
 * Psi_q's, kept as in the banded layout for the increments' size and the indicator). */
static int saddle_factor(const Model *M, const Implicit *p, Scratch *s, double *kept,
                        const double *values, const double *lam, double c_h, double cq,
                        double cv, double e, double h, const double *q, const double *qd,
                        const double *uf, const double *F0, double *w) {
    I n = S_(M, n), m = S_(M, m), N = n + m;
    double *A = dense_factors(M, kept), *piv = A + N * N, pmin, pmax;
    double *v = kept + KEPT_HEAD + 3 * n;
    memset(A, 0, (size_t)(N * N) * sizeof(double));
    for (I k = 0; k < n; k++) A[k * N + k] = M->mass[k];
    if (c_h != 0.0) add_hessian(M, s, lam, c_h, A, N);
    if (p->fd) {
        int st = add_force_jacobians(M, p, q, qd, uf, F0, cq, cv, A, N, w);
        if (st != ST_OK) return st;
    }
    for (I k = 0; k < S_(M, nkeep); k++) {
        I r = n + S_(M, rows)[k], c = S_(M, cols)[k];
        A[r * N + c] += values[k];
        A[c * N + r] += values[k];
    }
    for (I r = n; r < N; r++) A[r * N + r] = -e;
    if (!all_finite_values(A, N * N)) return ST_NOT_FINITE;
    saddle_lu(A, N, piv, &pmin, &pmax);
    if (!(pmin > p->singular_pivot * pmax)) return ST_SINGULAR;
    memcpy(v, values, (size_t)S_(M, nkeep) * sizeof(double));
    return kept_valid(M, s, kept, v, h, e);
}

/* kept_solve's dense case: (x (n); y (m)) = LU^-1 (a; b), x and y apart in memory. */
#define DENSE_AT(k) (*((k) < n ? x + (k) : y + ((k) - n)))
static void saddle_solve(const Model *M, const double *kept, const double *a, const double *b,
                        double *x, double *y) {
    I n = S_(M, n), N = n + S_(M, m);
    const double *A = dense_factors(M, kept), *piv = A + N * N;
    memcpy(x, a, (size_t)n * sizeof(double));
    memcpy(y, b, (size_t)S_(M, m) * sizeof(double));
    for (I k = 0; k < N; k++) {
        I r = (I)piv[k];
        if (r != k) { double t = DENSE_AT(k); DENSE_AT(k) = DENSE_AT(r); DENSE_AT(r) = t; }
    }
    for (I i = 1; i < N; i++) {
        double sum = DENSE_AT(i);
        for (I j = 0; j < i; j++) sum -= A[i * N + j] * DENSE_AT(j);
        DENSE_AT(i) = sum;
    }
    for (I i = N - 1; i >= 0; i--) {
        double sum = DENSE_AT(i);
        for (I j = i + 1; j < N; j++) sum -= A[i * N + j] * DENSE_AT(j);
        DENSE_AT(i) = sum / A[i * N + i];
    }
}
#undef DENSE_AT
