"""Steps of ``rk4p`` and of the projected embedded pairs in the C kernel (kernel "c").

The arithmetic of a step (stages, error norm, projections, the next q'') runs in one C
call (``equations.ckernel``); what a step decides stays here, line for line as in
``RK4P._advance_fixed`` / ``ProjectedRK._step_impl`` (acceptance, step factors, the energy
audit, counters), except in runs of an embedded pair's steps (``prk_run``), which take
them in C the same way. Input signals are evaluated in Python at every time a step needs them;
a run takes none (no force inputs, no driver driven by them) and evaluates the scene's
drivers' motions itself (``ckernel/motions.h``). Whatever the kernel
hands back (a singular Schur complement, a failed projection, a non-finite state, a
spring of zero length) is redone by the Python step, which then does and says what it
always does.
"""

from __future__ import annotations

import numpy as np

from ..equations import ckernel
from ..equations.ckernel.adaptive import RUN_ENERGY, RUN_FAILED, RUN_PYTHON  # noqa: F401
from ..equations.ckernel.adaptive import prk_run as ckernel_prk_run
from ..equations.projection import PROJECTION_MAX_ITER
from . import singular_zone
from .adaptive import accepted_step, rejected_step
from .base import Integrator
from .dense_output import DenseStep
from .energy_audit import ENERGY_DIVERGENCE_FRACTION, ENERGY_ROUNDOFF, ENERGY_STEP_FACTOR
from .stated_accuracy import adopt_c_estimate, c_estimate

# The energy check's running state as kernel.c reads it (rk4p_compiled.AuditField's order).
AUDIT_FIELDS = ("active", "e0", "v0", "kinetic_max", "potential_swing", "magnitude", "checks",
                "worst", "last_energy", "rtol", "atol", "factor", "tolerance_joules")
# Steps per C call of an rk4p run: the work limits are checked between calls.
RUN_LENGTH = 64
_TABLEAUS: dict[type, tuple] = {}


def stage_inputs(integrator, times, kernel=None) -> None:
    """(c, c', c'') of every row and the force inputs at each of ``times``, from the
    integrator's input signals, into the kernel's (default: the equations') ``buf.motions``
    and ``buf.ufs``."""
    eq = integrator.equations
    kernel, k = kernel or eq.ckernel, len(times)
    motions, forces = kernel.buf.motions, kernel.buf.ufs
    if not eq.scene.drivers:
        if kernel.static_rows < k:      # offsets only: the same at every time, written once
            motions[:k] = np.concatenate(eq.motion_values(0.0))
            kernel.static_rows = k
        if kernel.nf:
            # the same object at both ends is the held inputs' cache (Simulation.inputs_at
            # returns it at every t or at none): one value for the whole step
            first, last = integrator.inputs(times[0]), integrator.inputs(times[-1])
            if first is last:
                forces[:k] = first.forces
            else:       # Taylor polynomials at every time at once where the inputs can
                at = getattr(integrator.inputs, "forces_at", lambda times: None)(times)
                forces[:k] = at if at is not None else [integrator.inputs(t).forces
                                                        for t in times]
        return
    inputs = [integrator.inputs(t) for t in times] if eq.layout.drivers or kernel.nf else None
    motions[:k] = eq.constraint_set.motion_block(times, inputs).reshape(k, -1)
    if kernel.nf:
        forces[:k] = [u.forces for u in inputs]


NO_AUDIT = np.zeros(len(AUDIT_FIELDS))      # inactive: no energy check in the kernel


def audit_state(audit) -> list:
    """An ``EnergyAudit``'s running state as the kernel's audit array (active)."""
    return [1.0] + [getattr(audit, name) for name in AUDIT_FIELDS[1:]]


def audit_back(audit, state) -> None:
    """The kernel's audit array back into the ``EnergyAudit`` after a compiled run."""
    for k, name in enumerate(AUDIT_FIELDS[1:], 1):
        setattr(audit, name, int(state[k]) if name == "checks" else float(state[k]))


def rk4p_run(rk, t0: float, h: float, k: int, stop: int, n: int, t_target: float) -> int:
    """``RK4P._fixed_run`` with runs of steps in C (same grid, checks and counts): steps
    k + 1 .. stop of the grid t0 + j h (n steps to t_target); returns stop."""
    while k < stop:            # the kernel checks the energy (stepping.h total_energy)
        count = min(RUN_LENGTH, stop - k)
        done, status = rk4p_c_steps(rk, t0, h, k, count)
        k += done
        rk.t = t0 + k * h if k < n else t_target
        rk.stats.nsteps += done
        if status == ckernel.ENERGY:
            rk._after_step()                         # says why
        elif status != ckernel.OK:                   # this step on the Python path
            k = Integrator._fixed_run(rk, t0, h, k, k + 1, n, t_target)
        if rk.limit is not None:
            rk.limit.check(rk.stats, rk.t, t_target)
    return stop


def rk4p_check_step(rk, h: float) -> bool:
    """One rk4p step of h from (rk.t, q, q') in C for the step-doubling check
    (``stated_accuracy.py``); False (nothing changed) when the Python step must take it."""
    done, status = rk4p_c_steps(rk, rk.t, h, 0, 1)
    return done == 1 and status in (ckernel.OK, ckernel.ENERGY)


def rk4p_c_steps(rk, t0: float, h: float, k: int, count: int) -> tuple[int, int]:
    """Steps k .. k + count - 1 of the grid t0 + j h in one C call: (steps done, status)."""
    eq = rk.equations
    if count == 1:
        start = t0 + h * k
        stage_inputs(rk, (start, start + 0.5 * h, start + h))
    else:
        starts = t0 + h * np.arange(k, k + count)
        stage_inputs(rk, (starts[:, None] + np.array([0.0, 0.5 * h, h])).ravel())
    audit = audit_state(rk.audit) if rk.audit is not None else NO_AUDIT
    n = rk.q.size
    q, qd, qdd, done, status = eq.ckernel.rk4p_steps(
        rk.q, rk.qd, rk.f[n:], h, count, rk._projection_tol(), PROJECTION_MAX_ITER,
        audit, ENERGY_DIVERGENCE_FRACTION, ENERGY_ROUNDOFF)
    if rk.audit is not None:
        audit_back(rk.audit, eq.ckernel.buf.audit)
        if status == ckernel.ENERGY:      # _after_step checks this state again: count it once
            rk.audit.checks -= 1
    rk.q, rk.qd, rk.f = q, qd, np.concatenate((qd, qdd))
    rk.stats.naccel += 4 * done
    rk.stats.nprojections += done
    return done, status


def tableau(rk) -> tuple:
    """(ns, A (ns, ns), B, E, E3 or None) of an embedded pair as the kernel takes them,
    then the stages' time fractions with 1 appended (the step's end)."""
    cls = type(rk)
    if cls not in _TABLEAUS:
        ns = rk.n_stages
        A = np.zeros((ns, ns))
        A[:, :rk.A.shape[1]] = rk.A[:ns]
        E, E3 = (rk.E5, rk.E3) if hasattr(rk, "E5") else (rk.E, None)
        _TABLEAUS[cls] = (A, rk.B, E, E3), np.append(rk.C[:ns], 1.0)
    arrays, fractions = _TABLEAUS[cls]
    return (*rk.equations.ckernel.tableau(cls, *arrays), fractions)


def prk_attempt(rk, h: float, c0: float, safety: float, min_factor: float,
                max_factor: float):
    """``ProjectedRK._attempt`` with the step's arithmetic in C: (accepted, next step,
    state), or None when the Python step must do it (the kernel handed it back). Near a
    singular configuration (c0, the indicator at the start, or the one at the step's end
    below NEAR_ZONE) the kernel estimates the error along the constraints, as the Python
    step does. The factors are projected_rk.py's."""
    t, n = rk.t, rk.q.size
    table = tableau(rk)
    stage_inputs(rk, t + h * table[-1])        # row s: stage s, then t + h
    local = rk.local_tolerance
    status, err, y_new, f_new, c1 = rk.equations.ckernel.prk_trial_near(
        table[:-1], h, rk.q, rk.qd, rk.f, local * rk.rtol, local * rk.atol,
        rk._projection_tol(), PROJECTION_MAX_ITER, c0, not rk.skip_end)
    if status in (ckernel.SINGULAR, ckernel.SPRING, ckernel.PROJECTION):
        return None
    ns = rk.n_stages
    y = np.concatenate((rk.q, rk.qd))
    K = rk.equations.ckernel.buf.K[:(ns + 1) * 2 * n].reshape(ns + 1, 2 * n).copy()
    # the step's end before the projection, summed as the kernel's runs sum it (stepping.h
    # weighted_sum), so that a dense output is the same whichever took the step
    y_end = np.zeros(2 * n)
    for j in range(ns):
        y_end += K[j] * rk.B[j]
    y_end = y + h * y_end
    rk.stats.naccel += ns - 1 if rk.skip_end else ns
    if status == ckernel.NOT_FINITE:
        return False, h * min_factor, None
    if status == ckernel.ERROR_NORM:
        return False, rejected_step(h, err, rk.alpha, safety, min_factor), None
    rk.stats.nprojections += 1
    q, qd = y_new[:n], y_new[n:]
    rejected = rk._energy_rejects(t + h, q, qd, h)
    if rejected is not None:
        return False, rejected, None
    rk.stats.naccel += 1
    rk.err_step = err
    return True, accepted_step(h, err, rk.err_old, rk.alpha, rk.beta, safety, max_factor), \
        (q, qd, f_new, c1, None if rk.skip_end else DenseStep(t, h, y, y_end, K))


def decide(rk, h, status, err, y_new, f_new, safety, min_factor, max_factor,
           energy_min_gain, end_evaluated: bool = False) -> tuple[bool, float]:
    """What ``ProjectedRK._step_impl`` decides on a trial step's outcome: accept it (q, q',
    f updated) or reject it, and the next step. ``end_evaluated``: the trial's last stage
    was already y' at the accepted end (minimal coordinates), not one more evaluation."""
    t, n = rk.t, rk.q.size
    rk.trial_status = status
    rk.stats.naccel += rk.n_stages
    if status == ckernel.NOT_FINITE:
        return False, h * min_factor
    if status == ckernel.ERROR_NORM:
        return False, rejected_step(h, err, rk.alpha, safety, min_factor)
    if status == ckernel.PROJECTION:
        return False, h * 0.5
    rk.stats.nprojections += 1
    q, qd = y_new[:n], y_new[n:]
    if rk.audit is not None:
        energy_err = rk.audit.step_error(rk.equations, t + h, q, qd)
        last, rk.energy_rejected = rk.energy_rejected, None
        if not energy_err <= 1.0 and (last is None or energy_err < energy_min_gain * last):
            rk.energy_rejected = energy_err
            return False, rejected_step(h, energy_err, rk.alpha, safety, min_factor)
    rk.q, rk.qd, rk.f = q, qd, f_new
    rk.stats.naccel += 0 if end_evaluated else 1
    rk.err_step = err
    return True, accepted_step(h, err, rk.err_old, rk.alpha, rk.beta, safety, max_factor)


def mc_step(rk, h: float, safety: float, min_factor: float, max_factor: float,
            energy_min_gain: float):
    """``minimal.MinimalCoordinates``'s step with its arithmetic in C (``mbd_mc_trial``):
    (accepted, next step), or None when the Python step must do it."""
    table = tableau(rk)
    stage_inputs(rk, rk.t + h * table[-1])
    kernel = rk.equations.ckernel
    status, err, y_new, f_new = kernel.mc_trial(
        kernel.partition(rk.independent), table[:-1], h, rk.q, rk.qd, rk.f, rk.rtol, rk.atol,
        rk._projection_tol(), PROJECTION_MAX_ITER)
    if status in (ckernel.SINGULAR, ckernel.SPRING):
        return None
    return decide(rk, h, status, err, y_new, f_new, safety, min_factor, max_factor,
                  energy_min_gain, end_evaluated=True)


# A CPU limit per communication step below this (s) keeps rk4p's steps in Python, where it
# is checked: the wrapper's own steps (at most a check interval of them) are not timed.
MIN_CPU_LIMIT = 0.01


def wrapper_steps(limit) -> int | None:
    """The steps (accepted or not) one communication step in C may take under ``limit``
    (a ``WorkLimit`` or None), or None when a short CPU limit keeps the steps in Python."""
    if limit is None:
        return 2 ** 62
    if limit.max_cpu is not None and limit.max_cpu < MIN_CPU_LIMIT:
        return None
    return limit.max_steps or 2 ** 62


def wrapper_attempts(limit) -> int | None:
    """``wrapper_steps`` for the wrapper's landing steps, which are not timed: under a CPU
    limit at most PRK_RUN_LENGTH, what Python's runs take between two checks of it."""
    attempts = wrapper_steps(limit)
    if attempts is not None and limit is not None and limit.max_cpu is not None:
        attempts = min(attempts, PRK_RUN_LENGTH)
    return attempts


def count_rk4p_work(stats, steps: int, checks: int) -> None:
    """The counters of ``steps`` rk4p steps and ``checks`` step-doubling checks taken in C
    (a check: three steps' work, four evaluations of eq. (14) and a projection each)."""
    stats.nsteps += steps
    stats.naccel += 4 * (steps + 3 * checks)
    stats.nprojections += steps + 3 * checks


def fast_prk_run(rk, limit, time_tol: float, factors: tuple,
                 stiff_limit: float | None = None) -> dict | None:
    """What ``ckernel/adaptive.h`` needs to take an embedded pair's coming communication
    steps as ``_advance_adaptive`` lands on them (ckernel.PrkRun's fields), or None when
    they must go through Python: another method, a watch after each step (unless
    ``stiff_limit`` says auto's watch can be kept in C: 0, nothing to check, or the h
    |lambda| above which a step goes to Python), an energy audit (or a scene whose restart
    would start one), a state inside the last step, a short CPU limit. ``factors``:
    projected_rk.py's (safety, min, max) step factors."""
    eq = rk.equations
    if rk.name not in ("rk45p", "dop853p") or (rk.watch is not None and stiff_limit is None) or \
            rk.audit is not None or \
            eq.nonconservative_reason() is None or eq.m == 0 or eq.ckernel is None or \
            rk.out is not None or rk.energy_rejected is not None:
        return None
    max_work = wrapper_attempts(limit)
    if max_work is None:
        return None
    # the wrapper's steps keep no dense output: y' at a trial's unprojected end serves only
    # an error estimate that weighs it (rk45p's) and auto's stiffness check
    skip_end = not (rk.error_reads_end or stiff_limit)
    return pair_settings(rk, factors, max_work) | dict(
        t_now=rk.t, time_tol=time_tol, stiff_limit=stiff_limit or 0.0, skip_end=int(skip_end),
        y=np.concatenate((rk.q, rk.qd)), f=rk.f)


def adopt_pair_state(rk, state: dict) -> None:
    """An embedded pair's state, controller and counters after steps the kernel took for
    the FMU's wrapper (``state``: t, h, err_old, indicator, landing, y, f, counters), as
    ``_advance_adaptive`` leaves them."""
    n = rk.q.size
    y = state["y"]
    rk.q, rk.qd, rk.f, rk.t, rk.h = y[:n].copy(), y[n:].copy(), state["f"], state["t"], state["h"]
    rk.err_old = state["err_old"]
    rk.zone.indicator, rk.zone.crossing, rk.zone.landing = state["indicator"], False, \
        state["landing"]
    for name, count in state["counters"].items():
        setattr(rk.stats, name, getattr(rk.stats, name) + count)


def adopt_prk_run(rk, state: dict) -> None:
    """``adopt_pair_state`` after the wrapper's landing steps (``fast_prk_run``), without a
    dense output: a step that lands on the communication point is never read inside."""
    adopt_pair_state(rk, state)
    rk.out = rk.dense = rk.energy_rejected = None


# Attempts per call of a run of an embedded pair's steps: the work limit is checked between.
PRK_RUN_LENGTH = 64
# ... without one: one call per output time on most runs, bounded so that an interrupt is seen.
PRK_RUN_LENGTH_FREE = 4096
# Runs of an embedded pair's steps in C (``prk_run``); False: one C trial per Python step.
PRK_RUNS = True


def held_forces(rk) -> np.ndarray | None:
    """The force inputs when they hold over rk's coming steps (the same held values at any
    time: ``Simulation.inputs_at``'s cache), else None."""
    first = rk.inputs(rk.t)
    return first.forces if first is rk.inputs(rk.t + 1.0) else None


def prk_runs(rk) -> bool:
    """Whether ``prk_run`` can take rk's coming steps (the caller checks that rk steps as
    ``ProjectedRK`` does): an embedded pair on a scene whose force inputs, if any, hold
    (``held_forces``), no driver taking its motion from the inputs, its drivers' motions
    ones the kernel evaluates (``motion_table``), no watch after each step (events,
    auto's)."""
    eq = rk.equations
    return (PRK_RUNS and rk.name in ("rk45p", "dop853p") and eq.ckernel is not None and
            eq.m > 0 and rk.watch is None and not eq.layout.drivers
            and (eq.ckernel.nf == 0 or held_forces(rk) is not None)
            and (not eq.scene.drivers or eq.ckernel.motion_table(eq.constraint_set) is not None))


def pair_settings(rk, factors: tuple, max_work: int) -> dict:
    """PrkRun's fields for rk's coming steps: its controller, tolerances and zone state;
    ``factors``: projected_rk.py's (safety, min, max) step factors."""
    return dict(h=rk.h, max_step=rk.max_step, exponent=-rk.alpha, safety=factors[0],
                min_factor=factors[1], max_factor=factors[2], beta=rk.beta, err_old=rk.err_old,
                rtol=rk.local_tolerance * rk.rtol, atol=rk.local_tolerance * rk.atol,
                tol=rk._projection_tol(), max_iter=PROJECTION_MAX_ITER,
                indicator=rk.zone.indicator, landing=int(rk.zone.landing), max_work=max_work)


def run_settings(rk, factors: tuple, energy: tuple, max_work: int) -> dict:
    """PrkPy's fields (PrkRun's in "run": ``pair_settings``) for a run of rk's steps."""
    last = rk.energy_rejected
    return dict(run=pair_settings(rk, factors, max_work), t=rk.t,
                energy_rejected=np.nan if last is None else last,
                step_factor=ENERGY_STEP_FACTOR, min_gain=energy[0], jump_limit=energy[1],
                divergence=ENERGY_DIVERGENCE_FRACTION, roundoff=ENERGY_ROUNDOFF)


def prk_run(rk, t_target: float, dense: bool, rejections: int, factors: tuple,
            energy: tuple) -> tuple[int, int]:
    """Steps of ``_advance_adaptive`` in C (``ckernel/adaptive.h`` ``mbd_prk_run``) until
    the target, a step Python must take or PRK_RUN_LENGTH attempts (then the work limit;
    PRK_RUN_LENGTH_FREE without one):
    the same decisions, counters, energy audit and dense output as the Python loop.
    ``factors``: projected_rk.py's (safety, min, max) step factors; ``energy``: its
    (ENERGY_MIN_GAIN, ENERGY_JUMP_LIMIT). Returns (the kernel's RUN_* status, steps
    rejected in a row)."""
    eq, n = rk.equations, rk.q.size
    table = tableau(rk)
    attempts = PRK_RUN_LENGTH if rk.limit is not None else PRK_RUN_LENGTH_FREE
    if rk.limit is not None and rk.limit.max_steps is not None:
        used = rk.stats.nsteps + rk.stats.nrejected - rk.limit.first
        attempts = max(1, min(attempts, rk.limit.max_steps - used))
    settings = run_settings(rk, factors, energy, attempts)
    settings.update(t_target=t_target, dense=int(dense), rejections=rejections)
    settings["run"]["skip_end"] = int(rk.skip_end)
    audit = audit_state(rk.audit) if rk.audit is not None else None
    motion = np.concatenate(eq.motion_values(rk.t))
    gaps = singular_zone.gaps(rk.C[:rk.n_stages])
    motions = (eq.ckernel.motion_table(eq.constraint_set), eq.constraint_set.offsets,
               table[-1]) if eq.scene.drivers else None
    forces = held_forces(rk) if eq.ckernel.nf else None
    status, p, b = ckernel_prk_run(eq.ckernel, table[:-1], gaps, settings, np.concatenate(
        (rk.q, rk.qd)), rk.f, motion, audit, motions, forces)
    r = p.r
    for name in ("nsteps", "nrejected", "naccel", "nprojections"):
        setattr(rk.stats, name, getattr(rk.stats, name) + int(getattr(r, name)))
    if rk.audit is not None:
        audit_back(rk.audit, b.audit)
        if status == RUN_ENERGY:               # _after_step checks this state again
            rk.audit.checks -= 1
    rk.energy_rejected = None if np.isnan(p.energy_rejected) else float(p.energy_rejected)
    rk.h, rk.zone.indicator, rk.err_old = float(r.h), float(r.indicator), float(r.err_old)
    rk.zone.crossing, rk.zone.landing = False, bool(r.landing)
    if p.stepped:
        rk.t = float(p.t)
        rk.q, rk.qd, rk.f = b.y[:n].copy(), b.y[n:].copy(), b.f.copy()
        rk.dense = None if rk.skip_end else DenseStep(p.t_old, p.h_old, b.y_old.copy(),
                                                      b.y_end.copy(), b.K_old.copy())
    return status, int(p.rejections)
