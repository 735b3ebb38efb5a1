"""The Newton iteration and the base class of the implicit index-3 methods (``genalpha``,
``ali3p``).

Both solve a nonlinear system per step by Newton's method with an iteration matrix that is
evaluated (``njev``) and factorised (``nlu``) only when needed: it is kept across iterations
and steps while the iteration contracts fast enough, and refreshed at the current iterate
when it does not (a modified Newton method, Hairer and Wanner, Solving ODEs II, sec. IV.8).
A step whose iteration fails is retried internally as two half steps, recursively (scipy's
way with Radau/BDF); only when that also fails does the run stop, with a ``SolverError``
that names the time and the reason.
"""

from __future__ import annotations

import numpy as np
import scipy.linalg

from ..errors import SolverError
from ..plain import Plain
from .base import Integrator

_getrf, _getrs = scipy.linalg.lapack.dgetrf, scipy.linalg.lapack.dgetrs

# Newton has converged when the increment dq and the constraint residual Psi (max-norms, m or
# rad) fall below h atol / 2: the position error it leaves becomes a velocity error of about
# 2 |dq| / h through the integration formulas (and a systematic one, since every step starts
# from the same side), so atol bounds that velocity error. Never less than this times the
# mechanism's size (round-off).
NEWTON_TOL_FLOOR = 1e-13
# Iterations allowed per attempt (with a fresh matrix, Newton converges in 2-4).
NEWTON_MAX_ITER = 12
# Contraction rate ||dq_k|| / ||dq_k-1|| above which a kept matrix is re-evaluated, and
# growth rate that means divergence with a fresh one.
NEWTON_SLOW_RATE = 0.3
NEWTON_DIVERGING_RATE = 2.0
# Times a failed step is halved before the run stops.
MAX_HALVINGS = 8
# A pivot below this times the largest one: the iteration matrix is singular.
SINGULAR_PIVOT = 1e-13


def newton_tolerance(atol: float, h: float, length_scale: float) -> float:
    """Convergence threshold of a Newton iteration on positions (m, rad) with step h."""
    return max(0.5 * h * atol, NEWTON_TOL_FLOOR * length_scale)


def converged(increment: float, residual: np.ndarray, Psi: np.ndarray, tol: float) -> bool:
    """Positions hold the constraints to tol, and either the last increment or the dynamic
    residual (as a displacement: residual / M) is below tol.

    The residual test matters near singular configurations, where the increments along the
    direction that loses rank shrink only slowly although the equations already hold.
    """
    if Psi.size and float(np.max(np.abs(Psi))) > tol:
        return False
    return increment <= tol or float(np.max(np.abs(residual))) <= tol


def increment_converged(size: float, previous: float | None, tol: float) -> bool:
    """After an increment of max-norm ``size``: is the remaining error below tol?

    Estimated as theta / (1 - theta) * size with the observed contraction theta =
    size / previous (Hairer and Wanner II, eq. IV.8.10); after a first increment, that
    increment must be ten times below tol.
    """
    if previous is None:
        return size <= 0.1 * tol
    theta = size / previous if previous > 0 else 0.0
    return theta < 1.0 and theta / (1.0 - theta) * size <= tol


def check_rate(matrix, size: float, previous: float | None) -> float | None:
    """Watch the contraction: re-evaluate a kept matrix that converges slowly (returns None
    to restart the rate), fail when a fresh one diverges. Returns the new 'previous'."""
    if previous is not None and size > NEWTON_SLOW_RATE * previous:
        if not matrix.fresh:
            matrix.lu = None
            return None
        if size > NEWTON_DIVERGING_RATE * previous:
            raise NewtonFailure(f"Newton diverges (increment {size:.3g} after {previous:.3g})")
    return size


class NewtonFailure(Exception):
    """A step's Newton iteration that did not converge: retried with a smaller step."""


class IterationMatrix(Plain):
    """An LU factorisation kept between Newton iterations and steps, with its step size."""

    plain_fields = ("lu", "h", "fresh")

    def __init__(self):
        self.lu = None
        self.h = None
        self.fresh = False   # evaluated at the current step's iterate

    def valid_for(self, h: float) -> bool:
        return self.lu is not None and self.h == h

    def factor(self, S: np.ndarray, h: float, stats) -> None:
        stats.njev += 1
        stats.nlu += 1
        if not np.all(np.isfinite(S)):
            raise NewtonFailure("non-finite iteration matrix")
        lu, piv, info = _getrf(S)
        pivots = np.abs(np.diag(lu))
        if info != 0 or pivots.min() <= SINGULAR_PIVOT * pivots.max():
            self.lu = None
            raise NewtonFailure("the iteration matrix is singular (redundant constraints or a "
                                "singular configuration)")
        self.lu, self.h, self.fresh = (lu, piv), h, True

    def solve(self, b: np.ndarray) -> np.ndarray:
        # LAPACK directly: scipy's wrapper costs more than the solve at these sizes.
        x, info = _getrs(self.lu[0], self.lu[1], b)
        return x


def newton_iterate(evaluate, build_matrix, apply, matrix: IterationMatrix, h: float,
                   tol: float, mass: np.ndarray, stats) -> None:
    """Newton's method on a step's equations until they hold to ``tol``.

    ``evaluate()`` returns the residual at the current iterate as (dynamic (n,), Psi (m,)),
    the dynamic rows already scaled to a displacement times the mass; ``build_matrix()``
    the iteration matrix there (called only when the kept one is dropped); ``apply(dx)``
    moves the iterate by the increment dx = -S^-1 (dynamic, Psi). Raises NewtonFailure.
    """
    if not matrix.valid_for(h):
        matrix.lu = None
    matrix.fresh = False
    previous, size, Psi = None, np.inf, np.zeros(0)
    n = mass.size
    for _ in range(NEWTON_MAX_ITER):
        stats.nnewton += 1
        dynamic, Psi = evaluate()
        if not np.all(np.isfinite(dynamic)):
            raise NewtonFailure("non-finite residual")
        if converged(size, dynamic / mass, Psi, tol):
            return
        if matrix.lu is None:
            matrix.factor(build_matrix(), h, stats)
        dx = -matrix.solve(np.concatenate((dynamic, Psi)))
        size = float(np.max(np.abs(dx[:n])))
        if not np.isfinite(size):
            raise NewtonFailure("non-finite Newton increment")
        apply(dx)
        if increment_converged(size, previous, tol):
            return
        previous = check_rate(matrix, size, previous)
    raise NewtonFailure(f"Newton did not converge in {NEWTON_MAX_ITER} iterations (last "
                        f"increment {size:.3g}, constraint residual "
                        f"{np.max(np.abs(Psi), initial=0.0):.3g}, tolerance {tol:.3g})")


def advance_with_halving(try_step, t: float, h: float, name: str, depth: int = 0) -> int:
    """Run ``try_step(t, h)``; on ``NewtonFailure`` do two half steps instead, recursively.

    Returns the number of halvings used (rejected attempts). Raises ``SolverError`` with the
    time and the last reason after ``MAX_HALVINGS`` levels.
    """
    try:
        try_step(t, h)
        return 0
    except NewtonFailure as exc:
        if depth >= MAX_HALVINGS:
            raise SolverError(f"{name}: Newton iteration failed even with the step halved "
                              f"{MAX_HALVINGS} times (to {h:.3g} s): {exc}", t) from None
    rejected = 1 + advance_with_halving(try_step, t, h / 2, name, depth + 1)
    return rejected + advance_with_halving(try_step, t + h / 2, h / 2, name, depth + 1)


class ImplicitMethod(Integrator):
    """Base of the implicit index-3 methods: q'' and lam carried from step to step, one
    Newton iteration matrix kept across steps, a failed step halved (``_try_step(t, h)``
    does one step or raises NewtonFailure)."""

    state_fields = ("qdd", "lam", "matrix")

    def restart(self):
        self.qdd, self.lam = self.accelerations(self.t, self.q, self.qd)
        self.matrix = IterationMatrix()

    def _step_impl(self, h):
        self.stats.nrejected += advance_with_halving(self._try_step, self.t, h, self.name)
        return True, h

    def _try_step(self, t: float, h: float) -> None:
        raise NotImplementedError

    def saddle_matrix(self, top_left: np.ndarray, J: np.ndarray,
                      bottom_right: np.ndarray | None = None) -> np.ndarray:
        """[[top_left, J^T], [J, bottom_right]], (n + m) square; bottom_right zero if None."""
        n, m = self.equations.n, self.equations.m
        S = np.zeros((n + m, n + m))
        S[:n, :n] = top_left
        S[:n, n:] = J.T
        S[n:, :n] = J
        if bottom_right is not None:
            S[n:, n:] = bottom_right
        return S
