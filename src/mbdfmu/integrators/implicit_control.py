"""Step-size control of the implicit index-3 methods (``genalpha``, ``ali3p``).

A method named by the user runs at its fixed step (its stated accuracy kept by
``stated_accuracy.py``); with the option ``step_control = "adaptive"``, and whenever
``auto`` chooses it, it controls its step like the adaptive methods (``adaptive.py``) with
a local error estimate from the step's own accelerations: the difference of the
accelerations at the two ends of a step is h q^(3), and each method's position formula
differs from Taylor's by a known multiple of h^3 q^(3) (``_local_error``: Geradin and
Cardona, Flexible Multibody Dynamics, 2001, sec. 4.6, for Newmark and generalized-alpha;
-1/12 for the trapezoidal rule). Nothing is evaluated for it beyond the step.

The error is controlled per unit step (Shampine, Numerical Solution of ODEs, 1994, sec.
5.1): a step of size h may leave at most ERROR_SHARE (atol + rtol L) h / T_REF, L the mechanism's size
(angles count times L), so that the errors of the steps of one T_REF of simulated time add
up to the tolerance, not to the tolerance times the number of steps. With a local error
~ h^3 this allows h ~ sqrt(tol), and the global error of a run over T_REF stays near the
tolerance.

A stiff spring's fast oscillation shows in a_{n+1} - a_n with an amplitude that says
nothing about the position error it causes (its positions move by a / w^2, not h^2 a).
The estimate is therefore filtered through the step's iteration matrix, as Radau5 does
(Hairer and Wanner, Solving ODEs II, sec. IV.8, eq. 8.20):
err = [S^-1 (M e, 0)]_q with S = [[M + G C + D K, Psi_q^T], [Psi_q, 0]], which leaves
slow components as they are, divides a stiff one by about D k / m = (h w)^2 beta', and
keeps only the part tangent to the constraints (the normal part is projected out by the
index-3 position constraints). The steps then follow the slow motion and their number per
simulated second does not grow with the stiffness. After a rejected step the estimate is
filtered twice, as Radau5 does on its first and rejected steps (ibid., p. 124): a stiff
mode rung by a sudden force (a push along a stiff spring) leaves a filtered error that no
longer falls with h, since the filter divides it by about (h w)^2, so that cutting the step
only made it larger relative to what the step may leave, down to steps that resolve the
ringing.

The step is kept unless it may grow by KEEP_GROWTH or must be cut: the Newton
iteration matrix is then reused (``newton.IterationMatrix`` is kept for one step size).
"""

from __future__ import annotations

import math

import numpy as np

from .adaptive import AdaptiveStepping
from .base import Option
from .newton import T_REF, NewtonFailure

STEP_CONTROL = Option("step_control", '"fixed" or "adaptive"',
                      lambda v: v in ("fixed", "adaptive"))
# Share of the tolerance per unit step given to the local position error: the estimate
# leaves out the velocity's local error (also O(h^3)), which the motion then carries into
# the positions, and the errors of a pendulum-like motion grow along it (measured on a
# stiff pendulum over 1 s: about 4 times the sum of the estimates).
ERROR_SHARE = 0.2
# Step factor's safety, largest growth and largest cut per step.
SAFETY = 0.8
MAX_GROWTH = 2.0
MAX_CUT = 0.2
# An accepted step is followed by one of the same size unless it may grow by this factor
# (it never shrinks: a step that turns out too long is rejected and cut).
KEEP_GROWTH = 1.25


class StepControl(AdaptiveStepping):
    """Adaptive mode of an ``ImplicitMethod`` (a mixin before it in the bases): the method
    implements ``_attempt(t, h) -> x`` (a step not yet taken, or NewtonFailure),
    ``_commit(x)`` and ``_local_error(x, h)`` (n,) in its coordinates' units."""

    def restart(self):
        super().restart()
        if self.adaptive and self.h is None:
            self.h = self._initial_step()

    def _tolerance(self) -> float:
        return self.atol + self.rtol * self.equations.length_scale

    def _initial_step(self) -> float:
        """A first step whose error, if q^(3) were about q'' per second, would be within
        the tolerance; the controller corrects it after one step."""
        L = self.equations.length_scale
        scaled = self.qdd.reshape(-1, 3) * np.array([1.0, 1.0, L])
        accel = float(np.max(np.abs(scaled), initial=0.0))
        h = math.sqrt(self._tolerance() * T_REF / accel) if accel > 0 else self.default_step
        return min(self.max_step, h)

    def _error_ratio(self, x: dict, h: float) -> float:
        """The step's local error over what a step of size h may leave (<= 1: accepted)."""
        eq = self.equations
        err = self._local_error(x, h)
        if self.matrix.lu is not None:
            # filtered through the iteration matrix (stiff components count as the
            # method damps them, tangent to the constraints); after a rejection twice
            passes = 2 if getattr(self, "rejections_in_a_row", 0) > 0 else 1
            for _ in range(passes):
                err = self.matrix.solve(np.concatenate((eq.mass * err, np.zeros(eq.m))))[:eq.n]
        err = err.reshape(-1, 3) * np.array([1.0, 1.0, eq.length_scale])
        allowed = ERROR_SHARE * self._tolerance() * h / T_REF
        return float(np.max(np.abs(err), initial=0.0)) / allowed

    def _step_impl(self, h):
        if not self.adaptive:
            return super()._step_impl(h)
        try:
            x = self._attempt(self.t, h)
        except NewtonFailure:
            return False, 0.5 * h
        ratio = self._error_ratio(x, h)
        factor = SAFETY / math.sqrt(ratio) if ratio > 0 else MAX_GROWTH
        if ratio > 1.0:
            return False, h * max(MAX_CUT, min(factor, 0.9))
        self._commit(x)
        factor = min(MAX_GROWTH, factor)
        if factor < KEEP_GROWTH:
            factor = 1.0
        return True, h * factor
