"""The accuracy a fixed-step run states, and the checks that keep it or stop the run.

A fixed-step method has no error control: the step is the user's choice. It still states
an accuracy, its rtol and atol (``SolverSettings``: FIXED_STEP_RTOL and FIXED_STEP_ATOL
unless given), and keeps it or stops with a ``SolverError`` naming the time and the reason,
by three checks that together leave no silently wrong run:

* the energy of a conservative scene (``energy_audit.py``) stays within ENERGY_TOL_FACTOR
  times what errors at the stated accuracy would change;
* methods that do not project (taylor, baumgarte) keep the constraint violation, a lower
  bound of their error, within ENERGY_TOL_FACTOR (atol + rtol L) (``Integrator.check_drift``);
* a step-doubling estimate (Richardson; Hairer, Norsett and Wanner, Solving ODEs I, sec.
  II.4): every SPOT_CHECK_EVERY steps, one step of the run's size and two half steps from
  the same state (then restored); their difference estimates the local error of a step,
  and every step until the next check is charged with it. The sum, an estimate of the
  global error of a stable run (``Counters.error_estimate``), must stay within
  ENERGY_TOL_FACTOR (atol + rtol L).
"""

from __future__ import annotations

import numpy as np

from ..errors import SolverError
from ..plain import Plain
from .energy_audit import ENERGY_TOL_FACTOR

# Steps between two step-doubling checks of a fixed-step run.
SPOT_CHECK_EVERY = 50
# Counters of evaluations, which a check adds to (its steps are not the run's steps).
WORK_FIELDS = ("naccel", "nprojections", "nnewton", "njev", "nlu")


def allowed_error(integrator) -> float:
    """The largest error (m or rad) a run's stated accuracy allows its checks."""
    return ENERGY_TOL_FACTOR * (integrator.atol + integrator.rtol
                                * integrator.equations.length_scale)


class ErrorEstimate(Plain):
    """The running step-doubling estimate of a fixed-step run: the last local error, the
    steps charged with errors so far and the steps since the last check."""

    plain_fields = ("local", "charged", "unchecked")
    flat_fields = True

    def __init__(self):
        self.local, self.charged, self.unchecked = 0.0, 0, SPOT_CHECK_EVERY

    def due(self) -> bool:
        return self.unchecked >= SPOT_CHECK_EVERY

    def spot_check(self, integrator, h: float) -> None:
        """The local error of a step of size h from the current state (which is kept)."""
        saved = integrator.get_state()
        del saved["accuracy"]             # this object: it goes on counting
        try:
            integrator._step_impl(h)
            one = integrator.q.copy()
            integrator.set_state(saved)
            integrator._step_impl(0.5 * h)
            integrator.t += 0.5 * h
            integrator._step_impl(0.5 * h)
            self.local = float(np.max(np.abs(one - integrator.q), initial=0.0))
        except SolverError:
            pass                          # the run itself will say why
        finally:
            work = integrator.stats
            integrator.set_state(saved)
            for name in WORK_FIELDS:      # the check's evaluations are work done
                setattr(integrator.stats, name, getattr(work, name))
        self.unchecked = 0

    def charge(self, integrator) -> None:
        """Charge the steps taken since the last call with the last local error; stop when
        the sum exceeds what the stated accuracy allows."""
        stats = integrator.stats
        done = stats.nsteps - self.charged
        self.charged = stats.nsteps
        self.unchecked += done
        stats.error_estimate += self.local * done
        allowed = allowed_error(integrator)
        if stats.error_estimate > allowed:
            raise SolverError(
                f"{integrator.name}: estimated error {stats.error_estimate:.3g} (step doubling: "
                f"{self.local:.2g} per step of {integrator.h:g} s) exceeds {allowed:.3g}, what "
                f"the stated accuracy rtol = {integrator.rtol:g}, atol = {integrator.atol:g} "
                "allows; use a smaller step", integrator.t)
