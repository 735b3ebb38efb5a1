/*
 * implicit_run.h (part of kernel.c): runs of genalpha's and ali3p's controlled steps
 * (integrators/implicit_control.py StepControl in adaptive.py's _advance_adaptive) in one
 * call, landing on the output time: the same attempts (implicit.h), error ratio, step
 * factors, commits, energy checks and counters as the Python loop, in the same order, so
 * the run is Python's bit for bit. Python takes over where the loop would leave the
 * kernel's cases: an attempt the kernel hands back (ST_SINGULAR, ST_SPRING), a commit that
 * fails (its error is raised there), the energy check's verdict, the step size failure.
 *
 * The drivers' motions come from the motion table (motions.h) at each step's end, or are
 * the constant `motion` of a scene without drivers; the force inputs `uf` are held over the
 * run (Python's runs: a scene without force inputs, integrators/implicit_runs.py
 * can_run; an FMU's wrapper: the held inputs).
 *
 * mbd_implicit_fast_step is such a run as an FMU's communication step taken by its wrapper
 * without Python (fmu_build/runtime real_cache.py FastSteps), landing on the communication
 * point and publishing the values there as the other fast steps do (outputs.h); any run
 * that does not reach it puts everything back and hands the doStep to Python. Force
 * inputs the master sets before a step (mbd_implicit_set, as adaptive.h's mbd_prk_set)
 * restart the method first as Python does (Simulation._reinitialize's projection,
 * Integrator.reset_state, ImplicitMethod.restart: q'' and lam of eq. (14), the angles
 * wrapped anew, a fresh iteration matrix, genalpha's a = q''; the step kept); only in
 * scenes without an energy audit, which such a restart would start. For a method named
 * with its step the wrapper's step is Integrator._advance_fixed instead (imp_fixed): the
 * grid, the energy check after each step, the stated accuracy's estimate charged and its
 * step-doubling checks taken as fixed.h does them for rk4p.
 */

typedef struct {
    double t, t_target, h, max_step;   /* the run's time, the output time, the next step */
    double share_tol;        /* ERROR_SHARE (atol + rtol L): a step of h may leave
                              * share_tol h / T_REF (implicit_control.py _error_ratio) */
    double safety, max_growth, max_cut, keep_growth;   /* implicit_control.py's factors */
    I max_work, rejections;  /* attempts this call may make; rejections in a row */
    I nsteps, nrejected, stepped;   /* counters of this call; a step was accepted */
    double divergence, roundoff;    /* the energy check's ENERGY_DIVERGENCE_FRACTION, ROUNDOFF */
    double *y, *x;           /* the state (5n + m: implicit.h's Y_*) and an attempt's x */
    double *motion;          /* (3m) the motion at the step's end */
    double *uf;              /* the force inputs, held (nf) */
    double *audit;           /* the energy audit's state, or NULL */
    double *work;            /* 3 (n + m): the error filter's right-hand side and solution */
    MotionTable mt;          /* nmotion 0: `motion` is constant */
} ImpRun;

/* StepControl._error_ratio: the local error (genalpha's or ali3p's _local_error), filtered
 * through the kept iteration matrix when it is valid, each body's angle times L, its
 * largest entry over what a step of hh may leave (NaN if any entry is NaN, as numpy's max). */
static double implicit_error_ratio(const Model *M, const Implicit *p, const ImpRun *r,
                                   const double *kept, double hh) {
    I n = S_(M, n), m = S_(M, m);
    const double *a_old = r->y + Y_A * n, *a_new = r->x + X_A * n;
    double *e = r->work, *rhs = e + n + m, *out = rhs + n + m;
    if (p->method == IMP_GENALPHA) {
        double c = fabs(p->beta + 0.5 * (p->am - p->af) - 1.0 / 6.0) * hh * hh;
        for (I k = 0; k < n; k++) e[k] = c * (a_new[k] - a_old[k]);
    } else {
        double c = hh * hh / 12.0;
        for (I k = 0; k < n; k++) e[k] = c * (a_new[k] - a_old[k]);
    }
    if (kept[KEPT_VALID] != 0.0) {
        Scratch s = scratch(M, M->work);
        for (int pass = 0; pass < (r->rejections > 0 ? 2 : 1); pass++) {
            for (I k = 0; k < n; k++) rhs[k] = M->mass[k] * e[k];
            for (I k = 0; k < m; k++) rhs[n + k] = 0.0;
            kept_solve(M, p, kept, rhs, rhs + n, out, out + n, s.qv, s.qv + m);
            e = out;
        }
    }
    double big = 0.0;
    int nan = 0;
    for (I k = 0; k < n; k++) {
        double v = fabs(k % 3 == 2 ? e[k] * p->length_scale : e[k]);
        if (isnan(v)) nan = 1;
        else if (v > big) big = v;
    }
    return nan ? NAN : big / (r->share_tol * hh / p->t_ref);
}

/* Controlled steps from r->t until r->t_target (landing on it), r->max_work attempts, or a
 * case Python takes: RUN_DONE, RUN_WORK, RUN_PYTHON (the next attempt is Python's, nothing
 * of it kept), RUN_ENERGY (the energy check failed after the last step: Python says why),
 * RUN_FAILED (the step size fell below the smallest, or too many rejections in a row). */
int mbd_implicit_run(const Model *M, Implicit *p, double *kept, ImpRun *r) {
    Scratch s = scratch(M, M->work);
    I n = S_(M, n), m = S_(M, m), attempts = 0;
    double *w = attempt_work(M, &s), *q = w + 14 * n + 3 * m;
    r->nsteps = r->nrejected = r->stepped = 0;
    while (r->t < r->t_target) {
        if (attempts >= r->max_work) return RUN_WORK;
        double h_min = MIN_STEP_RELATIVE * fmax(1.0, fabs(r->t));
        double proposal = fmin(r->h, r->max_step), h_next;
        I lands = 0;
        double hh = landing_step(proposal, r->t_target - r->t, &lands);
        if (r->mt.nmotion) motion_at(M, &r->mt, r->t + hh, r->motion);
        int st = attempt(M, p, &s, kept, r->y, hh, r->motion, r->uf, r->x, w);
        attempts++;
        int accepted = 0;
        if (st == ST_NEWTON) {
            h_next = 0.5 * hh;
        } else if (st != ST_OK) {
            return RUN_PYTHON;
        } else {
            double ratio = implicit_error_ratio(M, p, r, kept, hh);
            double factor = ratio > 0.0 ? r->safety / sqrt(ratio) : r->max_growth;
            if (ratio > 1.0) {
                h_next = hh * fmax(r->max_cut, fmin(factor, 0.9));
            } else {
                if (commit(M, p, &s, r->y, r->x, r->motion, q) != ST_OK) return RUN_PYTHON;
                factor = fmin(r->max_growth, factor);
                if (factor < r->keep_growth) factor = 1.0;
                h_next = hh * factor;
                accepted = 1;
            }
        }
        if (!accepted) {
            r->rejections++;
            r->nrejected++;
            r->h = h_next;
            if (h_next < h_min || r->rejections > MAX_REJECTIONS_IN_A_ROW) return RUN_FAILED;
            continue;
        }
        r->rejections = 0;
        r->nsteps++;
        r->stepped = 1;
        r->t = lands ? r->t_target : r->t + hh;
        r->h = hh < proposal && h_next >= hh ? proposal : h_next;
        if (r->audit && r->audit[A_ACTIVE] != 0.0 &&
                !energy_check(M, q, r->y + Y_QD * n, r->audit, r->divergence, r->roundoff))
            return RUN_ENERGY;
    }
    return RUN_DONE;
}

/* ---- an FMU's communication step (the wrapper's, see the header) --------------------------- */

/* q (n), unwrapped, of the state y: q wrapped plus 2 pi turns (Python's q). */
static void unwrapped(I n, const double *y, double *q) {
    for (I k = 0; k < n; k++) q[k] = y[k] + 2.0 * M_PI * y[Y_TURNS * n + k];
}

typedef struct {
    ImpRun run;              /* the run: its state run.y, its buffers and settings */
    Implicit *p;             /* the method's settings (their counters add up since armed) */
    double *kept;            /* the method's kept iteration matrix (nkept), shared */
    I nkept, naudit;         /* its size; the audit's (0: none) */
    double t_now, time_tol;  /* the FMU's time */
    I max_work;              /* attempts one doStep may take */
    double *save;            /* y, kept and audit at the doStep's start, put back if the
                              * run hands it to Python (with h, the estimate, the counters) */
    double *y2;              /* (q, q') at the step's end (2n) for the outputs */
    I steps, nsteps, nrejected, restarts;   /* since armed */
    I nout, npub; const I *pub_dst, *pub_src;
    double *V;               /* (outputs, q, q', q''), then lam */
    /* force inputs set by fmi2SetReal (mbd_implicit_set; nvr = 0: none may be set here) */
    I nvr; const I *vrs, *slots;   /* value reference of each settable input, its place in uf */
    I *set;                  /* nvr: 1 where set since the last step */
    I changed;               /* an input was set since the last step */
    double *uf_step;         /* the inputs the last step held (nf) */
    double tol; I max_iter;  /* the restart's position projection */
    /* a method named with its step (fixed: 1): Integrator._advance_fixed's grid of steps
     * of at most h_max (STEP_COUNT_SLACK, newton.SAME_STEP) and the stated accuracy's
     * estimate charged after each run of steps and its step-doubling checks (fixed.h's
     * est_charge and est_resample) */
    I fixed;
    double h_max, slack, same_step;
    Estimate *est;
    double *check;           /* a step-doubling check's room: y, kept, then q and q' (2n) */
} ImpFast;

int mbd_implicit_set(ImpFast *f, const unsigned int *vr, size_t nvr, const double *value,
                     double *values) {
    return set_force_inputs(f->nvr, f->vrs, f->slots, f->run.uf, f->set, &f->changed, vr, nvr,
                            value, values);
}

/* The restart after a force input was set (see the header), from the state in r->y at
 * f->t_now: ST_OK, or the status of the projection or eq. (14) that failed. */
static int imp_restart(const Model *M, ImpFast *f) {
    ImpRun *r = &f->run;
    I n = S_(M, n), m = S_(M, m);
    double *y = r->y, *q = f->y2, *qd = f->y2 + n;
    if (r->mt.nmotion) motion_at(M, &r->mt, f->t_now, r->motion);
    unwrapped(n, y, q);
    memcpy(qd, y + Y_QD * n, (size_t)n * sizeof(double));
    if (m) {
        int st = mbd_project_positions(M, q, r->motion, f->tol, f->max_iter);
        if (st == ST_OK) st = mbd_project_velocities(M, q, qd, r->motion, r->motion + m);
        if (st != ST_OK) return st;
    }
    int st = mbd_accelerations(M, q, qd, r->motion, r->motion + 2 * m, r->uf, y + Y_QDD * n,
                               y + Y_A * n + n);
    if (st != ST_OK) return st;
    for (I k = 0; k < n; k++) {
        double turn = f->p->periodic[k] != 0.0 ? floor((q[k] + M_PI) / (2.0 * M_PI)) : 0.0;
        y[k] = q[k] - 2.0 * M_PI * turn;
        y[Y_TURNS * n + k] = turn;
    }
    memcpy(y + Y_QD * n, qd, (size_t)n * sizeof(double));
    memcpy(y + Y_A * n, y + Y_QDD * n, (size_t)n * sizeof(double));
    memset(f->kept, 0, (size_t)f->nkept * sizeof(double));
    return ST_OK;
}

/* One step of hh ending at t_end, its input there, without the energy check (a check's
 * steps: CompiledNewton._step_impl's _c_run). */
static int imp_one(const Model *M, ImpFast *f, Scratch *s, double *w, double *q, double t_end,
                   double hh) {
    ImpRun *r = &f->run;
    if (r->mt.nmotion) motion_at(M, &r->mt, t_end, r->motion);
    int st = attempt(M, f->p, s, f->kept, r->y, hh, r->motion, r->uf, r->x, w);
    return st == ST_OK ? commit(M, f->p, s, r->y, r->x, r->motion, q) : st;
}

/* ErrorEstimate.spot_check at t: a step of hh and two of hh / 2 from the state, the
 * difference of their positions (q, unwrapped) and velocities times Richardson's factors
 * resampled, the state and the kept matrix put back as Python's rollback does (the work
 * stays counted). Not ST_OK: a step failed (Python's check then takes it on its path). */
static int imp_check(const Model *M, ImpFast *f, Scratch *s, double *w, double *q, double t,
                     double hh) {
    ImpRun *r = &f->run;
    Estimate *E = f->est;
    I n = S_(M, n), ny = 5 * n + S_(M, m);
    double *saved = f->check, *one = saved + ny + f->nkept, *y = r->y;
    memcpy(saved, y, (size_t)ny * sizeof(double));
    memcpy(saved + ny, f->kept, (size_t)f->nkept * sizeof(double));
    int st = imp_one(M, f, s, w, q, t + hh, hh);
    if (st == ST_OK) {
        memcpy(one, q, (size_t)n * sizeof(double));
        memcpy(one + n, y + Y_QD * n, (size_t)n * sizeof(double));
        memcpy(y, saved, (size_t)ny * sizeof(double));
        memcpy(f->kept, saved + ny, (size_t)f->nkept * sizeof(double));
        st = imp_one(M, f, s, w, q, t + 0.5 * hh, 0.5 * hh);
        if (st == ST_OK) st = imp_one(M, f, s, w, q, (t + 0.5 * hh) + 0.5 * hh, 0.5 * hh);
    }
    if (st == ST_OK) {
        double dq = 0.0, dv = 0.0;
        for (I i = 0; i < n; i++) {
            dq = fmax(dq, fabs(one[i] - q[i]));
            dv = fmax(dv, fabs(one[n + i] - y[Y_QD * n + i]));
        }
        est_resample(E, t, hh, E->factor_q * dq, E->carry ? E->factor_v * dv : 0.0);
        E->unchecked = E->since = 0;
        E->checks += 1;
    }
    memcpy(y, saved, (size_t)ny * sizeof(double));
    memcpy(f->kept, saved + ny, (size_t)f->nkept * sizeof(double));
    return st;
}

/* Integrator._advance_fixed from f->t_now to end with CompiledNewton's runs of steps
(implicit_c.py _run_steps: each step's inputs at (t0 + h (j - 1)) + h, as stage_inputs
 gets them), the energy check after each step, the estimate charged after each run:
 RUN_DONE, or RUN_PYTHON for anything Python must do (a step the kernel hands back or
 whose Newton iteration fails, a check's too, more steps than the work limit allows, the
 energy check or the estimate stopping the run). */
static int imp_fixed(const Model *M, ImpFast *f, double end) {
    ImpRun *r = &f->run;
    Estimate *E = f->est;
    Scratch s = scratch(M, M->work);
    I n_coord = S_(M, n), m = S_(M, m);
    double *w = attempt_work(M, &s), *q = w + 14 * n_coord + 3 * m;
    double t0 = f->t_now, span = end - t0;
    double steps = ceil(span / f->h_max - f->slack);
    I n = steps < 1.0 ? 1 : (I)steps;
    double hh = span / (double)n;
    if (fabs((double)n * f->h_max - span) <= f->same_step * span) hh = f->h_max;
    if (n > f->max_work) return RUN_PYTHON;
    for (I k = 0; k < n;) {
        if (E->unchecked >= E->every &&
                imp_check(M, f, &s, w, q, t0 + hh * (double)k, hh) != ST_OK)
            return RUN_PYTHON;
        I run = n - k, room = E->every - E->unchecked;
        if (room < 1) room = 1;
        if (run > room) run = room;
        for (I j = k + 1; j <= k + run; j++) {
            if (r->mt.nmotion) motion_at(M, &r->mt, (t0 + hh * (double)(j - 1)) + hh, r->motion);
            int st = attempt(M, f->p, &s, f->kept, r->y, hh, r->motion, r->uf, r->x, w);
            if (st == ST_OK) st = commit(M, f->p, &s, r->y, r->x, r->motion, q);
            if (st != ST_OK) return RUN_PYTHON;
            E->nsteps++;
            r->nsteps++;
            if (r->audit && r->audit[A_ACTIVE] != 0.0 &&
                    !energy_check(M, q, r->y + Y_QD * n_coord, r->audit, r->divergence,
                                  r->roundoff))
                return RUN_PYTHON;
        }
        k += run;
        if (!est_charge(E, k < n ? t0 + (double)k * hh : end, hh)) return RUN_PYTHON;
    }
    r->t = end;
    return RUN_DONE;
}

static void imp_save(const Model *M, ImpFast *f, int back) {
    I ny = 5 * S_(M, n) + S_(M, m);
    double *to[3] = {f->save, f->save + ny, f->save + ny + f->nkept};
    double *from[3] = {f->run.y, f->kept, f->run.audit};
    I size[3] = {ny, f->nkept, f->naudit};
    for (int k = 0; k < 3; k++)
        if (size[k]) {
            if (back) memcpy(from[k], to[k], (size_t)size[k] * sizeof(double));
            else memcpy(to[k], from[k], (size_t)size[k] * sizeof(double));
        }
}

int mbd_implicit_fast_step(const Model *M, ImpFast *f, double t, double hc, double *values) {
    if (!(fabs(t - f->t_now) <= f->time_tol * fmax(fabs(t), fabs(f->t_now)))) return ST_ERROR_NORM;
    ImpRun *r = &f->run;
    Implicit *p = f->p;
    I n = S_(M, n), counts[4] = {p->nnewton, p->njev, p->nlu, p->nprojections};
    double h = r->h;
    imp_save(M, f, 0);
    int st = f->changed ? imp_restart(M, f) : ST_OK;
    if (st != ST_OK) {
        imp_save(M, f, 1);
        return ST_ERROR_NORM;
    }
    Estimate est_before;
    if (f->fixed) est_before = *f->est;
    r->t = f->t_now;
    r->t_target = t + hc;
    r->rejections = 0;
    r->max_work = f->max_work;
    r->nsteps = r->nrejected = 0;
    st = f->fixed ? imp_fixed(M, f, t + hc) : mbd_implicit_run(M, p, f->kept, r);
    if (st == RUN_DONE) {
        Scratch s = scratch(M, M->work);
        unwrapped(n, r->y, f->y2);
        memcpy(f->y2 + n, r->y + Y_QD * n, (size_t)n * sizeof(double));
        if (r->mt.nmotion) motion_at(M, &r->mt, r->t, r->motion);
        st = publish_step_end(M, &s, f->y2, r->motion, r->uf, f->nout, f->npub, f->pub_src,
                              f->pub_dst, f->V, values) == ST_OK ? RUN_DONE : RUN_PYTHON;
    }
    if (st != RUN_DONE) {       /* Python takes this doStep from where it began */
        imp_save(M, f, 1);
        if (f->fixed) *f->est = est_before;
        r->h = h;
        p->nnewton = counts[0];
        p->njev = counts[1];
        p->nlu = counts[2];
        p->nprojections = counts[3];
        return ST_ERROR_NORM;
    }
    f->restarts += f->changed;
    f->changed = 0;
    for (I k = 0; k < f->nvr; k++) f->set[k] = 0;
    if (S_(M, nf)) memcpy(f->uf_step, r->uf, (size_t)S_(M, nf) * sizeof(double));
    f->t_now = r->t;
    f->steps += 1;
    f->nsteps += r->nsteps;
    f->nrejected += r->nrejected;
    return ST_OK;
}
