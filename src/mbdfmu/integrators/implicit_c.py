"""genalpha's and ali3p's steps in the C kernel (``equations/ckernel/implicit.h``).

The C code is the Python step line for line (predictor, ``newton.newton_iterate`` with its
convergence test, the step's end) on another linear solver for the iteration matrix
[[K, Psi_q^T], [Psi_q, -E]] (``kernel_newton`` chooses):

- the banded Schur complement Psi_q K^-1 Psi_q^T + E, where K is diagonal or
  block-diagonal: no line rows (translational and slot joints: their geometric stiffness
  couples coordinates) and forces of the state that each act on one moving body (springs
  and dampers to the ground, forces off a centre of mass: K has 3 x 3 blocks, their force
  Jacobians by forward differences as forces.py does them; genalpha with ``jacobian =
  "mass"``: any forces). Its cost grows linearly with the mechanism.
- otherwise a dense LU with partial pivoting of the whole matrix (``implicit_dense.h``),
  K built as the Python step builds it (the line rows' geometric stiffness, every force
  Jacobian by forward differences one coordinate at a time), up to DENSE_MAX unknowns
  n + m: the slider-crank, the crane, springs between two moving bodies.

Larger mechanisms of the second kind, and an attempt the kernel hands back (K or the
Schur complement near singular, a dense LU's pivots below newton.py's singular ratio, a
spring of zero length), run the Python step (LAPACK's LU), which then does what it always
does. The kernel is the equations' C kernel (kernel "c", what FMUs run), or one built for
this method under the numba kernel when it can be compiled.

A fixed-step run takes RUN_LENGTH steps per C call with the energy check inside; a step
whose Newton iteration fails there is halved by ``newton.advance_with_halving`` as always.
A run of controlled steps (``step_control = "adaptive"``, auto's stiff scenes) takes its
steps up to the output time in one C call (``implicit_runs``), the step control's
acceptance and factors included. What stays in Python: halving a failed fixed step, the
energy audit's verdict, work limits between calls, and any attempt the kernel hands back.
"""

from __future__ import annotations

import math
import weakref

import numpy as np

from ..equations import ckernel
from ..equations.forces import FD_STEP
from ..model.scene import RotationalSpringDamper, SpringDamper
from . import newton
from .c_steps import (NO_AUDIT, RUN_ENERGY, RUN_FAILED, RUN_PYTHON, audit_back, audit_state,
                      stage_inputs)
from . import implicit_runs
from .energy_audit import ENERGY_DIVERGENCE_FRACTION, ENERGY_ROUNDOFF
from .implicit_runs import step_state
from .crossing_step import CrossingWatch, fixed_run_across
from .newton import IterationMatrix, NewtonFailure

# Off: every step on the Python path (the tests compare the two).
ENABLED = True
# A genalpha step through the Schur complement whose iteration matrix has a singularity
# indicator below this runs a dense LU (the Python step): the Schur complement squares the
# condition number (ali3p's is bounded by its penalty), and at P2's crossings its noise
# left velocity errors that did not shrink with h.
DENSE_BELOW = 1e-3
# Fixed steps per C call: the work limits are checked between calls (ckernel.MAX_ROWS
# rows of inputs).
RUN_LENGTH = 64
# Largest n + m solved by the kernel's dense LU (implicit_dense.h) where the banded Schur
# complement does not apply: its cost grows as (n + m)^3, and beyond a few hundred unknowns
# the Python step's blocked LAPACK LU catches up (benchmarks/implicit_speed.py).
DENSE_MAX = 250
_OWN_KERNELS: weakref.WeakKeyDictionary = weakref.WeakKeyDictionary()


class KernelMatrix(IterationMatrix):
    """An ``IterationMatrix`` that may hold the C kernel's kept matrix (``kept``, valid
    when kept[0] != 0) instead of LAPACK factors: ``lu`` is then a marker and ``solve``
    uses the kernel. Setting ``lu`` (the Python path) drops the C matrix."""

    plain_fields = ("_lu", "h", "fresh", "indicator", "reach", "kept")

    def __init__(self, kept: np.ndarray, newton):
        self.kept, self.newton = kept, newton
        super().__init__()

    @property
    def lu(self):
        if self._lu is not None:
            return self._lu
        return True if self.kept[0] != 0.0 else None

    @lu.setter
    def lu(self, value):
        self._lu = value
        self.kept[0] = 0.0

    def solve(self, b: np.ndarray) -> np.ndarray:
        if self._lu is not None:
            return super().solve(b)
        return self.newton.kernel.implicit_solve(self.newton.settings, self.kept, b)


class KernelNewton:
    """A method's kernel and its ``ckernel.implicit.Implicit`` settings."""

    def __init__(self, method, kernel, blocks: bool, dense: bool = False):
        eq = method.equations
        self.kernel, self.genalpha, self.dense = kernel, method.name == "genalpha", dense
        am, af, beta, gamma = method.coefficients if self.genalpha else (0.0,) * 4
        self.settings = kernel.implicit_settings(
            method.name, method.periodic, eq.pattern if blocks else None, fd_step=FD_STEP,
            dense=int(dense), fd=int(dense and eq.forces_depend_on_state()),
            jacobian_full=int(getattr(method, "jacobian", "") == "full"),
            count_multipliers=int(self.genalpha), max_iter=newton.NEWTON_MAX_ITER, am=am, af=af,
            beta=beta, gamma=gamma, length_scale=eq.length_scale, roundoff=newton.ROUNDOFF,
            atol_max=newton.NEWTON_ATOL_MAX, tol_floor=newton.NEWTON_TOL_FLOOR, t_ref=newton.T_REF,
            noise_max=newton.NOISE_MAX, near_indicator=newton.NEAR_SINGULAR_INDICATOR,
            near_floor=newton.NEAR_SINGULAR_FLOOR,
            t_near=newton.T_NEAR, slow_rate=newton.NEWTON_SLOW_RATE,
            diverging_rate=newton.NEWTON_DIVERGING_RATE, singular_pivot=newton.SINGULAR_PIVOT,
            dense_below=DENSE_BELOW, h_fine=newton.H_FINE)

    def prepare(self, method):
        """The settings with the run's current values, counters cleared."""
        p = self.settings
        p.penalty_base = getattr(method, "penalty_base", 1.0)
        p.alpha = getattr(method, "alpha_option", None) or 0.0
        p.atol = method.atol
        p.nnewton = p.njev = p.nlu = p.nprojections = p.reason = 0
        return p

    def count(self, stats) -> None:
        p = self.settings
        stats.nnewton += p.nnewton
        stats.njev += p.njev
        stats.nlu += p.nlu
        stats.nprojections += p.nprojections

    def failure(self) -> str:
        p = self.settings
        if p.reason in ckernel.implicit.NEWTON_REASONS:
            return ckernel.implicit.NEWTON_REASONS[p.reason]
        return (f"Newton did not converge in {p.max_iter} iterations (last increment "
                f"{p.last_size:.3g}, constraint residual {p.last_residual:.3g}, tolerance "
                f"{p.last_tol:.3g})")


def _kernel(eq):
    if eq.ckernel is not None:
        return eq.ckernel
    if eq.kernel != "numba" or not ckernel.available():
        return None
    if eq not in _OWN_KERNELS:
        _OWN_KERNELS[eq] = ckernel.Kernel(eq)
    return _OWN_KERNELS[eq]


def kernel_newton(method) -> KernelNewton | None:
    """The C path of ``method`` (genalpha or ali3p), or None where it runs in Python (see
    the module docstring)."""
    eq = method.equations
    kernel = _kernel(eq) if ENABLED else None
    if kernel is None:
        return None
    blocks = eq.forces_depend_on_state() and getattr(method, "jacobian", None) != "mass"
    if not eq.constraint_set.line.n and not (
            blocks and not all(_on_one_body(eq, f) for f in eq.applied.state_forces)):
        try:
            return KernelNewton(method, kernel, blocks)
        except ValueError:  # K's blocks couple rows outside the band (ckernel.body_pairs)
            pass
    if eq.n + eq.m > DENSE_MAX:
        return None
    return KernelNewton(method, kernel, False, dense=True)


def _on_one_body(eq, force) -> bool:
    """The force acts on one moving body (the other end, if any, on the ground): its
    Jacobian is a 3 x 3 block of K."""
    if isinstance(force, RotationalSpringDamper):
        joint = eq.scene.joint(force.joint)
        ends = (joint.body_i, joint.body_j)
    else:
        ends = (force.body_i, force.body_j) if isinstance(force, SpringDamper) else (force.body,)
    index = eq.applied.index
    return sum(index.get(name, eq.nb) < eq.nb for name in ends) <= 1


def attempt(method, t: float, h: float) -> dict | None:
    """``_attempt(t, h)`` of genalpha or ali3p in C: the step not yet taken (their ``x``),
    NewtonFailure, or None: the Python path does this attempt."""
    kn = method.c_newton
    if kn is None:
        return None
    t1 = t + h
    u = method.inputs(t1)
    p = kn.prepare(method)
    method.matrix._lu = None        # a Python path's factors: the kernel keeps its own
    status, (dq, qd, qdd, a, lam) = kn.kernel.implicit_attempt(
        p, method.matrix.kept, step_state(method), h, method.equations.motion_values(t1, u),
        u.forces)
    kn.count(method.stats)
    if status == ckernel.OK:
        return {"dq": dq, "qd": qd, "qdd": qdd, "lam": lam, "a": a, "t1": t1}
    if status == ckernel.NEWTON:
        raise NewtonFailure(kn.failure())
    method.matrix.lu = None
    return None


class CompiledNewton:
    """Mixin of genalpha and ali3p (first in their bases): the C path when ``kernel_newton``
    gives one (``c_newton``), fixed steps and runs of them in C, a step failed in C halved
    in Python."""

    def restart(self):
        super().restart()
        # once per run: a restart (every input a master sets) keeps the method's settings
        if "c_newton" not in self.__dict__:
            self.c_newton = kernel_newton(self)
        self._failed = None
        self._crossing = CrossingWatch()
        if self.c_newton is not None:
            self.matrix = KernelMatrix(self.c_newton.kernel.kept_matrix(self.c_newton.dense),
                                       self.c_newton)

    def step_change(self, ratio: float):
        """The next step is ``ratio`` times the last (crossing_step.py): the history a
        method carries rescaled (genalpha's a; ali3p carries none)."""
        return None

    def restore_history(self, kept) -> None:
        pass

    def set_state(self, state):
        super().set_state(state)
        if isinstance(self.matrix, KernelMatrix):
            if self.c_newton is None:         # a state saved where the kernel ran
                self.matrix = IterationMatrix()
            else:
                self.matrix.newton = self.c_newton

    def _try_step(self, t, h):
        if self._failed is not None:      # the C run's failure at this step: halve it
            reason, self._failed = self._failed, None
            raise NewtonFailure(reason)
        super()._try_step(t, h)

    def _step_impl(self, h):
        """A fixed step in C (the stated accuracy's spot checks, steps one at a time);
        in Python (halved if it failed in C) where the kernel hands it back."""
        if self.c_newton is None or self.adaptive or self._failed is not None:
            return super()._step_impl(h)
        status, _ = self._c_run((self.t + h,), h, audited=False)
        if status == ckernel.OK:
            return True, h
        self._failed = self.c_newton.failure() if status == ckernel.NEWTON else None
        return super()._step_impl(h)

    def _fixed_run(self, t0, h, k, stop, n, t_target):
        # no step ends next to a singular configuration (crossing_step.py)
        while k < stop:
            k = fixed_run_across(self, t0, h, k, stop, n, t_target, self._crossing)
            if k < stop:
                k = self._run_steps(t0, h, k, min(stop, k + RUN_LENGTH), n, t_target)
        return stop

    def _run_steps(self, t0, h, k, stop, n, t_target):
        if self.c_newton is None or self.watch is not None:
            return super()._fixed_run(t0, h, k, stop, n, t_target)
        while k < stop:
            count = min(RUN_LENGTH, stop - k)
            status, done = self._c_run((t0 + h * np.arange(k, k + count)) + h, h,
                                       audited=self.audit is not None)
            k += done
            self.t = t0 + k * h if k < n else t_target
            self.stats.nsteps += done
            if status == ckernel.ENERGY:
                self._after_step()                      # says why
            elif status != ckernel.OK:                  # this step in Python
                self._failed = self.c_newton.failure() if status == ckernel.NEWTON else None
                k = super()._fixed_run(t0, h, k, k + 1, n, t_target)
            if self.limit is not None:
                self.limit.check(self.stats, self.t, t_target)
        return stop

    def _steps_in_c(self, t_target, dense, rejections):
        """Controlled steps of ``_advance_adaptive`` in C (``implicit_runs``)."""
        if dense or not implicit_runs.can_run(self):
            return None
        status, rejections = implicit_runs.implicit_run(self, t_target, rejections)
        if status == RUN_FAILED:
            self._step_size_failed()
        if status == RUN_ENERGY:
            self._after_step()                 # says why
        return rejections, status == RUN_PYTHON

    def _c_run(self, ends, h: float, audited: bool) -> tuple[int, int]:
        """Fixed steps of h ending at ``ends`` in one C call, the energy check inside when
        ``audited``: (status, steps done), the state taken."""
        kn = self.c_newton
        stage_inputs(self, ends, kn.kernel)
        status, done, state = kn.kernel.implicit_steps(
            kn.prepare(self), self.matrix.kept, step_state(self), h, len(ends),
            audit_state(self.audit) if audited else NO_AUDIT,
            ENERGY_DIVERGENCE_FRACTION, ENERGY_ROUNDOFF)
        kn.count(self.stats)
        if audited:
            audit_back(self.audit, kn.kernel.buf.audit)
            if status == ckernel.ENERGY:      # _after_step checks this state again
                self.audit.checks -= 1
        if done:
            self.qw, self.turns, self.qd, self.qdd, a, self.lam = state
            if self.name == "genalpha":
                self.a = a
            self.q = self.qw + 2.0 * math.pi * self.turns
        return status, done
