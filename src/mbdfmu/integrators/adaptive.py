"""The step loop of adaptive methods, which keeps their accuracy independent of the outputs.

An adaptive method's accuracy must not depend on where the outputs (an FMU's
communication points) fall. With ``dense=True`` (the inputs over the coming steps are
known) it steps past an output time and gives the state there from its dense output
(``Integrator.output_state``); the steps go on from their own ends, so outputs do not
change the run at all. Otherwise it lands on the output time with a step cut short, or two
equal steps instead of a tiny last one, and then goes on with the step size its
controller proposed before the cut (the cut says nothing about the next step), as
SUNDIALS' ``tstop`` and the "tstops" of DifferentialEquations.jl do.

The embedded pairs' step control is a PI controller (Gustafsson 1991; the "stabilised"
control of Hairer's DOPRI5 and DOP853 codes, Solving ODEs I sec. IV.2): the factor of an
accepted step is safety err^-alpha err_old^beta, with err_old the error of the last step
whose proposal the loop kept. It damps the growth that otherwise runs into a rejection
where the error rises step after step; beta = 0 is the I controller. A step cut short to
land on an output time keeps neither its proposal nor its error, for the same reason as
above.
"""

from __future__ import annotations

from ..errors import SolverError

# The smallest step, relative to the time, before an adaptive method gives up.
MIN_STEP_RELATIVE = 1e-13
# Steps an adaptive method may reject in a row before giving up.
MAX_REJECTIONS_IN_A_ROW = 60
# Landing on an output time: a step up to this factor longer than proposed lands on it ...
LAND_STRETCH = 1.01
# ... and when less than this factor of the proposed step would be left after a full step,
# the rest is taken as two equal steps (no tiny last step).
LAND_SPLIT = 1.5
# The PI controller's memory starts at this error (Hairer's FACOLD) and never goes below it.
ERR_OLD_MIN = 1e-4


def accepted_step(h: float, err: float, err_old: float, alpha: float, beta: float,
                  safety: float, max_factor: float) -> float:
    """The step proposed after an accepted step of size h with error norm err (PI)."""
    if err == 0:
        return h * max_factor
    return h * min(max_factor, safety * err ** -alpha * err_old ** beta)


def rejected_step(h: float, err: float, alpha: float, safety: float,
                  min_factor: float) -> float:
    """The step to retry with after a step of size h rejected with error norm err."""
    return h * max(min_factor, safety * err ** -alpha)


class AdaptiveStepping:
    """The ``_advance_adaptive`` of ``Integrator.advance`` for adaptive methods (a mixin:
    ``_step_impl`` returns (accepted, h_next) from the step controller)."""

    def _landing(self, h: float, t_target: float) -> tuple[float, bool]:
        """The step towards an output time to land on, and whether it lands there."""
        remaining = t_target - self.t
        if LAND_STRETCH * h >= remaining:
            return remaining, True
        if remaining < LAND_SPLIT * h:
            return 0.5 * remaining, False
        return h, False

    def _advance_adaptive(self, t_target: float, dense: bool) -> None:
        if dense and self.t >= t_target:
            self.out = self._output_at(t_target)
            return
        self.out = None
        rejections = 0
        while self.t < t_target:
            taken = self._steps_in_c(t_target, dense, rejections)
            if taken is not None:
                rejections, python = taken
                if self.limit is not None:
                    self.limit.check(self.stats, self.t, t_target)
                if not python:
                    continue
                if self.t >= t_target:
                    break
            h_min = MIN_STEP_RELATIVE * max(1.0, abs(self.t))
            proposal = min(self.h, self.max_step)
            h, lands = (proposal, False) if dense else self._landing(proposal, t_target)
            planned = self._plan_step(h, lands, proposal)
            lands = lands and planned == h
            h = planned
            self.rejections_in_a_row = rejections     # for step controls that read it
            accepted, h_next = self._step_impl(h)
            if accepted:
                rejections = 0
                self.stats.nsteps += 1
                self.t = t_target if lands else self.t + h
                # a step cut short (to land, or by the plan) says nothing about the next one
                cut = h < proposal and h_next >= h
                self.h = proposal if cut else h_next
                if not cut:
                    self._error_kept()
                self._after_step()
            else:
                rejections += 1
                self.stats.nrejected += 1
                self.h = h_next
                if h_next < h_min or rejections > MAX_REJECTIONS_IN_A_ROW:
                    self._step_size_failed()
            if self.limit is not None:
                self.limit.check(self.stats, self.t, t_target)
        if self.t > t_target:
            self.out = self._output_at(t_target)   # from dense output

    def _error_kept(self) -> None:
        """The accepted step's error becomes the controller's memory (PI controllers)."""

    def _step_size_failed(self):
        raise SolverError(f"{self.name}: step size fell to {self.h:.3g} s without meeting "
                          f"rtol={self.rtol:g}, atol={self.atol:g}" + self.singularity_hint(),
                          self.t)

    def _steps_in_c(self, t_target: float, dense: bool, rejections: int):
        """Steps of this loop taken in C (``c_steps.prk_run``) with the same decisions:
        None when there are none to take, else (steps rejected in a row, whether Python
        takes the next attempt)."""
        return None
