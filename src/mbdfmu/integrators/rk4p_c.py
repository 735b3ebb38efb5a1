"""rk4p's runs with the loop of ``Integrator._advance_fixed`` in the C kernel: its steps,
the energy check after each, and the stated accuracy's step-doubling checks with their
charges (``ckernel/fixed.h`` ``mbd_fixed_advance``; ``stated_accuracy.py`` is the
reference of the rule, which the kernel follows to round-off, taking the same decisions).

The kernel evaluates the drivers' motions (``ckernel/fixed.py`` ``motion_table``) and holds
the force inputs, so a run goes there when its inputs cannot change over it. It hands
back, with nothing of the turn lost, what Python must do: a check whose step fails, a step
that fails (both then on rk4p's usual path), an energy check or a charge that stops the
run (Python's check and charge then say why).
"""

from __future__ import annotations

import numpy as np

from ..equations import ckernel
from ..equations.ckernel.fixed import CHECK, ESTIMATE
from ..equations.projection import PROJECTION_MAX_ITER
from .base import STEP_COUNT_SLACK, Integrator
from .c_steps import (RUN_LENGTH, audit_back, audit_state, count_rk4p_work, rk4p_c_steps,
                      wrapper_steps)
from .energy_audit import ENERGY_DIVERGENCE_FRACTION, ENERGY_ROUNDOFF
from .stated_accuracy import adopt_c_estimate, c_estimate


def inputs_held(rk, t_target: float):
    """(the drivers' motion table, the force inputs) when the kernel can take rk's run to
    t_target (motions it evaluates, force inputs held over the run), else None."""
    eq = rk.equations
    table = eq.ckernel.motion_table(eq.constraint_set)
    if table is None:
        return None
    if not eq.ckernel.nf:
        return table, None
    first = rk.inputs(rk.t)
    # the same object at both ends: the held inputs' cache (c_steps.stage_inputs)
    return (table, first.forces) if first is rk.inputs(t_target) else None


def advance_fixed(rk, t_target: float) -> bool:
    """``_advance_fixed`` to t_target in C; False (nothing done) when Python's loop takes
    it: at most RUN_LENGTH steps and no check due on the way (one call of
    ``c_steps.rk4p_run``, which costs less to make), no C kernel or constraints, inputs
    the kernel does not hold."""
    eq, accuracy = rk.equations, rk.accuracy
    if eq.ckernel is None or eq.m == 0 or rk.watch_each_step:
        return False
    t0, n, h = rk.fixed_grid(t_target)
    if not accuracy.due() and n <= min(RUN_LENGTH, accuracy.every - accuracy.unchecked):
        return False
    held = inputs_held(rk, t_target)
    if held is None:
        return False
    k = 0
    while k < n:
        timed = rk.limit is not None and rk.limit.max_cpu is not None
        status, k, stop = _turns(rk, held, (t0, h, n, t_target), k,
                                 k + RUN_LENGTH if timed else n)
        if status == CHECK:                     # this turn on Python's path
            rk.accuracy.spot_check(rk, h)
            stop = min(n, k + max(1, rk.accuracy.every - rk.accuracy.unchecked))
        elif status == ckernel.ENERGY:
            rk._after_step()                    # says why
        if status == ESTIMATE:
            rk.accuracy.charge(rk, h)           # says why
        elif status != ckernel.OK:              # the turn's rest on rk4p's path
            k = rk._fixed_run(t0, h, k, stop, n, t_target)
            rk.accuracy.charge(rk, h)
        if rk.limit is not None:
            rk.limit.check(rk.stats, rk.t, t_target)
    return True


def _turns(rk, held, grid, k: int, pause: int) -> tuple[int, int, int]:
    """Turns of the loop in C from grid step k until one ends at or past ``pause``; rk
    where the kernel left it. Returns (status, k, the turn's last step)."""
    eq = rk.equations
    audit = audit_state(rk.audit) if rk.audit is not None else None
    run = dict(tol=rk._projection_tol(), max_iter=PROJECTION_MAX_ITER, estimate=c_estimate(rk),
               q=rk.q, qd=rk.qd, f=rk.f, divergence=ENERGY_DIVERGENCE_FRACTION,
               roundoff=ENERGY_ROUNDOFF)
    steps_before = rk.stats.nsteps
    status, k, stop, rk.q, rk.qd, rk.f, estimate, state = eq.ckernel.fixed_advance(
        run, held[0], eq.constraint_set.offsets, held[1], audit, grid, k, pause)
    t0, h, steps, t_target = grid
    rk.t = t0 + k * h if k < steps else t_target
    count_rk4p_work(rk.stats, estimate["nsteps"] - steps_before, estimate["checks"])
    adopt_c_estimate(rk, estimate)
    if audit is not None:
        audit_back(rk.audit, state)
        if status == ckernel.ENERGY:      # _after_step checks this state again: count it once
            rk.audit.checks -= 1
    return status, k, stop


def watched_run(rk, t0: float, h: float, k: int, stop: int, n: int, t_target: float) -> int:
    """``_fixed_run`` with the event runner's watch after each step (``watch_each_step``):
    steps k + 1 .. stop of the grid t0 + j h (n steps to t_target), each one C call, so
    that they are the arithmetic of the FMU wrapper's (fixed.h), which watches the same
    event functions in C; returns stop. The energy check is the kernel's, after the watch
    as in ``_after_step`` (fixed.h checks in that order too)."""
    for j in range(k, stop):
        done, status = rk4p_c_steps(rk, t0, h, j, 1)
        if done == 1 and status in (ckernel.OK, ckernel.ENERGY):
            rk.t = t0 + (j + 1) * h if j + 1 < n else t_target
            rk.stats.nsteps += 1
            if status == ckernel.OK:
                rk.watch(rk)
            else:
                rk._after_step()                  # the watch, then the audit says why
        else:                                     # this step on the Python path
            Integrator._fixed_run(rk, t0, h, j, j + 1, n, t_target)
        if rk.limit is not None:
            rk.limit.check(rk.stats, rk.t, t_target)
    return stop


def fast_run(rk, limit, time_tol: float) -> dict | None:
    """What ``ckernel/fixed.h`` needs to take rk4p's coming communication steps as
    ``_advance_fixed`` would (its grid, its step-doubling checks, its energy audit's
    state or None, its work limit), or None when they must go through Python: another
    method, no constraints, a short CPU limit."""
    eq = rk.equations
    if rk.name != "rk4p" or eq.m == 0 or eq.ckernel is None or rk.out is not None:
        return None
    max_steps = wrapper_steps(limit)
    if max_steps is None:
        return None
    return dict(t_now=rk.t, time_tol=time_tol, h_max=rk.h, slack=STEP_COUNT_SLACK,
                max_steps=max_steps, tol=rk._projection_tol(), max_iter=PROJECTION_MAX_ITER,
                estimate=c_estimate(rk), y=np.concatenate((rk.q, rk.qd)), f=rk.f,
                audit=None if rk.audit is None else audit_state(rk.audit),
                divergence=ENERGY_DIVERGENCE_FRACTION, roundoff=ENERGY_ROUNDOFF)


def adopt_fast_run(rk, steps: int, t: float, y, f, estimate: dict, audit) -> None:
    """The state, counters, error estimate and energy audit (``audit``: its state, or
    None) after ``steps`` rk4p steps and the checks among them the FMU's wrapper took in C
    (``fast_run``), as ``_advance_fixed`` with ``rk4p_run`` leaves them."""
    n = rk.q.size
    rk.q, rk.qd, rk.f, rk.t = y[:n].copy(), y[n:].copy(), f, t
    count_rk4p_work(rk.stats, steps, estimate["checks"])
    adopt_c_estimate(rk, estimate)
    if rk.audit is not None:
        audit_back(rk.audit, audit)
