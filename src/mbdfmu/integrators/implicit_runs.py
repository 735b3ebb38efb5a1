"""Runs of genalpha's and ali3p's controlled steps (``step_control = "adaptive"``,
auto's stiff scenes) in the C kernel (``ckernel/implicit_run.h``): the steps of
``AdaptiveStepping._advance_adaptive`` up to the output time in one call, with
``StepControl._step_impl``'s acceptance and step factors, the commits and the energy
check after each step, the same decisions and counters as Python's loop taking the same C
attempts one at a time (tests/test_implicit_runs.py); and the same runs as an FMU's
communication steps taken by its wrapper without Python (``arm_fast_implicit``, read back
by ``adopt_fast_implicit``), which takes the fixed steps of a method named with its step
too (``can_run_fixed``: ``_advance_fixed``'s grid, the stated accuracy's estimate and
checks).

They apply to the kernel's attempts (``implicit_c.kernel_newton``) on a scene without
force inputs (the wrapper's: held over the step, or set by the master before it) whose
drivers' motions the kernel evaluates, with no watch after each step that would see them
(``can_run``). Python takes over at an attempt the kernel hands back, a commit that
fails, the energy audit's verdict, the step size failure, and checks the work limit
between runs.
"""

from __future__ import annotations

import math

from ..equations.projection import PROJECTION_MAX_ITER
from .base import STEP_COUNT_SLACK
from .c_steps import (PRK_RUN_LENGTH, PRK_RUN_LENGTH_FREE, RUN_ENERGY, audit_back, audit_state,
                      wrapper_attempts)
from .energy_audit import ENERGY_DIVERGENCE_FRACTION, ENERGY_ROUNDOFF
from .implicit_control import ERROR_SHARE, KEEP_GROWTH, MAX_CUT, MAX_GROWTH, SAFETY
from .newton import H_FINE, SAME_STEP
from .stated_accuracy import adopt_c_estimate, c_estimate

# Off: one C attempt per Python step (the tests compare the two).
IMPLICIT_RUNS = True


def step_state(method) -> tuple:
    """The method's state as the kernel's attempts take it: (q wrapped, turns, q', q'',
    genalpha's a or ali3p's q'', lam)."""
    a = method.a if method.name == "genalpha" else method.qdd
    return method.qw, method.turns, method.qd, method.qdd, a, method.lam


def can_run(method, held: bool = False) -> bool:
    """Whether ``implicit_run`` can take method's coming controlled steps: the kernel's
    attempts, a scene without force inputs (``held``: or with them held over the run, an
    FMU's wrapper) whose drivers' motions the kernel evaluates (``motion_table``), and no
    watch after each step that would see them (events; auto's, unless idle for this
    method: ``AutoWatch.idle``)."""
    kn, eq = method.c_newton, method.equations
    return (IMPLICIT_RUNS and kn is not None and method.adaptive and
            (held or kn.kernel.nf == 0) and not eq.layout.drivers and unwatched(method) and
            (not eq.scene.drivers or kn.kernel.motion_table(eq.constraint_set) is not None))


def unwatched(method) -> bool:
    """No watch after each step would see method's coming steps: none (events run their
    own), or auto's at rest for this method (``AutoWatch.idle``)."""
    watch = method.watch
    return watch is None or getattr(getattr(watch, "__self__", None), "idle",
                                    lambda _: False)(method)


def can_run_fixed(method) -> bool:
    """Whether an FMU's wrapper can take method's fixed steps (``_advance_fixed``): the
    kernel's attempts, no Newton failure pending, steps coarser than those whose ends
    ``crossing_step.py`` watches next to a singular configuration (or no constraints), the
    stated accuracy's estimate, and the scene's inputs and watch as ``can_run`` asks (auto
    runs genalpha at a fixed step after a switch for stiffness)."""
    kn, eq = method.c_newton, method.equations
    return (IMPLICIT_RUNS and kn is not None and not method.adaptive and unwatched(method)
            and method._failed is None and method.accuracy is not None
            and (method.h > H_FINE or eq.m == 0) and not eq.layout.drivers
            and (not eq.scene.drivers or kn.kernel.motion_table(eq.constraint_set) is not None))


def run_settings(method) -> tuple[dict, tuple | None]:
    """ImpRun's settings for method's coming steps: the energy check's and, under step
    control, its step and the controller's constants; and the drivers' motion table or
    None."""
    eq = method.equations
    settings = dict(divergence=ENERGY_DIVERGENCE_FRACTION, roundoff=ENERGY_ROUNDOFF)
    if method.adaptive:
        settings.update(h=method.h, max_step=method.max_step,
                        share_tol=ERROR_SHARE * method._tolerance(), safety=SAFETY,
                        max_growth=MAX_GROWTH, max_cut=MAX_CUT, keep_growth=KEEP_GROWTH)
    table = ((method.c_newton.kernel.motion_table(eq.constraint_set), eq.constraint_set.offsets)
             if eq.scene.drivers else None)
    return settings, table


def implicit_run(method, t_target: float, rejections: int) -> tuple[int, int]:
    """Controlled steps of ``_advance_adaptive`` (``StepControl._step_impl``, the energy
    check after each) in one C call until t_target, an attempt Python must take, or
    PRK_RUN_LENGTH attempts when a work limit is set (PRK_RUN_LENGTH_FREE without): the
    same decisions and counters as the Python loop. Returns (the kernel's RUN_* status,
    steps rejected in a row)."""
    kn, eq, stats = method.c_newton, method.equations, method.stats
    attempts = PRK_RUN_LENGTH if method.limit is not None else PRK_RUN_LENGTH_FREE
    if method.limit is not None and method.limit.max_steps is not None:
        used = stats.nsteps + stats.nrejected - method.limit.first
        attempts = max(1, min(attempts, method.limit.max_steps - used))
    method.matrix._lu = None        # a Python path's factors: the kernel keeps its own
    settings, table = run_settings(method)
    settings.update(t=method.t, t_target=t_target, max_work=attempts, rejections=rejections)
    audit = audit_state(method.audit) if method.audit is not None else None
    status, r, state, audit_after = kn.kernel.implicit_run(
        kn.prepare(method), method.matrix.kept, step_state(method), settings,
        eq.motion_values(method.t), audit, table)
    kn.count(stats)
    stats.nsteps += int(r.nsteps)
    stats.nrejected += int(r.nrejected)
    if audit is not None:
        audit_back(method.audit, audit_after)
        if status == RUN_ENERGY:    # _after_step checks this state again
            method.audit.checks -= 1
    method.h = float(r.h)
    if r.stepped:
        method.t = float(r.t)
        method.qw, method.turns, method.qd, method.qdd, a, method.lam = state
        if method.name == "genalpha":
            method.a = a
        method.q = method.qw + 2.0 * math.pi * method.turns
    return status, int(r.rejections)


def arm_fast_implicit(method, kernel, limit, time_tol: float, u, inputs, published,
                      reinitialize_tol: float) -> tuple | None:
    """The arguments of the FMU slave's ``arm_fast_steps`` for the coming communication
    steps as method's controlled or fixed steps in ``kernel`` (``Kernel.arm_implicit_steps``)
    from its state, the force inputs ``u`` held, publishing ``published`` (value
    references, places); ``inputs``: (value references, places in u.forces) of the force
    inputs the wrapper may take from fmi2SetReal, then restarting as
    ``Simulation._reinitialize`` does with ``reinitialize_tol`` (none in a scene with an
    energy audit, which the restart would start). None when the steps must go through
    Python (``can_run``, ``can_run_fixed``, another kernel, a short CPU limit)."""
    kn = method.c_newton
    if not (can_run(method, held=True) or can_run_fixed(method)) or kn.kernel is not kernel:
        return None
    max_work = wrapper_attempts(limit)
    if max_work is None:
        return None
    method.matrix._lu = None
    settings, table = run_settings(method)
    settings.update(t_now=method.t, time_tol=time_tol, max_work=max_work,
                    tol=reinitialize_tol, max_iter=PROJECTION_MAX_ITER)
    if not method.adaptive:
        settings.update(fixed=1, h_max=method.h, slack=STEP_COUNT_SLACK, same_step=SAME_STEP,
                        estimate=c_estimate(method))
    audit = audit_state(method.audit) if method.audit is not None else None
    if method.equations.nonconservative_reason() is None:
        inputs = ((), ())
    return kernel.arm_implicit_steps(kn.prepare(method), method.matrix.kept, step_state(method),
                                     settings, method.equations.motion_values(method.t, u),
                                     u.forces, audit, table, inputs, *published)


def adopt_fast_implicit(method, taken: dict) -> None:
    """The state, step, energy audit, stated accuracy's estimate and counters the
    wrapper's steps left (``Kernel.implicit_taken``), as ``_advance_adaptive`` or
    ``_advance_fixed`` leaves them."""
    kn, stats = method.c_newton, method.stats
    kn.count(stats)
    kn.prepare(method)
    stats.nsteps += taken["nsteps"]
    stats.nrejected += taken["nrejected"]
    stats.naccel += taken["restarts"]        # each restart's q'', as Python's
    method.t, method.out = taken["t"], None
    if method.adaptive:
        method.h = taken["h"]
    method.qw, method.turns, method.qd, method.qdd, a, method.lam = taken["state"]
    if method.name == "genalpha":
        method.a = a
    method.q = method.qw + 2.0 * math.pi * method.turns
    if method.audit is not None:
        audit_back(method.audit, taken["audit"])
    if taken["estimate"] is not None:
        adopt_c_estimate(method, taken["estimate"])
    if taken["restarts"]:     # a restart made a fresh iteration matrix (KernelMatrix's)
        method.matrix._lu = None
