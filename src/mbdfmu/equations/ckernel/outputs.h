/*
 * outputs.h (part of kernel.c): every output of a scene at one instant in one call, the
 * vector of dynamics.Equations.output_values from q'' and lam the step already computed.
 */

/* Reactions of each joint on its body_j in its frame (Equations.reactions, eqs. 16-17,
 * 28) into out (nj, 3), NaN for couplers, then the coupler efforts -lam, then a zero, then
 * the sliding friction forces (friction.h). */
static void joint_values(const Model *M, const double *q, const double *lam,
                         const double *data, double *out) {
    for (I k = 0; k < 3 * S_(M, nj); k++) out[k] = NAN;
    for (I k = 0; k < S_(M, nr); k++)
        joint_reaction(M, q, lam, data, k, out + 3 * S_(M, reaction_joints)[k]);
    for (I k = 0; k < S_(M, ncoupler); k++) out[3 * S_(M, nj) + k] = -lam[S_(M, coupler_rows)[k]];
    out[3 * S_(M, nj) + S_(M, ncoupler)] = 0.0;   /* the plan's zero: outputs no joint type computes
                                          * here (a stop's force while nothing touches it) */
    for (I k = 0; k < S_(M, nslide); k++)     /* the sliding friction of the last evaluation */
        out[3 * S_(M, nj) + S_(M, ncoupler) + 1 + k] = M->slide_f[k];
}

/* Potential energy of gravity and springs (AppliedForces.potential_energy). */
static double potential(const Model *M, const double *q) {
    double e = 0.0;
    for (I k = 0; k < S_(M, n); k++) e += M->gravity[k] * q[k];
    return spring_potentials(M, q, -e);
}

/* The groups of the output vector after the body states, which a wrapper's step computes
 * only when it publishes one of their values (outputs_at's `want`). */
enum { W_JOINTS, W_DRIVERS, W_SPRINGS, W_ENERGIES, W_NORMS, W_GROUPS };

/* want[g]: 1 when one of the npub published sources (places in the nout outputs, then
 * q, q', q'') lies in group g of the output vector, else 0. */
static void published_groups(const Model *M, I nout, I npub, const I *src, int *want) {
    I joints = 6 * S_(M, nb), drivers = joints + S_(M, nplan), springs = drivers + S_(M, ndriver);
    for (int g = 0; g < W_GROUPS; g++) want[g] = 0;
    for (I k = 0; k < npub; k++) {
        I i = src[k];
        if (i < joints || i >= nout) continue;
        want[i < drivers ? W_JOINTS : i < springs ? W_DRIVERS : i < nout - 4 ? W_SPRINGS
             : i < nout - 2 ? W_ENERGIES : W_NORMS] = 1;
    }
}

/* The output vector (model.variables.outputs order): body states, joint outputs, driver
 * efforts, spring states, kinetic and potential energy, |Psi|, |Psi_q q' - nu|. motion:
 * c, c', c'' (3 m) at t. ST_SPRING for a spring of zero length. `fresh`: s holds Psi and
 * Psi_q's data and values at (q, c) already (the evaluation of eq. (14) there left them).
 * want: NULL for every value, else published_groups' flags: a group left out is NaN. */
static int outputs_at(const Model *M, Scratch *sp, int fresh, const double *q,
                      const double *qd, const double *lam, const double *motion,
                      const double *uf, const int *want, double *out) {
    Scratch s = *sp;
    I nb = S_(M, nb), n = S_(M, n), m = S_(M, m), o = 0;
    int all = want == NULL;
    for (I b = 0; b < nb; b++) {
        for (int c = 0; c < 3; c++) out[o++] = q[3 * b + c];
        for (int c = 0; c < 3; c++) out[o++] = qd[3 * b + c];
    }
    if (!fresh) {
        jacobian_at(M, &s, q, motion);
    }
    double *joints = s.qv;
    if (all || want[W_JOINTS]) {
        joint_values(M, q, lam, s.data, joints);
        for (I k = 0; k < S_(M, nplan); k++) out[o++] = joints[S_(M, joint_plan)[k]];
    } else for (I k = 0; k < S_(M, nplan); k++) out[o++] = NAN;
    for (I k = 0; k < S_(M, ndriver); k++)
        out[o++] = all || want[W_DRIVERS] ? -lam[S_(M, driver_rows)[k]] : NAN;
    for (I k = 0; k < S_(M, nforce); k++) {
        if (S_(M, f_int)[4 * k] != F_SPRING) continue;
        double g[8];
        if (!all && !want[W_SPRINGS]) {
            for (int c = 0; c < 3; c++) out[o++] = NAN;
            continue;
        }
        if (spring_geometry(M, k, q, qd, s.cs, g) != ST_OK) return ST_SPRING;
        out[o++] = g[0];
        out[o++] = g[1];
        out[o++] = spring_tension(M, k, g[0], g[1], uf);
    }
    double kinetic = 0.0, psi2 = 0.0, v2 = 0.0;
    if (all || want[W_ENERGIES]) {
        for (I k = 0; k < n; k++) kinetic += qd[k] * (M->mass[k] * qd[k]);
        out[o++] = 0.5 * kinetic;
        out[o++] = potential(M, q);
    } else { out[o++] = NAN; out[o++] = NAN; }
    if (!all && !want[W_NORMS]) { out[o++] = NAN; out[o++] = NAN; return ST_OK; }
    jac_mul(M, s.values, qd, s.rhs);
    for (I r = 0; r < m; r++) {
        double v = s.rhs[r] - motion[m + r];
        psi2 += s.psi[r] * s.psi[r];
        v2 += v * v;
    }
    out[o++] = sqrt(psi2);
    out[o++] = sqrt(v2);
    return ST_OK;
}

int mbd_outputs(const Model *M, const double *q, const double *qd, const double *qdd,
                const double *lam, const double *motion, const double *uf, double *out) {
    Scratch s = scratch(M, M->work);
    (void)qdd;
    return outputs_at(M, &s, 0, q, qd, lam, motion, uf, NULL, out);
}

/* The outputs at a state: q'' and lam of eq. (14) (the kept evaluation when the step
 * ended here, else computed), then mbd_outputs. qdd (n), lam (m): filled. */
int mbd_state_outputs(const Model *M, const double *q, const double *qd, const double *motion,
                      const double *uf, double *qdd, double *lam, double *out) {
    int st = mbd_accelerations(M, q, qd, motion, motion + 2 * S_(M, m), uf, qdd, lam);
    return st != ST_OK ? st : mbd_outputs(M, q, qd, qdd, lam, motion, uf, out);
}

/* A wrapper's step end: q'' and lam of eq. (14) at y = (q, q') with motion (c, c', c'') and
 * forces uf, into V after its nout outputs, then the output groups it publishes, and the
 * published values (V[pub_src[k]] to values[pub_dst[k]]). Without evaluating Psi_q once
 * more: the step's end evaluated eq. (14) at these arguments last (kept), or it is evaluated
 * now; either way Psi and Psi_q at (q, c) are then in s. */
static int publish_step_end(const Model *M, Scratch *s, const double *y, const double *motion,
                            const double *uf, I nout, I npub, const I *pub_src,
                            const I *pub_dst, double *V, double *values) {
    I n = S_(M, n);
    double *q = V + nout, *qd = q + n, *qdd = qd + n, *lam = qdd + n;
    int want[W_GROUPS];
    memcpy(q, y, (size_t)(2 * n) * sizeof(double));
    published_groups(M, nout, npub, pub_src, want);
    int st = mbd_accelerations(M, q, qd, motion, motion + 2 * S_(M, m), uf, qdd, lam);
    if (st == ST_OK) st = outputs_at(M, s, S_(M, m) > 0, q, qd, lam, motion, uf, want, V);
    if (st == ST_OK)
        for (I k = 0; k < npub; k++) values[pub_dst[k]] = V[pub_src[k]];
    return st;
}
