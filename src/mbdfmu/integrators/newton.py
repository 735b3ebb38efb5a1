"""The Newton iteration and the base class of the implicit index-3 methods (``genalpha``,
``ali3p``).

Both solve a nonlinear system per step by Newton's method with an iteration matrix that is
evaluated (``njev``) and factorised (``nlu``) only when needed: it is kept across iterations
and steps while the iteration contracts fast enough, and refreshed at the current iterate
when it does not (a modified Newton method, Hairer and Wanner, Solving ODEs II, sec. IV.8).
A step whose iteration fails is retried internally as two half steps, recursively (scipy's
way with Radau/BDF); only when that also fails does the run stop, with a ``SolverError``
that names the time and the reason.

How far Newton is iterated. A position error dq that Newton leaves becomes a velocity error
of about 2 dq / h and an acceleration error of dq / (beta h^2) that every later step
inherits, and with a kept matrix it has the same sign step after step: over the T / h
steps of a run it adds up like T^2 dq / h^2. So the error left must shrink like h^2, which
at the usual steps is below the rounding of the coordinates: the iteration goes on until
its increments are rounding noise (``NewtonTolerances``), i.e. they fall below the noise
level of the iteration matrix, or stop shrinking with a fresh matrix while below
``stagnation``. Rounding is also why the methods keep their angles wrapped and iterate on
the step's increment (``ImplicitMethod``): the noise is eps times the size of the
coordinates, and a crank that has turned ten times has angles twenty times the size of its
mechanism. Near a singular configuration (``singularity_indicator`` of the matrix's Psi_q
below NEAR_SINGULAR_INDICATOR) the iteration contracts slowly along the direction that
loses rank, and the noise grows like 1 / indicator^2: there the tolerance is a looser one
that still shrinks like h^2 below T_NEAR (``near_singular``).

The size of an increment counts the multipliers too, as the displacement
M^-1 Psi_q^T D dlam they cause (``IterationMatrix.increment_size``; genalpha's): near a
singular configuration a kept matrix corrects the positions at once but the multipliers
slowly. ali3p's multipliers along the direction where Psi_q loses rank are set by its
penalty and do not act on the motion: ali3p counts its positions only.

Small increments prove convergence only with a matrix evaluated in the step: with a kept
matrix, once the increments have converged, the iteration goes on until the dynamic
residual (as a displacement) is within ``tolerances.residual`` (a kept matrix that does not
reduce it by NEWTON_SLOW_RATE is re-evaluated; an increment with a fresh one ends it).
Increments that stop shrinking at the noise level with a fresh matrix end it only if the
residual is within the near-singular tolerance too (``_dynamics_hold``). ``_converged``
(before an increment) accepts a last increment within the tolerance from a kept matrix
except at fine steps next to a singular configuration (``_at_rounding``), where the
tolerance is the positions' rounding and says nothing of the dynamics.

The residual tolerances, as accelerations, shrink like h^2 below H_FINE: a displacement
floor (the positions' rounding) is an acceleration error ~ 1 / h^2 (P2's error over 10 s
grew as h shrank, docs/accuracy.md). Next to a singular configuration at fine steps, a
fresh matrix's increments of its noise level end the iteration instead of a halving.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np
import scipy.linalg

from ..equations.singular import singularity_indicator
from ..errors import SolverError
from ..plain import Plain
from .base import Integrator

_getrf, _getrs = scipy.linalg.lapack.dgetrf, scipy.linalg.lapack.dgetrs

# The rounding of a coordinate, relative to its size.
ROUNDOFF = 4.0 * np.finfo(float).eps
# Newton's tolerances never use an atol looser than this (a fixed-step run's stated
# accuracy may be loose; the iteration is not), and never fall below this times the
# mechanism's size.
NEWTON_ATOL_MAX = 1e-8
NEWTON_TOL_FLOOR = 1e-13
T_REF = 1.0     # time scale (s) over which Newton's errors add up (module docstring)
# Rounding noise grows near a singular configuration like 1 / indicator^2, up to NOISE_MAX.
NOISE_MAX = 1e-6
# Below this singularity indicator of the matrix's Psi_q, the near-singular tolerance; below
# H_FINE, this times (h / H_FINE)^2 down to the floor (fine steps converge there with the
# ordinary one, and on P2 the looser one cost ali3p 5e-8 J per crossing at h = 2.5e-5).
NEAR_SINGULAR_INDICATOR, NEAR_SINGULAR_FLOOR = 0.1, 1e-3
# Below this step the near-singular tolerance shrinks like h^2.
T_NEAR = 2e-3
# Below this step the residual tolerances, as accelerations, shrink like h^2.
H_FINE = 1e-4
# Iterations allowed per attempt (with a fresh matrix, Newton converges in 2-4).
NEWTON_MAX_ITER = 12
# Contraction rate ||dq_k|| / ||dq_k-1|| above which a kept matrix is re-evaluated, and
# growth rate that means divergence with a fresh one.
NEWTON_SLOW_RATE = 0.3
NEWTON_DIVERGING_RATE = 2.0
# Times a failed step is halved before the run stops.
MAX_HALVINGS = 8
# Grid steps within this (relative) of the method's step are it (``fixed_grid``).
SAME_STEP = 1e-9
# A pivot below this times the largest one: the iteration matrix is singular.
SINGULAR_PIVOT = 1e-13


class NewtonTolerances(NamedTuple):
    """A step's tolerances (positions in m or rad; ``residual`` as a displacement):
    ``tol`` what a converged iterate is within, ``stagnation`` below which increments that
    stop shrinking with a fresh matrix are noise, ``near_singular`` the tolerance near a
    singular configuration, ``near_residual`` the dynamic residual's there, ``size`` the
    coordinates' size (for the noise level)."""

    tol: float
    residual: float
    stagnation: float
    near_singular: float
    near_residual: float
    size: float


def newton_tolerances(atol: float, h: float, length_scale: float, q: np.ndarray,
                      D: float, accelerations: np.ndarray) -> NewtonTolerances:
    """The tolerances of a step of size h from positions q with accelerations of the size of
    ``accelerations``; D converts an acceleration residual to a displacement (the dynamic
    rows' scaling). See the module docstring."""
    atol = min(atol, NEWTON_ATOL_MAX)
    size = max(length_scale, float(np.max(np.abs(q), initial=0.0)))
    stagnation = max(0.5 * h * atol, NEWTON_TOL_FLOOR * length_scale)
    fine = min(1.0, h / H_FINE) ** 2     # module docstring
    residual = D * max(atol / T_REF ** 2 * fine,
                       ROUNDOFF * float(np.max(np.abs(accelerations), initial=1.0)))
    near = stagnation * min(1.0, h / T_NEAR)
    return NewtonTolerances(
        tol=min(0.5 * atol * (h / T_REF) ** 2, 0.01 * ROUNDOFF * size),
        residual=residual, stagnation=stagnation,
        near_singular=max(near, ROUNDOFF * size),
        # without the positions' rounding floor (module docstring)
        near_residual=max(0.5 * h * atol * min(1.0, h / T_NEAR) * fine, residual),
        size=size)


class IterationMatrix(Plain):
    """An LU factorisation kept between Newton iterations and steps, with its step size and
    the singularity indicator of the Psi_q it was evaluated with."""

    plain_fields = ("lu", "h", "fresh", "indicator", "reach")

    def __init__(self):
        self.lu = None
        self.h = None
        self.fresh = False   # evaluated at the current step's iterate
        self.indicator = 1.0
        self.reach = None    # M^-1 Psi_q^T: a scaled multiplier increment as a displacement

    def valid_for(self, h: float) -> bool:
        return self.lu is not None and self.h == h

    def factor(self, S: np.ndarray, J: np.ndarray, h: float, stats,
               mass: np.ndarray | None = None) -> None:
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
        self.indicator = singularity_indicator(J) if J.shape[0] else math.inf
        # a multiplier increment D dlam changes the accelerations by M^-1 J^T dlam, i.e.
        # moves the positions by M^-1 J^T D dlam (nothing along the null space of J^T)
        self.reach = (J / mass).T if J.shape[0] and mass is not None else None

    def increment_size(self, dx: np.ndarray, n: int) -> float:
        """Max-norm of a Newton increment as a displacement: the positions' part and what
        the multipliers' part does to them (a multiplier left unconverged is an error in
        the accelerations however small the position increment)."""
        size = float(np.max(np.abs(dx[:n])))
        if dx.size > n and self.reach is not None:
            size = max(size, float(np.max(np.abs(self.reach @ dx[n:]))))
        return size

    def near_singular(self) -> bool:
        fine = min(1.0, self.h / H_FINE) ** 2 if self.h else 1.0
        return self.indicator < max(NEAR_SINGULAR_INDICATOR * fine, NEAR_SINGULAR_FLOOR)

    def noise(self, tolerances: NewtonTolerances, length_scale: float) -> float:
        """The rounding noise of the increments this matrix gives, within the stagnation
        tolerance and NOISE_MAX."""
        noise = ROUNDOFF * tolerances.size / max(self.indicator ** 2, 1e-300)
        return max(tolerances.stagnation, min(noise, NOISE_MAX * length_scale))

    def solve(self, b: np.ndarray) -> np.ndarray:
        # LAPACK directly: scipy's wrapper costs more than the solve at these sizes.
        x, info = _getrs(self.lu[0], self.lu[1], b)
        return x


class NewtonFailure(Exception):
    """A step's Newton iteration that did not converge: retried with a smaller step."""


def _at_rounding(tols: NewtonTolerances, h: float) -> bool:
    """The near-singular tolerance is the positions' rounding (fine steps)."""
    return tols.near_singular > tols.stagnation * min(1.0, h / T_NEAR)


def _converged(tols: NewtonTolerances, matrix: IterationMatrix, size: float,
               residual: np.ndarray, Psi: np.ndarray, h: float) -> bool:
    """Before an increment: Psi within the tolerance, and the last increment or the dynamic
    residual (as a displacement) too; near a singular configuration the looser one."""
    near = matrix.near_singular()
    if near:
        tol, residual_tol = tols.near_singular, tols.near_residual
    else:
        tol, residual_tol = tols.tol, tols.residual
    if Psi.size and float(np.max(np.abs(Psi))) > tol:
        return False
    if float(np.max(np.abs(residual))) <= residual_tol:
        return True
    # near a singular configuration an increment at the positions' rounding says nothing
    # of the dynamic residual
    return size <= tol and not (near and _at_rounding(tols, h))


def _dynamics_hold(tols: NewtonTolerances, residual: np.ndarray, noise: bool = False) -> bool:
    """The dynamic residual (as a displacement) within its tolerance; after increments of
    rounding noise, within what that noise allows near a singular configuration."""
    tol = max(tols.near_residual, tols.near_singular) if noise else tols.residual
    return float(np.max(np.abs(residual))) <= tol


def _increment_converged(tols, matrix, size, previous, length_scale) -> str | None:
    """After an increment of max-norm ``size``: is the remaining error below the tolerance?
    Estimated as theta / (1 - theta) size with the contraction theta = size / previous
    (Hairer and Wanner II, eq. IV.8.10); a first increment must be ten times below it:
    "estimate". Increments of the rounding noise's size that stop shrinking with a fresh
    matrix: "noise" (converged if the dynamic residual holds, ``_dynamics_hold``)."""
    tol = tols.near_singular if matrix.near_singular() else tols.tol
    if previous is None:
        return "estimate" if size <= 0.1 * tol else None
    theta = size / previous if previous > 0 else 0.0
    if matrix.fresh and size <= matrix.noise(tols, length_scale) and \
            NEWTON_SLOW_RATE < theta <= NEWTON_DIVERGING_RATE:
        return "noise"
    return "estimate" if theta < 1.0 and theta / (1.0 - theta) * size <= tol else None


def _check_rate(matrix, tols, size, previous, length_scale):
    """Watch the contraction: re-evaluate a kept matrix that converges slowly (returns None
    to restart the rate), fail when a fresh one diverges (increments of rounding noise that
    grow are not divergence: near a singular configuration, the matrix's noise level).
    Returns the new 'previous'."""
    if previous is not None and size > NEWTON_SLOW_RATE * previous:
        if not matrix.fresh:
            matrix.lu = None
            return None
        if size > NEWTON_DIVERGING_RATE * previous and size > matrix.noise(tols, length_scale):
            raise NewtonFailure(f"Newton diverges (increment {size:.3g} after {previous:.3g})")
    return size


def newton_iterate(evaluate, build_matrix, apply, matrix: IterationMatrix, h: float,
                   tols: NewtonTolerances, mass: np.ndarray, length_scale: float, stats, *,
                   count_multipliers: bool = True) -> None:
    """Newton's method on a step's equations until they hold to the rounding noise.

    ``evaluate()`` returns the residual at the current iterate as (dynamic (n,), Psi (m,)),
    the dynamic rows already scaled to a displacement times the mass; ``build_matrix()``
    the iteration matrix there and Psi_q (called only when the kept one is dropped);
    ``apply(dx)`` moves the iterate by the increment dx = -S^-1 (dynamic, Psi). Raises
    NewtonFailure. ``count_multipliers``: increments include the multipliers' part
    (``IterationMatrix.increment_size``).
    """
    if not matrix.valid_for(h):
        matrix.lu = None
    matrix.fresh = False
    previous, size, Psi = None, np.inf, np.zeros(0)
    n = mass.size
    unchecked, last = False, None   # positions converged with a kept matrix; residual
    for _ in range(NEWTON_MAX_ITER):
        stats.nnewton += 1
        dynamic, Psi = evaluate()
        if not np.all(np.isfinite(dynamic)):
            raise NewtonFailure("non-finite residual")
        if _converged(tols, matrix, size, dynamic / mass, Psi, h):
            return
        if unchecked:
            if _dynamics_hold(tols, dynamic / mass, unchecked == "noise"):
                return
            rsize = float(np.max(np.abs(dynamic / mass)))
            if last is not None and rsize > NEWTON_SLOW_RATE * last:
                matrix.lu = None
            last = rsize
        if matrix.lu is None:
            matrix.factor(*build_matrix(), h, stats, mass if count_multipliers else None)
        dx = -matrix.solve(np.concatenate((dynamic, Psi)))
        size = matrix.increment_size(dx, n)
        if not np.isfinite(size):
            raise NewtonFailure("non-finite Newton increment")
        apply(dx)
        if unchecked:
            if matrix.fresh and unchecked == "estimate":
                return
            continue
        unchecked = _increment_converged(tols, matrix, size, previous, length_scale)
        if unchecked == "estimate" and matrix.fresh:
            return
        previous = _check_rate(matrix, tols, size, previous, length_scale)
    residual = float(np.max(np.abs(Psi), initial=0.0))
    if size <= tols.stagnation and residual <= tols.stagnation:
        return      # rounding noise above the tolerance near a singular configuration
    if matrix.fresh and matrix.near_singular() and residual <= tols.near_singular and \
            size <= matrix.noise(tols, length_scale) and _at_rounding(tols, h):
        # at fine steps (the near-singular tolerance at the positions' rounding), next to
        # the singular configuration: increments of the noise that a halving cannot reduce
        return
    raise NewtonFailure(f"Newton did not converge in {NEWTON_MAX_ITER} iterations (last "
                        f"increment {size:.3g}, constraint residual {residual:.3g}, "
                        f"tolerance {tols.tol:.3g})")


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


def wrap_angles(q: np.ndarray, periodic: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(q with the ``periodic`` angles in [-pi, pi), the 2 pi multiples taken off)."""
    turns = np.where(periodic, np.floor((q + math.pi) / (2.0 * math.pi)), 0.0)
    return q - 2.0 * math.pi * turns, turns


class ImplicitMethod(Integrator):
    """Base of the implicit index-3 methods: q'' and lam carried from step to step, one
    Newton iteration matrix kept across steps, a failed step halved (``_try_step(t, h)``
    does one step or raises NewtonFailure).

    The steps work on ``qw``, the positions with the angles that enter the equations only
    through sine and cosine (``Equations.periodic_angles``) wrapped into [-pi, pi)
    (``turns`` holds the 2 pi multiples taken off), so that their rounding is that of the
    mechanism's size; ``q`` (outputs) is qw + 2 pi turns, never read back by the steps."""

    state_fields = ("qdd", "lam", "matrix", "qw", "turns")

    def restart(self):
        self.qdd, self.lam = self.accelerations(self.t, self.q, self.qd)
        self.periodic = self.equations.periodic_angles()
        self.qw, self.turns = wrap_angles(self.q, self.periodic)
        self.matrix = IterationMatrix()

    def _set_positions(self, qw: np.ndarray) -> None:
        """The step's new wrapped positions: wrapped again, and q for the outputs."""
        again, turns = wrap_angles(qw, self.periodic)
        self.qw, self.turns = again, self.turns + turns
        self.q = self.qw + 2.0 * math.pi * self.turns

    def _unwrapped(self, qw: np.ndarray) -> np.ndarray:
        """Positions near qw with the angles of q (for forces, which may use the angles)."""
        return qw + 2.0 * math.pi * self.turns

    def fixed_grid(self, t_target: float) -> tuple[float, int, float]:
        """The method's own step where n of them land on t_target to rounding: the run must
        not depend on its output points ((t_target - t0) / n differs in its last bits)."""
        t0, n, h = super().fixed_grid(t_target)
        if abs(n * self.h - (t_target - t0)) <= SAME_STEP * (t_target - t0):
            h = self.h
        return t0, n, h

    def _step_impl(self, h):
        self.stats.nrejected += advance_with_halving(self._try_step, self.t, h, self.name)
        return True, h

    def _try_step(self, t: float, h: float) -> None:
        """One step from t to t + h (updates the state) or NewtonFailure."""
        self._commit(self._attempt(t, h))

    def _attempt(self, t: float, h: float) -> dict:
        raise NotImplementedError

    def _commit(self, x: dict) -> None:
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
