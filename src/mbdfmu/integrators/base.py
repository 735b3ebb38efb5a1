"""The stepping interface every method implements (modelled on scipy.integrate's OdeSolver).

A method is a subclass of ``Integrator`` that

1. sets ``name``, a one-line ``summary``, ``adaptive``, ``default_step`` and the
   ``options`` it takes beyond the common settings (with the rule each must meet);
2. implements ``_step_impl(h) -> (accepted, h_next)``: a step from ``self.t`` that on
   acceptance updates ``self.q``, ``self.qd`` and any private state, and on rejection
   changes nothing (the base class then retries with ``h_next``); the base class moves
   ``self.t``. A step it cannot take at all raises ``SolverError``;
3. lists in ``state_fields`` any private attribute that must be saved with the state;
4. may override ``restart()``, called when (q, q') or the inputs change from outside.

The equations are pure functions of (t, q, q', u); the integrator gets the inputs as a
function ``inputs(t) -> InputValues`` from whoever runs it (``Simulation``) and passes them
on through ``accelerations``, ``constraints`` and ``forces`` below. The public
``advance(t_target)`` does the bookkeeping: it lands exactly on ``t_target``, counts the
work, checks the energy balance of conservative scenes after every accepted step
(``energy_audit.py``) and raises ``SolverError`` (with time and reason) on any failure.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, fields
from typing import Callable, NamedTuple

import numpy as np

from ..equations import Equations
from ..errors import SettingError, SolverError
from ..model.variables import InputValues
from ..plain import Plain, decode, encode
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
# Fixed steps per communication interval are counted as ceil(interval / h - this), so that
# an interval that is a whole number of steps up to round-off is not given one step more.
STEP_COUNT_SLACK = 1e-9


class Option(NamedTuple):
    """A method's own setting: its name, the rule it must meet and how to check it."""

    name: str
    rule: str
    valid: Callable[[object], bool]


def number_in(low: float, high: float, *, low_open: bool = False) -> Callable:
    def valid(v) -> bool:
        if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
            return False
        return (low < v if low_open else low <= v) and v <= high
    return valid


@dataclass
class Counters(Plain):
    """Work done, as scipy counts it: steps, rejections, q'' evaluations, projections,
    Newton iterations, iteration-matrix evaluations and factorisations (implicit methods)."""

    nsteps: int = 0
    nrejected: int = 0
    naccel: int = 0
    nprojections: int = 0
    nnewton: int = 0
    njev: int = 0
    nlu: int = 0


Counters.plain_fields = tuple(f.name for f in fields(Counters))


class WorkLimit:
    """Bounds on the work of one ``advance`` call: at most ``max_steps`` internal steps
    (accepted and rejected) and ``max_cpu`` CPU seconds of the calling thread, checked
    after every internal step (a fixed-step run longer than ``max_steps`` is refused before
    its first step). None: no bound. ``names`` are the settings' names in messages (an
    FMU's parameters). Exceeding either raises ``SolverError``; ``Simulation.advance`` then
    restores the state it started from."""

    def __init__(self, max_steps: int | None = None, max_cpu: float | None = None,
                 names: tuple[str, str] = ("max_steps", "max_cpu")):
        self.max_steps, self.max_cpu, self.names = max_steps, max_cpu, names
        self.first, self.deadline = 0, math.inf

    def start(self, stats: "Counters") -> None:
        self.first = stats.nsteps + stats.nrejected
        self.deadline = time.thread_time() + self.max_cpu if self.max_cpu else math.inf

    def check_planned(self, steps: int, h: float, t: float, t_target: float) -> None:
        if self.max_steps is not None and steps > self.max_steps:
            count = steps if steps < 10 ** 9 else f"{float(steps):.3g}"
            raise SolverError(f"reaching t = {t_target:.9g} s takes {count} steps of "
                              f"{h:.3g} s, more than {self.names[0]} = {self.max_steps}", t)

    def check(self, stats: "Counters", t: float, t_target: float) -> None:
        used = stats.nsteps + stats.nrejected - self.first
        if self.max_steps is not None and used >= self.max_steps and t < t_target:
            raise SolverError(f"{used} internal steps did not reach t = {t_target:.9g} s "
                              f"({self.names[0]} = {self.max_steps})", t)
        if time.thread_time() > self.deadline:
            raise SolverError(f"{self.max_cpu:g} CPU seconds did not reach t = "
                              f"{t_target:.9g} s ({self.names[1]} = {self.max_cpu:g})", t)


class Integrator:
    """Base class: advances (t, q, q') of the ``Equations`` of a scene in time."""

    name = ""
    summary = ""
    adaptive = False
    default_step: float = 1e-3
    options: tuple[Option, ...] = ()
    option_names: tuple[str, ...] = ()
    state_fields: tuple[str, ...] = ()
    limit: WorkLimit | None = None      # of the running ``advance`` call
    # Called as watch(self) after each accepted step; events.py sets it to find events
    # (it raises to stop the run there).
    watch: Callable | None = None

    def __init_subclass__(cls, **kwargs):
        super().__init_subclass__(**kwargs)
        cls.option_names = tuple(o.name for o in cls.options)

    def __init__(self, equations: Equations, t0: float, q0: np.ndarray, qd0: np.ndarray, *,
                 step: float, rtol: float, atol: float,
                 inputs: Callable[[float], InputValues] | None = None):
        self.equations = equations
        self.inputs = inputs if inputs is not None else (lambda t: equations.no_inputs)
        self.t = float(t0)
        self.q = np.array(q0, dtype=float)
        self.qd = np.array(qd0, dtype=float)
        self.rtol, self.atol = float(rtol), float(atol)
        if self.adaptive:
            self.max_step, self.h = float(step), None   # h chosen by restart()
        else:
            self.h = float(step)
        self.stats = Counters()
        self.restart()
        self.audit = self._start_audit()

    @classmethod
    def check_options(cls, options: dict, name: str = "options", where: str = "") -> None:
        """Every option known to this method and within its rule, else ``SettingError``."""
        rules = {o.name: o for o in cls.options}
        for key, value in options.items():
            if key not in rules:
                allowed = ", ".join(rules) or "none"
                raise SettingError(name, f'method "{cls.name}" has no option {key} '
                                   f"(its options: {allowed})", where)
            if not rules[key].valid(value):
                raise SettingError(key, f"{cls.name}: {key} must be {rules[key].rule}, "
                                   f"got {value!r}", where)

    # ------------------------------------------------------------------ for subclasses

    def _step_impl(self, h: float) -> tuple[bool, float]:
        raise NotImplementedError

    def restart(self) -> None:
        """Forget anything derived from the current (q, q') (called after outside changes)."""

    def accelerations(self, t: float, q: np.ndarray, qd: np.ndarray):
        """q'' and lam from eq. (14) with the inputs at t, counted."""
        self.stats.naccel += 1
        return self.equations.accelerations(t, q, qd, self.inputs(t))

    def constraints(self, t: float, q: np.ndarray, qd: np.ndarray | None = None, **kwargs):
        """Psi, Psi_q (and nu, gamma with qd) with the driver inputs at t."""
        return self.equations.constraints(t, q, qd, self.inputs(t), **kwargs)

    def forces(self, t: float, q: np.ndarray, qd: np.ndarray) -> np.ndarray:
        return self.equations.forces(t, q, qd, self.inputs(t))

    def _start_audit(self) -> EnergyAudit | None:
        """The energy check of this run (None for scenes whose energy is not conserved)."""
        if self.adaptive:
            rtol, atol, factor = self.rtol, self.atol, ENERGY_TOL_FACTOR
            what = f"rtol = {self.rtol:g}, atol = {self.atol:g}"
        else:
            rtol, atol, factor = 0.0, 0.0, 0.0
            what = "a fixed-step method's divergence check"
        return EnergyAudit.start(self.equations, self.q, self.qd, method=self.name, rtol=rtol,
                                 atol=atol, factor=factor, what=what)

    def _after_step(self) -> None:
        """Checks on an accepted step (self.t already moved)."""
        if self.watch is not None:
            self.watch(self)
        if self.audit is not None:
            problem = self.audit.check(self.equations, self.t, self.q, self.qd)
            if problem:
                raise SolverError(problem + self.singularity_hint(), self.t)

    def singularity_hint(self) -> str:
        """For failure messages: a note when Psi_q is nearly singular at the current state."""
        if self.equations.m == 0:
            return ""
        _, J = self.constraints(self.t, self.q)
        sv = np.linalg.svd(J, compute_uv=False)
        if not np.all(np.isfinite(sv)) or sv[-1] >= SINGULAR_HINT * sv[0]:
            return ""
        return (f" (the constraint Jacobian is nearly singular here, singular values "
                f"{sv[-1]:.2g} / {sv[0]:.2g}: a singular configuration, which method ali3p passes)")

    def check_finite(self, t: float, *arrays) -> None:
        for a in arrays:
            if not np.all(np.isfinite(a)):
                raise SolverError(f"{self.name}: the state became non-finite (the method diverged)", t)

    def check_drift(self, t: float, q: np.ndarray) -> None:
        """For methods without projection: a violation beyond the mechanism's size is divergence."""
        Psi, _ = self.constraints(t, q)
        err = float(np.max(np.abs(Psi))) if Psi.size else 0.0
        limit = DIVERGENCE_FRACTION * self.equations.length_scale
        if not err <= limit:
            raise SolverError(f"{self.name}: constraint violation {err:.3g} exceeds {limit:.3g} "
                              "(half the mechanism's size): the solution has diverged", t)

    # ------------------------------------------------------------------ public

    def advance(self, t_target: float, limit: WorkLimit | None = None) -> None:
        """Integrate to exactly ``t_target`` (>= self.t), within ``limit`` if given."""
        self.limit = limit
        if limit is not None:
            limit.start(self.stats)
        if not math.isfinite(t_target):
            raise SolverError(f"cannot integrate to t = {t_target}", self.t)
        if t_target < self.t:
            raise SolverError(f"cannot integrate backwards to t = {t_target}", self.t)
        if t_target == self.t:
            return
        if self.adaptive:
            self._advance_adaptive(t_target)
        else:
            self._advance_fixed(t_target)

    def fixed_grid(self, t_target: float) -> tuple[float, int, float]:
        """(t0, steps, step) of equal steps no longer than ``self.h`` up to ``t_target``."""
        t0 = self.t
        n = max(1, math.ceil((t_target - t0) / self.h - STEP_COUNT_SLACK))
        if self.limit is not None:
            self.limit.check_planned(n, self.h, t0, t_target)
        return t0, n, (t_target - t0) / n

    def _advance_fixed(self, t_target: float) -> None:
        # Times are t0 + k h, never accumulated.
        t0, n, h = self.fixed_grid(t_target)
        for k in range(1, n + 1):
            accepted, _ = self._step_impl(h)
            if not accepted:
                raise SolverError(f"{self.name}: a fixed step of {h:.3g} s failed", self.t)
            self.t = t0 + k * h if k < n else t_target
            self.stats.nsteps += 1
            self._after_step()
            if self.limit is not None:
                self.limit.check(self.stats, self.t, t_target)

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
            if self.limit is not None:
                self.limit.check(self.stats, self.t, t_target)

    def get_state(self) -> dict:
        """Everything needed to continue bit for bit, as plain data (``plain.py``)."""
        names = ("t", "q", "qd", "h", "stats", "audit") + self.state_fields
        return {k: encode(getattr(self, k)) for k in names}

    def rollback_point(self) -> dict:
        """``get_state()`` for a rollback within the process, cheaper: arrays copied, the
        counters and the energy audit (flat: numbers and strings) copied shallowly,
        anything else encoded; ``set_state`` restores it."""
        state = {}
        for name in ("t", "q", "qd", "h", "stats", "audit") + self.state_fields:
            value = getattr(self, name)
            kind = type(value)
            if kind is np.ndarray:
                state[name] = value.copy()
            elif kind is Counters or kind is EnergyAudit:
                copied = object.__new__(kind)
                copied.__dict__.update(value.__dict__)
                state[name] = copied
            else:
                state[name] = encode(value)
        return state

    def set_state(self, state: dict) -> None:
        for k, v in state.items():
            setattr(self, k, decode(v))

    def reset_state(self, q: np.ndarray, qd: np.ndarray) -> None:
        """Replace (q, q') at the current time (after an input jump) and restart."""
        self.q, self.qd = np.array(q, dtype=float), np.array(qd, dtype=float)
        h = self.h
        self.restart()
        self.audit = self._start_audit()
        if self.adaptive and h is not None:
            self.h = h

