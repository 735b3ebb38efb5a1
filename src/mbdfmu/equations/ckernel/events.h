/*
 * events.h (part of kernel.c): the event functions of a contact mode (modes.ContactModes.
 * values, formulation.md eq. 33), checked after each step an FMU's wrapper takes (its dense
 * runs, dense_run.h; rk4p's steps, fixed.h; an embedded pair's landing steps, adaptive.h)
 * as the event runner's watch does after each of Python's: a step in which one changes
 * sign (v < 0 where it was not, or fell further) ends the run, which then puts everything
 * back for Python to take the doStep, locate the event and change the mode. After a force
 * input is set they are read again at the restart (events_restart).
 * Per event (events.py c_events): its kind, the held coordinate's row, the joint as
 * friction.h reads it; the limit and the sign.
 */

enum { EV_DISTANCE, EV_HELD, EV_STICK, EV_RATE };
enum { EV_KIND, EV_ROW, EV_JOINT, EV_INTS = EV_JOINT + SL_INTS };
enum { EV_LIMIT = SL_REALS, EV_SIGN, EV_REALS };
enum { RUN_EVENT = 5 };          /* mbd_prk_run: a step changed an event function's sign */

/* The event functions a run watches (none when nevent is 0) and their values: at the last
 * step's end (ev_g[0, nevent)), then room for the next (ev_g[nevent, 2 nevent)). */
typedef struct {
    I nevent;
    const I *ev_int; const double *ev_real;
    double *ev_g;
} EventWatch;

/* The joint's coordinate (limits.Coordinate.value, in its arithmetic). */
static double coordinate_value(const I *si, const double *sr, const double *q) {
    I i = si[SL_BI], j = si[SL_BJ];
    double xi = 0.0, yi = 0.0, ai = 0.0, xj = 0.0, yj = 0.0, aj = 0.0;
    if (i >= 0) { xi = q[3 * i]; yi = q[3 * i + 1]; ai = q[3 * i + 2]; }
    if (j >= 0) { xj = q[3 * j]; yj = q[3 * j + 1]; aj = q[3 * j + 2]; }
    if (si[SL_REVOLUTE]) return aj - ai;
    double ci = cos(ai), sn_i = sin(ai), cj = cos(aj), sn_j = sin(aj);
    const double *u = sr + SL_U, *pi = sr + SL_PI, *pj = sr + SL_PJ;
    double dx = xj + cj * pj[0] - sn_j * pj[1] - xi - ci * pi[0] + sn_i * pi[1];
    double dy = yj + sn_j * pj[0] + cj * pj[1] - yi - sn_i * pi[0] - ci * pi[1];
    return (ci * u[0] - sn_i * u[1]) * dx + (sn_i * u[0] + ci * u[1]) * dy;
}

/* The event functions at the state y (2n) into g, with the step end's motion (c, c', c'':
 * 3m) and force inputs uf. A held coordinate's effort is -lam of eq. (14) there: the kept
 * evaluation's (the step's end), as Python's watch reads it (mbd_accelerations), else a
 * new one; a sticking joint's bound also needs Psi_q's data there. */
static int event_values(const Model *M, const EventWatch *w, const double *motion,
                        const double *uf, Scratch *s, const double *y, double *g) {
    I n = S_(M, n), m = S_(M, m);
    const double *lam = NULL, *cval = motion, *cdd = motion + 2 * m;
    int data = 0;
    for (I e = 0; e < w->nevent; e++) {
        const I *ei = w->ev_int + EV_INTS * e, *si = ei + EV_JOINT;
        const double *er = w->ev_real + EV_REALS * e;
        I kind = ei[EV_KIND];
        if (kind == EV_DISTANCE) {
            g[e] = er[EV_SIGN] * (coordinate_value(si, er, y) - er[EV_LIMIT]);
            continue;
        }
        if (kind == EV_RATE) {
            double *grad = s->nv, rate = 0.0;
            coordinate_gradient(M, si, er, y, grad);
            for (I k = 0; k < n; k++) rate += grad[k] * y[n + k];
            g[e] = er[EV_SIGN] * rate;
            continue;
        }
        if (!lam && memo_hit(M, y, y + n, cval, cdd, uf)) {
            lam = M->memo + 1 + 3 * n + 2 * m + S_(M, nf);
        } else if (!lam) {
            int st = accelerations(M, s, y, y + n, cval, cdd, uf, s->qv, s->lam);
            if (st != ST_OK) return st;
            lam = s->lam;
            data = 1;
        }
        double effort = -lam[ei[EV_ROW]];
        if (kind == EV_HELD) {
            g[e] = er[EV_SIGN] * effort;
            continue;
        }
        if (!data) {             /* Psi_q's data at y, for the joint's reaction */
            jacobian_at(M, s, y, cval);
            data = 1;
        }
        g[e] = friction_bound(M, si, er, y, lam, s->data) - fabs(effort);
    }
    return ST_OK;
}

/* After an accepted step ending at y (motion and uf as event_values takes them): 1 when an
 * event function changed sign since the last step's end (w->ev_g, then updated), 0 when
 * none did, -1 when they cannot be evaluated. */
static int events_crossed(const Model *M, const EventWatch *w, const double *motion,
                          const double *uf, Scratch *s, const double *y) {
    double *g0 = w->ev_g, *g = w->ev_g + w->nevent;
    if (event_values(M, w, motion, uf, s, y, g) != ST_OK) return -1;
    for (I e = 0; e < w->nevent; e++)
        if (g[e] < 0.0 && (g0[e] >= 0.0 || g[e] < g0[e])) return 1;
    memcpy(g0, g, (size_t)w->nevent * sizeof(double));
    return 0;
}

/* After an input change: the event functions at the restart y with the new inputs into
 * w->ev_g (the event runner's advance reads them so before its first step: a held
 * coordinate's effort moves with the forces); 1 when a held coordinate's (a stop's force,
 * a sticking joint's margin) is negative, so that it leaves its stop or slips at once
 * (events.py EventRunner._released, which the doStep is handed to), 0 when none is, -1
 * when they cannot be evaluated. */
static int events_restart(const Model *M, const EventWatch *w, const double *motion,
                          const double *uf, Scratch *s, const double *y) {
    if (event_values(M, w, motion, uf, s, y, w->ev_g) != ST_OK) return -1;
    for (I e = 0; e < w->nevent; e++) {
        I kind = w->ev_int[EV_INTS * e + EV_KIND];
        if ((kind == EV_HELD || kind == EV_STICK) && w->ev_g[e] < 0.0) return 1;
    }
    return 0;
}
