"""The accuracy a fixed-step run states, and the checks that keep it or stop the run.

A fixed-step method has no error control: the step is the user's choice. It still states
an accuracy, its rtol and atol (``SolverSettings``: FIXED_STEP_RTOL and FIXED_STEP_ATOL
unless given), and keeps it or stops with an ``AccuracyError`` (a ``SolverError``) naming
the time and the reason, by three checks that together leave no silently wrong run:

* the energy of a conservative scene (``energy_audit.py``) stays within ENERGY_TOL_FACTOR
  times what errors at the stated accuracy would change;
* methods that do not project (taylor, baumgarte) keep the constraint violation, a lower
  bound of their error, within ENERGY_TOL_FACTOR (atol + rtol L) (``Integrator.check_drift``);
* a step-doubling estimate (Richardson; Hairer, Norsett and Wanner, Solving ODEs I, sec.
  II.4): at the intervals below (SPOT_CHECK_*), one step of the run's size and two half steps from
  the same state (then restored); their differences, times Richardson's factor for the
  method's orders (a method's ``orders``: of q's and q''s local errors, DEFAULT_ORDERS
  unless it states others), estimate the local errors dq and dq' of a step,
  and every step until the next check is charged with them. The global
  position error at t is estimated as the sum of each step's dq plus its dq' carried to t,
  ``sum_i dq_i + dq'_i (t - t_i)`` (the error propagation of q'' = 0), for the methods
  that carry velocity errors (``carry_velocity_error`` set: the explicit ones keep
  every velocity error they make; genalpha and ali3p damp what their step does not
  resolve, a stiff spring's, so only their position errors are summed). The position error
  alone misses what a velocity error does later: taylor's q' is only first order (local
  error O(h^2) against q's O(h^3)), and summed dq stayed far below the error of runs that
  were wrong by order one (docs/accuracy.md); counting dq' bounds such runs. The estimate
  (``Counters.error_estimate``) must stay within ENERGY_TOL_FACTOR (atol + rtol L).

This module is the reference of the estimate's rule. rk4p's runs (``rk4p_c.py``) and an
FMU's rk4p doSteps take the checks, charges and intervals in the C kernel
(``ckernel/fixed.h``), which follows it to the same decisions and estimate
(tests/test_fixed_estimate_c.py runs both side by side).
"""

from __future__ import annotations

import numpy as np

from ..errors import AccuracyError, SolverError
from ..plain import Plain
from .energy_audit import ENERGY_TOL_FACTOR

# Steps between two step-doubling checks of a fixed-step run. A check costs three steps and
# a save and two restores of the state, which in Python weigh as much as a few hundred
# compiled rk4p steps, so checks are sampled: the first after SPOT_CHECK_EVERY steps, then
# the interval doubles up to the steps taken so far over SPOT_CHECK_SHARE (at most
# SPOT_CHECK_MAX), and halves when a check finds a local error more than SPOT_CHECK_CHANGE
# times the one charged (it grows faster than it is sampled: checks every 50 steps missed
# the peak of Andrews' mechanism's local error and under-estimated 30 times). Steps are
# charged with an envelope of the checks: the last one's local error, or the envelope
# before it times SPOT_CHECK_DECAY if larger, so that an error varying along a period
# (a crank's turn) is charged near its peak however the checks fall on it; the steps since
# the last check are charged again when a check finds more.
SPOT_CHECK_EVERY = 4
SPOT_CHECK_SHARE = 4
SPOT_CHECK_MAX = 200
SPOT_CHECK_CHANGE = 2.0
SPOT_CHECK_DECAY = 0.5
# Local errors below this fraction of what the stated accuracy allows are rounding (their
# ratios are noise, and two kernels would sample differently): no rise is read from them.
SPOT_CHECK_FLOOR = 1e-9
# The orders of q's and q''s local errors of methods that state none: genalpha, ali3p.
DEFAULT_ORDERS = (2, 2)


def richardson_factor(order: int) -> float:
    """A step h and two of h/2 differ by C h^(p+1) (1 - 2^-p) for a local error C h^(p+1)
    (order p): the step's own error is 2^p / (2^p - 1) times that difference."""
    return 2.0 ** order / (2.0 ** order - 1.0)
# Counters of evaluations, which a check adds to (its steps are not the run's steps).
WORK_FIELDS = ("naccel", "nprojections", "nnewton", "njev", "nlu")


def allowed_error(integrator) -> float:
    """The largest error (m or rad) a run's stated accuracy allows its checks."""
    return ENERGY_TOL_FACTOR * (integrator.atol + integrator.rtol
                                * integrator.equations.length_scale)


class ErrorEstimate(Plain):
    """The running step-doubling estimate of a fixed-step run: the last local errors of q
    (m or rad) and q' (m/s or rad/s), the sums charged so far (dq, dq' and dq' t_i), the
    steps charged and the steps since the last check."""

    plain_fields = ("local", "local_v", "sum_q", "sum_v", "sum_vt", "charged", "unchecked",
                    "every", "since")
    flat_fields = True

    def __init__(self):
        self.local, self.local_v, self.charged, self.unchecked = 0.0, 0.0, 0, SPOT_CHECK_EVERY
        self.sum_q = self.sum_v = self.sum_vt = 0.0
        self.every = SPOT_CHECK_EVERY     # steps from one check to the next
        self.since = 0                    # steps charged since the last check

    def due(self) -> bool:
        return self.unchecked >= self.every

    def spot_check(self, integrator, h: float) -> None:
        """The local error of a step of size h from the current state (which is kept)."""
        t = integrator.t                  # where the steps since the last check end
        saved = integrator.rollback_point()
        del saved["accuracy"]             # this object: it goes on counting
        try:
            step = getattr(integrator, "check_step", integrator._step_impl)  # a faster path
            step(h)
            one, one_v = integrator.q.copy(), integrator.qd.copy()
            _restore(integrator, saved, keep_work=True)
            step(0.5 * h)
            integrator.t += 0.5 * h
            step(0.5 * h)
            p_q, p_v = getattr(integrator, "orders", DEFAULT_ORDERS)
            local = richardson_factor(p_q) * float(np.max(np.abs(one - integrator.q),
                                                          initial=0.0))
            local_v = richardson_factor(p_v) * float(np.max(np.abs(one_v - integrator.qd),
                                                            initial=0.0)) \
                if getattr(integrator, "carry_velocity_error", False) else 0.0
            self._resample(integrator, t, h, local, local_v)
        except SolverError:
            pass                          # the run itself will say why
        finally:
            _restore(integrator, saved, keep_work=True)
        self.unchecked = self.since = 0

    def _resample(self, integrator, t: float, h: float, local: float,
                  local_v: float) -> None:
        """Take a check's local errors into the envelope charged per step; charge the steps
        since the last check with what it adds; set the interval to the next check."""
        env_q = max(local, SPOT_CHECK_DECAY * self.local)
        env_v = max(local_v, SPOT_CHECK_DECAY * self.local_v)
        floor = SPOT_CHECK_FLOOR * allowed_error(integrator)
        rising = (local > max(SPOT_CHECK_CHANGE * self.local, floor)
                  or local_v > max(SPOT_CHECK_CHANGE * self.local_v, floor))
        self._add(t, h, self.since, max(0.0, env_q - self.local),
                  max(0.0, env_v - self.local_v))
        self.local, self.local_v = env_q, env_v
        grow = min(SPOT_CHECK_MAX, max(SPOT_CHECK_EVERY,
                                       integrator.stats.nsteps // SPOT_CHECK_SHARE))
        self.every = max(1, self.every // 2) if rising else min(grow, 2 * self.every)

    def _add(self, t: float, h: float, steps: int, dq: float, dv: float) -> None:
        """Charge ``steps`` steps of size h ending at t with local errors dq and dv."""
        self.sum_q += dq * steps
        self.sum_v += dv * steps
        self.sum_vt += dv * steps * (t - 0.5 * steps * h)   # at the steps' middle

    def charge(self, integrator, h: float) -> None:
        """Charge the steps of size h taken since the last call with the last local errors;
        stop when the estimated global error exceeds what the stated accuracy allows."""
        stats, t = integrator.stats, integrator.t
        done = stats.nsteps - self.charged
        self.charged = stats.nsteps
        self.unchecked += done
        self.since += done
        self._add(t, h, done, self.local, self.local_v)
        stats.error_estimate = self.sum_q + max(0.0, t * self.sum_v - self.sum_vt)
        allowed = allowed_error(integrator)
        if stats.error_estimate > allowed:
            raise AccuracyError(
                f"{integrator.name}: estimated error {stats.error_estimate:.3g} (step doubling: "
                f"{self.local:.2g} in q and {self.local_v:.2g} in q' per step of {h:g} s, "
                f"carried to t) exceeds {allowed:.3g}, what the stated accuracy rtol = "
                f"{integrator.rtol:g}, atol = {integrator.atol:g} allows; use a smaller step",
                integrator.t)


def c_estimate(integrator) -> dict:
    """The running estimate, the run's step count and the rule's constants as the C
    kernel's ``Estimate`` takes them (``ckernel/fixed.h`` applies this module's rule to
    rk4p's runs and an FMU's steps without leaving C; this module stays the reference)."""
    accuracy, stats, allowed = integrator.accuracy, integrator.stats, allowed_error(integrator)
    p_q, p_v = getattr(integrator, "orders", DEFAULT_ORDERS)
    return dict({name: getattr(accuracy, name) for name in ErrorEstimate.plain_fields},
                nsteps=stats.nsteps, checks=0, estimate=stats.error_estimate,
                allowed=allowed, floor=SPOT_CHECK_FLOOR * allowed,
                factor_q=richardson_factor(p_q), factor_v=richardson_factor(p_v),
                carry=int(getattr(integrator, "carry_velocity_error", False)),
                first=SPOT_CHECK_EVERY, share=SPOT_CHECK_SHARE, most=SPOT_CHECK_MAX,
                change=SPOT_CHECK_CHANGE, decay=SPOT_CHECK_DECAY)


def adopt_c_estimate(integrator, values: dict) -> None:
    """The estimate as the C kernel left it (``c_estimate``'s fields): the running sums
    and the error estimate; the caller counts the steps and the checks' work."""
    for name in ErrorEstimate.plain_fields:
        setattr(integrator.accuracy, name, values[name])
    integrator.stats.error_estimate = values["estimate"]


def _restore(integrator, point: dict, keep_work: bool = False) -> None:
    """``set_state`` from a rollback point that stays usable: its flat objects copied
    again (set_state takes them as they are, and the steps change them). ``keep_work``:
    the evaluations counted since (WORK_FIELDS) stay counted, a check's work being done."""
    work = integrator.stats
    fresh = {}
    for name, value in point.items():
        if isinstance(value, Plain):
            value = object.__new__(type(value))
            value.__dict__.update(point[name].__dict__)
        fresh[name] = value
    integrator.set_state(fresh)
    if keep_work:
        for name in WORK_FIELDS:
            setattr(integrator.stats, name, getattr(work, name))
