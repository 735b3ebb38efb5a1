/*
 * dense.h (part of kernel.c): the state and the outputs at a time inside an adaptive
 * method's last step, from its dense output (integrators/dense_output.py's interpolants,
 * projected as ProjectedRK._output_at projects them), and the FMU's communication step that
 * does nothing else (fmu_build/runtime: a doStep that ends inside the last step of a scene
 * whose inputs are held, served by the wrapper without entering Python; the drivers'
 * motions at the point it reads, motions.h).
 *
 * Python's path (ProjectedRK._output_at, Simulation.output_vector) calls the same two
 * functions, so a value the wrapper serves is the value Python would have computed, bit
 * for bit.
 */

enum { DENSE_RK45 = 1, DENSE_DOP853 = 2 };

/* One step's dense output and what the wrapper's step needs; filled by ckernel.DenseRead. */
typedef struct {
    double t_now;           /* the FMU's time (the last communication point) */
    double t_old, h;        /* the step holding the outputs: [t_old, t_old + h] */
    double time_tol;        /* a communication point this close (relative) is t_now */
    double tol;             /* the position projection's tolerance */
    I max_iter;
    I kind, rows;           /* DENSE_RK45: Q (2n x rows), y = y_old + h Q [x, x^2, ...];
                             * DENSE_DOP853: F (rows x 2n), scipy's Dop853DenseOutput */
    const double *coef, *y_old;
    const double *motion;   /* (c, c', c'') of every row, held over the step (3m) */
    const double *uf;       /* the force inputs, held */
    I nout;                 /* the output vector's length */
    I npub;                 /* values[pub_dst[k]] = V[pub_src[k]] after a step ... */
    const I *pub_dst, *pub_src;
    double *V;              /* ... V = (outputs, q, q', q''): nout + 3n; then lam (m) */
    MotionTable mt;         /* the wrapper's steps: the drivers' motions (none: `motion`) */
    double *mbuf;           /* ... evaluated at the point read (3m) */
} DenseRead;

/* y (2n) = the interpolant at t. */
static void dense_interpolate(const DenseRead *d, I n2, double t, double *y) {
    double x = (t - d->t_old) / d->h;
    if (d->kind == DENSE_RK45) {
        for (I i = 0; i < n2; i++) {
            double s = 0.0, p = 1.0;
            for (I j = 0; j < d->rows; j++) {
                p *= x;
                s += d->coef[i * d->rows + j] * p;
            }
            y[i] = d->y_old[i] + d->h * s;
        }
        return;
    }
    for (I i = 0; i < n2; i++) y[i] = 0.0;
    for (I r = d->rows - 1, k = 0; r >= 0; r--, k++) {     /* from the last row */
        double f = k % 2 == 0 ? x : 1.0 - x;
        for (I i = 0; i < n2; i++) y[i] = (y[i] + d->coef[r * n2 + i]) * f;
    }
    for (I i = 0; i < n2; i++) y[i] += d->y_old[i];
}

/* (q, q') at t inside the step, projected (q, qd: n each, contiguous: y = q); ST_OK or
 * the case the caller's Python path takes. */
int mbd_dense_state(const Model *M, const DenseRead *d, double t, double *q) {
    Scratch s = scratch(M, M->work);
    dense_interpolate(d, 2 * S_(M, n), t, q);
    for (I i = 0; i < 2 * S_(M, n); i++)
        if (!isfinite(q[i])) return ST_NOT_FINITE;
    return project(M, &s, q, q + S_(M, n), d->motion, d->tol, d->max_iter);
}

/* The wrapper's doStep from t over h when it ends inside the step: V and values filled,
 * t_now moved; anything else (another time, beyond the step, at its end, a failed
 * projection) returns non-zero and the wrapper calls Python instead. */
int mbd_dense_step(const Model *M, DenseRead *d, double t, double h, double *values) {
    I n = S_(M, n);
    if (!(fabs(t - d->t_now) <= d->time_tol * fmax(fabs(t), fabs(d->t_now)))) return ST_ERROR_NORM;
    double end = t + h;
    if (!(end > d->t_now && end < d->t_old + d->h && end >= d->t_old)) return ST_ERROR_NORM;
    double *out = d->V, *q = out + d->nout, *qd = q + n, *qdd = qd + n, *lam = qdd + n;
    DenseRead at = *d;      /* with drivers, their motion at the point (Python loads it so) */
    if (d->mt.nmotion) {
        motion_at(M, &d->mt, end, d->mbuf);
        at.motion = d->mbuf;
    }
    int st = mbd_dense_state(M, &at, end, q);
    if (st != ST_OK) return st;
    st = mbd_state_outputs(M, q, qd, at.motion, d->uf, qdd, lam, out);
    if (st != ST_OK) return st;
    for (I k = 0; k < d->npub; k++) values[d->pub_dst[k]] = d->V[d->pub_src[k]];
    d->t_now = end;
    return ST_OK;
}
