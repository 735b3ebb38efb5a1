/*
 * dense_run.h (part of kernel.c): an FMU's communication step past the end of the adaptive
 * step whose dense output the wrapper reads (dense.h), taken by the wrapper without Python:
 * the pair's next steps with mbd_prk_run's decisions in dense mode (the steps go past the
 * communication point, as AdaptiveStepping._advance_adaptive's do with dense output), the
 * last one's interpolant (DOP853's, dop853_dense below, or Dormand-Prince 5(4)'s,
 * mbd_rk45_dense), then the read at the point. For a
 * scene whose inputs are held (the drivers' motions at every stage's time, at DOP853's
 * extra nodes and at the point, motions.h); under auto (stiff_limit) a step auto's
 * stiffness rule would count goes to Python. Anything mbd_prk_run hands back, a failed
 * evaluation or read, and a point that is the last step's end leave everything as it was
 * (the state is kept before the run and put back) and the wrapper calls Python, which
 * takes the same steps and says why; so does a run that passes the doStep's CPU limit
 * (PrkPy.cpu_limit), which Python then discards. In a scene with end stops or friction the
 * run watches the contact mode's event functions after each step (events.h) and keeps its
 * steps within the event runner's horizon, closing in on a stop ahead as the runner does
 * (run_within_horizon); a step that changes a sign within the doStep is Python's.
 *
 * Python's own interpolants (DOP853P._interpolant, RK45P._interpolant with the C kernel)
 * call the same functions, so a value read here is the one Python reads, bit for bit.
 */

#define DENSE_STAGES 16          /* DOP853's 12 stages, f at the end and 3 more */
#define DENSE_ROWS 7             /* rows of its interpolant F */
#define RK45_ROWS 4              /* powers of x in Dormand-Prince 5(4)'s interpolant */

/* The three extra stages and F (7 x n2) of scipy's Dop853DenseOutput for the step from
 * y_old over h whose stages are K (13 rows: the last f at the unprojected end y_end):
 * dense_output.dop853_interpolant's arithmetic. a_extra (3 x 16), c_extra (3), D (4 x 16):
 * the tableau; motions, ufs: the inputs at the three extra nodes (3 rows each); Kx
 * (16 x n2) and ys (n2): scratch. */
static int dop853_dense(const Model *M, Scratch *s, const double *K, const double *y_old,
                        const double *y_end, double h, const double *a_extra,
                        const double *D, const double *motions, const double *ufs, double *F,
                        double *Kx, double *ys) {
    I n2 = 2 * S_(M, n), m = S_(M, m), nf = S_(M, nf), first = DENSE_STAGES - 3;
    memcpy(Kx, K, (size_t)(first * n2) * sizeof(double));
    for (I e = 0; e < 3; e++) {
        I row = first + e;
        combine(y_old, h, Kx, n2, a_extra + e * DENSE_STAGES, row, ys);
        int st = rhs(M, s, ys, motions + e * 3 * m, ufs + e * nf, Kx + row * n2, s->lam);
        if (st != ST_OK) return st;
        if (!all_finite(Kx + row * n2, n2)) return ST_NOT_FINITE;
    }
    const double *f_end = K + (first - 1) * n2;
    for (I k = 0; k < n2; k++) {
        double delta = y_end[k] - y_old[k];
        F[k] = delta;
        F[n2 + k] = h * Kx[k] - delta;
        F[2 * n2 + k] = 2.0 * delta - h * (f_end[k] + Kx[k]);
    }
    for (I r = 0; r < 4; r++) {
        weighted_sum(Kx, n2, D + r * DENSE_STAGES, DENSE_STAGES, ys);
        for (I k = 0; k < n2; k++) F[(3 + r) * n2 + k] = h * ys[k];
    }
    return ST_OK;
}

/* Q (n2 x rows) of the Dormand-Prince 5(4) interpolant, y(t_old + x h) = y_old +
 * h Q [x, x^2, ...] (dense_output.rk45_interpolant: K^T P), from the step's stages K
 * (nk rows of n2) and P (nk x rows), each entry summed over the stages in their order.
 * Python's RK45P._interpolant with the C kernel calls it too. */
void mbd_rk45_dense(I n2, I nk, I rows, const double *K, const double *P, double *Q) {
    for (I i = 0; i < n2; i++)
        for (I j = 0; j < rows; j++) {
            double s = 0.0;
            for (I k = 0; k < nk; k++) s += K[k * n2 + i] * P[k * rows + j];
            Q[i * rows + j] = s;
        }
}

/* Python's DOP853P._interpolant with the C kernel: F (7 x n2) as dop853_dense. */
int mbd_dop853_dense(const Model *M, const double *K, const double *y_old, const double *y_end,
                     double h, const double *a_extra, const double *D, const double *motions,
                     const double *ufs, double *F, double *Kx, double *ys) {
    Scratch s = scratch(M, M->work);
    return dop853_dense(M, &s, K, y_old, y_end, h, a_extra, D, motions, ufs, F, Kx, ys);
}

typedef struct {
    DenseRead d;                 /* the step being read (dense.h): first, the wrapper's context */
    PrkPy p;                     /* the pair's state and decisions (adaptive.h), dense mode */
    const double *a_extra, *D;   /* DOP853's dense output tableau (3 x 16, 4 x 16); with
                                  * d.kind DENSE_RK45, D is Dormand-Prince's P ((ns + 1) x
                                  * RK45_ROWS) and the interpolant is free */
    double *motions, *ufs;       /* the inputs at its three extra nodes (held: all alike) */
    double *coef[2];             /* F of the steps taken here: the one read, the next */
    I which;                     /* the one read (when d.coef is one of them) */
    double *Kx, *ys;             /* dop853_dense's scratch */
    double *saved;               /* the state before a run (save_run) */
    I taken;                     /* steps were taken since armed: Python adopts them */
    double horizon;              /* no step past it (events.py's EventRunner.advance), or NAN */
    const double *c_extra;       /* DOP853's extra nodes in a step (with drivers) */
} DenseRun;

/* doubles of saved: the pair's state (save_pair), then the scalars below */
#define RUN_SCALARS 4
#define HORIZON_REACHED 1e-12    /* events.HORIZON_REACHED */
#define HORIZON_FRACTION 0.9     /* events.HORIZON_FRACTION */

static void save_run(const Model *M, const DenseRun *R, double *b) {
    save_pair(M, &R->p, b);
    b += pair_state_size(M, &R->p);
    b[0] = R->d.t_old; b[1] = R->d.h; b[2] = (double)R->taken; b[3] = R->horizon;
}

static void restore_run(const Model *M, DenseRun *R, const double *b) {
    restore_pair(M, &R->p, b);
    b += pair_state_size(M, &R->p);
    R->d.t_old = b[0]; R->d.h = b[1]; R->taken = (I)b[2]; R->horizon = b[3];
}

/* EventRunner.advance's run to `end` within its horizon: a horizon reached is dropped,
 * else the steps end by it; a step past `end` that changes a stop's distance's sign is
 * taken again from its start, the horizon HORIZON_FRACTION of the way to where the change
 * comes, as long as that horizon is past `end` (else the event is this doStep's: Python's).
 * The pair's RUN_* status. */
static int run_within_horizon(const Model *M, DenseRun *R, double end) {
    PrkPy *p = &R->p;
    double max_step = p->r.max_step;
    int status;
    for (;;) {
        if (!isnan(R->horizon) && p->t >= R->horizon - HORIZON_REACHED * fmax(1.0, R->horizon))
            R->horizon = NAN;
        p->r.max_step = isnan(R->horizon) ? max_step : fmin(max_step, R->horizon - p->t);
        status = mbd_prk_run(M, p);
        p->r.max_step = max_step;
        if (status != RUN_EVENT || !p->undo || isnan(p->coming)) break;
        double horizon = p->t + HORIZON_FRACTION * (p->coming - p->t);
        if (!(horizon > end)) break;
        R->horizon = horizon;
        p->rejections = 0;              /* a new advance: its own count and CPU limit */
        p->cpu_start = thread_cpu();
    }
    return status;
}

/* The wrapper's doStep from t over h (dense.h's mbd_dense_step inside the step read; past
 * its end, the steps described above); values filled, or non-zero with nothing changed. */
int mbd_dense_run_step(const Model *M, DenseRun *R, double t, double h, double *values) {
    DenseRead *d = &R->d;
    PrkPy *p = &R->p;
    if (!(fabs(t - d->t_now) <= d->time_tol * fmax(fabs(t), fabs(d->t_now)))) return ST_ERROR_NORM;
    double end = t + h;
    if (end < d->t_old + d->h) return mbd_dense_step(M, d, t, h, values);
    const double *coef = d->coef, *y_old = d->y_old;
    save_run(M, R, R->saved);
    p->cpu_start = thread_cpu();    /* the doStep's CPU limit counts from here */
    p->t_target = end;
    p->rejections = 0;              /* _advance_adaptive counts them per call */
    p->stepped = 0;
    int st = run_within_horizon(M, R, end) == RUN_DONE && p->stepped &&
             end < p->t_old + p->h_old ? ST_OK : ST_ERROR_NORM;
    I w = d->coef == R->coef[R->which] ? !R->which : R->which;
    if (st == ST_OK && d->kind == DENSE_RK45) {
        mbd_rk45_dense(2 * S_(M, n), p->r.ns + 1, RK45_ROWS, p->K_old, R->D, R->coef[w]);
    } else if (st == ST_OK) {
        Scratch s = scratch(M, M->work);
        for (I e = 0; e < 3 && p->r.mt.nmotion; e++)      /* DOP853P._interpolant's times */
            motion_at(M, &p->r.mt, p->t_old + R->c_extra[e] * p->h_old,
                      R->motions + e * 3 * S_(M, m));
        st = dop853_dense(M, &s, p->K_old, p->y_old, p->y_end, p->h_old, R->a_extra, R->D,
                          R->motions, R->ufs, R->coef[w], R->Kx, R->ys);
    }
    if (st == ST_OK) {       /* the run's y_old: a later run that fails puts it back */
        d->t_old = p->t_old;
        d->h = p->h_old;
        d->coef = R->coef[w];
        d->y_old = p->y_old;
        st = mbd_dense_step(M, d, t, h, values);
    }
    if (st != ST_OK) {
        restore_run(M, R, R->saved);
        d->coef = coef;
        d->y_old = y_old;
        return st;
    }
    if (d->kind == DENSE_DOP853)
        p->r.naccel += 3;           /* the interpolant's stages, as Python counts them */
    R->which = w;
    R->taken = 1;
    return ST_OK;
}
