/*
 * kernel.c: the C kernel of mbdfmu's equations (compiled by ckernel/build.py, called through
 * ctypes by ckernel/__init__.py). A line-by-line translation of the numpy code:
 *
 *   terms()          constraints.py ConstraintSet._values_numpy (joints.py's three row
 *                    primitives, rows summing weighted terms, formulation.md eqs. 5-7, 24)
 *   forces()         forces.py AppliedForces.__call__ (eq. 12; a spring's length by sqrt
 *                    where numpy takes hypot: the same to an ulp)
 *   schur_solve()    sparsity.py JacobianPattern.schur_solve's Cholesky branch (eq. 15),
 *                    the band factorised as L D L^T (solve.h): the same to round-off
 *   accelerations()  dynamics.py Equations.accelerations (eq. 14), with singular.py's
 *                    nullspace_accelerations where S is ill-conditioned (nullspace.h)
 *   project_*()      projection.py project_positions / project_velocities (eqs. 18-19)
 *   mbd_rk4p_steps   rk4p.py's step (rk4_step, _project, the next q'') for runs of steps,
 *                    with the energy audit's check (stepping.h total_energy)
 *   mbd_prk_trial    projected_rk.py ProjectedRK._step_impl's arithmetic: stages, error
 *                    norm, projections, the next q'' (the decisions stay in Python);
 *                    mbd_prk_trial_near also near singular configurations (stepping.h)
 *   mbd_prk_run      runs of those steps with _advance_adaptive's decisions (adaptive.h)
 *   mbd_outputs      dynamics.py Equations.output_values (reactions eqs. 16-17, 28)
 *   mbd_singularity_indicator  singular.py singularity_indicator
 *   mbd_dense_state  ProjectedRK._output_at: the projected dense output inside a step
 *   mbd_dense_step   an FMU's communication step that only reads it (dense.h)
 *   mbd_fixed_step   an FMU's communication step of rk4p with the drivers' motions (fixed.h)
 *   mbd_prk_fast_step  an FMU's communication step of an embedded pair after inputs were
 *                    set (mbd_prk_set), landing on the communication point (adaptive.h)
 *   mbd_dense_run_step  an FMU's communication step past the step it reads: the pair's
 *                    next steps and their interpolant (dense_run.h)
 *   mbd_implicit_*   genalpha.py / ali3p.py steps with newton.py's iteration on the
 *                    banded Schur complement (implicit.h), or a dense LU where K couples
 *                    bodies (implicit_dense.h); mbd_implicit_run: their controlled
 *                    steps up to an output time, the step control's decisions
 *                    included (implicit_run.h)
 *
 * Eq. (14) with an ill-conditioned Schur complement (next to a singular configuration,
 * redundant rows) is solved here in singular.py's null-space form (nullspace.h) for the
 * dense form of S, and the projections' and error estimates' singular solves take
 * sparsity.py's minimum-norm solutions (solve.h, Model.min_norm); a banded scene's
 * eq. (14) at a singular S returns ST_SINGULAR and the caller redoes the work on the numpy
 * path; a spring of zero length returns ST_SPRING and the numpy path raises its error.
 * Nothing allocates: scratch space is the caller's `work` (mbd_work_size doubles).
 */
#define _GNU_SOURCE      /* sincos */
#include <float.h>
#include <math.h>
#include <stdint.h>
#include <string.h>
#include <time.h>

typedef int64_t I;

enum { ST_OK = 0, ST_SINGULAR = 1, ST_PROJECTION = 2, ST_NOT_FINITE = 3, ST_SPRING = 4,
       ST_ENERGY = 5, ST_ERROR_NORM = 6 };
enum { F_POINT = 0, F_TORQUE = 1, F_SPRING = 2, F_TORSION = 3 };
/* slots of the energy check's running state (rk4p_compiled.AuditField) */
enum { A_ACTIVE, A_E0, A_V0, A_KINETIC_MAX, A_POTENTIAL_SWING, A_MAGNITUDE, A_CHECKS,
       A_WORST, A_LAST_ENERGY, A_RTOL, A_ATOL, A_FACTOR, A_TOLERANCE_JOULES, A_FIELDS };
#define MIN_SPRING_LENGTH 1e-12

typedef struct {
    I nb, n, m, nf;
    I kc; const I *c_rows, *c_bi, *c_bj; const double *c_si, *c_sj;
    I kl; const I *l_rows, *l_bi, *l_bj; const double *l_si, *l_sj, *l_u, *l_w;
    I ka; const I *a_rows, *a_bi, *a_bj; const double *a_w;
    I nconst; const double *constants;
    I nraw; const I *merge; I size; I nkeep; const I *keep, *rows, *cols;
    I npairs; const I *pair_a, *pair_b; const double *pair_minv; const I *band_index, *perm;
    I kd;
    const double *mass, *minv, *gravity;
    double rank_tol;
    const double *f_const; I nforce; const I *f_int; const double *f_real;
    /* outputs: reactions and the output plan */
    I nr; const I *joint_rows, *reaction_entries, *joint_bj, *frame_body, *reaction_joints;
    const double *frame_angle, *frame_point;
    I nj, nplan; const I *joint_plan; I ncoupler; const I *coupler_rows;
    I ndriver; const I *driver_rows;
    I banded, min_norm;   /* S in band storage (else dense); minimum-norm solves here */
    I psi_only;           /* positions projected until Psi alone is within tol (held rows) */
    I nslide; const I *s_int; const double *s_real;   /* sliding friction (friction.h) */
    double *slide_f;
    double *work;
    double *memo;   /* the last evaluation of eq. (14): its arguments and results (memo_size) */
} Model;

/* A scene's structure: its counts and index tables (the Model's integer fields). Built for
 * one scene (scene_kernel.py writes the header MBD_SCENE names), they are compile-time
 * constants, so the compiler unrolls the loops over them and folds the indexing, and S's
 * band factor is the header's straight-line code for its pattern (solve.h); else the
 * Model's fields. Everything else (masses, geometry, forces) is read from the Model in
 * both: a scene's parameters stay settable. */
#ifdef MBD_SCENE
#include MBD_SCENE
#define S_(M, f) ((void)(M), SC_##f)
#else
#define S_(M, f) ((M)->f)
#endif

/* ---- row primitives (joints.py) ------------------------------------------------------ */

/* cos and sin of x: glibc's sincos returns the same two doubles as its cos and sin, in one
 * call (the argument reduction done once) */
static inline void cos_sin(double x, double *c, double *s) {
#if defined(__GLIBC__)
    sincos(x, s, c);
#else
    *c = cos(x);
    *s = sin(x);
#endif
}

/* A_b (vx, vy) with body b's cos and sin (cs, sn: per body, the ground's last). */
static inline void rotated(const double *cs, const double *sn, I b, double vx, double vy,
                           double *x, double *y) {
    *x = cs[b] * vx - sn[b] * vy;
    *y = sn[b] * vx + cs[b] * vy;
}

/* psi (m) = terms - cval; raw (nraw) = the terms' Jacobian values (constants first, then
 * the coincidence and line blocks, constraints.py's layout); gamma (m) without c'' when
 * qde is given. qe, qde: (n + 3), the ground's three zeros last. */
static void terms(const Model *M, const double *qe, const double *qde, const double *cval,
                  double *psi, double *raw, double *gamma, double *cs) {
    I k0 = S_(M, nconst), kc = S_(M, kc), kl = S_(M, kl);
    double *sn = cs + S_(M, nb) + 1;  /* cos and sin of every body's angle, once (planar.poses) */
    for (I b = 0; b < S_(M, nb); b++) cos_sin(qe[3 * b + 2], cs + b, sn + b);
    cs[S_(M, nb)] = 1.0;                 /* the ground's angle is 0: cos and sin exact */
    sn[S_(M, nb)] = 0.0;
    memcpy(raw, M->constants, (size_t)k0 * sizeof(double));
    for (I r = 0; r < S_(M, m); r++) { psi[r] = 0.0; if (gamma) gamma[r] = 0.0; }
    for (I k = 0; k < kc; k++) {
        I i = S_(M, c_bi)[k], j = S_(M, c_bj)[k];
        I r0 = S_(M, c_rows)[2 * k], r1 = S_(M, c_rows)[2 * k + 1];
        double aix, aiy, ajx, ajy;
        rotated(cs, sn, i, M->c_si[2 * k], M->c_si[2 * k + 1], &aix, &aiy);
        rotated(cs, sn, j, M->c_sj[2 * k], M->c_sj[2 * k + 1], &ajx, &ajy);
        psi[r0] = qe[3 * i] + aix - qe[3 * j] - ajx;
        psi[r1] = qe[3 * i + 1] + aiy - qe[3 * j + 1] - ajy;
        raw[k0 + k] = -aiy;
        raw[k0 + kc + k] = aix;
        raw[k0 + 2 * kc + k] = ajy;
        raw[k0 + 3 * kc + k] = -ajx;
        if (gamma) {
            double wi2 = qde[3 * i + 2] * qde[3 * i + 2], wj2 = qde[3 * j + 2] * qde[3 * j + 2];
            gamma[r0] = aix * wi2 - ajx * wj2;
            gamma[r1] = aiy * wi2 - ajy * wj2;
        }
    }
    I k1 = k0 + 4 * kc;
    for (I k = 0; k < kl; k++) {
        I i = S_(M, l_bi)[k], j = S_(M, l_bj)[k], row = S_(M, l_rows)[k];
        double aix, aiy, ajx, ajy, ux, uy, w = M->l_w[k];
        rotated(cs, sn, i, M->l_si[2 * k], M->l_si[2 * k + 1], &aix, &aiy);
        rotated(cs, sn, j, M->l_sj[2 * k], M->l_sj[2 * k + 1], &ajx, &ajy);
        rotated(cs, sn, i, M->l_u[2 * k], M->l_u[2 * k + 1], &ux, &uy);
        double dx = qe[3 * j] + ajx - qe[3 * i] - aix, dy = qe[3 * j + 1] + ajy - qe[3 * i + 1] - aiy;
        double ud = ux * dx + uy * dy;
        psi[row] += w * ud;
        raw[k1 + k] = w * -ux;
        raw[k1 + kl + k] = w * -uy;
        raw[k1 + 2 * kl + k] = w * ((-uy * dx + ux * dy) - (-ux * aiy + uy * aix));
        raw[k1 + 3 * kl + k] = w * ux;
        raw[k1 + 4 * kl + k] = w * uy;
        raw[k1 + 5 * kl + k] = w * (-ux * ajy + uy * ajx);
        if (gamma) {
            double wi = qde[3 * i + 2], wj = qde[3 * j + 2];
            double ddx = qde[3 * j] - wj * ajy - qde[3 * i] + wi * aiy;
            double ddy = qde[3 * j + 1] + wj * ajx - qde[3 * i + 1] - wi * aix;
            double g = wi * wi * ud - 2.0 * wi * (-uy * ddx + ux * ddy)
                       + (ux * (ajx * wj * wj - aix * wi * wi) + uy * (ajy * wj * wj - aiy * wi * wi));
            gamma[row] += w * g;
        }
    }
    for (I k = 0; k < S_(M, ka); k++)
        psi[S_(M, a_rows)[k]] += M->a_w[k] * (qe[3 * S_(M, a_bj)[k] + 2]
                                              - qe[3 * S_(M, a_bi)[k] + 2]);
    for (I r = 0; r < S_(M, m); r++) psi[r] -= cval[r];
}

/* data (size): the terms merged (repeated entries summed, sparsity.JacobianPattern.merged);
 * values (nkeep): data's entries in moving bodies' columns. */
/* For one scene these three are the header's straight-line code (scene_kernel.py): the same
 * sums in the same order, each result summed in a register, not stored and read back per
 * term through the index tables. */
static void merged(const Model *M, const double *raw, double *data, double *values) {
#ifdef MBD_SCENE
    (void)M;
    sc_merged(raw, data, values);
#else
    if (S_(M, size) == S_(M, nraw)) memcpy(data, raw, (size_t)S_(M, nraw) * sizeof(double));
    else {
        memset(data, 0, (size_t)S_(M, size) * sizeof(double));
        for (I k = 0; k < S_(M, nraw); k++) data[S_(M, merge)[k]] += raw[k];
    }
    for (I k = 0; k < S_(M, nkeep); k++) values[k] = data[S_(M, keep)[k]];
#endif
}

static void jac_mul(const Model *M, const double *values, const double *x, double *out) {
#ifdef MBD_SCENE
    (void)M;
    sc_jac_mul(values, x, out);
#else
    memset(out, 0, (size_t)S_(M, m) * sizeof(double));
    for (I k = 0; k < S_(M, nkeep); k++) out[S_(M, rows)[k]] += values[k] * x[S_(M, cols)[k]];
#endif
}

static void jac_t_mul(const Model *M, const double *values, const double *y, double *out) {
#ifdef MBD_SCENE
    (void)M;
    sc_jac_t_mul(values, y, out);
#else
    memset(out, 0, (size_t)S_(M, n) * sizeof(double));
    for (I k = 0; k < S_(M, nkeep); k++) out[S_(M, cols)[k]] += values[k] * y[S_(M, rows)[k]];
#endif
}

static int all_finite_values(const double *x, I k) {
    for (I i = 0; i < k; i++) if (!isfinite(x[i])) return 0;
    return 1;
}

#include "solve.h"
#include "nullspace.h"

/* ---- applied forces (forces.py) --------------------------------------------------------- */

/* cs: NULL, or the cos and sin of every body's angle at q (terms()'s), taken instead of
 * computing them again (the same libm calls on the same angles: the same doubles) */
static inline void body_point(const Model *M, const double *q, const double *cs, I b,
                              double px, double py, double *x, double *y, double *ax, double *ay) {
    if (b >= S_(M, nb)) { *x = 0.0; *y = 0.0; *ax = px; *ay = py; return; }
    double c = cs ? cs[b] : cos(q[3 * b + 2]), s = cs ? cs[S_(M, nb) + 1 + b] : sin(q[3 * b + 2]);
    *x = q[3 * b]; *y = q[3 * b + 1];
    *ax = c * px - s * py;
    *ay = s * px + c * py;
}

/* Length, rate, unit vector and arms of spring item k (AppliedForces.spring_geometry). */
static int spring_geometry(const Model *M, I k, const double *q, const double *qd,
                           const double *cs, double g[8]) {
    const I *fi = S_(M, f_int) + 4 * k;
    const double *fr = M->f_real + 8 * k;
    I bi = fi[1], bj = fi[2], nb = S_(M, nb);
    double xi, yi, aix, aiy, xj, yj, ajx, ajy;
    body_point(M, q, cs, bi, fr[0], fr[1], &xi, &yi, &aix, &aiy);
    body_point(M, q, cs, bj, fr[2], fr[3], &xj, &yj, &ajx, &ajy);
    /* sqrt, not hypot: glibc's hypot guards against overflow a length in metres never
     * reaches, at several times the cost; the two differ by an ulp at most */
    double dx = xj + ajx - xi - aix, dy = yj + ajy - yi - aiy, length = sqrt(dx * dx + dy * dy);
    if (length < MIN_SPRING_LENGTH) return ST_SPRING;
    double ux = dx / length, uy = dy / length, z[3] = {0.0, 0.0, 0.0};
    const double *vi = bi < nb ? qd + 3 * bi : z, *vj = bj < nb ? qd + 3 * bj : z;
    double vx = vj[0] - vj[2] * ajy - vi[0] + vi[2] * aiy;
    double vy = vj[1] + vj[2] * ajx - vi[1] - vi[2] * aix;
    g[0] = length; g[1] = ux * vx + uy * vy; g[2] = ux; g[3] = uy;
    g[4] = aix; g[5] = aiy; g[6] = ajx; g[7] = ajy;
    return ST_OK;
}

static double spring_tension(const Model *M, I k, double length, double rate, const double *uf) {
    const double *fr = M->f_real + 8 * k;
    double tension = fr[4] * (length - fr[6]) + fr[5] * rate;
    if (S_(M, f_int)[4 * k + 3] >= 0) tension -= uf[S_(M, f_int)[4 * k + 3]];
    return tension;
}

/* F (n) at (q, qd) with the force inputs uf; cs as body_point's. */
static int forces_cs(const Model *M, const double *q, const double *qd, const double *uf,
                     const double *cs, double *F) {
    I nb = S_(M, nb);
    memcpy(F, M->f_const, (size_t)S_(M, n) * sizeof(double));
    for (I k = 0; k < S_(M, nforce); k++) {
        const I *fi = S_(M, f_int) + 4 * k;
        const double *fr = M->f_real + 8 * k;
        if (fi[0] == F_POINT) {
            I b = fi[1];
            double fx = fi[3] >= 0 ? uf[fi[3]] : fr[2], fy = fi[3] >= 0 ? uf[fi[3] + 1] : fr[3];
            double x, y, ax, ay;
            body_point(M, q, cs, b, fr[0], fr[1], &x, &y, &ax, &ay);
            F[3 * b] += fx; F[3 * b + 1] += fy; F[3 * b + 2] += ax * fy - ay * fx;
        } else if (fi[0] == F_TORQUE) {
            F[3 * fi[1] + 2] += uf[fi[3]];
        } else if (fi[0] == F_SPRING) {
            double g[8];
            if (spring_geometry(M, k, q, qd, cs, g) != ST_OK) return ST_SPRING;
            double tension = spring_tension(M, k, g[0], g[1], uf);
            double fx = -tension * g[2], fy = -tension * g[3];
            I bi = fi[1], bj = fi[2];
            if (bj < nb) { F[3 * bj] += fx; F[3 * bj + 1] += fy; F[3 * bj + 2] += g[6] * fy - g[7] * fx; }
            if (bi < nb) { F[3 * bi] -= fx; F[3 * bi + 1] -= fy; F[3 * bi + 2] -= g[4] * fy - g[5] * fx; }
        } else {
            I bi = fi[1], bj = fi[2];
            double phi_i = bi < nb ? q[3 * bi + 2] : 0.0, w_i = bi < nb ? qd[3 * bi + 2] : 0.0;
            double phi_j = bj < nb ? q[3 * bj + 2] : 0.0, w_j = bj < nb ? qd[3 * bj + 2] : 0.0;
            double torque = -fr[0] * (phi_j - phi_i - fr[2]) - fr[1] * (w_j - w_i);
            if (bj < nb) F[3 * bj + 2] += torque;
            if (bi < nb) F[3 * bi + 2] -= torque;
        }
    }
    return ST_OK;
}

static int forces(const Model *M, const double *q, const double *qd, const double *uf, double *F) {
    return forces_cs(M, q, qd, uf, NULL, F);
}

/* ---- scratch space ----------------------------------------------------------------------- */

/* scratch of schur_solve: two dense m x m or two bands */
static I solve_size(const Model *M) {
    I band = (S_(M, kd) + 1) * S_(M, m);
    return 2 * (S_(M, banded) ? band : (S_(M, m) * S_(M, m) > band ? S_(M, m) * S_(M, m) : band));
}

typedef struct {
    double *qe, *qde, *psi, *raw, *data, *values, *gamma, *rhs, *lam, *x, *band, *tmp, *F,
           *Fm, *nv, *cs, *svd, *qv;
    int kept;     /* band holds the factor of S at the projected state (project_velocities) */
} Scratch;

static Scratch scratch(const Model *M, double *w) {
    Scratch s;
    I n = S_(M, n), m = S_(M, m);
    s.qe = w; w += n + 3;
    s.qde = w; w += n + 3;
    s.psi = w; w += m;
    s.raw = w; w += S_(M, nraw);
    s.data = w; w += S_(M, size) + 1;
    s.values = w; w += S_(M, nkeep);
    s.gamma = w; w += m;
    s.rhs = w; w += m;
    s.lam = w; w += m;
    s.x = w; w += m;
    s.band = w; w += solve_size(M);
    s.tmp = w; w += 3 * m;
    s.F = w; w += n;
    s.Fm = w; w += n;
    s.nv = w; w += n;
    s.cs = w; w += 2 * (S_(M, nb) + 1);
    s.svd = w; w += nullspace_size(M);
    s.qv = w;
    s.kept = 0;
    return s;
}

/* doubles of scratch space the kernel needs, with room for the steppers' stages */
I mbd_work_size(const Model *M, I stages) {
    I n = S_(M, n), m = S_(M, m);
    return 2 * (n + 3) + 9 * m + S_(M, nraw) + S_(M, size) + 1 + S_(M, nkeep) + solve_size(M)
           + 4 * n
           + 2 * (S_(M, nb) + 1) + nullspace_size(M) + 16 + (stages + 4) * 2 * n + 14 * n + 3 * m;
}

static void extend(const Model *M, const double *q, double *qe) {
    memcpy(qe, q, (size_t)S_(M, n) * sizeof(double));
    qe[S_(M, n)] = qe[S_(M, n) + 1] = qe[S_(M, n) + 2] = 0.0;
}

/* Psi and Psi_q's values (s->psi; s->data, s->values) at q, the rows' motions cval: what a
 * projection, the singularity indicator or a reaction reads, without q' and gamma. */
static void jacobian_at(const Model *M, Scratch *s, const double *q, const double *cval) {
    extend(M, q, s->qe);
    terms(M, s->qe, NULL, cval, s->psi, s->raw, NULL, s->cs);
    merged(M, s->raw, s->data, s->values);
}

/* ---- eq. (14) ------------------------------------------------------------------------------ */

#include "friction.h"

/* again: S's factor is in s->band already (s->kept after a projection to this q). */
/* eq. (14)'s solve with the forces in s->F and Psi_q's values, gamma and the band factor of
 * S = Psi_q M^-1 Psi_q^T given (none of them depends on the forces): q'' and lam. */
static int solve_with_factor(const Model *M, Scratch *s, const double *values,
                             const double *gamma, const double *band, const double *cdd,
                             double *qdd, double *lam) {
    I n = S_(M, n), m = S_(M, m);
    for (I k = 0; k < n; k++) s->Fm[k] = M->minv[k] * s->F[k];
    jac_mul(M, values, s->Fm, s->rhs);
    for (I r = 0; r < m; r++) s->rhs[r] -= gamma[r] + cdd[r];
    schur_again(M, s->rhs, lam, band, s->tmp);
    jac_t_mul(M, values, lam, s->nv);
    for (I k = 0; k < n; k++) qdd[k] = M->minv[k] * (s->F[k] - s->nv[k]);
    return ST_OK;
}

static int accelerations_at(const Model *M, Scratch *s, const double *q, const double *qd,
                            const double *cval, const double *cdd, const double *uf,
                            double *qdd, double *lam, int again) {
    I n = S_(M, n), m = S_(M, m);
    if (m == 0) {
        int st = forces(M, q, qd, uf, s->F);
        if (st != ST_OK) return st;
        for (I k = 0; k < n; k++) qdd[k] = M->minv[k] * s->F[k];
        return ST_OK;
    }
    extend(M, q, s->qe);
    extend(M, qd, s->qde);
    terms(M, s->qe, s->qde, cval, s->psi, s->raw, s->gamma, s->cs);
    merged(M, s->raw, s->data, s->values);
    int st = forces_cs(M, q, qd, uf, s->cs, s->F);      /* with the angles' trig of terms() */
    if (st != ST_OK) return st;
    if (S_(M, nslide)) return sliding_accelerations(M, s, q, cdd, qdd, lam);
    if (again) return solve_with_factor(M, s, s->values, s->gamma, s->band, cdd, qdd, lam);
    return solve_eq14(M, s, s->F, cdd, qdd, lam);
}

/* Eq. (14) for the applied forces F, with s holding Psi_q's values and gamma at (q, q'). */
static int solve_eq14(const Model *M, Scratch *s, const double *F, const double *cdd,
                      double *qdd, double *lam) {
    I n = S_(M, n), m = S_(M, m);
    for (I k = 0; k < n; k++) s->Fm[k] = M->minv[k] * F[k];
    jac_mul(M, s->values, s->Fm, s->rhs);
    for (I r = 0; r < m; r++) s->rhs[r] -= s->gamma[r] + cdd[r];
    int kept;
    int st = schur_solve_mode(M, s->values, s->rhs, lam, s->band, s->tmp, &kept, 0);
    if (st == ST_SINGULAR) {       /* S ill-conditioned: the null-space form (nullspace.h) */
        for (I r = 0; r < m; r++) s->x[r] = s->gamma[r] + cdd[r];
        return nullspace_accelerations(M, s->values, F, s->x, qdd, lam, s->svd);
    }
    if (st != ST_OK) return st;
    jac_t_mul(M, s->values, lam, s->nv);
    for (I k = 0; k < n; k++) qdd[k] = M->minv[k] * (F[k] - s->nv[k]);
    return ST_OK;
}

static int accelerations(const Model *M, Scratch *s, const double *q, const double *qd,
                         const double *cval, const double *cdd, const double *uf,
                         double *qdd, double *lam) {
    return accelerations_at(M, s, q, qd, cval, cdd, uf, qdd, lam, 0);
}

/* ---- the last evaluation, kept: outputs read the q'' and lam of the step's end --------------- */

I mbd_memo_size(const Model *M) { return 1 + 3 * S_(M, n) + 3 * S_(M, m) + S_(M, nf) + S_(M, m); }

static void memo_store(const Model *M, const double *q, const double *qd, const double *cval,
                       const double *cdd, const double *uf, const double *qdd, const double *lam) {
    I n = S_(M, n), m = S_(M, m);
    double *p = M->memo + 1;
    memcpy(p, q, (size_t)n * sizeof(double)); p += n;
    memcpy(p, qd, (size_t)n * sizeof(double)); p += n;
    memcpy(p, cval, (size_t)m * sizeof(double)); p += m;
    memcpy(p, cdd, (size_t)m * sizeof(double)); p += m;
    memcpy(p, uf, (size_t)S_(M, nf) * sizeof(double)); p += S_(M, nf);
    memcpy(p, qdd, (size_t)n * sizeof(double)); p += n;
    memcpy(p, lam, (size_t)m * sizeof(double));
    M->memo[0] = 1.0;
}

/* 1 when (q, qd, c, c'', uf) are bit for bit those of the kept evaluation. */
static int memo_hit(const Model *M, const double *q, const double *qd, const double *cval,
                    const double *cdd, const double *uf) {
    I n = S_(M, n), m = S_(M, m);
    const double *p = M->memo + 1;
    if (M->memo[0] == 0.0) return 0;
    if (memcmp(p, q, (size_t)n * sizeof(double))) return 0;
    p += n;
    if (memcmp(p, qd, (size_t)n * sizeof(double))) return 0;
    p += n;
    if (memcmp(p, cval, (size_t)m * sizeof(double))) return 0;
    p += m;
    if (memcmp(p, cdd, (size_t)m * sizeof(double))) return 0;
    p += m;
    return memcmp(p, uf, (size_t)S_(M, nf) * sizeof(double)) == 0;
}

/* q'' (n) and lam (m) of eq. (14); the kept results when the arguments are the same. */
int mbd_accelerations(const Model *M, const double *q, const double *qd, const double *cval,
                      const double *cdd, const double *uf, double *qdd, double *lam) {
    I n = S_(M, n), m = S_(M, m);
    if (memo_hit(M, q, qd, cval, cdd, uf)) {
        const double *p = M->memo + 1 + 2 * n + 2 * m + S_(M, nf);
        memcpy(qdd, p, (size_t)n * sizeof(double));
        memcpy(lam, p + n, (size_t)m * sizeof(double));
        return ST_OK;
    }
    Scratch s = scratch(M, M->work);
    int st = accelerations(M, &s, q, qd, cval, cdd, uf, qdd, lam);
    if (st == ST_OK) memo_store(M, q, qd, cval, cdd, uf, qdd, lam);
    return st;
}

int mbd_forces(const Model *M, const double *q, const double *qd, const double *uf, double *F) {
    return forces(M, q, qd, uf, F);
}

/* Psi (m), data (size: Psi_q's merged values, ground columns included) and, with qd,
 * gamma (m) without c''. */
void mbd_constraints(const Model *M, const double *q, const double *qd, const double *cval,
                     double *psi, double *data, double *gamma) {
    Scratch s = scratch(M, M->work);
    extend(M, q, s.qe);
    if (qd) extend(M, qd, s.qde);
    terms(M, s.qe, qd ? s.qde : NULL, cval, psi, s.raw, qd ? gamma : NULL, s.cs);
    merged(M, s.raw, data, s.values);
}

/* ---- projections (eqs. 18-19) ------------------------------------------------------------------ */

/* `at_q`: s->psi and s->values hold Psi and Psi_q at q already (a trial's end, whose
 * evaluation left them): the first iteration reads them instead of evaluating again. */
static int project_positions(const Model *M, Scratch *s, double *q, const double *cval,
                             double tol, I max_iter, int at_q) {
    I n = S_(M, n), m = S_(M, m);
    double increment = INFINITY;
    for (I it = 0; it <= max_iter; it++) {
        if (it > 0 || !at_q) jacobian_at(M, s, q, cval);
        double err = 0.0;
        for (I r = 0; r < m; r++) {
            if (!isfinite(s->psi[r])) return ST_NOT_FINITE;
            if (fabs(s->psi[r]) > err) err = fabs(s->psi[r]);
        }
        /* converged in q, not only in Psi (projection.project_positions): near a singular
         * configuration |Psi| <= tol alone leaves q off by up to tol / sigma; what does not
         * get there goes back to the numpy path (ST_PROJECTION). A scene with stops or
         * friction stops on Psi alone: the extra increment would move what its events hold */
        if (err <= tol && (increment <= tol || S_(M, psi_only))) return ST_OK;
        if (it == max_iter) break;
        int st = schur_solve(M, s->values, s->psi, s->x, s->band, s->tmp);
        if (st != ST_OK) return st;
        jac_t_mul(M, s->values, s->x, s->nv);
        increment = 0.0;
        for (I k = 0; k < n; k++) {
            double dq = M->minv[k] * s->nv[k];
            q[k] -= dq;
            if (fabs(dq) > increment) increment = fabs(dq);
        }
    }
    return ST_PROJECTION;
}

/* q' onto Psi_q q' = nu at q (whose Jacobian values are in s->values). */
static int project_velocities(const Model *M, Scratch *s, double *qd, const double *cd) {
    I n = S_(M, n), m = S_(M, m);
    jac_mul(M, s->values, qd, s->rhs);
    for (I r = 0; r < m; r++) s->rhs[r] -= cd[r];
    int st = schur_solve_keeping(M, s->values, s->rhs, s->x, s->band, s->tmp, &s->kept);
    if (st != ST_OK) return st;
    jac_t_mul(M, s->values, s->x, s->nv);
    for (I k = 0; k < n; k++) qd[k] -= M->minv[k] * s->nv[k];
    return ST_OK;
}

/* Both projections at motion (c, c', c'') = motion[0..2m): q, qd in place; `at_q` as
 * project_positions'. */
static int project_at(const Model *M, Scratch *s, double *q, double *qd, const double *motion,
                      double tol, I max_iter, int at_q) {
    s->kept = 0;
    if (S_(M, m) == 0) return ST_OK;
    int st = project_positions(M, s, q, motion, tol, max_iter, at_q);
    return st != ST_OK ? st : project_velocities(M, s, qd, motion + S_(M, m));
}

static int project(const Model *M, Scratch *s, double *q, double *qd, const double *motion,
                   double tol, I max_iter) {
    return project_at(M, s, q, qd, motion, tol, max_iter, 0);
}

int mbd_project_positions(const Model *M, double *q, const double *cval, double tol, I max_iter) {
    Scratch s = scratch(M, M->work);
    return project_positions(M, &s, q, cval, tol, max_iter, 0);
}

int mbd_project_velocities(const Model *M, const double *q, double *qd, const double *cval,
                           const double *cd) {
    Scratch s = scratch(M, M->work);
    if (S_(M, m) == 0) return ST_OK;
    jacobian_at(M, &s, q, cval);
    return project_velocities(M, &s, qd, cd);
}

/* singular.py singularity_indicator: the smallest over the largest pivot of the Cholesky
 * factor of Psi_q D Psi_q^T, D scaling Psi_q's columns to unit norm; in band storage in
 * the band's order when S_(M, banded), else dense in the rows' order (as numpy factorises
 * each); 0 where the factorisation fails. */
static double indicator_of(const Model *M, Scratch *s, const double *values) {
    I n = S_(M, n), m = S_(M, m), kd = S_(M, kd);
    double *scale = s->nv, dmin = INFINITY, dmax = 0.0;
    for (I k = 0; k < n; k++) scale[k] = 0.0;
    for (I k = 0; k < S_(M, nkeep); k++) scale[S_(M, cols)[k]] += values[k] * values[k];
    for (I k = 0; k < n; k++) scale[k] = 1.0 / (scale[k] > 0.0 ? scale[k] : 1.0);
    int ok = 1;
    if (S_(M, banded)) {
        I size = (kd + 1) * m;
        double *L = s->band;
        memset(L, 0, (size_t)size * sizeof(double));
        for (I p = 0; p < S_(M, npairs); p++)
            L[S_(M, band_index)[p]] += values[S_(M, pair_a)[p]] * values[S_(M, pair_b)[p]]
                                   * scale[S_(M, cols)[S_(M, pair_a)[p]]];
        ok = band_cholesky(L, m, kd, &dmin, &dmax);
    } else {
        double *U = s->band;
        memset(U, 0, (size_t)(m * m) * sizeof(double));
        for (I p = 0; p < S_(M, npairs); p++) {
            I ra = S_(M, rows)[S_(M, pair_a)[p]], rb = S_(M, rows)[S_(M, pair_b)[p]];
            double w = values[S_(M, pair_a)[p]] * values[S_(M, pair_b)[p]]
                       * scale[S_(M, cols)[S_(M, pair_a)[p]]];
            U[ra * m + rb] += w;
            if (ra != rb) U[rb * m + ra] += w;
        }
        ok = dense_cholesky(U, m, &dmin, &dmax);
    }
    return ok && isfinite(dmin) && isfinite(dmax) && dmax > 0.0 ? dmin / dmax : 0.0;
}

int mbd_singularity_indicator(const Model *M, const double *q, const double *cval,
                              double *out) {
    Scratch s = scratch(M, M->work);
    if (S_(M, m) == 0) { *out = INFINITY; return ST_OK; }
    jacobian_at(M, &s, q, cval);
    *out = indicator_of(M, &s, s.values);
    return ST_OK;
}

/* A run's start at (q, q'), motion: (c, c', c''): q'' and lam of eq. (14) as
 * mbd_accelerations, then the singularity indicator at q as mbd_singularity_indicator
 * (ProjectedRK.restart's two evaluations in one call). */
int mbd_start(const Model *M, const double *q, const double *qd, const double *motion,
              const double *uf, double *qdd, double *lam, double *indicator) {
    int st = mbd_accelerations(M, q, qd, motion, motion + 2 * S_(M, m), uf, qdd, lam);
    return st != ST_OK ? st : mbd_singularity_indicator(M, q, motion, indicator);
}

/* The dense minimum-norm solve (pivoted_min_norm) of S x = b on its own, S (m x m,
 * 0 < m < BANDED_MIN_ROWS) copied: the tests hold it to LAPACK's pseudo-inverse on
 * matrices of chosen rank and conditioning. 0 for a size out of range or a failed solve. */
int mbd_min_norm_solve(I m, const double *S, const double *b, double *x, double rank_tol) {
    if (m <= 0 || m >= 60) return 0;
    double A[m * m], T[m * m];
    memcpy(A, S, (size_t)(m * m) * sizeof(double));
    return pivoted_min_norm(rank_tol, A, m, b, x, T);
}

#include "stepping.h"
#include "outputs.h"
#include "motions.h"
#include "dense.h"
#include "events.h"
#include "fixed.h"
#include "adaptive.h"
#include "dense_run.h"
#include "implicit.h"
#include "implicit_run.h"

/* 1 when M's structure is the one this library was built for (scene_kernel.py: the kernel
 * of one scene; a Model of another, a contact mode's, takes the generic library), always 1
 * for the generic library. */
I mbd_structure_check(const Model *M) {
#ifdef MBD_SCENE
    return sc_structure_is(M);
#else
    (void)M;
    return 1;
#endif
}
