/*
 * friction.h (part of kernel.c): eq. (14) in a contact mode where joints with Coulomb
 * friction slide (limits.ModeEquations, formulation.md eq. 31). Each sliding joint's
 * friction, -direction (F0 + mu r |F|) on its coordinate, depends on the reactions it
 * changes: eq. (14) is solved with a guess (the last converged forces, slide_f), the
 * forces updated from the reactions, until they no longer change, in the same order and
 * arithmetic as ModeEquations.accelerations. What does not converge goes back to the numpy
 * path, which says why.
 */

#define FRICTION_MAX_ITER 60          /* limits.FRICTION_MAX_ITER */
#define FRICTION_TOL 1e-14            /* limits.FRICTION_TOL */

/* model.friction_table's columns */
enum { SL_REVOLUTE, SL_BI, SL_BJ, SL_REACTION, SL_INTS };
enum { SL_PI = 0, SL_PJ = 2, SL_U = 4, SL_DIRECTION = 6, SL_COULOMB, SL_COEFFICIENT, SL_RADIUS,
       SL_FRAME_ANGLE, SL_REALS };

/* The force on body_j of the k-th joint with reactions, in its frame, from lam and Psi_q's
 * data at q (Equations.reactions, eqs. 16-17, 28): (along, across, torque). */
static void joint_reaction(const Model *M, const double *q, const double *lam,
                           const double *data, I k, double *out) {
    I nb = S_(M, nb), m = S_(M, m);
    double gen[3];
    for (int b = 0; b < 3; b++) {
        double g = 0.0;
        for (int a = 0; a < 2; a++) {
            I row = S_(M, joint_rows)[2 * k + a];
            I e = S_(M, reaction_entries)[6 * k + 3 * a + b];
            double l = row < m ? lam[row] : 0.0, d = e < S_(M, size) ? data[e] : 0.0;
            g += d * l;
        }
        gen[b] = -g;
    }
    I bj = S_(M, joint_bj)[k], fb = S_(M, frame_body)[k];
    double c = bj < nb ? cos(q[3 * bj + 2]) : 1.0, s = bj < nb ? sin(q[3 * bj + 2]) : 0.0;
    double px = M->frame_point[2 * k], py = M->frame_point[2 * k + 1];
    double ax = c * px - s * py, ay = s * px + c * py;
    double theta = (fb < nb ? q[3 * fb + 2] : 0.0) + M->frame_angle[k];
    double co = cos(theta), si = sin(theta);
    out[0] = co * gen[0] + si * gen[1];
    out[1] = -si * gen[0] + co * gen[1];
    out[2] = gen[2] - (ax * gen[1] - ay * gen[0]);
}

/* The gradient in q of a sliding joint's coordinate (limits.Coordinate.gradient):
 * phi_j - phi_i, or (r_Pj - r_Pi) . u_i for a translational joint. */
static void coordinate_gradient(const Model *M, const I *si, const double *sr,
                                const double *q, double *g) {
    I n = S_(M, n), i = si[SL_BI], j = si[SL_BJ];
    for (I k = 0; k < n; k++) g[k] = 0.0;
    if (si[SL_REVOLUTE]) {
        if (j >= 0) g[3 * j + 2] += 1.0;
        if (i >= 0) g[3 * i + 2] -= 1.0;
        return;
    }
    double xi = 0.0, yi = 0.0, ai = 0.0, xj = 0.0, yj = 0.0, aj = 0.0;
    if (i >= 0) { xi = q[3 * i]; yi = q[3 * i + 1]; ai = q[3 * i + 2]; }
    if (j >= 0) { xj = q[3 * j]; yj = q[3 * j + 1]; aj = q[3 * j + 2]; }
    double ci = cos(ai), sn_i = sin(ai), cj = cos(aj), sn_j = sin(aj);
    const double *u = sr + SL_U, *pi = sr + SL_PI, *pj = sr + SL_PJ;
    double a0 = ci * u[0] - sn_i * u[1], a1 = sn_i * u[0] + ci * u[1];
    double Ai0 = ci * pi[0] - sn_i * pi[1], Ai1 = sn_i * pi[0] + ci * pi[1];
    double Aj0 = cj * pj[0] - sn_j * pj[1], Aj1 = sn_j * pj[0] + cj * pj[1];
    double d0 = (xj + Aj0) - xi - Ai0, d1 = (yj + Aj1) - yi - Ai1;
    if (j >= 0) {
        g[3 * j] += a0;
        g[3 * j + 1] += a1;
        g[3 * j + 2] += a0 * -Aj1 + a1 * Aj0;
    }
    if (i >= 0) {
        g[3 * i] -= a0;
        g[3 * i + 1] -= a1;
        g[3 * i + 2] += (-a1 * d0 + a0 * d1) - (a0 * -Ai1 + a1 * Ai0);
    }
}

/* Eq. 31: the friction magnitude a sliding joint can give, from its reaction. */
static double friction_bound(const Model *M, const I *si, const double *sr, const double *q,
                             const double *lam, const double *data) {
    double r[3];
    joint_reaction(M, q, lam, data, si[SL_REACTION], r);
    if (si[SL_REVOLUTE])
        return sr[SL_COULOMB] + sr[SL_COEFFICIENT] * sr[SL_RADIUS] * hypot(r[0], r[1]);
    double normal = r[0] * sin(sr[SL_FRAME_ANGLE]) + r[1] * cos(sr[SL_FRAME_ANGLE]);
    return sr[SL_COULOMB] + sr[SL_COEFFICIENT] * fabs(normal);
}

static int solve_eq14(const Model *M, Scratch *s, const double *F, const double *cdd,
                      double *qdd, double *lam);

/* Eq. (14) with the sliding friction (see the header): s holds Psi_q's data and values,
 * gamma and the applied forces F at (q, q'). slide_f: the last converged forces (nslide),
 * then the iterate, the update, the forces with friction (n) and the gradients. */
static int sliding_accelerations(const Model *M, Scratch *s, const double *q,
                                 const double *cdd, double *qdd, double *lam) {
    I n = S_(M, n), ns = S_(M, nslide);
    double *last = M->slide_f, *f = last + ns, *next = f + ns, *Fx = next + ns, *g = Fx + n;
    for (I k = 0; k < ns; k++) {
        coordinate_gradient(M, S_(M, s_int) + SL_INTS * k, M->s_real + SL_REALS * k, q, g + k * n);
        f[k] = last[k];
    }
    for (int it = 0; it < FRICTION_MAX_ITER; it++) {
        for (I c = 0; c < n; c++) {
            double extra = 0.0;
            for (I k = 0; k < ns; k++) extra += f[k] * g[k * n + c];
            Fx[c] = s->F[c] + extra;
        }
        int st = solve_eq14(M, s, Fx, cdd, qdd, lam);
        if (st != ST_OK) return st;
        int same = 1;
        for (I k = 0; k < ns; k++) {
            const double *sr = M->s_real + SL_REALS * k;
            next[k] = -sr[SL_DIRECTION] * friction_bound(M, S_(M, s_int) + SL_INTS * k, sr, q, lam,
                                                         s->data);
            if (!(fabs(next[k] - f[k]) <= FRICTION_TOL * (1.0 + fabs(next[k])))) same = 0;
        }
        if (same) {
            memcpy(last, f, (size_t)ns * sizeof(double));
            return ST_OK;
        }
        memcpy(f, next, (size_t)ns * sizeof(double));
    }
    return ST_SINGULAR;
}
