"""The stepping interface every method implements (modelled on scipy.integrate's OdeSolver).

A method is a subclass of ``Integrator`` that

1. sets ``name``, a one-line ``summary``, ``adaptive``, ``default_step`` and the
   ``options`` it takes beyond the common settings (with the rule each must meet);
2. implements ``_step_impl(h) -> (accepted, h_next)``: a step from ``self.t`` that on
   acceptance updates ``self.q``, ``self.qd`` and any private state, and on rejection
   changes nothing (the base class then retries with ``h_next``); the base class moves
   ``self.t``. A step it cannot take at all raises ``SolverError``;
3. lists in ``state_fields`` any private attribute that must be saved with the state;
4. may override ``restart()``, called when (q, q') or the inputs change from outside;
5. adaptive methods with ``dense_output`` implement ``_output_at(t)``: the state at a time
   inside the last step (then ``advance(t, dense=True)`` steps past output times instead
   of landing on them), and may shorten a step in ``_plan_step``.

The equations are pure functions of (t, q, q', u); the integrator gets the inputs as a
function ``inputs(t) -> InputValues`` from whoever runs it (``Simulation``) and passes them
on through ``accelerations``, ``constraints`` and ``forces`` below. The public
``advance(t_target)`` does the bookkeeping: it reaches ``t_target``, counts the work, checks
the energy balance of conservative scenes after every accepted step (``energy_audit.py``),
keeps a fixed-step run's stated accuracy (``stated_accuracy.py``) and raises ``SolverError``
(with time and reason) on any failure.

Adaptive methods step with ``adaptive.AdaptiveStepping``, which keeps their step sequence
independent of the output times.
"""

from __future__ import annotations

import math
from typing import Callable, NamedTuple

import numpy as np

from ..equations import Equations
from ..errors import AccuracyError, SettingError, SolverError
from ..model.variables import InputValues
from ..plain import Plain, decode, encode
from .energy_audit import ENERGY_TOL_FACTOR, EnergyAudit
from .stated_accuracy import ErrorEstimate, allowed_error
from .work import Counters, WorkLimit  # noqa: F401  (WorkLimit: the public place is here)

# A constraint violation beyond this fraction of the mechanism's size means divergence.
DIVERGENCE_FRACTION = 0.5
# Failure messages mention a singular configuration when the smallest singular value of
# Psi_q is below this fraction of the largest.
SINGULAR_HINT = 1e-2
# Fixed steps per communication interval are counted as ceil(interval / h - this), so that
# an interval that is a whole number of steps up to round-off is not given one step more.
STEP_COUNT_SLACK = 1e-9


class OutputPoint(Plain):
    """The state at an output time inside an adaptive method's last step."""

    plain_fields = ("t", "q", "qd")
    flat_fields = True

    def __init__(self, t: float, q: np.ndarray, qd: np.ndarray):
        self.t, self.q, self.qd = float(t), q, qd


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


class Integrator:
    """Base class: advances (t, q, q') of the ``Equations`` of a scene in time."""

    name = ""
    summary = ""
    adaptive = False
    dense_output = False     # gives states inside its last step (``_output_at``)
    default_step: float = 1e-3
    options: tuple[Option, ...] = ()
    option_names: tuple[str, ...] = ()
    state_fields: tuple[str, ...] = ()
    limit: WorkLimit | None = None      # of the running ``advance`` call
    # Called as watch(self) after each accepted step; events.py sets it to find events
    # (it raises to stop the run there).
    watch: Callable | None = None
    # The watch must see every step (events): no run of several steps in one C call.
    watch_each_step = False

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
        self.out: OutputPoint | None = None    # the state at the last output time, if not (t, q, q')
        self.accuracy = None if self.adaptive else ErrorEstimate()
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

    def _plan_step(self, h: float, landing: bool, proposal: float) -> float:
        """The step to try from self.t (adaptive methods): h, the controller's
        ``proposal`` or less to end on an output time (``landing``), or a shorter one; or,
        only to cross a singular configuration, a longer landing step (no longer than the
        proposal; the output then comes from dense output)."""
        return h

    def _output_at(self, t: float) -> OutputPoint:
        """The state at a time inside the last step (methods with ``dense_output``)."""
        raise NotImplementedError

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
        """The energy check of this run (None for scenes whose energy is not conserved):
        within ENERGY_TOL_FACTOR of what the tolerances allow (an adaptive method's, or a
        fixed-step method's stated accuracy)."""
        what = f"rtol = {self.rtol:g}, atol = {self.atol:g}"
        if not self.adaptive:
            what = f"the stated accuracy of this fixed step ({self.h:g} s), {what},"
        return EnergyAudit.start(self.equations, self.q, self.qd, method=self.name,
                                 rtol=self.rtol, atol=self.atol, factor=ENERGY_TOL_FACTOR,
                                 what=what, fixed_step=not self.adaptive)

    def _after_step(self) -> None:
        """Checks on an accepted step (self.t already moved)."""
        if self.watch is not None:
            self.watch(self)
        if self.audit is not None:
            problem = self.audit.check(self.equations, self.t, self.q, self.qd)
            if problem:      # a fixed step's stated accuracy: a smaller step may keep it
                raise (SolverError if self.adaptive else AccuracyError)(
                    problem + self.singularity_hint(), self.t)

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
        """For methods without projection: a violation beyond the mechanism's size is
        divergence; beyond what the stated accuracy allows (the exact solution keeps Psi = 0,
        so the violation is a lower bound of the error), the step is too large for it."""
        Psi, _ = self.constraints(t, q)
        err = float(np.max(np.abs(Psi))) if Psi.size else 0.0
        limit = DIVERGENCE_FRACTION * self.equations.length_scale
        if not err <= limit:
            raise SolverError(f"{self.name}: constraint violation {err:.3g} exceeds {limit:.3g} "
                              "(half the mechanism's size): the solution has diverged", t)
        allowed = allowed_error(self)
        if not err <= allowed:
            raise AccuracyError(
                f"{self.name}: constraint violation {err:.3g} exceeds {allowed:.3g}, what the "
                f"stated accuracy rtol = {self.rtol:g}, atol = {self.atol:g} allows: the step "
                f"{self.h:g} s is too large for it; use a smaller step or a projected method", t)

    # ------------------------------------------------------------------ public

    @property
    def output_state(self) -> tuple[float, np.ndarray, np.ndarray]:
        """(t, q, q') at the last output time: the end of the last step, or a state inside
        it (dense output)."""
        if self.out is None:
            return self.t, self.q, self.qd
        return self.out.t, self.out.q, self.out.qd

    def advance(self, t_target: float, limit: WorkLimit | None = None, *,
                dense: bool = False) -> None:
        """Integrate to ``t_target`` (>= the last output time), within ``limit`` if given.
        ``dense``: the inputs over the coming steps are known, so a method with dense
        output may step past ``t_target`` (``output_state`` is then the state there).
        The run goes on from its steps' ends, past the last output time too: a caller that
        changes the inputs at an output time restarts from it (``reset_state``)."""
        self.limit = limit
        if limit is not None:
            limit.start(self.stats)
        t_now = self.output_state[0]
        if not math.isfinite(t_target):
            raise SolverError(f"cannot integrate to t = {t_target}", t_now)
        if t_target < t_now:
            raise SolverError(f"cannot integrate backwards to t = {t_target}", t_now)
        dense = dense and self.dense_output
        if t_target == t_now:
            return
        if self.adaptive:
            self._advance_adaptive(t_target, dense)
        else:
            self._advance_fixed(t_target)

    def interpolates_to(self, t_target: float, dense: bool) -> bool:
        """Whether ``advance(t_target, dense=dense)`` only reads the dense output of the
        last step (no step taken, nothing but the output state changes)."""
        return dense and self.dense_output and self.adaptive and \
            self.output_state[0] < t_target <= self.t

    def fixed_grid(self, t_target: float) -> tuple[float, int, float]:
        """(t0, steps, step) of equal steps no longer than ``self.h`` up to ``t_target``."""
        t0 = self.t
        n = max(1, math.ceil((t_target - t0) / self.h - STEP_COUNT_SLACK))
        if self.limit is not None:
            self.limit.check_planned(n, self.h, t0, t_target)
        return t0, n, (t_target - t0) / n

    def _advance_fixed(self, t_target: float) -> None:
        """Equal steps (times t0 + k h, never accumulated) in runs between the step-doubling
        checks of the stated accuracy (``stated_accuracy.py``)."""
        t0, n, h = self.fixed_grid(t_target)
        k = 0
        while k < n:
            if self.accuracy.due():
                self.accuracy.spot_check(self, h)
            run = min(n - k, max(1, self.accuracy.every - self.accuracy.unchecked))
            k = self._fixed_run(t0, h, k, k + run, n, t_target)
            self.accuracy.charge(self, h)

    def _fixed_run(self, t0: float, h: float, k: int, stop: int, n: int,
                   t_target: float) -> int:
        """Steps k + 1 .. stop of the grid t0 + j h (n steps to t_target); returns stop."""
        for j in range(k + 1, stop + 1):
            accepted, _ = self._step_impl(h)
            if not accepted:
                raise SolverError(f"{self.name}: a fixed step of {h:.3g} s failed", self.t)
            grid_step_taken(self, t0 + j * h if j < n else t_target, t_target)
        return stop

    def get_state(self) -> dict:
        """Everything needed to continue bit for bit, as plain data (``plain.py``)."""
        return {k: encode(getattr(self, k)) for k in self._state_names()}

    def _state_names(self) -> tuple[str, ...]:
        return ("t", "q", "qd", "h", "stats", "audit", "out", "accuracy") + self.state_fields

    def rollback_point(self) -> dict:
        """``get_state()`` for a rollback within the process, cheaper: arrays copied,
        ``Plain.flat_fields`` objects copied shallowly, anything else encoded; ``set_state``
        restores it."""
        state = {}
        for name in self._state_names():
            value = getattr(self, name)
            kind = type(value)
            if kind is np.ndarray:
                state[name] = value.copy()
            elif issubclass(kind, Plain) and kind.flat_fields:
                copied = object.__new__(kind)
                copied.__dict__.update(value.__dict__)
                state[name] = copied
            else:
                state[name] = encode(value)
        return state

    def set_state(self, state: dict) -> None:
        for k, v in state.items():
            setattr(self, k, decode(v))

    def reset_state(self, q: np.ndarray, qd: np.ndarray, t: float | None = None) -> None:
        """Replace (q, q') at the current time (after an input jump), or at the output
        time ``t``, and restart."""
        if t is not None:
            self.t = float(t)
        self.out = None
        self.q, self.qd = np.array(q, dtype=float), np.array(qd, dtype=float)
        h = self.h
        self.restart()
        self.audit = self._start_audit()
        if self.adaptive and h is not None:
            self.h = h


def grid_step_taken(method: Integrator, t: float, t_target: float) -> None:
    """A fixed step of ``method`` taken to the grid time t: counted, checked, within the
    work limit."""
    method.t = t
    method.stats.nsteps += 1
    method._after_step()
    if method.limit is not None:
        method.limit.check(method.stats, method.t, t_target)
