/*
 * fixed.h (part of kernel.c): an FMU's communication step of rk4p taken by its wrapper
 * without Python (fmu_build/runtime real_cache.py FastSteps), for scenes whose drivers
 * follow motions the kernel evaluates (constant, linear, harmonic) and whose force inputs
 * are held or set by the master before a step (mbd_fixed_set: fmi2SetReal of a force input
 * taken by the wrapper, then Simulation._reinitialize and the restart as Python does them).
 *
 * The arithmetic is Python's, in the same order: the grid of Integrator.fixed_grid (equal
 * steps no longer than h_max up to t + h, times t0 + j step), motion.py's evaluate() at
 * each stage time (c_steps.stage_inputs), rk4p_step, then the output vector at t + h
 * (Simulation.output_vector). The slave takes the state the steps reached when it catches
 * up (ckernel/fixed.py), so every value served is the one Python would have computed.
 */

enum { MOTION_CONSTANT = 0, MOTION_LINEAR = 1, MOTION_HARMONIC = 2 };

typedef struct {
    double t_now, time_tol;  /* the FMU's time (the integrator's: rk4p has no dense output) */
    double h_max, slack;     /* Integrator.fixed_grid: the method's step, STEP_COUNT_SLACK */
    I max_steps;             /* the work limit's steps per doStep (or a huge number) */
    I unchecked, check_every; /* steps since the last step-doubling check, and how often */
    double tol; I max_iter;  /* the position projection */
    I nmotion;               /* driver rows: row, kind (MOTION_*), four coefficients each */
    const I *mrow, *mkind; const double *mcoef;
    const double *offsets;   /* c of every row (m), the drivers' rows overwritten */
    double *ufs;             /* the held force inputs, three times (3 nf) */
    double *y, *f, *save;    /* the state (2n each) and f = y'; a copy to roll back */
    double *motions;         /* (3, 3m): one step's stage inputs; then (3m) at t + h */
    I steps;                 /* steps taken since the slave armed this */
    double local, estimate, allowed;  /* stated_accuracy.ErrorEstimate.charge's sum */
    I nout, npub;            /* values[pub_dst[k]] = V[pub_src[k]] after a step ... */
    const I *pub_dst, *pub_src;
    double *V;               /* ... V = (outputs, q, q', q''): nout + 3n; then lam (m) */
    /* force inputs set by fmi2SetReal (mbd_fixed_set; nvr = 0: none may be set here) */
    double reinit_tol;       /* Simulation._reinitialize's projection */
    double *uf;              /* the force inputs as set (nf) */
    I nvr; const I *vrs, *slots;   /* value reference of each settable input, its place in uf */
    I *set;                  /* nvr: 1 where set since the last step */
    I changed;               /* an input was set since the last step */
    I restarts;              /* steps since armed that began with a restart */
} FixedRun;

/* fmi2SetReal of force inputs a fast step holds (mbd_fixed_set, adaptive.h's
 * mbd_prk_set): 0 when every value reference is one of the nknown settable ones and every
 * value finite (then applied to uf, flagged in set, also to the published values), else
 * non-zero with nothing applied (Python sets them and says what is wrong). */
static int set_force_inputs(I nknown, const I *vrs, const I *slots, double *uf, I *set,
                            I *changed, const unsigned int *vr, size_t nvr,
                            const double *value, double *values) {
    for (size_t i = 0; i < nvr; i++) {
        I k = 0;
        while (k < nknown && vrs[k] != (I)vr[i]) k++;
        if (k == nknown || !isfinite(value[i])) return 1;
    }
    for (size_t i = 0; i < nvr; i++) {
        I k = 0;
        while (vrs[k] != (I)vr[i]) k++;
        uf[slots[k]] = value[i];
        set[k] = 1;
        values[vr[i]] = value[i];
    }
    *changed = 1;
    return 0;
}

int mbd_fixed_set(FixedRun *r, const unsigned int *vr, size_t nvr, const double *value,
                  double *values) {
    return set_force_inputs(r->nvr, r->vrs, r->slots, r->uf, r->set, &r->changed, vr, nvr,
                            value, values);
}

/* (c, c', c'') of every row at t into out (3m), as ConstraintSet.motion_values. */
static void motion_at(const Model *M, const FixedRun *r, double t, double *out) {
    I m = M->m;
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
        } else {                          /* offset, amplitude, w = 2 pi frequency, phase */
            double w = c[2], a = c[1], s = sin(w * t + c[3]), co = cos(w * t + c[3]);
            out[row] = c[0] + a * s;
            out[m + row] = a * w * co;
            out[2 * m + row] = -a * w * w * s;
        }
    }
}

/* After an input was set: Simulation._reinitialize's projection at t0 and the restart's
 * f = (q', q'') with the new inputs; the inputs then held over the step's stages. */
static int fixed_restart(const Model *M, FixedRun *r, Scratch *s, double t0) {
    I n = M->n, m = M->m, nf = M->nf;
    motion_at(M, r, t0, r->motions);
    int st = project(M, s, r->y, r->y + n, r->motions, r->reinit_tol, r->max_iter);
    if (st != ST_OK) return st;
    memcpy(r->f, r->y + n, (size_t)n * sizeof(double));
    st = mbd_accelerations(M, r->y, r->y + n, r->motions, r->motions + 2 * m, r->uf, r->f + n,
                           s->lam);
    if (st != ST_OK) return st;
    for (I row = 0; row < 3; row++)
        if (nf) memcpy(r->ufs + row * nf, r->uf, (size_t)nf * sizeof(double));
    return ST_OK;
}

/* The wrapper's doStep from t over h: the steps of the grid, V and values filled, t_now
 * moved; non-zero (nothing changed) when Python must take it: another time, more steps
 * than allowed, an estimated error beyond the stated accuracy, or whatever the kernel
 * hands back (Python then redoes the step and says why). */
int mbd_fixed_step(const Model *M, FixedRun *r, double t, double h, double *values) {
    I n = M->n, n2 = 2 * n, m = M->m;
    if (!(fabs(t - r->t_now) <= r->time_tol * fmax(fabs(t), fabs(r->t_now)))) return ST_ERROR_NORM;
    double t0 = r->t_now, end = t + h;
    if (!(end > t0)) return ST_ERROR_NORM;
    double count = ceil((end - t0) / r->h_max - r->slack);
    if (!(count <= (double)r->max_steps)) return ST_ERROR_NORM;
    I steps = count < 1.0 ? 1 : (I)count;
    /* a step-doubling check due before or within these steps (stated_accuracy.py) */
    if (r->unchecked + steps > r->check_every) return ST_ERROR_NORM;
    double estimate = r->estimate + r->local * (double)steps;
    if (estimate > r->allowed) return ST_ERROR_NORM;
    double step = (end - t0) / (double)steps;
    Scratch s = scratch(M, M->work);
    double *K = s.qv, *ys = K + 4 * n2;
    memcpy(r->save, r->y, (size_t)n2 * sizeof(double));
    memcpy(r->save + n2, r->f, (size_t)n2 * sizeof(double));
    if (r->changed) {
        int st = fixed_restart(M, r, &s, t0);
        if (st != ST_OK) {
            memcpy(r->y, r->save, (size_t)n2 * sizeof(double));
            memcpy(r->f, r->save + n2, (size_t)n2 * sizeof(double));
            return st;
        }
    }
    for (I j = 0; j < steps; j++) {
        double start = t0 + step * (double)j;
        motion_at(M, r, start, r->motions);
        motion_at(M, r, start + 0.5 * step, r->motions + 3 * m);
        motion_at(M, r, start + step, r->motions + 6 * m);
        int st = rk4p_step(M, &s, r->y, r->f, step, r->motions, r->ufs, r->tol, r->max_iter, K, ys);
        if (st != ST_OK) {
            memcpy(r->y, r->save, (size_t)n2 * sizeof(double));
            memcpy(r->f, r->save + n2, (size_t)n2 * sizeof(double));
            return st;
        }
    }
    double *out = r->V, *q = out + r->nout, *qd = q + n, *qdd = qd + n, *lam = qdd + n;
    motion_at(M, r, end, r->motions);
    memcpy(q, r->y, (size_t)n2 * sizeof(double));
    int st = mbd_state_outputs(M, q, qd, r->motions, r->ufs, qdd, lam, out);
    if (st != ST_OK) {
        memcpy(r->y, r->save, (size_t)n2 * sizeof(double));
        memcpy(r->f, r->save + n2, (size_t)n2 * sizeof(double));
        return st;
    }
    for (I k = 0; k < r->npub; k++) values[r->pub_dst[k]] = r->V[r->pub_src[k]];
    r->t_now = end;
    r->restarts += r->changed;
    r->changed = 0;
    for (I k = 0; k < r->nvr; k++) r->set[k] = 0;
    r->steps += steps;
    r->unchecked += steps;
    r->estimate = estimate;
    return ST_OK;
}
