/*
 * fixed.h (part of kernel.c): an FMU's communication step of rk4p taken by its wrapper
 * without Python (fmu_build/runtime real_cache.py FastSteps), for scenes whose drivers
 * follow motions the kernel evaluates (constant, linear, harmonic, or positions the master
 * sets: motions.h) and whose force inputs are held or set by the master before a step
 * (mbd_fixed_set: fmi2SetReal of an input taken by the wrapper, then the restart as
 * Simulation._reinitialize does it: after a force, no projection, the constraints do not
 * depend on forces and the last step ended projected; after a driver's position, the
 * projection onto its new motion, drivers_restart).
 *
 * The arithmetic is Python's, in the same order: the grid of Integrator.fixed_grid (equal
 * steps no longer than h_max up to t + h, times t0 + j step), motion.py's evaluate() at
 * each stage time (c_steps.stage_inputs), rk4p_step, then the output vector at t + h
 * (Simulation.output_vector). The slave takes the state the steps reached when it catches
 * up (ckernel/fixed.py), so every value served is the one Python would have computed.
 *
 * The stated accuracy's step-doubling checks (stated_accuracy.py ErrorEstimate, the
 * reference: its checks, envelope, charges and interval) are taken here too, in the loop
 * of Integrator._advance_fixed (fixed_loop), for the wrapper's steps and for rk4p's runs
 * (mbd_fixed_advance), so neither leaves C for them.
 */

typedef struct {
    double t_now, time_tol;  /* the FMU's time (the integrator's: rk4p has no dense output) */
    double h_max, slack;     /* Integrator.fixed_grid: the method's step, STEP_COUNT_SLACK */
    I max_steps;             /* the work limit's steps per doStep (or a huge number) */
    double tol; I max_iter;  /* the position projection */
    MotionTable mt;          /* the drivers' motions (motions.h) */
    double *ufs;             /* the held force inputs, three times (3 nf) */
    double *y, *f, *save;    /* the state (2n each) and f = y'; a copy to roll back */
    double *motions;         /* (3, 3m): one step's stage inputs; then (3m) at t + h */
    I steps;                 /* steps taken since the slave armed this */
    I nout, npub;            /* values[pub_dst[k]] = V[pub_src[k]] after a step ... */
    const I *pub_dst, *pub_src;
    double *V;               /* ... V = (outputs, q, q', q''): nout + 3n; then lam (m) */
    /* force inputs set by fmi2SetReal (mbd_fixed_set; nvr = 0: none may be set here) */
    double *uf;              /* the force inputs as set (nf) */
    I nvr; const I *vrs, *slots;   /* value reference of each settable input, its place in uf */
    I *set;                  /* nvr: 1 where set since the last step */
    I changed;               /* an input was set since the last step */
    I restarts;              /* steps since armed that began with a restart */
    struct Estimate *est;    /* the step-doubling estimate (ErrorEstimate) */
    double *check;           /* a check's room: y and f saved (4n), then its one step (2n) */
    double *audit;           /* the energy check's state (A_FIELDS), or NULL; in the
                              * wrapper's steps followed by its copy at the doStep's start */
    double divergence, roundoff;  /* ... its ENERGY_DIVERGENCE_FRACTION, ENERGY_ROUNDOFF */
    double *kept;            /* the last step's end for the restart (keep_step_end) */
    EventWatch ev;           /* a contact mode's event functions (events.h), or none: set
                              * anew at each arm, as a doStep handed back is followed by one */
    SampledSet sd;           /* drivers whose position the master sets (motions.h) */
} FixedRun;

/* stated_accuracy.ErrorEstimate: its fields, the run's step count (Counters.nsteps) and
 * the rule's constants as Python gives them (SPOT_CHECK_*, Richardson's factors, the
 * allowance), so that the rule is written once here and once, the reference, there. */
typedef struct Estimate {
    double local, local_v, sum_q, sum_v, sum_vt;
    I charged, unchecked, every, since;
    I nsteps, checks;        /* stats.nsteps; checks done (three steps' work each) */
    double estimate;         /* stats.error_estimate */
    double allowed, floor;   /* allowed_error; SPOT_CHECK_FLOOR times it */
    double factor_q, factor_v; I carry;  /* richardson_factor of orders; carry_velocity_error */
    I first, share, most;    /* SPOT_CHECK_EVERY, _SHARE, _MAX */
    double change, decay;    /* SPOT_CHECK_CHANGE, _DECAY */
} Estimate;

/* ErrorEstimate._add: steps steps of h ending at t charged with dq and dv. */
static void est_add(Estimate *E, double t, double h, I steps, double dq, double dv) {
    double k = (double)steps;
    E->sum_q += dq * k;
    E->sum_v += dv * k;
    E->sum_vt += dv * k * (t - 0.5 * k * h);
}

static I est_imin(I a, I b) { return a < b ? a : b; }
static I est_imax(I a, I b) { return a > b ? a : b; }

/* ErrorEstimate._resample: a check's local errors at t into the envelope, the steps since
 * the last check charged with what it adds, the interval to the next check. */
static void est_resample(Estimate *E, double t, double h, double local, double local_v) {
    double env_q = fmax(local, E->decay * E->local);
    double env_v = fmax(local_v, E->decay * E->local_v);
    int rising = local > fmax(E->change * E->local, E->floor)
                 || local_v > fmax(E->change * E->local_v, E->floor);
    est_add(E, t, h, E->since, fmax(0.0, env_q - E->local), fmax(0.0, env_v - E->local_v));
    E->local = env_q;
    E->local_v = env_v;
    I grow = est_imin(E->most, est_imax(E->first, E->nsteps / E->share));
    E->every = rising ? est_imax(1, E->every / 2) : est_imin(grow, 2 * E->every);
}

/* ErrorEstimate.charge at t: 0 (nothing changed) when the estimate would exceed the
 * allowance, for Python's charge to stop the run with its message. */
static int est_charge(Estimate *E, double t, double h) {
    Estimate c = *E;
    I done = c.nsteps - c.charged;
    c.charged = c.nsteps;
    c.unchecked += done;
    c.since += done;
    est_add(&c, t, h, done, c.local, c.local_v);
    double estimate = c.sum_q + fmax(0.0, t * c.sum_v - c.sum_vt);
    if (estimate > c.allowed) return 0;
    c.estimate = estimate;
    *E = c;
    return 1;
}

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

/* Doubles of FixedRun.kept (and PrkRun.kept): a flag, y (2n) and the motion (3m) at the
 * last step's end, Psi_q's values (nkeep) and gamma (m) there, the band factor of S
 * (2 (kd + 1) m). */
I mbd_fixed_kept_size(const Model *M) {
    return 1 + 2 * S_(M, n) + 3 * S_(M, m) + S_(M, nkeep) + S_(M, m)
           + 2 * (S_(M, kd) + 1) * S_(M, m);
}

/* After a step to y at motion (c, c', c'') whose q'' was solved by the band factor its
 * velocity projection kept (s->kept; s holds that evaluation's values and gamma): what
 * eq. (14) at y needs besides the forces, into kept, for a restart there after a force
 * input was set. */
static void keep_end(const Model *M, double *kept, const double *y, const double *motion,
                     const Scratch *s) {
    I n2 = 2 * S_(M, n), m = S_(M, m);
    double *p = kept;
    if (!p) return;
    p[0] = (s->kept && m > 0) ? 1.0 : 0.0;
    if (p[0] == 0.0) return;
    memcpy(p + 1, y, (size_t)n2 * sizeof(double)); p += 1 + n2;
    memcpy(p, motion, (size_t)(3 * m) * sizeof(double)); p += 3 * m;
    memcpy(p, s->values, (size_t)S_(M, nkeep) * sizeof(double)); p += S_(M, nkeep);
    memcpy(p, s->gamma, (size_t)m * sizeof(double)); p += m;
    memcpy(p, s->band, (size_t)(2 * (S_(M, kd) + 1) * m) * sizeof(double));
}

/* Psi_q's values kept for the state y at motion (checked bit for bit), or NULL (also
 * when kept is NULL: nothing is kept). */
static const double *kept_values(const Model *M, const double *kept, const double *y,
                                 const double *motion) {
    I n2 = 2 * S_(M, n), m = S_(M, m);
    if (!kept || kept[0] == 0.0 || memcmp(kept + 1, y, (size_t)n2 * sizeof(double)) ||
            memcmp(kept + 1 + n2, motion, (size_t)(3 * m) * sizeof(double)))
        return NULL;
    return kept + 1 + n2 + 3 * m;
}

/* eq. (14) at the state y and motion keep_end kept with the force inputs uf: q'' (n) by
 * solve_with_factor with Psi_q, gamma and S's factor as they were (they do not depend on
 * forces), so q'' and lam are those of a whole evaluation. 0: nothing kept for this
 * state, the caller evaluates it all. */
static int solve_kept(const Model *M, const double *kept, const double *y,
                      const double *motion, const double *uf, Scratch *s, double *qdd) {
    I n = S_(M, n), m = S_(M, m);
    const double *values = kept_values(M, kept, y, motion), *q = y, *qd = y + n;
    if (!values || S_(M, nslide)) return 0;     /* sliding friction iterates: a whole evaluation */
    const double *gamma = values + S_(M, nkeep), *band = gamma + m, *cdd = motion + 2 * m;
    if (forces(M, q, qd, uf, s->F) != ST_OK) return 0;
    solve_with_factor(M, s, values, gamma, band, cdd, qdd, s->lam);
    memo_store(M, q, qd, motion, cdd, uf, qdd, s->lam);
    return 1;
}

/* After a doStep's steps (the last thing fixed_loop did was a step). */
static void keep_step_end(const Model *M, FixedRun *r, const Scratch *s) {
    keep_end(M, r->kept, r->y, r->motions + 6 * S_(M, m), s);
}

/* The restart's eq. (14) from what keep_step_end kept; 0: evaluate it all. */
static int restart_kept(const Model *M, FixedRun *r, Scratch *s) {
    return solve_kept(M, r->kept, r->y, r->motions, r->uf, s, r->f + S_(M, n));
}

/* After a force input was set: the restart's f = (q', q'') at t0 with the new inputs (the
 * state as it is, Simulation._reinitialize); the inputs then held over the step's stages. */
static int fixed_restart(const Model *M, FixedRun *r, Scratch *s, double t0) {
    I n = S_(M, n), m = S_(M, m), nf = S_(M, nf);
    motion_at(M, &r->mt, t0, r->motions);
    memcpy(r->f, r->y + n, (size_t)n * sizeof(double));
    int st = restart_kept(M, r, s) ? ST_OK :
        mbd_accelerations(M, r->y, r->y + n, r->motions, r->motions + 2 * m, r->uf, r->f + n,
                          s->lam);
    if (st != ST_OK) return st;
    for (I row = 0; row < 3; row++)
        if (nf) memcpy(r->ufs + row * nf, r->uf, (size_t)nf * sizeof(double));
    return ST_OK;
}

/* After a driver's set: Simulation._reinitialize's restart, (q, q') projected onto the
 * constraints at t0 with the new motion (drivers_project), then f there (reset_state). */
static int drivers_restart(const Model *M, FixedRun *r, Scratch *s, double t0) {
    motion_at(M, &r->mt, t0, r->motions);
    int st = drivers_project(M, s, &r->sd, r->y, r->motions);
    return st == ST_OK ? fixed_restart(M, r, s, t0) : st;
}

/* One rk4p step of h from start on the run's state (motions evaluated here). */
static int fixed_one(const Model *M, FixedRun *r, Scratch *s, double start, double h,
                     double *K, double *ys) {
    I m = S_(M, m);
    motion_at(M, &r->mt, start, r->motions);
    motion_at(M, &r->mt, start + 0.5 * h, r->motions + 3 * m);
    motion_at(M, &r->mt, start + h, r->motions + 6 * m);
    return rk4p_step(M, s, r->y, r->f, h, r->motions, r->ufs, r->tol, r->max_iter, K, ys);
}

/* ErrorEstimate.spot_check at t: a step of h and two of h/2 from the state (kept), their
 * differences times Richardson's factors resampled. Not ST_OK: a step failed, nothing
 * changed (Python's check then takes it on its own path). */
static int est_check(const Model *M, FixedRun *r, Scratch *s, Estimate *E, double t,
                     double h, double *K, double *ys) {
    I n = S_(M, n), n2 = 2 * n;
    double *saved = r->check, *one = saved + 2 * n2;
    memcpy(saved, r->y, (size_t)n2 * sizeof(double));
    memcpy(saved + n2, r->f, (size_t)n2 * sizeof(double));
    int st = fixed_one(M, r, s, t, h, K, ys);
    if (st == ST_OK) {
        memcpy(one, r->y, (size_t)n2 * sizeof(double));
        memcpy(r->y, saved, (size_t)n2 * sizeof(double));
        memcpy(r->f, saved + n2, (size_t)n2 * sizeof(double));
        st = fixed_one(M, r, s, t, 0.5 * h, K, ys);
        if (st == ST_OK) st = fixed_one(M, r, s, t + 0.5 * h, 0.5 * h, K, ys);
    }
    if (st == ST_OK) {
        double dq = 0.0, dv = 0.0;
        for (I i = 0; i < n; i++) {
            dq = fmax(dq, fabs(one[i] - r->y[i]));
            dv = fmax(dv, fabs(one[n + i] - r->y[n + i]));
        }
        est_resample(E, t, h, E->factor_q * dq, E->carry ? E->factor_v * dv : 0.0);
        E->unchecked = E->since = 0;
        E->checks += 1;
    }
    memcpy(r->y, saved, (size_t)n2 * sizeof(double));
    memcpy(r->f, saved + n2, (size_t)n2 * sizeof(double));
    return st;
}

#define ST_CHECK 16      /* a check's step failed: Python takes this turn of the loop */
#define ST_ESTIMATE 17   /* the next charge exceeds the allowance: Python's stops the run */
#define ST_EVENT 18      /* a step changed an event function's sign: Python locates it */

/* Integrator._advance_fixed's loop over the grid t0 + j step (n steps, the last ending at
 * end) from step *k, until a turn of it ends at or past step `pause`: a check when due,
 * the steps to the next (after each the event runner's watch with r->ev, then the energy
 * check with r->audit, in Python's order), their charge. ST_OK at the end of a turn;
 * ST_CHECK at its start; ST_ESTIMATE with the turn's steps taken (up to *stop) and not
 * charged; ST_EVENT (or ST_ERROR_NORM where the event functions cannot be evaluated) and
 * ST_ENERGY after step *k, a step's failure at it, all with the turn's steps before it
 * taken and not charged (Python takes the rest). */
static int fixed_loop(const Model *M, FixedRun *r, Scratch *s, Estimate *E, double t0,
                      double step, I n, double end, I pause, I *k, I *stop) {
    I n2 = 2 * S_(M, n);
    double *K = s->qv, *ys = K + 4 * n2;
    while (*k < n && *k < pause) {
        if (E->unchecked >= E->every &&
                est_check(M, r, s, E, t0 + step * (double)*k, step, K, ys) != ST_OK)
            return ST_CHECK;
        *stop = *k + est_imin(n - *k, est_imax(1, E->every - E->unchecked));
        while (*k < *stop) {
            int st = fixed_one(M, r, s, t0 + step * (double)*k, step, K, ys);
            if (st != ST_OK) return st;
            *k += 1;
            E->nsteps += 1;
            if (r->ev.nevent) {
                int crossed = events_crossed(M, &r->ev, r->motions + 6 * S_(M, m),
                                             r->ufs + 2 * S_(M, nf), s, r->y);
                if (crossed) return crossed > 0 ? ST_EVENT : ST_ERROR_NORM;
            }
            if (r->audit != NULL && r->audit[A_ACTIVE] != 0.0 &&
                    !energy_check(M, r->y, r->y + S_(M, n), r->audit, r->divergence, r->roundoff))
                return ST_ENERGY;
        }
        if (!est_charge(E, *k < n ? t0 + step * (double)*k : end, step)) return ST_ESTIMATE;
    }
    return ST_OK;
}

/* RK4P._advance_fixed's loop in C for a Simulation's run (integrators/rk4p_c.py): r's
 * state, E and r->audit updated; the status and *k, *stop as fixed_loop's. */
int mbd_fixed_advance(const Model *M, FixedRun *r, double t0, double step, I n, double end,
                      I pause, I *k, I *stop) {
    Scratch s = scratch(M, M->work);
    return fixed_loop(M, r, &s, r->est, t0, step, n, end, pause, k, stop);
}

/* The wrapper's doStep from t over h: the steps of the grid with the checks due among
 * them, V and values filled, t_now moved; non-zero (nothing changed) when Python must
 * take it: another time, more steps than allowed, an estimated error beyond the stated
 * accuracy, a check's step failing, or whatever the kernel hands back (Python then
 * redoes the step and says why). */
int mbd_fixed_step(const Model *M, FixedRun *r, double t, double h, double *values) {
    I n = S_(M, n), n2 = 2 * n;
    if (!(fabs(t - r->t_now) <= r->time_tol * fmax(fabs(t), fabs(r->t_now)))) return ST_ERROR_NORM;
    double t0 = r->t_now, end = t + h;
    if (!(end > t0)) return ST_ERROR_NORM;
    double count = ceil((end - t0) / r->h_max - r->slack);
    if (!(count <= (double)r->max_steps)) return ST_ERROR_NORM;
    I steps = count < 1.0 ? 1 : (I)count;
    double step = (end - t0) / (double)steps;
    Scratch s = scratch(M, M->work);
    memcpy(r->save, r->y, (size_t)n2 * sizeof(double));
    memcpy(r->save + n2, r->f, (size_t)n2 * sizeof(double));
    Estimate E = *r->est;     /* kept only when the whole step is */
    if (r->audit)             /* the energy check's state too: the slave takes it back */
        memcpy(r->audit + A_FIELDS, r->audit, A_FIELDS * sizeof(double));
    int moved = r->changed ? drivers_apply(&r->sd, &r->mt, r->nvr, r->set, r->slots, r->uf, t0)
                           : 0;
    int st = moved < 0 ? ST_ERROR_NORM : moved ? drivers_restart(M, r, &s, t0) :
             r->changed ? fixed_restart(M, r, &s, t0) : ST_OK;
    if (st == ST_OK && r->changed && r->ev.nevent) {   /* events from the restart */
        int released = events_restart(M, &r->ev, r->motions, r->uf, &s, r->y);
        if (released) st = released > 0 ? ST_EVENT : ST_ERROR_NORM;
    }
    I k = 0, stop = 0;
    if (st == ST_OK) st = fixed_loop(M, r, &s, &E, t0, step, steps, end, steps, &k, &stop);
    if (st == ST_OK) keep_step_end(M, r, &s);
    if (st == ST_OK) {
        motion_at(M, &r->mt, end, r->motions);
        st = publish_step_end(M, &s, r->y, r->motions, r->ufs, r->nout, r->npub, r->pub_src,
                              r->pub_dst, r->V, values);
    }
    if (st != ST_OK) {
        memcpy(r->y, r->save, (size_t)n2 * sizeof(double));
        memcpy(r->f, r->save + n2, (size_t)n2 * sizeof(double));
        if (r->audit) memcpy(r->audit, r->audit + A_FIELDS, A_FIELDS * sizeof(double));
        if (moved > 0) drivers_undo(&r->sd, &r->mt);
        return st;
    }
    r->t_now = end;
    r->restarts += r->changed;
    r->changed = 0;
    for (I j = 0; j < r->nvr; j++) r->set[j] = 0;
    r->steps += steps;
    *r->est = E;
    return ST_OK;
}
