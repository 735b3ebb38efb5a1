/*
 * adaptive.h (part of kernel.c): an FMU's communication step of an embedded pair (rk45p,
 * dop853p) landing on the communication point, taken by its wrapper without Python, with
 * the force inputs the master sets before every step (fmu_build/runtime real_cache.py
 * FastSteps: fmi2SetReal of those inputs lands in PrkRun.uf without Python either).
 *
 * The decisions are Python's, in the same order and arithmetic: Simulation._reinitialize
 * and ProjectedRK.restart after a force input was set (q'' and the singularity
 * indicator; no projection: the constraints do not depend on forces),
 * AdaptiveStepping._advance_adaptive without dense output (landing, the controller's
 * proposal kept after a step cut short, rejections), c_steps.prk_attempt's
 * step factors. Anything else (a step near a singular configuration, where
 * singular_zone.py plans, a case the kernel hands back, too many rejections, the work
 * limit) returns non-zero with nothing changed, and Python takes the step and says why.
 * For scenes without an energy audit (non-conservative forces). With drivers, their
 * motions at each stage's time from the motion table (motions.h), and a driver position
 * the master sets taken as fixed.h takes it: applied at the step, then the restart's
 * projection. In a scene with end stops or friction, in the current contact mode with its
 * event functions checked after each step (events.h, at the step's end motion), a step
 * that changes a sign handing the doStep back.
 * Under auto (stiff_limit > 0, dop853p), a step that auto's stiffness rule would count
 * (auto_watch.stiffness above stiff_limit) hands the doStep back to Python as well.
 */

#define NEAR_ZONE 0.1                 /* singular_zone.NEAR_ZONE */
#define MIN_STEP_RELATIVE 1e-13       /* adaptive.py */
#define MAX_REJECTIONS_IN_A_ROW 60
#define LAND_STRETCH 1.01
#define LAND_SPLIT 1.5
#define ERR_OLD_MIN 1e-4              /* adaptive.py */

typedef struct {
    double t_now, time_tol;
    double h, max_step;            /* Integrator.h (the controller's proposal), max_step */
    I ns; const double *A, *B, *E, *E3;   /* the pair (c_steps.tableau) */
    double exponent, safety, min_factor, max_factor;   /* exponent: -alpha */
    double beta, err_old;          /* the PI controller's (adaptive.py), its memory */
    double rtol, atol;             /* local_tolerance times the method's */
    double tol; I max_iter;        /* the projection after a step */
    double indicator;              /* zone.indicator at t_now */
    I landing;                     /* zone.landing of the last step */
    I max_work;                    /* steps (accepted or not) one doStep may take */
    double *motion;                /* (c, c', c'') of every row: constant without drivers;
                                    * with them, at the time of a restart or the end */
    double *motions, *ufs;         /* (ns + 1) rows of each: a trial's stage inputs */
    double *uf;                    /* the force inputs as set (nf) */
    I nvr; const I *vrs, *slots;   /* value reference of each settable input, its place in uf */
    I *set;                        /* nvr: 1 where set since the last step */
    I changed;                     /* an input was set since the last step */
    double *uf_step;               /* the inputs the last step took (nf) */
    double *y, *f, *y1, *f1;       /* the state (2n) and f = y'; working copies */
    double *K, *y_new, *f_new;     /* prk_trial's stages ((ns + 1) 2n) and results */
    I steps, nsteps, nrejected, naccel, nprojections;   /* since armed */
    I nout, npub; const I *pub_dst, *pub_src;
    double *V;                     /* (outputs, q, q', q''), then lam */
    double stiff_limit;            /* > 0: auto's watch; Hairer's h |lambda| at most this */
    double *kept;                  /* the last accepted step's end (keep_end) */
    EventWatch ev;                 /* a contact mode's event functions after each step
                                    * (events.h), or none */
    MotionTable mt;                /* the drivers' motions (nmotion 0: none, `motion` holds) */
    const double *fractions;       /* the stages' times in a step, then 1 (c_steps.tableau) */
    SampledSet sd;                 /* drivers whose position the master sets (motions.h) */
    I skip_end;                    /* 1: the trials leave out y' at their unprojected end
                                    * (prk_trial), which nothing reads: mbd_prk_run's
                                    * (ProjectedRK.skip_end) and the wrapper's steps
                                    * (c_steps.fast_prk_run) */
} PrkRun;

/* auto_watch.stiffness, Hairer's h |lambda| of a step of the pair (ns stages, A (ns, ns),
 * B) from y over hh with stages K ((ns + 1) rows of n2, the last f at the unprojected end):
 * h ||K_ns - K_s|| / ||y_end - y_s||, y_s the stage at C = 1 (s = ns - 1), y_end the end
 * before the projection; 0 when y_end = y_s. Python calls this function too, so that the
 * watcher of auto and this file's steps count the same steps (y_end - y_s is often at the
 * round-off of y: another summation order would change it in its leading digits). */
double mbd_stiff_h_lambda(I ns, const double *A, const double *B, I n2, const double *K,
                          const double *y, double hh) {
    I st = ns - 1;
    double num = 0.0, den = 0.0;
    for (I k = 0; k < n2; k++) {
        double b = 0.0, a = 0.0;
        for (I j = 0; j < ns; j++) b += K[j * n2 + k] * B[j];
        for (I j = 0; j < st; j++) a += K[j * n2 + k] * A[st * ns + j];
        double d = (y[k] + hh * b) - (y[k] + hh * a), e = K[ns * n2 + k] - K[st * n2 + k];
        den += d * d;
        num += e * e;
    }
    return den > 0.0 ? hh * sqrt(num) / sqrt(den) : 0.0;
}

/* fmi2SetReal of inputs the kernel holds (fixed.h's set_force_inputs). */
int mbd_prk_set(PrkRun *r, const unsigned int *vr, size_t nvr, const double *value,
                double *values) {
    return set_force_inputs(r->nvr, r->vrs, r->slots, r->uf, r->set, &r->changed, vr, nvr,
                            value, values);
}

/* The landing step's size towards end (AdaptiveStepping._landing); *lands: it ends there. */
static double landing_step(double proposal, double remaining, I *lands) {
    *lands = 0;
    if (LAND_STRETCH * proposal >= remaining) { *lands = 1; return remaining; }
    if (remaining < LAND_SPLIT * proposal) return 0.5 * remaining;
    return proposal;
}

/* adaptive.accepted_step: the PI controller's step after an accepted one */
static double accepted_step(const PrkRun *r, double hh, double err, double err_old) {
    if (err == 0.0) return hh * r->max_factor;
    return hh * fmin(r->max_factor, r->safety * pow(err, r->exponent) * pow(err_old, r->beta));
}

/* One trial step from (y, f) (prk_attempt): 1 accepted, 0 rejected, -1 Python's case;
 * err_old the PI controller's memory, *h_next its next step, *c1 the indicator at the
 * step's end, *err_out the error norm. */
static int prk_try(const Model *M, PrkRun *r, Scratch *s, const double *y, const double *f,
                   double hh, double err_old, double *h_next, double *c1, double *err_out,
                   I *naccel, I *nproj) {
    I ns = r->ns, evals = r->skip_end ? ns - 1 : ns;
    double err = 0.0;
    int kept = 0;
    /* the indicator at the start is at least NEAR_ZONE (checked before), so the trial's
     * error estimate is the plain one unless *c1 < NEAR_ZONE, which hands the step back;
     * y' at the unprojected end only where something reads it (skip_end: c_steps.
     * fast_prk_run; these steps keep no dense output) */
    int st = prk_trial(M, ns, r->A, r->B, r->E, r->E3, hh, y, f, r->motions, r->ufs, r->rtol,
                       r->atol, r->tol, r->max_iter, r->y_new, r->f_new, &err, r->K,
                       INFINITY, c1, &kept, !r->skip_end);
    if (st == ST_SINGULAR || st == ST_SPRING || st == ST_PROJECTION) return -1;
    if (st == ST_NOT_FINITE) { *naccel += evals; *h_next = hh * r->min_factor; return 0; }
    if (*c1 < NEAR_ZONE) return -1;    /* the indicator at the step's end, before projecting */
    *naccel += evals;
    if (st == ST_ERROR_NORM) {
        *h_next = hh * fmax(r->min_factor, r->safety * pow(err, r->exponent));
        return 0;
    }
    *nproj += 1;
    *naccel += 1;
    *h_next = accepted_step(r, hh, err, err_old);
    *err_out = err;
    s->kept = kept;         /* the trial's scratch is this one: keep what a restart needs */
    keep_end(M, r->kept, r->y_new, r->motions + ns * 3 * S_(M, m), s);
    return 1;
}

/* The motion at the end of the last trial: its last stage row where drivers move. */
static const double *end_motion(const Model *M, const PrkRun *r) {
    return r->mt.nmotion ? r->motions + r->ns * 3 * S_(M, m) : r->motion;
}

/* c_steps.stage_inputs of a trial of hh from tt where drivers move: their motions at each
 * stage's time t + h C_s and at the end, as the rows of r->motions. */
static void stage_motions(const Model *M, PrkRun *r, double tt, double hh) {
    if (!r->mt.nmotion) return;
    for (I s = 0; s <= r->ns; s++)
        motion_at(M, &r->mt, tt + hh * r->fractions[s], r->motions + s * 3 * S_(M, m));
}

/* The wrapper's doStep from t over hc (see the header), `moved`: drivers_apply applied a
 * driver's set; values filled, state moved. */
static int prk_fast_step(const Model *M, PrkRun *r, double t, double hc, double *values,
                         int moved) {
    I n = S_(M, n), n2 = 2 * n, m = S_(M, m), nf = S_(M, nf);
    if (!(fabs(t - r->t_now) <= r->time_tol * fmax(fabs(t), fabs(r->t_now)))) return ST_ERROR_NORM;
    double end = t + hc, tt = r->t_now, h_ctl = r->h, c0 = r->indicator, err_old = r->err_old;
    if (!(end > tt)) return ST_ERROR_NORM;
    double *y = r->y1, *f = r->f1;
    I naccel = 0, nsteps = 0, nrej = 0, nproj = 0, landing = r->landing, rejections = 0;
    memcpy(y, r->y, (size_t)n2 * sizeof(double));
    memcpy(f, r->f, (size_t)n2 * sizeof(double));
    Scratch s = scratch(M, M->work);
    for (I row = 0; row <= r->ns; row++)
        if (nf) memcpy(r->ufs + row * nf, r->uf, (size_t)nf * sizeof(double));
    if (r->changed) {      /* reset_state's restart (h kept): no projection for a force
                            * input (Simulation._reinitialize), the state ended projected */
        if (r->mt.nmotion) motion_at(M, &r->mt, tt, r->motion);    /* a set may move it */
        if (moved && drivers_project(M, &s, &r->sd, y, r->motion) != ST_OK) return ST_SINGULAR;
        memcpy(f, y + n, (size_t)n * sizeof(double));
        /* Psi_q, gamma and S's factor as the last step's end left them (the projected
         * state: a force does not move it), else a whole evaluation */
        const double *values = kept_values(M, r->kept, y, r->motion);
        if (!solve_kept(M, r->kept, y, r->motion, r->uf, &s, f + n) &&
                mbd_accelerations(M, y, y + n, r->motion, r->motion + 2 * m, r->uf, f + n, s.lam) != ST_OK)
            return ST_SINGULAR;
        naccel += 1;
        if (values) c0 = m ? indicator_of(M, &s, values) : INFINITY;
        else mbd_singularity_indicator(M, y, r->motion, &c0);
        landing = 0;
        int released = r->ev.nevent ? events_restart(M, &r->ev, r->motion, r->uf, &s, y) : 0;
        if (released) return released > 0 ? ST_EVENT : ST_ERROR_NORM;  /* events.h */
    }
    while (tt < end) {
        if (nsteps + nrej >= r->max_work) return ST_ERROR_NORM;      /* the work limit */
        double h_min = MIN_STEP_RELATIVE * fmax(1.0, fabs(tt));
        double proposal = fmin(h_ctl, r->max_step), h_next = 0.0, c1 = 0.0, err = 0.0;
        I lands;
        double hh = landing_step(proposal, end - tt, &lands);
        if (!(c0 >= NEAR_ZONE)) return ST_SINGULAR;        /* singular_zone.plan's case */
        stage_motions(M, r, tt, hh);
        int ok = prk_try(M, r, &s, y, f, hh, err_old, &h_next, &c1, &err, &naccel, &nproj);
        if (ok < 0) return ST_SINGULAR;
        if (ok && r->stiff_limit > 0.0 &&
                mbd_stiff_h_lambda(r->ns, r->A, r->B, n2, r->K, y, hh) > r->stiff_limit)
            return ST_SINGULAR;               /* auto's watch counts this step: Python's */
        if (ok) {
            rejections = 0;
            nsteps++;
            memcpy(y, r->y_new, (size_t)n2 * sizeof(double));
            memcpy(f, r->f_new, (size_t)n2 * sizeof(double));
            c0 = c1;
            landing = lands;
            tt = lands ? end : tt + hh;
            int cut = hh < proposal && h_next >= hh;
            h_ctl = cut ? proposal : h_next;
            if (!cut) err_old = fmax(err, ERR_OLD_MIN);
            if (r->ev.nevent) {          /* the event runner's watch: Python locates it */
                int crossed = events_crossed(M, &r->ev, end_motion(M, r), r->uf, &s, y);
                if (crossed) return crossed > 0 ? ST_EVENT : ST_ERROR_NORM;
            }
        } else {
            rejections++;
            nrej++;
            landing = lands;
            h_ctl = h_next;
            if (h_next < h_min || rejections > MAX_REJECTIONS_IN_A_ROW) return ST_ERROR_NORM;
        }
    }
    if (r->mt.nmotion) motion_at(M, &r->mt, end, r->motion);
    if (publish_step_end(M, &s, y, r->motion, r->uf, r->nout, r->npub, r->pub_src, r->pub_dst,
                         r->V, values) != ST_OK)
        return ST_SINGULAR;
    memcpy(r->y, y, (size_t)n2 * sizeof(double));
    memcpy(r->f, f, (size_t)n2 * sizeof(double));
    r->t_now = end;
    r->h = h_ctl;
    r->err_old = err_old;
    r->indicator = c0;
    r->landing = landing;
    r->changed = 0;
    for (I k = 0; k < r->nvr; k++) r->set[k] = 0;
    if (nf) memcpy(r->uf_step, r->uf, (size_t)nf * sizeof(double));
    r->steps += 1;
    r->nsteps += nsteps;
    r->nrejected += nrej;
    r->naccel += naccel;
    r->nprojections += nproj;
    return ST_OK;
}

int mbd_prk_fast_step(const Model *M, PrkRun *r, double t, double hc, double *values) {
    int moved = r->changed ? drivers_apply(&r->sd, &r->mt, r->nvr, r->set, r->slots, r->uf,
                                           r->t_now) : 0;
    if (moved < 0) return ST_ERROR_NORM;
    int st = prk_fast_step(M, r, t, hc, values, moved);
    if (st != ST_OK && moved > 0) drivers_undo(&r->sd, &r->mt);
    return st;
}

/* ---- runs of steps for Python's _advance_adaptive (c_steps.prk_run) ------------------------
 *
 * AdaptiveStepping._advance_adaptive's loop, ProjectedRK._step_impl and _energy_rejects and
 * Integrator._after_step's energy check, in the same order and arithmetic, for steps that
 * need nothing else: a scene without force inputs (the drivers' motions evaluated at each
 * stage's time, stage_motions; the singularity indicator of zone_plan does not depend on
 * them), no watch (auto's stiffness limit aside: a step it counts is RUN_PYTHON),
 * its energy audited (total_energy, as energy_check) or not. The step decisions and
 * prk_try are those of the wrapper's landing steps above; with `dense` the steps go past
 * the target (the last accepted step is kept for the dense output). It stops with the
 * state and counters of the decisions taken so far: RUN_DONE at the target; RUN_PYTHON
 * before an attempt Python takes (singular_zone.plan's case, a trial the kernel hands
 * back, an energy jump Python raises on); RUN_WORK after max_work attempts, or with
 * cpu_limit when the thread's CPU time passes it (Python checks its work limit);
 * RUN_ENERGY after a step whose energy check failed (Python's check says why); RUN_FAILED
 * when the step size fell below its minimum or too many steps were rejected in a row;
 * RUN_EVENT after a step that changed the sign of a watched event function (events.h:
 * only an FMU wrapper's dense run watches them; with `undo` the run is first put back to
 * that step's start, and `coming` says where the change comes when the step ended past
 * a dense run's target, else NAN). */

enum { RUN_DONE = 0, RUN_PYTHON = 1, RUN_WORK = 2, RUN_ENERGY = 3, RUN_FAILED = 4 };

typedef struct {
    PrkRun r;                    /* the pair, factors, tolerances, motion(s), y, f, K, h */
    double t, t_target;
    I dense, rejections;         /* steps rejected in a row, carried to and from Python */
    double energy_rejected;      /* ProjectedRK.energy_rejected; NAN: None */
    double *audit;               /* EnergyAudit's state (c_steps.AUDIT_FIELDS), or NULL */
    double step_factor, min_gain, jump_limit, divergence, roundoff;
    double t_old, h_old;         /* the last accepted step (DenseStep) ... */
    double *y_old, *y_end, *K_old;
    I stepped;                   /* ... kept when 1 */
    I ngaps; const double *gap_mid, *gap_width;   /* singular_zone.gaps of the nodes */
    double cpu_limit, cpu_start; /* > 0: RUN_WORK once the thread's CPU time since cpu_start
                                  * passes cpu_limit (s; WorkLimit's max_cpu), else unchecked */
    double *undo;                /* with watched events: the state at the last step's end
                                  * (save_pair), where a step that changes a sign puts the
                                  * run back (the event runner's watching point), or NULL */
    double coming;               /* then: where that sign change comes (coming_event) */
} PrkPy;

/* doubles of a pair's state (save_pair): y, f, y_old, y_end (2n each), K_old, the
 * audit, PAIR_SCALARS, the event functions' values */
#define PAIR_SCALARS 13

static I pair_state_size(const Model *M, const PrkPy *p) {
    return (4 + p->r.ns + 1) * 2 * S_(M, n) + A_FIELDS + PAIR_SCALARS + p->r.ev.nevent;
}

/* The pair's state after a step (or at a run's start) into b: what the event runner's
 * watching point (Integrator.rollback_point) holds. */
static void save_pair(const Model *M, const PrkPy *p, double *b) {
    const PrkRun *r = &p->r;
    I n2 = 2 * S_(M, n), rows = r->ns + 1;
    memcpy(b, r->y, (size_t)n2 * sizeof(double)); b += n2;
    memcpy(b, r->f, (size_t)n2 * sizeof(double)); b += n2;
    memcpy(b, p->y_old, (size_t)n2 * sizeof(double)); b += n2;
    memcpy(b, p->y_end, (size_t)n2 * sizeof(double)); b += n2;
    memcpy(b, p->K_old, (size_t)(rows * n2) * sizeof(double)); b += rows * n2;
    if (p->audit) memcpy(b, p->audit, A_FIELDS * sizeof(double));
    b += A_FIELDS;
    double scalars[PAIR_SCALARS] = {
        r->h, r->err_old, r->indicator, (double)r->landing, p->t, p->energy_rejected,
        p->t_old, p->h_old, (double)p->stepped, (double)r->nsteps, (double)r->nrejected,
        (double)r->naccel, (double)r->nprojections};
    memcpy(b, scalars, sizeof scalars);
    b += PAIR_SCALARS;
    if (r->ev.nevent) memcpy(b, r->ev.ev_g, (size_t)r->ev.nevent * sizeof(double));
}

static void restore_pair(const Model *M, PrkPy *p, const double *b) {
    PrkRun *r = &p->r;
    I n2 = 2 * S_(M, n), rows = r->ns + 1;
    memcpy(r->y, b, (size_t)n2 * sizeof(double)); b += n2;
    memcpy(r->f, b, (size_t)n2 * sizeof(double)); b += n2;
    memcpy(p->y_old, b, (size_t)n2 * sizeof(double)); b += n2;
    memcpy(p->y_end, b, (size_t)n2 * sizeof(double)); b += n2;
    memcpy(p->K_old, b, (size_t)(rows * n2) * sizeof(double)); b += rows * n2;
    if (p->audit) memcpy(p->audit, b, A_FIELDS * sizeof(double));
    b += A_FIELDS;
    r->h = b[0]; r->err_old = b[1]; r->indicator = b[2]; r->landing = (I)b[3];
    p->t = b[4]; p->energy_rejected = b[5]; p->t_old = b[6]; p->h_old = b[7];
    p->stepped = (I)b[8]; r->nsteps = (I)b[9]; r->nrejected = (I)b[10]; r->naccel = (I)b[11];
    r->nprojections = (I)b[12];
    b += PAIR_SCALARS;
    if (r->ev.nevent) memcpy(r->ev.ev_g, b, (size_t)r->ev.nevent * sizeof(double));
}

/* EventRunner.advance's estimate of where the sign change of a step from t0 to t1 comes
 * (the watched values before it in ev_g, after it next to them): the earliest crossing
 * by linear interpolation (events._fraction); NAN unless every crossing is a stop's
 * distance, whose value is Python's to the bit (events.h coordinate_value). */
static double coming_event(const EventWatch *w, double t0, double t1) {
    const double *g0 = w->ev_g, *g1 = w->ev_g + w->nevent;
    double fraction = INFINITY;
    for (I e = 0; e < w->nevent; e++) {
        if (!(g1[e] < 0.0 && (g0[e] >= 0.0 || g1[e] < g0[e]))) continue;
        if (w->ev_int[EV_INTS * e + EV_KIND] != EV_DISTANCE) return NAN;
        fraction = fmin(fraction, g0[e] <= 0.0 ? 0.0 : g0[e] / (g0[e] - g1[e]));
    }
    return t0 + (t1 - t0) * fraction;
}

/* The calling thread's CPU time (s): WorkLimit's clock (time.thread_time). */
static double thread_cpu(void) {
    struct timespec ts;
    clock_gettime(CLOCK_THREAD_CPUTIME_ID, &ts);
    return (double)ts.tv_sec + 1e-9 * (double)ts.tv_nsec;
}

/* singular_zone.py's constants */
#define ZONE 1e-2
#define ZONE_MARGIN 1.2
#define REDUNDANT 1e-7
#define MIN_CLEARANCE 1e-4
#define INNER 1e-3
#define PROBE 1e-4

/* singular_zone.crossing_step; 0 when no step reaches the configuration. */
static int crossing_step(const PrkPy *p, double d, double w, double k, double limit, double *H) {
    double beyond = INFINITY, good_max = -INFINITY, fit = 0.0, clear_max = -INFINITY;
    int any_beyond = 0, any_good = 0, any_fit = 0;
    for (I g = 0; g < p->ngaps; g++) {
        double h = d / p->gap_mid[g], clearance = 0.5 * k * p->gap_width[g] * h;
        int fits = h <= limit;
        int good = fits && k * (h - d) >= INNER && clearance >= MIN_CLEARANCE;
        if (good && h >= d + w) { any_beyond = 1; beyond = fmin(beyond, h); }
        if (good) { any_good = 1; good_max = fmax(good_max, h); }
        if (fits && (!any_fit || clearance > clear_max)) { any_fit = 1; clear_max = clearance; fit = h; }
    }
    *H = any_beyond ? beyond : any_good ? good_max : fit;
    return any_beyond || any_good || any_fit;
}

/* singular_zone.plan from the state y at p->t: the step to try (h, or one that ends before
 * the zone, at its edge, or crosses it: *crossing). q + eps q' goes in r->y_new. */
static double zone_plan(const Model *M, PrkPy *p, const double *y, double h, double proposal,
                        int *crossing) {
    PrkRun *r = &p->r;
    I n = S_(M, n);
    double c0 = r->indicator, speed = 0.0, ahead = 0.0, H = 0.0;
    *crossing = 0;
    if (!(REDUNDANT <= c0 && c0 < NEAR_ZONE)) return h;
    for (I k = 0; k < n; k++) speed = fmax(speed, fabs(y[n + k]));
    if (speed == 0.0) return h;
    double eps = PROBE * c0 / speed;
    for (I k = 0; k < n; k++) r->y_new[k] = y[k] + eps * y[n + k];
    mbd_singularity_indicator(M, r->y_new, r->motion, &ahead);
    double k = (c0 - ahead) / eps;
    if (!(k > 0.0)) return h;
    double t0 = p->t, t_star = t0 + c0 / k, d = t_star - t0, w = ZONE_MARGIN * ZONE / k;
    if (t0 + h <= t_star - w) return h;
    if (d > 3.0 * w) return d - 2.0 * w;
    if (d > 1.5 * w) return d - w;
    if (!crossing_step(p, d, w, k, proposal, &H)) return h;
    *crossing = 1;
    return H;
}

/* prk_try with the trial that also works next to a singular configuration (the error
 * estimate along the constraints there: c_steps.prk_attempt): 1 accepted, 0 rejected, -1
 * a case the kernel hands back; *c1 the indicator at the step's end, *err_out the error
 * norm. */
static int near_try(const Model *M, PrkRun *r, Scratch *s, const double *y, const double *f,
                    double hh, double *h_next, double *c1, double *err_out, I *naccel,
                    I *nproj) {
    I n2 = 2 * S_(M, n), ns = r->ns;
    double err = 0.0;
    int st = prk_trial(M, ns, r->A, r->B, r->E, r->E3, hh, y, f, r->motions, r->ufs, r->rtol,
                       r->atol, r->tol, r->max_iter, r->y_new, r->f_new, &err, r->K,
                       r->indicator, c1, NULL, !r->skip_end);
    if (st == ST_SINGULAR || st == ST_SPRING || st == ST_PROJECTION) return -1;
    *naccel += r->skip_end ? ns - 1 : ns;
    if (st == ST_NOT_FINITE) { *h_next = hh * r->min_factor; return 0; }
    double *y_end = s->qv + 4 * n2;       /* the step's end before the projection: its */
    if (!r->skip_end) combine(y, hh, r->K, n2, r->B, ns, y_end);   /* dense output's */
    if (st == ST_ERROR_NORM) {
        *h_next = hh * fmax(r->min_factor, r->safety * pow(err, r->exponent));
        return 0;
    }
    *nproj += 1;
    *naccel += 1;
    *h_next = accepted_step(r, hh, err, r->err_old);
    *err_out = err;
    return 1;
}

/* singular_zone.after_step: the step to retry with when a step not planned to cross ended
 * inside the zone, else 0. */
static double zone_retry(int crossing, int landing, double t0, double hh, double c0,
                         double c1) {
    if (crossing || landing) return 0.0;
    if (c1 < ZONE && ZONE <= c0 && c0 >= REDUNDANT) {
        double t_star = t0 + hh * c0 / (c0 - c1);
        return fmax((t_star - t0) * (1.0 - ZONE_MARGIN * ZONE / c0), 0.1 * hh);
    }
    return 0.0;
}

/* EnergyAudit.step_error on total_energy and audit_joules (stepping.h). */
static double energy_step_error(const Model *M, const PrkPy *p, const double *q, const double *qd) {
    const double *a = p->audit;
    double kinetic;
    double change = fabs(total_energy(M, q, qd, &kinetic) - a[A_LAST_ENERGY]);
    if (change <= 10.0 * p->roundoff * a[A_MAGNITUDE]) return 0.0;
    double allowed = p->step_factor * audit_joules(M, q, qd, a[A_RTOL], a[A_ATOL]);
    return allowed > 0.0 ? change / allowed : INFINITY;
}

/* ProjectedRK._energy_rejects on an accepted trial: 1 accept, 0 reject (*h_next set),
 * -1 Python's case (the jump it raises on; energy_rejected left as it was). */
static int energy_decides(const Model *M, PrkPy *p, const double *y_new, double hh,
                          double *h_next) {
    if (!p->audit) return 1;
    double err = energy_step_error(M, p, y_new, y_new + S_(M, n)), last = p->energy_rejected;
    if (err <= 1.0) { p->energy_rejected = NAN; return 1; }
    if (isnan(last) || err < p->min_gain * last) {
        p->energy_rejected = err;
        *h_next = hh * fmax(p->r.min_factor, p->r.safety * pow(err, p->r.exponent));
        return 0;
    }
    if (err <= p->jump_limit) { p->energy_rejected = NAN; return 1; }
    return -1;
}

int mbd_prk_run(const Model *M, PrkPy *p) {
    PrkRun *r = &p->r;
    I n = S_(M, n), n2 = 2 * n, ns = r->ns, attempts = 0;
    Scratch s = scratch(M, M->work);
    double *y = r->y, *f = r->f;
    if (p->undo) save_pair(M, p, p->undo);
    while (p->t < p->t_target) {
        if (attempts >= r->max_work) return RUN_WORK;
        if (p->cpu_limit > 0.0 && thread_cpu() - p->cpu_start > p->cpu_limit) return RUN_WORK;
        double h_min = MIN_STEP_RELATIVE * fmax(1.0, fabs(p->t));
        double proposal = fmin(r->h, r->max_step), h_next = 0.0, c1 = 0.0, hh = proposal;
        double err = 0.0;
        I lands = 0, naccel = 0, nproj = 0;
        int crossing = 0;
        if (!p->dense) hh = landing_step(proposal, p->t_target - p->t, &lands);
        I zone_landing = lands;
        double planned = zone_plan(M, p, y, hh, proposal, &crossing), c0 = r->indicator;
        lands = lands && planned == hh;
        hh = planned;
        stage_motions(M, r, p->t, hh);
        int ok = near_try(M, r, &s, y, f, hh, &h_next, &c1, &err, &naccel, &nproj);
        if (ok < 0) return RUN_PYTHON;
        if (ok > 0) {
            int e = energy_decides(M, p, r->y_new, hh, &h_next);
            if (e < 0) return RUN_PYTHON;
            if (e == 0) { ok = 0; naccel -= 1; }     /* the end's q'' is counted when kept */
        }
        if (ok > 0) {
            double retry = zone_retry(crossing, (int)zone_landing, p->t, hh, c0, c1);
            if (retry > 0.0) { ok = 0; h_next = retry; }
        }
        attempts++;
        r->naccel += naccel;
        r->nprojections += nproj;
        r->landing = zone_landing;
        if (!ok) {
            p->rejections++;
            r->nrejected++;
            r->h = h_next;
            if (h_next < h_min || p->rejections > MAX_REJECTIONS_IN_A_ROW) return RUN_FAILED;
            continue;
        }
        if (r->stiff_limit > 0.0 &&
                mbd_stiff_h_lambda(ns, r->A, r->B, n2, r->K, y, hh) > r->stiff_limit)
            return RUN_PYTHON;            /* auto's watch counts this step: Python's */
        p->rejections = 0;
        r->nsteps++;
        p->t_old = p->t;
        p->h_old = hh;
        p->stepped = 1;
        if (!r->skip_end) {          /* the step's dense output: none kept when skipped */
            memcpy(p->y_old, y, (size_t)n2 * sizeof(double));
            memcpy(p->y_end, s.qv + 4 * n2, (size_t)n2 * sizeof(double));   /* near_try's */
            memcpy(p->K_old, r->K, (size_t)((ns + 1) * n2) * sizeof(double));
        }
        memcpy(y, r->y_new, (size_t)n2 * sizeof(double));
        memcpy(f, r->f_new, (size_t)n2 * sizeof(double));
        r->indicator = c1;
        p->t = lands ? p->t_target : p->t + hh;
        int cut = hh < proposal && h_next >= hh;
        r->h = cut ? proposal : h_next;
        if (!cut) r->err_old = fmax(err, ERR_OLD_MIN);
        if (r->ev.nevent) {              /* the event runner's watch, before the audit */
            int crossed = events_crossed(M, &r->ev, end_motion(M, r), r->ufs, &s, y);
            if (crossed > 0 && p->undo) {    /* back to the step's start (set_state) */
                double t1 = p->t;
                int past = p->dense && t1 > p->t_target;
                restore_pair(M, p, p->undo);
                p->coming = past ? coming_event(&r->ev, p->t, t1) : NAN;
            }
            if (crossed) return crossed > 0 ? RUN_EVENT : RUN_PYTHON;
            if (p->undo) save_pair(M, p, p->undo);
        }
        if (p->audit && p->audit[A_ACTIVE] != 0.0 &&
                !energy_check(M, y, y + n, p->audit, p->divergence, p->roundoff))
            return RUN_ENERGY;
    }
    return RUN_DONE;
}
