"""The stepping interface every method implements (modelled on scipy.integrate's OdeSolver).

A method is a subclass of ``Integrator`` that

1. sets ``name``, a one-line ``summary``, ``adaptive`` and its defaults;
2. implements ``_step_impl(h) -> (accepted, h_next)``: a step from ``self.t`` that on
   acceptance updates ``self.q``, ``self.qd`` and any private state, and on rejection
   changes nothing (the base class then retries with ``h_next``); the base class moves
   ``self.t``;
3. lists in ``state_fields`` any private attribute that must be saved with the state, and
   in ``option_names`` the keyword settings its ``__init__`` takes beyond the common ones;
4. may override ``restart()``, called when (q, q') or the inputs change from outside.

The public ``advance(t_target)`` does the bookkeeping: it lands exactly on ``t_target``,
counts the work, checks the energy balance of conservative scenes after every accepted step
(``energy_audit.py``) and raises ``SolverError`` (with time and reason) on any failure.
"""

from __future__ import annotations

import copy
import math
from dataclasses import dataclass

import numpy as np

from ..errors import SolverError
from ..system import System
from .energy_audit import ENERGY_TOL_FACTOR, EnergyAudit

# The smallest step, relative to the time, before an adaptive method gives up.
MIN_STEP_RELATIVE = 1e-13
# Steps an adaptive method may reject in a row before giving up.
MAX_REJECTIONS_IN_A_ROW = 60
# A constraint violation beyond this fraction of the mechanism's size means divergence.
DIVERGENCE_FRACTION = 0.5
# Failure messages mention a singular configuration when the smallest singular value of
# Psi_q is below this fraction of the largest.
SINGULAR_HINT = 1e-2


@dataclass
class Counters:
    """Work done, as scipy counts it: steps, rejections, q'' evaluations, projections,
    Newton iterations, iteration-matrix evaluations and factorisations (implicit methods)."""

    nsteps: int = 0
    nrejected: int = 0
    naccel: int = 0
    nprojections: int = 0
    nnewton: int = 0
    njev: int = 0
    nlu: int = 0


class Integrator:
    """Base class: advances (t, q, q') of a ``System`` in time."""

    name = ""
    summary = ""
    adaptive = False
    default_step: float | None = 1e-3
    default_rtol = 1e-6
    default_atol = 1e-8
    state_fields: tuple[str, ...] = ()
    option_names: tuple[str, ...] = ()

    def __init__(self, system: System, t0: float, q0: np.ndarray, qd0: np.ndarray, *,
                 step: float | None = None, rtol: float | None = None,
                 atol: float | None = None):
        self.system = system
        self.t = float(t0)
        self.q = np.array(q0, dtype=float)
        self.qd = np.array(qd0, dtype=float)
        self.rtol = float(rtol if rtol is not None else self.default_rtol)
        self.atol = float(atol if atol is not None else self.default_atol)
        if self.adaptive:
            self.max_step = float(step) if step is not None else math.inf
            self.h = None  # chosen by restart()
        else:
            self.h = float(step if step is not None else self.default_step)
        self.stats = Counters()
        self.restart()
        self.audit = self._start_audit()

    # ------------------------------------------------------------------ for subclasses

    def _step_impl(self, h: float) -> tuple[bool, float]:
        raise NotImplementedError

    def restart(self) -> None:
        """Forget anything derived from the current (q, q') (called after outside changes)."""

    def _start_audit(self) -> EnergyAudit | None:
        """The energy check of this run (None for scenes whose energy is not conserved)."""
        if self.adaptive:
            rtol, atol, factor = self.rtol, self.atol, ENERGY_TOL_FACTOR
            what = f"rtol = {self.rtol:g}, atol = {self.atol:g}"
        else:
            rtol, atol, factor = 0.0, 0.0, 0.0
            what = "a fixed-step method's divergence check"
        return EnergyAudit.start(self.system, self.q, self.qd, method=self.name, rtol=rtol,
                                 atol=atol, factor=factor, what=what)

    def _after_step(self) -> None:
        """Checks on an accepted step (self.t already moved)."""
        if self.audit is not None:
            problem = self.audit.check(self.system, self.t, self.q, self.qd)
            if problem:
                raise SolverError(problem + self.singularity_hint(), self.t)

    def singularity_hint(self) -> str:
        """For failure messages: a note when Psi_q is nearly singular at the current state."""
        if self.system.m == 0:
            return ""
        _, J = self.system.constraints(self.t, self.q)
        sv = np.linalg.svd(J, compute_uv=False)
        if not np.all(np.isfinite(sv)) or sv[-1] >= SINGULAR_HINT * sv[0]:
            return ""
        return (f" (the constraint Jacobian is nearly singular here, singular values "
                f"{sv[-1]:.2g} / {sv[0]:.2g}: a singular configuration, which method ali3p passes)")

    def accelerations(self, t: float, q: np.ndarray, qd: np.ndarray):
        """q'' and lam from the seed's eq. (14), counted."""
        self.stats.naccel += 1
        return self.system.accelerations(t, q, qd)

    def check_finite(self, t: float, *arrays) -> None:
        for a in arrays:
            if not np.all(np.isfinite(a)):
                raise SolverError(f"{self.name}: the state became non-finite (the method diverged)", t)

    def check_drift(self, t: float, q: np.ndarray) -> None:
        """For methods without projection: a violation beyond the mechanism's size is divergence."""
        Psi, _ = self.system.constraints(t, q)
        err = float(np.max(np.abs(Psi))) if Psi.size else 0.0
        limit = DIVERGENCE_FRACTION * self.system.length_scale
        if not err <= limit:
            raise SolverError(f"{self.name}: constraint violation {err:.3g} exceeds {limit:.3g} "
                              "(half the mechanism's size): the solution has diverged", t)

    # ------------------------------------------------------------------ public

    def advance(self, t_target: float) -> None:
        """Integrate to exactly ``t_target`` (>= self.t)."""
        if t_target < self.t:
            raise SolverError(f"cannot integrate backwards to t = {t_target}", self.t)
        if t_target == self.t:
            return
        if self.adaptive:
            self._advance_adaptive(t_target)
        else:
            self._advance_fixed(t_target)

    def _advance_fixed(self, t_target: float) -> None:
        # Equal steps no longer than self.h; times are t0 + k h, never accumulated.
        t0 = self.t
        n = max(1, math.ceil((t_target - t0) / self.h - 1e-9))
        h = (t_target - t0) / n
        for k in range(1, n + 1):
            accepted, _ = self._step_impl(h)
            if not accepted:
                raise SolverError(f"{self.name}: a fixed step of {h:.3g} s failed", self.t)
            self.t = t0 + k * h if k < n else t_target
            self.stats.nsteps += 1
            self._after_step()

    def _advance_adaptive(self, t_target: float) -> None:
        rejections = 0
        while self.t < t_target:
            h_min = MIN_STEP_RELATIVE * max(1.0, abs(self.t))
            h = min(self.h, self.max_step)
            clipped = self.t + 1.01 * h >= t_target
            if clipped:
                h = t_target - self.t
            proposal = self.h
            accepted, h_next = self._step_impl(h)
            if accepted:
                rejections = 0
                self.stats.nsteps += 1
                self.t = t_target if clipped else self.t + h
                # A step cut short to land on t_target says nothing about the next one.
                self.h = max(h_next, proposal) if clipped else h_next
                self._after_step()
            else:
                rejections += 1
                self.stats.nrejected += 1
                self.h = h_next
                if h_next < h_min or rejections > MAX_REJECTIONS_IN_A_ROW:
                    raise SolverError(
                        f"{self.name}: step size fell to {h_next:.3g} s without meeting "
                        f"rtol={self.rtol:g}, atol={self.atol:g}" + self.singularity_hint(),
                        self.t)

    def get_state(self) -> dict:
        """A deep copy of everything needed to continue bit for bit."""
        names = ("t", "q", "qd", "h", "stats", "audit") + self.state_fields
        return {k: _copy(getattr(self, k)) for k in names}

    def set_state(self, state: dict) -> None:
        for k, v in state.items():
            setattr(self, k, _copy(v))

    def reset_state(self, q: np.ndarray, qd: np.ndarray) -> None:
        """Replace (q, q') at the current time (after an input jump) and restart."""
        self.q, self.qd = np.array(q, dtype=float), np.array(qd, dtype=float)
        h = self.h
        self.restart()
        self.audit = self._start_audit()
        if self.adaptive and h is not None:
            self.h = h


def _copy(value):
    """A deep copy, without deepcopy's bookkeeping for the common cheap cases."""
    if value is None or isinstance(value, (float, int, bool, str)):
        return value
    if isinstance(value, np.ndarray):
        return value.copy()
    fields = getattr(value, "__dict__", None)   # counters and audits: scalars only
    if fields is not None and all(v is None or isinstance(v, (float, int, bool, str))
                                  for v in fields.values()):
        return copy.copy(value)
    return copy.deepcopy(value)
