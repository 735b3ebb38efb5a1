"""Fixed steps of genalpha and ali3p across a singular configuration: no step ends inside it.

At a step's end next to a singular configuration (``singularity_indicator`` s of Psi_q
small) the index-3 equations fix the positions along the direction where Psi_q loses rank
only to the positions' rounding over s: the step ends with that coordinate off by about
eps / s, and the next steps take it back through the velocities, an energy jump that does
not shrink with h (P2's crossings, docs/accuracy.md). At fine steps the jump is larger than
the method's error. So a fixed step whose end lands within ZONE of the configuration is not
taken: the run takes one step of 2 h over it instead and goes on on its grid. One step of
another size per crossing adds an O(h^3) local error (the methods handle a step-size change
as their step control does), so the order stays 2.

It applies below H_FINE only (coarse steps are as before), where the step can be merged
with the next one within the current run of steps (an output or communication point, or
the stated accuracy's spot check, is never stepped over), and while the mechanism
approaches a singular configuration: the indicator at the current state is below
APPROACH_STEPS times its change over the last checked step, or ZONE times SAFETY (not with
redundant constraints, whose indicator stays zero). Clear of the zone, the indicator is
checked again only after QUIET_STEPS steps: a master's communication steps of one step
each would otherwise pay one evaluation per step.
"""

from __future__ import annotations

import math

from . import singular_zone
from .base import grid_step_taken
from .newton import H_FINE, NewtonFailure, advance_with_halving

# A step must not end where the singularity indicator is below this: P2's steps ending
# within |sin theta| of about 3e-6 of the crossing left energy jumps of 2e-10 to 6e-10 J.
ZONE = 1e-5
# Single steps (with their end checked) start this many steps before the zone at the
# current rate of the indicator, or below ZONE * SAFETY when the rate is not known yet.
APPROACH_STEPS = 80
SAFETY = 10.0
# An indicator below this at two checks in a row: Psi_q stays rank-deficient (redundant
# constraints), there is nothing to step across.
RANK_DEFICIENT = 1e-9
# Steps after a check that found the zone at least APPROACH_STEPS steps away at its rate,
# before the next check (half of them: the rate may grow meanwhile).
QUIET_STEPS = APPROACH_STEPS // 2


class CrossingWatch:
    """The indicator at the last checked state, to tell when the zone comes near."""

    def __init__(self):
        self.t = None
        self.indicator = None
        self.quiet_until = -math.inf    # no check before this time (s): the zone was far

    def approaching(self, method, h: float) -> bool:
        """Whether the next steps must be checked one at a time."""
        if h > H_FINE or method.equations.m == 0:
            return False
        if self.t is not None and self.t <= method.t < self.quiet_until:
            return False
        now = end_indicator(method, method.t, method.qw)
        near = now < ZONE * SAFETY
        if self.t is not None and max(now, self.indicator) < RANK_DEFICIENT:
            near = False        # redundant constraints: no configuration to step across
        elif self.t is not None and method.t > self.t:
            rate = abs(now - self.indicator) / (method.t - self.t)
            near = near or now < ZONE + APPROACH_STEPS * h * rate
        else:
            near = True
        self.t, self.indicator = method.t, now
        self.quiet_until = -math.inf if near else method.t + QUIET_STEPS * h
        return near


def end_indicator(method, t: float, qw) -> float:
    return singular_zone.indicator(method, t, qw)     # in C where the kernel is


def crossing_steps(method, t: float, h: float, mergeable: bool) -> int:
    """One step from t of h, or of 2 h if h's end falls in the zone (or its Newton iteration
    fails there) and ``mergeable``; returns the grid steps covered (1 or 2). Raises
    NewtonFailure (the caller halves)."""
    try:
        x, failure = method._attempt(t, h), None
        in_zone = end_indicator(method, t + h, method.qw + x["dq"]) < ZONE
    except NewtonFailure as exc:
        x, failure, in_zone = None, exc, True
    if mergeable and in_zone:
        history = method.step_change(2.0)
        try:
            x2 = method._attempt(t, 2.0 * h)
        except NewtonFailure:
            x2 = None
        if x2 is not None and end_indicator(method, t + 2.0 * h, method.qw + x2["dq"]) >= ZONE:
            method._commit(x2)
            method.step_change(0.5)
            return 2
        method.restore_history(history)
    if failure is not None:
        raise failure
    method._commit(x)
    return 1


def fixed_run_across(method, t0: float, h: float, k: int, stop: int, n: int,
                     t_target: float, watch: CrossingWatch) -> int:
    """Steps k + 1 .. stop of the grid t0 + j h as ``Integrator._fixed_run``, each with
    ``crossing_steps`` while ``watch`` says the zone is near; returns the step reached
    (stop, or earlier when the zone is no longer near)."""
    while k < stop:
        if not watch.approaching(method, h):
            return k
        t = method.t
        try:
            done = crossing_steps(method, t, h, mergeable=k + 2 <= stop)
        except NewtonFailure:
            method.stats.nrejected += advance_with_halving(method._try_step, t, h,
                                                           method.name)   # as always
            done = 1
        k += done
        grid_step_taken(method, t0 + k * h if k < n else t_target, t_target)
    return k
