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
 * the constant `motion` of a scene without drivers; the scene has no force inputs (the
 * caller checks: integrators/implicit_c.py implicit_runs).
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
    double *audit;           /* the energy audit's state, or NULL */
    double *work;            /* 3 (n + m): the error filter's right-hand side and solution */
    MotionTable mt;          /* nmotion 0: `motion` is constant */
} ImpRun;

/* StepControl._error_ratio: the local error (genalpha's or ali3p's _local_error), filtered
 * through the kept iteration matrix when it is valid, each body's angle times L, its
 * largest entry over what a step of hh may leave (NaN if any entry is NaN, as numpy's max). */
static double implicit_error_ratio(const Model *M, const Implicit *p, const ImpRun *r,
                                   const double *kept, double hh) {
    I n = M->n, m = M->m;
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
        for (I k = 0; k < n; k++) rhs[k] = M->mass[k] * e[k];
        for (I k = 0; k < m; k++) rhs[n + k] = 0.0;
        kept_solve(M, p, kept, rhs, rhs + n, out, out + n, s.qv, s.qv + m);
        e = out;
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
    I n = M->n, m = M->m, attempts = 0;
    double *w = attempt_work(M, &s), *q = w + 14 * n + 3 * m;
    r->nsteps = r->nrejected = r->stepped = 0;
    while (r->t < r->t_target) {
        if (attempts >= r->max_work) return RUN_WORK;
        double h_min = MIN_STEP_RELATIVE * fmax(1.0, fabs(r->t));
        double proposal = fmin(r->h, r->max_step), h_next;
        I lands = 0;
        double hh = landing_step(proposal, r->t_target - r->t, &lands);
        if (r->mt.nmotion) motion_at(M, &r->mt, r->t + hh, r->motion);
        int st = attempt(M, p, &s, kept, r->y, hh, r->motion, NULL, r->x, w);
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
