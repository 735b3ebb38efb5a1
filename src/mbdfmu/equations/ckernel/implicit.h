/*
 * implicit.h (part of kernel.c): steps of the implicit index-3 methods genalpha and ali3p
 * (integrators/genalpha.py, ali3p.py) with their Newton iteration (integrators/newton.py),
 * line for line, on the sparse structure of the index-1 methods instead of a dense LU.
 *
 * The iteration matrix [[K, Psi_q^T], [Psi_q, -E]] (E = 0 for genalpha, I / P for ali3p)
 * is solved through its Schur complement S = Psi_q K^-1 Psi_q^T + E in band storage (the
 * pattern of J M^-1 J^T, solve.h), which needs K diagonal: no line rows (their geometric
 * stiffness couples coordinates) and applied forces that do not depend on the state (or
 * genalpha's jacobian "mass"); other mechanisms solve the whole matrix by a dense LU
 * (implicit_dense.h, Implicit.dense). The caller checks that (integrators/implicit_c.py). K's
 * diagonal must be positive and S's Cholesky pivots not below the singular-pivot ratio:
 * otherwise ST_SINGULAR and the attempt is redone on the numpy path (a dense LU), which then
 * does what it always does there.
 *
 * The kept iteration matrix (newton.IterationMatrix: kept across iterations and steps while
 * Newton contracts fast enough) lives in the caller's array `kept` (mbd_implicit_kept_size):
 * valid, h, fresh, indicator, E, then K^-1 (n), Psi_q's values (nkeep) and S's band factor.
 */

enum { IMP_GENALPHA = 0, IMP_ALI3P = 1 };
/* Why a Newton iteration failed (the caller halves the step and names it) */
enum { NF_NONE = 0, NF_RESIDUAL = 1, NF_MATRIX = 2, NF_INCREMENT = 3, NF_DIVERGES = 4,
       NF_ITERATIONS = 5 };
#define ST_NEWTON 7
enum { KEPT_VALID, KEPT_H, KEPT_FRESH, KEPT_INDICATOR, KEPT_E, KEPT_HEAD };

/* One method's settings and newton.py's constants (ckernel.Implicit, filled once) and the
 * counters of the last call. */
typedef struct {
    I method, jacobian_full, count_multipliers, max_iter;
    double am, af, beta, gamma;        /* genalpha's coefficients */
    double penalty_base, alpha;        /* ali3p: P = penalty_base, or alpha h^2 / 4 if alpha > 0 */
    double atol, length_scale;
    double roundoff, atol_max, tol_floor, t_ref, noise_max, near_indicator, near_floor, t_near;
    double slow_rate, diverging_rate, singular_pivot;
    double dense_below;                /* a matrix's indicator below this: the numpy path */
    double h_fine;
    const double *periodic;            /* 1.0 on the wrapped angles (n) */
    /* blocks: K has 3 x 3 blocks per body (forces of the state, each on one moving body),
     * by forward differences of fd_step as forces.py; Psi_q K^-1 Psi_q^T assembled from
     * the pairs of Psi_q's entries in one body's columns (bp_a, bp_b; bp_band: the band
     * position of their rows; bp_w: 9 b + 3 c_a + c_b) with K^-1's symmetric part */
    I blocks, nbp;
    double fd_step;
    const I *bp_a, *bp_b, *bp_band, *bp_w;
    I nnewton, njev, nlu, nprojections, reason;   /* counters and the last failure's reason */
    double last_size, last_residual, last_tol;   /* for the failure's message */
    /* dense: the whole matrix by a dense LU (implicit_dense.h), with fd: K's force terms */
    I dense, fd;
} Implicit;

I mbd_implicit_kept_size(const Model *M) {
    return KEPT_HEAD + 3 * S_(M, n) + S_(M, nkeep) + (S_(M, kd) + 1) * S_(M, m);
}

/* ---- the convergence test (newton.py: newton_tolerances, _converged, _increment_converged,
 * _check_rate, IterationMatrix.noise); kept together so it follows newton.py ------------- */

typedef struct { double tol, residual, stagnation, near_singular, near_residual, size; int at_rounding; } Tolerances;

static Tolerances newton_tolerances(const Implicit *p, double h, const double *q, double D,
                                    const double *acc, I n) {
    Tolerances t;
    double atol = fmin(p->atol, p->atol_max), qmax = 0.0, amax = 1.0;   /* numpy's initial= */
    for (I k = 0; k < n; k++) { qmax = fmax(qmax, fabs(q[k])); amax = fmax(amax, fabs(acc[k])); }
    t.size = fmax(p->length_scale, qmax);
    t.stagnation = fmax(0.5 * h * atol, p->tol_floor * p->length_scale);
    t.tol = fmin(0.5 * atol * (h / p->t_ref) * (h / p->t_ref), 0.01 * p->roundoff * t.size);
    double fine = fmin(1.0, h / p->h_fine);
    fine *= fine;
    t.residual = D * fmax(atol / (p->t_ref * p->t_ref) * fine, p->roundoff * amax);
    t.near_singular = fmax(t.stagnation * fmin(1.0, h / p->t_near), p->roundoff * t.size);
    t.near_residual = fmax(0.5 * h * atol * fmin(1.0, h / p->t_near) * fine, t.residual);
    t.at_rounding = t.near_singular > t.stagnation * fmin(1.0, h / p->t_near);
    return t;
}

static int near_singular(const Implicit *p, const double *kept) {
    double fine = fmin(1.0, kept[KEPT_H] / p->h_fine);     /* newton.py: near_singular */
    return kept[KEPT_INDICATOR] < fmax(p->near_indicator * fine * fine, p->near_floor);
}

/* Before an increment: Psi within the tolerance, and the last increment or the dynamic
 * residual (as a displacement) too; near a singular configuration the looser one. */
static int newton_converged(const Implicit *p, const Tolerances *t, const double *kept,
                            double size, double residual, double psi) {
    double tol = t->tol, residual_tol = t->residual;
    int near = near_singular(p, kept);
    if (near) { tol = t->near_singular; residual_tol = t->near_residual; }
    if (psi > tol) return 0;
    if (residual <= residual_tol) return 1;
    return size <= tol && !(near && t->at_rounding);
}

/* IterationMatrix.noise: the rounding noise of the kept matrix's increments */
static double matrix_noise(const Implicit *p, const Tolerances *t, const double *kept) {
    double noise = p->roundoff * t->size / fmax(kept[KEPT_INDICATOR] * kept[KEPT_INDICATOR], 1e-300);
    return fmax(t->stagnation, fmin(noise, p->noise_max * p->length_scale));
}

/* After an increment of max-norm size (previous < 0: the first): CONV_ESTIMATE, CONV_NOISE
 * (increments of the noise's size that stop shrinking with a fresh matrix) or 0. */
enum { CONV_ESTIMATE = 1, CONV_NOISE = 2 };
static int increment_converged(const Implicit *p, const Tolerances *t, const double *kept,
                               double size, double previous) {
    double tol = near_singular(p, kept) ? t->near_singular : t->tol;
    if (previous < 0.0) return size <= 0.1 * tol ? CONV_ESTIMATE : 0;
    double theta = previous > 0.0 ? size / previous : 0.0;
    if (kept[KEPT_FRESH] != 0.0 && size <= matrix_noise(p, t, kept) && p->slow_rate < theta && theta <= p->diverging_rate)
        return CONV_NOISE;
    return theta < 1.0 && theta / (1.0 - theta) * size <= tol ? CONV_ESTIMATE : 0;
}

/* Watch the contraction: drop a kept matrix that converges slowly (returns -1: restart the
 * rate), fail (NF_DIVERGES in *reason) when a fresh one diverges (not increments of the
 * rounding noise). Returns the new previous. */
static double check_rate(const Implicit *p, const Tolerances *t, double *kept, double size,
                         double previous, I *reason) {
    if (previous >= 0.0 && size > p->slow_rate * previous) {
        if (kept[KEPT_FRESH] == 0.0) { kept[KEPT_VALID] = 0.0; return -1.0; }
        double noise = matrix_noise(p, t, kept);
        if (size > p->diverging_rate * previous && size > noise) *reason = NF_DIVERGES;
    }
    return size;
}

/* ---- the iteration matrix ----------------------------------------------------------------- */

/* K's 3 x 3 blocks (forces of the state on one moving body each): diag(M) + c_h H -
 * cq dF/dq - cv dF/dq', dF by forward differences (forces.py AppliedForces.jacobians, one
 * evaluation per coordinate of a body for all bodies at once), inverted into W; its
 * symmetric part where the Schur complement needs it (m > 0). F0: F at (q, qd). */
static int block_inverses(const Model *M, const Implicit *p, const double *q, const double *qd,
                          const double *uf, const double *F0, const double *hdiag, double cq,
                          double cv, double *W, double *w) {
    I n = S_(M, n), nb = S_(M, nb);
    double *xp = w, *Fp = w + n, *jac = w + 2 * n;       /* jac: dF/dq then dF/dq' (9 nb each) */
    for (int which = 0; which < 2; which++) {
        const double *x = which ? qd : q;
        for (int c = 0; c < 3; c++) {
            memcpy(xp, x, (size_t)n * sizeof(double));
            for (I b = 0; b < nb; b++) xp[3 * b + c] += p->fd_step * fmax(1.0, fabs(x[3 * b + c]));
            int st = which ? forces(M, q, xp, uf, Fp) : forces(M, xp, qd, uf, Fp);
            if (st != ST_OK) return st;
            for (I b = 0; b < nb; b++) {
                double delta = p->fd_step * fmax(1.0, fabs(x[3 * b + c]));
                for (int r = 0; r < 3; r++)
                    jac[which * 9 * nb + 9 * b + 3 * r + c] = (Fp[3 * b + r] - F0[3 * b + r]) / delta;
            }
        }
    }
    for (I b = 0; b < nb; b++) {
        double K[9], *Wb = W + 9 * b;
        for (int k = 0; k < 9; k++) K[k] = -cq * jac[9 * b + k] - cv * jac[9 * nb + 9 * b + k];
        for (int r = 0; r < 3; r++) K[4 * r] += M->mass[3 * b + r] + hdiag[3 * b + r];
        double c0 = K[4] * K[8] - K[5] * K[7], c1 = K[5] * K[6] - K[3] * K[8],
               c2 = K[3] * K[7] - K[4] * K[6], det = K[0] * c0 + K[1] * c1 + K[2] * c2;
        if (!isfinite(det)) return ST_NOT_FINITE;
        if (det == 0.0) return ST_SINGULAR;
        Wb[0] = c0 / det; Wb[1] = (K[2] * K[7] - K[1] * K[8]) / det; Wb[2] = (K[1] * K[5] - K[2] * K[4]) / det;
        Wb[3] = c1 / det; Wb[4] = (K[0] * K[8] - K[2] * K[6]) / det; Wb[5] = (K[2] * K[3] - K[0] * K[5]) / det;
        Wb[6] = c2 / det; Wb[7] = (K[1] * K[6] - K[0] * K[7]) / det; Wb[8] = (K[0] * K[4] - K[1] * K[3]) / det;
        if (S_(M, m)) {
            for (int r = 0; r < 3; r++)
                for (int c = r + 1; c < 3; c++) Wb[3 * r + c] = Wb[3 * c + r] = 0.5 * (Wb[3 * r + c] + Wb[3 * c + r]);
        }
    }
    return ST_OK;
}

/* out = K^-1 a (diagonal, or W's blocks). */
static void k_inverse(const Model *M, const Implicit *p, const double *kinv, const double *a,
                      double *out) {
    if (!p->blocks) {
        for (I k = 0; k < S_(M, n); k++) out[k] = kinv[k] * a[k];
        return;
    }
    for (I b = 0; b < S_(M, nb); b++) {
        const double *Wb = kinv + 9 * b, *ab = a + 3 * b;
        for (int r = 0; r < 3; r++) out[3 * b + r] = Wb[3 * r] * ab[0] + Wb[3 * r + 1] * ab[1] + Wb[3 * r + 2] * ab[2];
    }
}

#include "implicit_dense.h"

/* Factorise at the current iterate: K = M + c_h H(lam) (its diagonal: coincidence rows'
 * d2/dphi2; c_h = D for genalpha "full", h^2/4 for ali3p, 0 for "mass"), with blocks minus
 * cq dF/dq + cv dF/dq'; S = J K^-1 J^T + E in band storage. values: Psi_q's at the iterate
 * (q, qd), lam the iterate's multipliers, F0 the forces there; w: 2 n + 6 n scratch. */
static int factor_matrix(const Model *M, const Implicit *p, Scratch *s, double *kept,
                         const double *values, const double *lam, double c_h, double cq,
                         double cv, double e, double h, const double *q, const double *qd,
                         const double *uf, const double *F0, double *w) {
    if (p->dense) return saddle_factor(M, p, s, kept, values, lam, c_h, cq, cv, e, h, q, qd, uf, F0, w);
    I n = S_(M, n), m = S_(M, m), nb = S_(M, nb);
    double *kinv = kept + KEPT_HEAD, *v = kinv + 3 * n, *L = v + S_(M, nkeep), dmin, dmax;
    double *hdiag = p->blocks ? w : kinv;
    for (I k = 0; k < n; k++) hdiag[k] = p->blocks ? 0.0 : M->mass[k];
    if (c_h != 0.0) {
        for (I k = 0; k < S_(M, kc); k++) {
            I i = S_(M, c_bi)[k], j = S_(M, c_bj)[k];
            I r0 = S_(M, c_rows)[2 * k], r1 = S_(M, c_rows)[2 * k + 1];
            double aix, aiy, ajx, ajy;
            rotated(s->cs, s->cs + nb + 1, i, M->c_si[2 * k], M->c_si[2 * k + 1], &aix, &aiy);
            rotated(s->cs, s->cs + nb + 1, j, M->c_sj[2 * k], M->c_sj[2 * k + 1], &ajx, &ajy);
            if (i < nb) hdiag[3 * i + 2] -= c_h * (aix * lam[r0] + aiy * lam[r1]);
            if (j < nb) hdiag[3 * j + 2] += c_h * (ajx * lam[r0] + ajy * lam[r1]);
        }
    }
    if (p->blocks) {
        int st = block_inverses(M, p, q, qd, uf, F0, hdiag, cq, cv, kinv, w + n);
        if (st != ST_OK) return st;
    } else {
        for (I k = 0; k < n; k++) {
            if (!isfinite(kinv[k])) return ST_NOT_FINITE;
            if (!(kinv[k] > 0.0)) return ST_SINGULAR;
            kinv[k] = 1.0 / kinv[k];
        }
    }
    memcpy(v, values, (size_t)S_(M, nkeep) * sizeof(double));
    I size = (S_(M, kd) + 1) * m;
    memset(L, 0, (size_t)size * sizeof(double));
    if (p->blocks)
        for (I k = 0; k < p->nbp; k++)
            L[p->bp_band[k]] += v[p->bp_a[k]] * v[p->bp_b[k]] * kinv[p->bp_w[k]];
    else
        for (I k = 0; k < S_(M, npairs); k++)
            L[S_(M, band_index)[k]] += v[S_(M, pair_a)[k]] * v[S_(M, pair_b)[k]]
                                       * kinv[S_(M, cols)[S_(M, pair_a)[k]]];
    for (I j = 0; j < m; j++) L[j] += e;
    if (!all_finite_values(L, size)) return ST_NOT_FINITE;
    if (m && (!band_cholesky(L, m, S_(M, kd), &dmin, &dmax)
              || !(dmin * dmin > p->singular_pivot * dmax * dmax)))
        return ST_SINGULAR;
    return kept_valid(M, s, kept, v, h, e);
}

/* [[K, J^T], [J, -E]] (x; y) = (a; b) with the kept factors: x (n), y (m); tm (m) and
 * tn (n) scratch. */
static void kept_solve(const Model *M, const Implicit *p, const double *kept, const double *a,
                       const double *b, double *x, double *y, double *tm, double *tn) {
    if (p->dense) { saddle_solve(M, kept, a, b, x, y); return; }
    I n = S_(M, n), m = S_(M, m);
    const double *kinv = kept + KEPT_HEAD, *v = kinv + 3 * n, *L = v + S_(M, nkeep);
    k_inverse(M, p, kinv, a, x);
    if (m == 0) return;
    jac_mul(M, v, x, y);                     /* (J K^-1 J^T + E) y = J K^-1 a - b */
    for (I i = 0; i < m; i++) tm[i] = y[S_(M, perm)[i]] - b[S_(M, perm)[i]];
    band_substitute(L, m, S_(M, kd), tm);
    for (I i = 0; i < m; i++) y[S_(M, perm)[i]] = tm[i];
    jac_t_mul(M, v, y, tn);                  /* x = K^-1 (a - J^T y) */
    for (I k = 0; k < n; k++) tn[k] = a[k] - tn[k];
    k_inverse(M, p, kinv, tn, x);
}

/* The kept matrix's solve for the step control's error filter: out (n + m) = S^-1 rhs. */
int mbd_implicit_solve(const Model *M, const Implicit *p, const double *kept,
                       const double *rhs, double *out) {
    Scratch s = scratch(M, M->work);
    if (kept[KEPT_VALID] == 0.0) return ST_SINGULAR;
    kept_solve(M, p, kept, rhs, rhs + S_(M, n), out, out + S_(M, n), s.qv, s.qv + S_(M, m));
    return ST_OK;
}

/* ---- one attempt ---------------------------------------------------------------------------- */

/* State y = (q wrapped, turns, q', q'', a, lam) (5n + m); an attempt's x = (dq, q', q'', a,
 * lam) (4n + m). */
enum { Y_Q, Y_TURNS, Y_QD, Y_QDD, Y_A, Y_LAM };
enum { X_DQ, X_QD, X_QDD, X_A, X_LAM };

/* Psi, Psi_q's values and F at q = qn + dq (with q' = qd); cos and sin in s->cs. */
static int evaluate(const Model *M, Scratch *s, const double *qn, const double *dq,
                    const double *qd, const double *motion, const double *uf, double *qc) {
    for (I k = 0; k < S_(M, n); k++) qc[k] = qn[k] + dq[k];
    jacobian_at(M, s, qc, motion);
    return forces(M, qc, qd, uf, s->F);
}

/* The trapezoidal rule's q' and q'' for the correction c of the increment (ali3p.py
 * rates), and the increment dq = its Taylor predictor + c. */
static void rates(I n, double h, const double *c, const double *vn, const double *an,
                  double *dq, double *qd, double *qdd) {
    for (I k = 0; k < n; k++) {
        dq[k] = h * vn[k] + 0.5 * h * h * an[k] + c[k];
        qd[k] = vn[k] + h * an[k] + (2.0 / h) * c[k];
        qdd[k] = an[k] + (4.0 / (h * h)) * c[k];
    }
}

/* ali3p's mass-orthogonal projections of q' and q'' at q (ali3p.py _attempt's end). */
static int ali3p_projections(const Model *M, Scratch *s, const double *q, double *qd,
                             double *qdd, const double *motion, double *g) {
    I m = S_(M, m);
    if (m == 0) return ST_OK;
    extend(M, q, s->qe);
    extend(M, qd, s->qde);
    terms(M, s->qe, s->qde, motion, s->psi, s->raw, s->gamma, s->cs);
    merged(M, s->raw, s->data, s->values);
    int st = project_velocities(M, s, qd, motion + m);
    if (st != ST_OK) return st;
    extend(M, qd, s->qde);
    terms(M, s->qe, s->qde, motion, s->psi, s->raw, s->gamma, s->cs);
    for (I r = 0; r < m; r++) g[r] = s->gamma[r] + motion[2 * m + r];
    return project_velocities(M, s, qdd, g);
}

/* One step from y over h (genalpha.py / ali3p.py _attempt, newton.py newton_iterate), not
 * taken: x filled. ST_OK; ST_NEWTON (p->reason: the caller halves the step); ST_SINGULAR
 * or ST_SPRING: the numpy path redoes the attempt. w: scratch of 13 n + 3 m. */
static int attempt(const Model *M, Implicit *p, Scratch *s, double *kept, const double *y,
                   double h, const double *motion, const double *uf, double *x, double *w) {
    I n = S_(M, n), m = S_(M, m);
    const double *qn = y, *vn = y + Y_QD * n, *qddn = y + Y_QDD * n, *an = y + Y_A * n;
    const double *lamn = y + Y_A * n + n;
    double *dq = x, *qd = x + X_QD * n, *qdd = x + X_QDD * n, *anew = x + X_A * n;
    double *lam = x + X_A * n + n;
    double *dyn = w, *dx = w + n, *tn = dx + n, *qc = tn + n, *tn2 = qc + n;
    double *dl = tn2 + n, *bm = dl + m, *tm = bm + m;
    int ga = p->method == IMP_GENALPHA;
    double am = p->am, af = p->af, beta = p->beta, gamma = p->gamma, D, G = 0.0, c_h, e = 0.0;
    double cq = 0.0, cv = 0.0;     /* K's force terms: - cq dF/dq - cv dF/dq' */
    Tolerances t;
    memcpy(lam, lamn, (size_t)m * sizeof(double));
    if (ga) {
        D = h * h * beta * (1.0 - af) / (1.0 - am);
        G = h * gamma * (1.0 - af) / (1.0 - am);
        c_h = p->jacobian_full ? D : 0.0;
        if (p->jacobian_full) { cq = D; cv = G; }
        for (I k = 0; k < n; k++) {        /* predictor: Newmark with q''_{n+1} = q''_n */
            double a = (af * qddn[k] - am * an[k] + (1.0 - af) * qddn[k]) / (1.0 - am);
            dq[k] = h * vn[k] + h * h * ((0.5 - beta) * an[k] + beta * a);
            qd[k] = vn[k] + h * ((1.0 - gamma) * an[k] + gamma * a);
            qdd[k] = qddn[k];
        }
        t = newton_tolerances(p, h, qn, D, qddn, n);
    } else {
        double alpha = p->alpha > 0.0 ? p->alpha : 4.0 * p->penalty_base / (h * h);
        D = c_h = cq = 0.25 * h * h;
        cv = 0.5 * h;
        e = 1.0 / (0.25 * h * h * alpha);
        memset(anew, 0, (size_t)n * sizeof(double));     /* c: the correction (rates) */
        t = newton_tolerances(p, h, qn, D, an, n);
    }
    if (!(kept[KEPT_VALID] != 0.0 && kept[KEPT_H] == h)) kept[KEPT_VALID] = 0.0;
    kept[KEPT_FRESH] = 0.0;
    double previous = -1.0, size = INFINITY, psi = 0.0, last = -1.0;
    int done = 0, unchecked = 0;   /* increments converged, the residual not yet seen */
    p->reason = NF_NONE;
    for (I it = 0; it < p->max_iter && !done; it++) {
        p->nnewton++;
        if (!ga) rates(n, h, anew, vn, an, dq, qd, qdd);
        int st = evaluate(M, s, qn, dq, qd, motion, uf, qc);
        if (st != ST_OK) return st;
        jac_t_mul(M, s->values, lam, tn);
        double residual = 0.0;
        for (I k = 0; k < n; k++) {
            dyn[k] = D * (M->mass[k] * qdd[k] + tn[k] - s->F[k]);
            if (!isfinite(dyn[k])) { p->reason = NF_RESIDUAL; return ST_NEWTON; }
            residual = fmax(residual, fabs(dyn[k] / M->mass[k]));
        }
        psi = 0.0;
        for (I r = 0; r < m; r++) psi = fmax(psi, fabs(s->psi[r]));
        if (newton_converged(p, &t, kept, size, residual, psi)) { done = 1; break; }
        if (unchecked) {            /* newton.py: _dynamics_hold */
            double rtol = unchecked == CONV_NOISE ? fmax(t.near_residual, t.near_singular) : t.residual;
            if (residual <= rtol) { done = 1; break; }
            if (last >= 0.0 && residual > p->slow_rate * last) kept[KEPT_VALID] = 0.0;
            last = residual;
        }
        if (kept[KEPT_VALID] == 0.0) {
            p->njev++;
            p->nlu++;
            st = factor_matrix(M, p, s, kept, s->values, lam, c_h, cq, cv, e, h, qc, qd, uf,
                               s->F, tm + m);
            if (st == ST_NOT_FINITE) { p->reason = NF_MATRIX; return ST_NEWTON; }
            if (st != ST_OK) return st;
            /* next to a singular configuration genalpha's Schur complement (ali3p's has
             * its penalty's E) squares the condition number, and its solve's noise
             * became velocity errors: the dense LU there */
            if (e == 0.0 && !p->dense && kept[KEPT_INDICATOR] < p->dense_below) {
                kept[KEPT_VALID] = 0.0;
                return ST_SINGULAR;
            }
        }
        for (I k = 0; k < n; k++) tn[k] = -dyn[k];
        for (I r = 0; r < m; r++) bm[r] = -s->psi[r];
        kept_solve(M, p, kept, tn, bm, dx, dl, tm, tn2);
        size = 0.0;
        for (I k = 0; k < n; k++) size = fmax(size, fabs(dx[k]));
        if (p->count_multipliers && m) {     /* IterationMatrix.increment_size */
            jac_t_mul(M, kept + KEPT_HEAD + 3 * n, dl, tn2);
            for (I k = 0; k < n; k++) size = fmax(size, fabs(tn2[k] / M->mass[k]));
        }
        if (!isfinite(size)) { p->reason = NF_INCREMENT; return ST_NEWTON; }
        if (ga) {
            for (I k = 0; k < n; k++) {
                dq[k] += dx[k];
                qd[k] += (G / D) * dx[k];
                qdd[k] += dx[k] / D;
            }
            for (I r = 0; r < m; r++) lam[r] += dl[r] / D;
        } else {
            for (I k = 0; k < n; k++) anew[k] += dx[k];
            for (I r = 0; r < m; r++) lam[r] += (4.0 / (h * h)) * dl[r];
        }
        if (unchecked) {
            if (kept[KEPT_FRESH] != 0.0 && unchecked == CONV_ESTIMATE) { done = 1; break; }
            continue;
        }
        unchecked = increment_converged(p, &t, kept, size, previous);
        if (unchecked == CONV_ESTIMATE && kept[KEPT_FRESH] != 0.0) { done = 1; break; }
        previous = check_rate(p, &t, kept, size, previous, &p->reason);
        if (p->reason != NF_NONE) return ST_NEWTON;
    }
    if (!done && !(size <= t.stagnation && psi <= t.stagnation) &&
        !(kept[KEPT_FRESH] != 0.0 && near_singular(p, kept) && psi <= t.near_singular &&
          size <= matrix_noise(p, &t, kept) && t.at_rounding)) {
        p->reason = NF_ITERATIONS;
        p->last_size = size;
        p->last_residual = psi;
        p->last_tol = t.tol;
        return ST_NEWTON;
    }
    if (ga) {
        for (I k = 0; k < n; k++) anew[k] = (af * qddn[k] - am * an[k] + (1.0 - af) * qdd[k]) / (1.0 - am);
        return ST_OK;
    }
    rates(n, h, anew, vn, an, dq, qd, qdd);
    for (I k = 0; k < n; k++) qc[k] = qn[k] + dq[k];
    int st = ali3p_projections(M, s, qc, qd, qdd, motion, bm);
    memcpy(anew, qdd, (size_t)n * sizeof(double));
    return st;
}

/* Work for attempt(): its w and the kept solve's scratch. */
static double *attempt_work(const Model *M, Scratch *s) { (void)M; return s->qv; }

/* One attempt (the step control's, or a fixed step's in Python): x (4n + m). */
int mbd_implicit_attempt(const Model *M, Implicit *p, double *kept, const double *y, double h,
                         const double *motion, const double *uf, double *x) {
    Scratch s = scratch(M, M->work);
    return attempt(M, p, &s, kept, y, h, motion, uf, x, attempt_work(M, &s));
}

/* ---- runs of fixed steps -------------------------------------------------------------------- */

static int all_finite_n(const double *a, I k) { return all_finite_values(a, k); }

/* Take the attempt x into y (genalpha.py / ali3p.py _commit, newton.ImplicitMethod
 * _set_positions): genalpha's q' projected onto Psi_q q' = nu; angles wrapped again.
 * q (n): the unwrapped positions, for the energy check. */
static int commit(const Model *M, Implicit *p, Scratch *s, double *y, double *x,
                  const double *motion, double *q) {
    I n = S_(M, n), m = S_(M, m);
    double *qw = y, *turns = y + Y_TURNS * n;
    for (I k = 0; k < n; k++) q[k] = qw[k] + x[k];
    if (p->method == IMP_GENALPHA && m) {
        jacobian_at(M, s, q, motion);
        int st = project_velocities(M, s, x + X_QD * n, motion + m);
        if (st != ST_OK) return st;
    }
    if (!all_finite_n(q, n) || !all_finite_n(x + X_QD * n, 2 * n)) return ST_NOT_FINITE;
    p->nprojections++;
    memcpy(y + Y_QD * n, x + X_QD * n, (size_t)(3 * n + m) * sizeof(double));
    for (I k = 0; k < n; k++) {
        double turn = p->periodic[k] != 0.0 ? floor((q[k] + M_PI) / (2.0 * M_PI)) : 0.0;
        qw[k] = q[k] - 2.0 * M_PI * turn;
        turns[k] += turn;
        q[k] = qw[k] + 2.0 * M_PI * turns[k];
    }
    return ST_OK;
}

/* Fixed steps over h from y: step k ends where motions[k] (3m) and ufs[k * uf_stride] hold.
 * The energy check after each step when audit[A_ACTIVE] (total_energy). *done:
 * steps taken. ST_NEWTON, ST_SINGULAR, ST_SPRING, ST_NOT_FINITE: at step *done, nothing of
 * it kept (the caller redoes it in Python: halving, or its error); ST_ENERGY: after it. */
int mbd_implicit_steps(const Model *M, Implicit *p, double *kept, double *y, double h,
                       I nsteps, const double *motions, const double *ufs, I uf_stride,
                       double *audit, double divergence_fraction, double roundoff, double *x,
                       I *done) {
    Scratch s = scratch(M, M->work);
    I n = S_(M, n), m = S_(M, m);
    double *w = attempt_work(M, &s), *q = w + 14 * n + 3 * m;
    *done = 0;
    for (I k = 0; k < nsteps; k++) {
        const double *motion = motions + 3 * m * k, *uf = ufs + uf_stride * k;
        int st = attempt(M, p, &s, kept, y, h, motion, uf, x, w);
        if (st == ST_OK) st = commit(M, p, &s, y, x, motion, q);
        if (st != ST_OK) return st;
        *done = k + 1;
        if (audit[A_ACTIVE] != 0.0 && !energy_check(M, q, y + Y_QD * n, audit, divergence_fraction, roundoff))
            return ST_ENERGY;
    }
    return ST_OK;
}
