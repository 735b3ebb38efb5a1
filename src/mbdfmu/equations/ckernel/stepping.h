/*
 * stepping.h (part of kernel.c): whole steps of the projected explicit methods.
 *
 * y = (q, q') (2n); the right-hand side is (q', q''(t, q, q')) with q'' from eq. (14).
 * `motion` arrays hold c, c', c'' of every row (3 m) and `uf` the force inputs (nf) at each
 * time a step evaluates; the caller computes them from its input signals.
 */

/* y' = (q', q'') at y with the inputs of one instant. */
static int rhs(const Model *M, Scratch *s, const double *y, const double *motion,
               const double *uf, double *f, double *lam) {
    I n = S_(M, n), m = S_(M, m);
    memcpy(f, y + n, (size_t)n * sizeof(double));
    return accelerations(M, s, y, y + n, motion, motion + 2 * m, uf, f + n, lam);
}

/* numpy's add.reduce of x (k contiguous doubles) to the last bit: its pairwise sum, eight
 * partial sums up to 128 terms, two halves (a multiple of 8 first) beyond. */
static double numpy_sum(const double *x, I k) {
    if (k < 8) {
        double r = 0.0;
        for (I i = 0; i < k; i++) r += x[i];
        return r;
    }
    if (k > 128) {
        I half = k / 2;
        half -= half % 8;
        return numpy_sum(x, half) + numpy_sum(x + half, k - half);
    }
    double r[8];
    I i;
    for (int j = 0; j < 8; j++) r[j] = x[j];
    for (i = 8; i < k - k % 8; i += 8)
        for (int j = 0; j < 8; j++) r[j] += x[i + j];
    double sum = ((r[0] + r[1]) + (r[2] + r[3])) + ((r[4] + r[5]) + (r[6] + r[7]));
    for (; i < k; i++) sum += x[i];
    return sum;
}

/* starting_step._rms of x / scale (k doubles; w: k scratch). */
static double rms_scaled(const double *x, const double *scale, I k, double *w) {
    for (I i = 0; i < k; i++) {
        double v = x[i] / scale[i];
        w[i] = v * v;
    }
    return sqrt(numpy_sum(w, k) / (double)k);
}

/* starting_step.initial_step (Hairer, Norsett and Wanner, Solving ODEs I, II.4) from y (2n)
 * with y' = f, the inputs held at (motion, uf): the same doubles, its one evaluation
 * (at y + h0 f) in C. *h the step; an evaluation's ST_* otherwise (the numpy path's case).
 * local: the step control's factor on rtol and atol (ProjectedRK.local_tolerance). */
int mbd_initial_step(const Model *M, const double *y, const double *f, const double *motion,
                     const double *uf, double local, double rtol, double atol, double max_step,
                     I order, double *h) {
    Scratch s = scratch(M, M->work);
    I n2 = 2 * S_(M, n);
    double *scale = s.qv, *w = scale + n2, *y1 = w + n2, *f1 = y1 + n2;
    for (I k = 0; k < n2; k++) scale[k] = local * (atol + rtol * fabs(y[k]));
    double d0 = rms_scaled(y, scale, n2, w), d1 = rms_scaled(f, scale, n2, w);
    double h0 = d0 < 1e-5 || d1 < 1e-5 ? 1e-6 : 0.01 * d0 / d1;
    if (max_step < h0) h0 = max_step;               /* Python's min: h0 unless max_step < h0 */
    for (I k = 0; k < n2; k++) y1[k] = y[k] + h0 * f[k];
    int st = rhs(M, &s, y1, motion, uf, f1, s.lam);
    if (st != ST_OK) return st;
    for (I k = 0; k < n2; k++) y1[k] = f1[k] - f[k];
    double d2 = rms_scaled(y1, scale, n2, w) / h0, top = d2 > d1 ? d2 : d1;
    double h1 = d1 <= 1e-15 && d2 <= 1e-15 ? (h0 * 1e-3 > 1e-6 ? h0 * 1e-3 : 1e-6)
                                           : pow(0.01 / top, 1.0 / (double)(order + 1));
    double best = 100.0 * h0;
    if (h1 < best) best = h1;
    if (max_step < best) best = max_step;
    *h = best;
    return ST_OK;
}

/* rhs at the state project() just left (same q: S's factor kept from the velocity
 * projection, not computed again). */
static int rhs_projected(const Model *M, Scratch *s, const double *y, const double *motion,
                         const double *uf, double *f, double *lam) {
    I n = S_(M, n), m = S_(M, m);
    memcpy(f, y + n, (size_t)n * sizeof(double));
    return accelerations_at(M, s, y, y + n, motion, motion + 2 * m, uf, f + n, lam, s->kept);
}

/* out (n2) = sum_j c[j] K[j] over j < terms (K: rows of n2), each entry summed in j's
 * order as a loop over j inside would, but with the loop over the entries inside, so the
 * compiler vectorises it (the same additions in the same order: the same doubles). */
static void weighted_sum(const double *restrict K, I n2, const double *restrict c, I terms,
                         double *restrict out) {
    for (I k = 0; k < n2; k++) out[k] = 0.0;
    for (I j = 0; j < terms; j++) {
        const double *Kj = K + j * n2, cj = c[j];
        for (I k = 0; k < n2; k++) out[k] += Kj[k] * cj;
    }
}

/* out (n2) = y + h sum_j c[j] K[j] over j < terms: a stage's state. */
static void combine(const double *y, double h, const double *K, I n2, const double *c,
                    I terms, double *out) {
    weighted_sum(K, n2, c, terms, out);
    for (I k = 0; k < n2; k++) out[k] = y[k] + h * out[k];
}

#define NEAR_ZONE_C 0.1          /* singular_zone.NEAR_ZONE */

static int all_finite(const double *x, I k) {
    for (I i = 0; i < k; i++) if (!isfinite(x[i])) return 0;
    return 1;
}

/* One classic RK4 step with projection (rk4p.py RK4P._step_impl): y (2n) and f = y'(t)
 * in place. motions: (3, 3 m) at t, t + h/2, t + h; ufs: (3, nf) likewise. */
static int rk4p_step(const Model *M, Scratch *s, double *y, double *f, double h,
                     const double *motions, const double *ufs, double tol, I max_iter,
                     double *K, double *ys) {
    static const double A[4][3] = {{0, 0, 0}, {0.5, 0, 0}, {0.0, 0.5, 0}, {0.0, 0.0, 1.0}};
    static const double B[4] = {1.0 / 6.0, 2.0 / 6.0, 2.0 / 6.0, 1.0 / 6.0};
    static const int ROW[4] = {0, 1, 1, 2};
    I n2 = 2 * S_(M, n), m = S_(M, m), nf = S_(M, nf);
    memcpy(K, f, (size_t)n2 * sizeof(double));
    for (int st = 1; st < 4; st++) {
        combine(y, h, K, n2, A[st], st, ys);
        int r = rhs(M, s, ys, motions + ROW[st] * 3 * m, ufs + ROW[st] * nf, K + st * n2, s->lam);
        if (r != ST_OK) return r;
    }
    combine(y, h, K, n2, B, 4, ys);
    if (!all_finite(ys, n2)) return ST_NOT_FINITE;
    int r = project(M, s, ys, ys + S_(M, n), motions + 6 * m, tol, max_iter);
    if (r != ST_OK) return r;
    r = rhs_projected(M, s, ys, motions + 6 * m, ufs + 2 * nf, K, s->lam);
    if (r != ST_OK) return r;
    if (!all_finite(K + S_(M, n), S_(M, n))) return ST_NOT_FINITE;
    memo_store(M, ys, ys + S_(M, n), motions + 6 * m, motions + 8 * m, ufs + 2 * nf, K + S_(M, n),
               s->lam);
    memcpy(y, ys, (size_t)n2 * sizeof(double));
    memcpy(f, K, (size_t)n2 * sizeof(double));
    return ST_OK;
}

/* e plus the potentials of the springs, 1/2 k (l - l0)^2, and rotational springs,
 * 1/2 k (phi_j - phi_i - phi0)^2, added one by one (AppliedForces.potential_energy's, a
 * length by hypot as there). */
static double spring_potentials(const Model *M, const double *q, double e) {
    for (I k = 0; k < S_(M, nforce); k++) {
        const I *fi = S_(M, f_int) + 4 * k;
        const double *fr = M->f_real + 8 * k;
        if (fi[0] == F_SPRING) {
            double xi, yi, aix, aiy, xj, yj, ajx, ajy;
            body_point(M, q, NULL, fi[1], fr[0], fr[1], &xi, &yi, &aix, &aiy);
            body_point(M, q, NULL, fi[2], fr[2], fr[3], &xj, &yj, &ajx, &ajy);
            double stretch = hypot(xj + ajx - xi - aix, yj + ajy - yi - aiy) - fr[6];
            e += 0.5 * fr[4] * stretch * stretch;
        } else if (fi[0] == F_TORSION) {
            double pi = fi[1] < S_(M, nb) ? q[3 * fi[1] + 2] : 0.0;
            double pj = fi[2] < S_(M, nb) ? q[3 * fi[2] + 2] : 0.0;
            double d = pj - pi - fr[2];
            e += 0.5 * fr[0] * d * d;
        }
    }
    return e;
}

/* Equations.total_energy of a conservative scene (forces.py potential_energy and
 * load_potential): 1/2 q'M q' (*kinetic), the potential -F.q of the constant forces
 * (gravity, constant torques, constant forces at a centre of mass), the springs'
 * (spring_potentials) and -F.(r + A s) of each constant force off a centre. A scene of
 * constant forces only: 1/2 q'M q' - F.q, rk4p_compiled._energy_check's arithmetic. */
static double total_energy(const Model *M, const double *q, const double *qd, double *kinetic) {
    double kin = 0.0, fq = 0.0;
    for (I k = 0; k < S_(M, n); k++) {
        kin += M->mass[k] * qd[k] * qd[k];
        fq += M->f_const[k] * q[k];
    }
    kin *= 0.5;
    *kinetic = kin;
    if (!S_(M, nforce)) return kin - fq;
    double energy = spring_potentials(M, q, kin - fq);
    for (I k = 0; k < S_(M, nforce); k++) {
        const I *fi = S_(M, f_int) + 4 * k;
        const double *fr = M->f_real + 8 * k;
        if (fi[0] == F_POINT && fi[3] < 0) {
            double x, y, ax, ay;
            body_point(M, q, NULL, fi[1], fr[0], fr[1], &x, &y, &ax, &ay);
            energy -= fr[2] * (x + ax) + fr[3] * (y + ay);
        }
    }
    return energy;
}

/* EnergyAudit.joules: sum |F| (atol + rtol |q|) + |M q'| (atol + rtol |q'|), F the applied
 * forces at (q, q') (the constant ones alone when there are no others; a conservative
 * scene has no inputs). */
static double audit_joules(const Model *M, const double *q, const double *qd, double rtol,
                           double atol) {
    I n = S_(M, n);
    double F[S_(M, nforce) ? n : 1], none[1] = {0.0}, joules = 0.0;
    const double *f = M->f_const;
    if (S_(M, nforce) && forces(M, q, qd, none, F) == ST_OK) f = F;
    for (I k = 0; k < n; k++)
        joules += fabs(f[k]) * (atol + rtol * fabs(q[k]))
                  + fabs(M->mass[k] * qd[k]) * (atol + rtol * fabs(qd[k]));
    return joules;
}

/* rk4p_compiled._energy_check (EnergyAudit.check) on total_energy. */
static int energy_check(const Model *M, const double *q, const double *qd, double *audit,
                        double divergence_fraction, double roundoff) {
    double kinetic;
    double energy = total_energy(M, q, qd, &kinetic);
    audit[A_KINETIC_MAX] = fmax(audit[A_KINETIC_MAX], kinetic);
    audit[A_POTENTIAL_SWING] = fmax(audit[A_POTENTIAL_SWING], fabs(energy - kinetic - audit[A_V0]));
    audit[A_MAGNITUDE] = fmax(fmax(audit[A_MAGNITUDE], fabs(energy)), kinetic);
    audit[A_LAST_ENERGY] = energy;
    audit[A_CHECKS] += 1.0;
    double error = fabs(energy - audit[A_E0]);
    if (error <= roundoff * audit[A_MAGNITUDE] * audit[A_CHECKS]) return 1;
    double allowance = divergence_fraction * fmax(audit[A_KINETIC_MAX], audit[A_POTENTIAL_SWING]);
    if (audit[A_FACTOR] != 0.0) {     /* a stated accuracy (EnergyAudit.check's budget) */
        double joules = audit_joules(M, q, qd, audit[A_RTOL], audit[A_ATOL]);
        audit[A_TOLERANCE_JOULES] = fmax(audit[A_TOLERANCE_JOULES], joules);
        allowance = fmin(audit[A_FACTOR] * audit[A_TOLERANCE_JOULES], allowance);
    }
    double ratio = allowance > 0.0 ? error / allowance : INFINITY;
    audit[A_WORST] = fmax(audit[A_WORST], ratio);
    return ratio <= 1.0;
}

/* Steps of rk4p: y (2n), f in place; step k uses motions[k] (3, 3m) and ufs[k] (3, nf)
 * (strides 0: the same for every step). The energy check after each step when
 * audit[A_ACTIVE] (total_energy). *done: steps taken. ST_SINGULAR, ST_PROJECTION,
 * ST_SPRING: at step *done, nothing of it kept; ST_ENERGY, ST_NOT_FINITE: after it. */
int mbd_rk4p_steps(const Model *M, double *y, double *f, double h, I nsteps,
                   const double *motions, I motion_stride, const double *ufs, I uf_stride,
                   double tol, I max_iter, double *audit, double divergence_fraction,
                   double roundoff, I *done) {
    Scratch s = scratch(M, M->work);
    I n2 = 2 * S_(M, n);
    double *K = s.qv, *ys = K + 4 * n2;
    *done = 0;
    for (I k = 0; k < nsteps; k++) {
        int r = rk4p_step(M, &s, y, f, h, motions + k * motion_stride, ufs + k * uf_stride,
                          tol, max_iter, K, ys);
        if (r != ST_OK) return r;   /* the caller redoes step *done on the numpy path */
        *done = k + 1;
        if (audit[A_ACTIVE] != 0.0
                && !energy_check(M, y, y + S_(M, n), audit, divergence_fraction, roundoff))
            return ST_ENERGY;
    }
    return ST_OK;
}

/* v (2n: the dq and dq' halves) -> its part along the constraints at q in the mass
 * metric, v - M^-1 J^T (J M^-1 J^T)^-1 J v (ProjectedRK._tangent), J's values in s->values;
 * `fresh`: S is factorised here, else its factor is kept from the last call. */
static int tangent_part(const Model *M, Scratch *s, double *v, int fresh) {
    I n = S_(M, n);
    for (int half = 0; half < 2; half++) {
        double *w = v + half * n;
        jac_mul(M, s->values, w, s->rhs);
        if (fresh || !s->kept) {   /* a minimum-norm solve keeps no factor: each half anew */
            int r = schur_solve_keeping(M, s->values, s->rhs, s->x, s->band, s->tmp, &s->kept);
            if (r != ST_OK) return ST_SINGULAR;              /* the numpy path's solve */
            fresh = 0;
        } else schur_again(M, s->rhs, s->x, s->band, s->tmp);
        jac_t_mul(M, s->values, s->x, s->nv);
        for (I k = 0; k < n; k++) w[k] -= M->minv[k] * s->nv[k];
    }
    return ST_OK;
}

/* The error estimate of a trial (ProjectedRK._error_norm): DOP853's combined estimate with
 * E3, else h E.K; with `tangent` only the estimate's part along the constraints at y_new
 * (its Jacobian values in s->values). ev: 4n scratch. */
static int error_norm(const Model *M, Scratch *s, I ns, const double *E, const double *E3,
                      double h, const double *y, const double *y_new, const double *K,
                      double rtol, double atol, int tangent, double *ev, double *err) {
    I n2 = 2 * S_(M, n);
    double *e5 = ev, *e3 = ev + n2, s5 = 0.0, s3 = 0.0;
    weighted_sum(K, n2, E, ns + 1, e5);
    if (E3) weighted_sum(K, n2, E3, ns + 1, e3);
    else for (I k = 0; k < n2; k++) { e5[k] *= h; e3[k] = 0.0; }
    if (tangent) {
        int r = tangent_part(M, s, e5, 1);
        if (r == ST_OK && E3) r = tangent_part(M, s, e3, 0);
        if (r != ST_OK) return r;
    }
    for (I k = 0; k < n2; k++) {
        double scale = atol + rtol * fmax(fabs(y[k]), fabs(y_new[k]));
        s5 += (e5[k] / scale) * (e5[k] / scale);
        s3 += (e3[k] / scale) * (e3[k] / scale);
    }
    if (!E3) *err = sqrt(s5 / (double)n2);
    else if (s5 == 0.0) *err = 0.0;
    else *err = fabs(h) * s5 / sqrt((s5 + 0.01 * s3) * (double)n2);
    return ST_OK;
}

/* The arithmetic of one step of an embedded pair with projection (ProjectedRK._step_impl):
 * tableau A (ns x ns, row s uses its first s entries), B (ns), error weights E (ns + 1)
 * and, for DOP853's combined estimate, E3 (ns + 1; NULL for a single estimate). Stage s
 * evaluates at motions[s] / ufs[s] (s = 1..ns-1: t + C[s] h; s = ns: t + h).
 * Returns ST_OK with y_new (2n, projected), f_new = y'(t + h, y_new) and *err; or
 * ST_NOT_FINITE (y_new or its derivative not finite), ST_ERROR_NORM (*err >= 1),
 * ST_PROJECTION (the position projection failed), ST_SINGULAR or ST_SPRING (the numpy path
 * redoes the step). K: (ns + 1) x 2n scratch. With c1 (not NULL): *c1 the singularity
 * indicator at the step's end before the projection, and the error estimate along the
 * constraints there when it or c0 (the indicator at the start) is below NEAR_ZONE, as
 * ProjectedRK._attempt's Python step does near a singular configuration. With kept (not
 * NULL): *kept 1 when f_new was solved by the factor of S the velocity projection kept
 * (the scratch then holds that evaluation's Psi_q values, gamma and factor: keep_end). */
static int prk_trial(const Model *M, I ns, const double *A, const double *B, const double *E,
                     const double *E3, double h, const double *y, const double *f0,
                     const double *motions, const double *ufs, double rtol, double atol,
                     double tol, I max_iter, double *y_new, double *f_new, double *err,
                     double *K, double c0, double *c1, int *kept, int end_rhs) {
    Scratch s = scratch(M, M->work);
    I n = S_(M, n), n2 = 2 * n, m = S_(M, m), nf = S_(M, nf);
    double *ys = s.qv;
    memcpy(K, f0, (size_t)n2 * sizeof(double));
    for (I st = 1; st < ns; st++) {
        combine(y, h, K, n2, A + st * ns, st, ys);
        int r = rhs(M, &s, ys, motions + st * 3 * m, ufs + st * nf, K + st * n2, s.lam);
        if (r != ST_OK) return r;
    }
    combine(y, h, K, n2, B, ns, y_new);
    if (end_rhs) {
        int r = rhs(M, &s, y_new, motions + ns * 3 * m, ufs + ns * nf, K + ns * n2, s.lam);
        if (r == ST_SINGULAR || r == ST_SPRING) return r;
        if (r != ST_OK || !all_finite(y_new, n2) || !all_finite(K + ns * n2, n2))
            return ST_NOT_FINITE;
    } else {    /* y' at the unprojected end, which the caller reads nowhere (ProjectedRK
                 * skip_end: an error estimate whose weights there are 0, no dense output,
                 * no watch): 0 in its place, and Psi_q's values there for the indicator */
        if (!all_finite(y_new, n2)) return ST_NOT_FINITE;
        memset(K + ns * n2, 0, (size_t)n2 * sizeof(double));
        if (m) {
            jacobian_at(M, &s, y_new, motions + ns * 3 * m);
        }
    }
    int r, tangent = 0;
    if (c1) {     /* Psi_q's values at y_new: the evaluation just above left them */
        *c1 = m ? indicator_of(M, &s, s.values) : INFINITY;
        tangent = m && !(fmin(c0, *c1) >= NEAR_ZONE_C);
    }
    r = error_norm(M, &s, ns, E, E3, h, y, y_new, K, rtol, atol, tangent, ys + n2, err);
    if (r != ST_OK) return r;
    if (!(*err < 1.0)) return ST_ERROR_NORM;
    /* Psi and Psi_q at y_new: the end's evaluation (rhs or jacobian_at) left them */
    r = project_at(M, &s, y_new, y_new + n, motions + ns * 3 * m, tol, max_iter, 1);
    if (r == ST_SINGULAR || r == ST_SPRING) return r;
    if (r != ST_OK) return ST_PROJECTION;
    r = rhs_projected(M, &s, y_new, motions + ns * 3 * m, ufs + ns * nf, f_new, s.lam);
    if (r == ST_OK) memo_store(M, y_new, y_new + n, motions + ns * 3 * m, motions + ns * 3 * m + 2 * m, ufs + ns * nf, f_new + n, s.lam);
    if (kept) *kept = s.kept;
    return r;
}

int mbd_prk_trial(const Model *M, I ns, const double *A, const double *B, const double *E,
                  const double *E3, double h, const double *y, const double *f0,
                  const double *motions, const double *ufs, double rtol, double atol,
                  double tol, I max_iter, double *y_new, double *f_new, double *err, double *K) {
    return prk_trial(M, ns, A, B, E, E3, h, y, f0, motions, ufs, rtol, atol, tol, max_iter,
                     y_new, f_new, err, K, 0.0, NULL, NULL, 1);
}

/* mbd_prk_trial with the indicator at the step's end in *c1 and, near a singular
 * configuration (c0 or *c1 below NEAR_ZONE), the error estimate along the constraints;
 * end_rhs 0: without y' at the unprojected end (prk_trial). */
int mbd_prk_trial_near(const Model *M, I ns, const double *A, const double *B, const double *E,
                       const double *E3, double h, const double *y, const double *f0,
                       const double *motions, const double *ufs, double rtol, double atol,
                       double tol, I max_iter, double *y_new, double *f_new, double *err,
                       double *K, double c0, double *c1, I end_rhs) {
    return prk_trial(M, ns, A, B, E, E3, h, y, f0, motions, ufs, rtol, atol, tol, max_iter,
                     y_new, f_new, err, K, c0, c1, NULL, (int)end_rhs);
}

/* One trial step of an embedded pair in minimal coordinates (integrators/minimal.py): the
 * tableau advances every component, but only the independent ones (z, z') are kept: at each
 * stage and at t + h the dependent coordinates are solved from Psi = 0 and Psi_q q' = nu
 * with (z, z') held, by Newton started from the tableau's values (project() with P: this
 * model with zero weights on the independent coordinates, so only dependent ones move);
 * the error norm is over (z, z') alone. Returns as mbd_prk_trial; ST_PROJECTION when a
 * Newton solve does not converge (the caller re-chooses the partition or halves the step). */
int mbd_mc_trial(const Model *M, const Model *P, I ns, const double *A, const double *B,
                 const double *E, const double *E3, double h, const double *y,
                 const double *f0, const double *motions, const double *ufs, double rtol,
                 double atol, double tol, I max_iter, double *y_new, double *f_new,
                 double *err, double *K) {
    Scratch s = scratch(M, M->work);
    I n = S_(M, n), n2 = 2 * n, m = S_(M, m), nf = S_(M, nf);
    double *ys = s.qv;
    memcpy(K, f0, (size_t)n2 * sizeof(double));
    for (I st = 1; st <= ns; st++) {
        const double *coef = st < ns ? A + st * ns : B;
        double *target = st < ns ? ys : y_new;
        I terms_used = st < ns ? st : ns;
        for (I k = 0; k < n2; k++) {
            double a = 0.0;
            for (I j = 0; j < terms_used; j++) a += K[j * n2 + k] * coef[j];
            target[k] = y[k] + h * a;
        }
        if (!all_finite(target, n2)) return ST_NOT_FINITE;
        int r = project(P, &s, target, target + n, motions + st * 3 * m, tol, max_iter);
        if (r == ST_SINGULAR || r == ST_SPRING) return r;
        if (r != ST_OK) return ST_PROJECTION;
        r = rhs(M, &s, target, motions + st * 3 * m, ufs + st * nf, K + st * n2, s.lam);
        if (r == ST_SINGULAR || r == ST_SPRING) return r;
        if (r != ST_OK || !all_finite(K + st * n2, n2)) return ST_NOT_FINITE;
    }
    double e5 = 0.0, e3 = 0.0;
    I count = 0;
    for (I k = 0; k < n2; k++) {
        if (P->minv[k % n] != 0.0) continue;          /* dependent: not integrated */
        double scale = atol + rtol * fmax(fabs(y[k]), fabs(y_new[k])), a = 0.0, b = 0.0;
        for (I j = 0; j <= ns; j++) { a += K[j * n2 + k] * E[j]; if (E3) b += K[j * n2 + k] * E3[j]; }
        if (E3) { e5 += (a / scale) * (a / scale); e3 += (b / scale) * (b / scale); }
        else e5 += (h * a / scale) * (h * a / scale);
        count++;
    }
    if (count == 0) *err = 0.0;
    else if (!E3) *err = sqrt(e5 / (double)count);
    else if (e5 == 0.0 && e3 == 0.0) *err = 0.0;
    else *err = fabs(h) * e5 / sqrt((e5 + 0.01 * e3) * (double)count);
    if (!(*err < 1.0)) return ST_ERROR_NORM;
    memcpy(f_new, K + ns * n2, (size_t)n2 * sizeof(double));
    memo_store(M, y_new, y_new + n, motions + ns * 3 * m, motions + ns * 3 * m + 2 * m, ufs + ns * nf, f_new + n, s.lam);
    return ST_OK;
}
