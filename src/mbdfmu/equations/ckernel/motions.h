/*
 * motions.h (part of kernel.c): the drivers' motions for the steps an FMU's wrapper takes
 * (fixed.h's rk4p steps, adaptive.h's landing steps of an embedded pair): the motion table
 * (constant, linear, harmonic: model/motion.py; sampled) evaluated at any time as
 * ConstraintSet.motion_values, and a driver position the master sets once per
 * communication step, signals.py's SampledDriver, with fmi2SetReal of its fields taken by
 * the wrapper. The same arithmetic in the same order, so the motion and the error estimate
 * are Python's bit for bit: the history of the last four samples, the quadratic through the
 * last three (SampledDriver._quadratic), the velocity and acceleration the master gives in
 * its place, the derived acceleration's estimated error (_cubic_term, _estimate) and
 * whether it is large (error_is_large). A sampled driver is DRV_SIZE doubles.
 */

enum { MOTION_CONSTANT = 0, MOTION_LINEAR = 1, MOTION_HARMONIC = 2, MOTION_SAMPLED = 3 };

typedef struct {
    I nmotion;               /* driver rows: row, kind (MOTION_*), four coefficients each */
    const I *mrow, *mkind; double *mcoef;   /* a sampled driver's rewritten at its sets */
    const double *offsets;   /* c of every row (m), the drivers' rows overwritten */
} MotionTable;

/* Drivers whose position the master sets: fmi2SetReal of their fields lands in
 * uf[dslot + 3 d + field] (set_force_inputs), applied at the next step (drivers_apply). */
typedef struct {
    I ndrv, dslot;
    const I *dmot;           /* each one's entry in the motion table (MOTION_SAMPLED) */
    double *drv;             /* ndrv DRV_SIZE states, then their copy and the table's */
    double reinit_tol; I reinit_iter;   /* the restart's projection after a set */
} SampledSet;

enum { D_COUNT, D_FRESH, D_T, D_P = D_T + 4, D_HAS_V = D_P + 4, D_V, D_HAS_A, D_A, D_ERROR,
       D_SCALE, D_REPORTED, DRV_SIZE };
enum { DRIVER_POSITION, DRIVER_VELOCITY, DRIVER_ACCELERATION };   /* signals.DRIVER_FIELDS */

#define LARGE_ERROR 0.1          /* signals.LARGE_ERROR */
#define ROUNDOFF_TERMS 8.0       /* signals.ROUNDOFF_TERMS */

/* SampledDriver._quadratic: position, velocity and acceleration at the last sample. */
static void drv_quadratic(const double *d, double *p, double *v, double *a) {
    I count = (I)d[D_COUNT], k = count < 3 ? count : 3;
    const double *t = d + D_T + count - k, *x = d + D_P + count - k;
    *p = x[k - 1];
    *v = *a = 0.0;
    if (k == 1) return;
    double d1 = (x[k - 1] - x[k - 2]) / (t[k - 1] - t[k - 2]);
    *v = d1;
    if (k == 2) return;
    double d0 = (x[1] - x[0]) / (t[1] - t[0]);
    *a = 2.0 * (d1 - d0) / (t[2] - t[0]);
    *v = d1 + 0.5 * *a * (t[2] - t[1]);
}

/* SampledDriver._cubic_term (four samples): the error, its round-off in *noise. */
static double drv_cubic_term(const double *d, double *noise) {
    const double *t = d + D_T, *p = d + D_P;
    double x = t[3] + (t[3] - t[2]), third = 0.0, size = 0.0;
    for (int i = 0; i < 4; i++) {
        double w = 1.0;
        for (int j = 0; j < 4; j++)
            if (j != i) w *= t[i] - t[j];
        third += p[i] / w;
        size += fabs(p[i] / w);
    }
    double k = 2.0 * (3.0 * x - t[1] - t[2] - t[3]);
    *noise = ROUNDOFF_TERMS * DBL_EPSILON * size * fabs(k);
    return third * k;
}

/* SampledDriver.set of one field at t (a position: the history and _estimate). */
static void drv_set(double *d, double t, int field, double value) {
    if (field == DRIVER_VELOCITY) {
        d[D_HAS_V] = 1.0;
        d[D_V] = value;
        return;
    }
    if (field == DRIVER_ACCELERATION) {
        d[D_HAS_A] = 1.0;
        d[D_A] = value;
        return;
    }
    I count = (I)d[D_COUNT];
    if (d[D_FRESH] == 0.0) {
        count = 1;
        d[D_T] = t;
        d[D_P] = value;
        d[D_FRESH] = 1.0;
    } else if (t == d[D_T + count - 1]) {
        d[D_P + count - 1] = value;
    } else {
        if (count == 4) {
            memmove(d + D_T, d + D_T + 1, 3 * sizeof(double));
            memmove(d + D_P, d + D_P + 1, 3 * sizeof(double));
            count = 3;
        }
        d[D_T + count] = t;
        d[D_P + count] = value;
        count += 1;
    }
    d[D_COUNT] = (double)count;
    double p, v, a, noise;
    drv_quadratic(d, &p, &v, &a);
    d[D_SCALE] = fmax(d[D_SCALE], fabs(a));
    d[D_ERROR] = count >= 4 ? drv_cubic_term(d, &noise) : 0.0;
}

/* SampledDriver.error_is_large. */
static int drv_large(const double *d) {
    if (d[D_HAS_V] != 0.0 || d[D_HAS_A] != 0.0 || d[D_COUNT] < 4.0 || !(d[D_SCALE] > 0.0))
        return 0;
    double noise;
    drv_cubic_term(d, &noise);
    return fabs(d[D_ERROR]) > fmax(LARGE_ERROR * d[D_SCALE], noise);
}

/* SampledDriver.step_motion: the motion over the next step as motion_at's MOTION_SAMPLED
 * reads it, (time of the last sample, p, v, a) with the master's velocity and
 * acceleration where it gave them. */
static void drv_coefficients(const double *d, double *c) {
    double p, v, a;
    drv_quadratic(d, &p, &v, &a);
    c[0] = d[D_T + (I)d[D_COUNT] - 1];
    c[1] = p;
    c[2] = d[D_HAS_V] != 0.0 ? d[D_V] : v;
    c[3] = d[D_HAS_A] != 0.0 ? d[D_A] : a;
}

/* (c, c', c'') of every row at t into out (3m), as ConstraintSet.motion_values. */
static void motion_at(const Model *M, const MotionTable *r, double t, double *out) {
    I m = S_(M, m);
    memcpy(out, r->offsets, (size_t)m * sizeof(double));
    memset(out + m, 0, (size_t)(2 * m) * sizeof(double));
    for (I k = 0; k < r->nmotion; k++) {
        const double *c = r->mcoef + 4 * k;
        I row = r->mrow[k];
        if (r->mkind[k] == MOTION_CONSTANT) {
            out[row] = c[0];
        } else if (r->mkind[k] == MOTION_LINEAR) {            /* start, rate */
            out[row] = c[0] + c[1] * t;
            out[m + row] = c[1];
        } else if (r->mkind[k] == MOTION_SAMPLED) {   /* SampledDriver.__call__: t_n, p, v, a */
            double tau = t - c[0];
            out[row] = c[1] + c[2] * tau + 0.5 * c[3] * tau * tau;
            out[m + row] = c[2] + c[3] * tau;
            out[2 * m + row] = c[3];
        } else {                          /* offset, amplitude, w = 2 pi frequency, phase */
            double w = c[2], a = c[1], s = sin(w * t + c[3]), co = cos(w * t + c[3]);
            out[row] = c[0] + a * s;
            out[m + row] = a * w * co;
            out[2 * m + row] = -a * w * w * s;
        }
    }
}

/* The drivers' states and table entries as before drivers_apply. */
static void drivers_undo(SampledSet *sd, MotionTable *mt) {
    I size = sd->ndrv * DRV_SIZE;
    const double *saved = sd->drv + size, *coef = saved + size;
    memcpy(sd->drv, saved, (size_t)size * sizeof(double));
    for (I d = 0; d < sd->ndrv; d++)
        memcpy(mt->mcoef + 4 * sd->dmot[d], coef + 4 * d, 4 * sizeof(double));
}

/* The driver sets taken since the last step (set flags and places of the nvr settable
 * inputs, values in uf), applied as Simulation.set_input applies them at the step's time
 * t0 (the states and the table's entries saved first, for drivers_undo). 0: none; 1: one
 * or more applied; -1: nothing applied, for Python to take the step, as a driver's
 * derived acceleration turns large or small again (its warning and its `reported` flag
 * are Python's). */
static int drivers_apply(SampledSet *sd, MotionTable *mt, I nvr, const I *set, const I *slots,
                         const double *uf, double t0) {
    I size = sd->ndrv * DRV_SIZE, any = 0;
    double *saved = sd->drv + size, *coef = saved + size;
    for (I k = 0; k < nvr; k++) any |= set[k] && slots[k] >= sd->dslot;
    if (!sd->ndrv || !any) return 0;
    memcpy(saved, sd->drv, (size_t)size * sizeof(double));
    for (I d = 0; d < sd->ndrv; d++)
        memcpy(coef + 4 * d, mt->mcoef + 4 * sd->dmot[d], 4 * sizeof(double));
    for (I k = 0; k < nvr; k++) {
        if (!set[k] || slots[k] < sd->dslot) continue;
        I field = slots[k] - sd->dslot;
        drv_set(sd->drv + DRV_SIZE * (field / 3), t0, (int)(field % 3), uf[slots[k]]);
    }
    for (I d = 0; d < sd->ndrv; d++) {
        const double *state = sd->drv + DRV_SIZE * d;
        if (drv_large(state) != (state[D_REPORTED] != 0.0)) {
            drivers_undo(sd, mt);        /* the drivers before it had their entries set */
            return -1;
        }
        drv_coefficients(state, mt->mcoef + 4 * sd->dmot[d]);
    }
    return 1;
}

/* Simulation._reinitialize after a driver's set: (q, q') = y projected onto the
 * constraints at motion (c, c', c'') as kernel.project does it. */
static int drivers_project(const Model *M, Scratch *s, const SampledSet *sd, double *y,
                           const double *motion) {
    int st = project_positions(M, s, y, motion, sd->reinit_tol, sd->reinit_iter, 0);
    return st == ST_OK ? mbd_project_velocities(M, y, y + S_(M, n), motion, motion + S_(M, m)) : st;
}
