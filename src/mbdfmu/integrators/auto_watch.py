"""``auto`` over the whole run: watch the steps and switch method when t0's choice stops fitting.

``choose.py`` picks a method from the state at t0. ``AutoWatch`` then runs alongside the
integrator of an ``auto`` run (``Simulation`` holds it): after every accepted step it looks
at signals the step already has, and on a failure it looks at the error; it switches by
these rules:

1. Singular configuration left: ali3p (chosen for a singular configuration at t0, or by
   rule 4) runs while the singularity indicator (``equations.singular``: 0 at the
   configuration, of order one away from it) stays below CLEAR. Once it has been at least
   CLEAR for CLEAR_STEPS accepted steps in a row (Psi_q has full rank, so the constraints
   are not redundant) and no spring or damper is stiff at this state (``choose.stiff_reason``),
   the run goes on with dop853p: away from the configuration it is far cheaper and more
   accurate than ali3p's fixed second-order steps, and it plans later crossings itself
   (``singular_zone.py``).
2. Stiffness: dop853p's steps are held by stability (Hairer's test of DOP853, Solving ODEs
   II, sec. IV.2: h |lambda| estimated from the last two stage derivatives at t + h, above
   STIFF_HLAMBDA on STIFF_STEPS steps without NONSTIFF_STEPS steps below in between) at a
   step STIFF_STEP_RATIO times below the implicit method's: the run goes on with genalpha
   (ali3p with redundant constraints), implicit, whose step is not held by stability (a
   stiff spring stretched at t0 gets dop853p, which resolves its oscillation; once it has
   died out, only stability holds dop853p's step).
3. A fixed-step method of auto's own step whose estimated error exceeds its stated
   accuracy (``AccuracyError``): the advance call is retried from where it started with
   the same method at half the step, at most HALVINGS times a call; a smaller step is what
   the error asks for, and the method keeps fitting the mechanism.
4. A method that stops otherwise (``SolverError`` other than the work limit): the advance
   call is retried from where it started with ali3p (which passes singular configurations and
   redundant constraints, where explicit methods and genalpha stop), or with dop853p if
   ali3p stopped; each method at most once per call; when none is left, the first
   method's error is raised, with the retries' errors after it.

A switch happens at a step's end, with the state (t, q, q') carried exactly: within an
advance call when that end is not past the output time being reached (a step past it gives
that output from its dense output; the switch then waits for the next call). The run's
counters and its energy balance (``energy_audit.py``: the energy at t0 stays the reference)
go on; ``stats.nswitches`` counts the switches, and ``switches`` lists each one as
[t (s), from, to, reason] for ``Result.switches``, the CLI and the FMU log. The watcher's
state is plain data (``plain.py``) saved with the run's state.
"""

from __future__ import annotations

import numpy as np

from ..errors import AccuracyError, SolverError, WorkLimitError
from ..plain import Plain, decode, encode
from . import c_steps, singular_zone
from .ali3p import ALI3P
from .choose import STIFF_STEP_RATIO, stiff_reason
from .genalpha import GeneralizedAlpha
from .projected_rk import DOP853P, RK45P
from .rk4p import RK4P
from .settings import adaptive_with

# Singularity indicator above which the mechanism is clear of a singular configuration
# (twice the level at which dop853p starts planning a crossing).
CLEAR = 2 * singular_zone.NEAR_ZONE
# Times an advance call is retried at half the step after an AccuracyError (rule 3).
HALVINGS = 3
# Accepted steps in a row with the indicator above CLEAR before leaving ali3p.
CLEAR_STEPS = 3
# Hairer's stiffness test (dop853.f): h |lambda| beyond this is at DOP853's stability
# boundary; STIFF_STEPS such steps, without NONSTIFF_STEPS below it in a row in between.
STIFF_HLAMBDA = 6.1
STIFF_STEPS = 15
NONSTIFF_STEPS = 6

AUTO_METHODS = {cls.name: cls for cls in (DOP853P, RK45P, RK4P, ALI3P, GeneralizedAlpha)}


class _Switch(Exception):
    """Raised by the step watch to stop an advance call at a step's end and switch."""


def stiffness(integrator) -> float:
    """Hairer's h |lambda| of dop853p's last step: ||f(y_new) - f(y_12)|| / ||y_new - y_12||
    times h, y_12 the stage at t + h (0 when it cannot be told)."""
    if integrator.name != DOP853P.name or integrator.dense is None:
        return 0.0
    step, kernel = integrator.dense, integrator.equations.ckernel
    if kernel is not None:   # the C kernel's sums: an FMU's wrapper checks its steps with them
        return kernel.stiff_h_lambda(c_steps.tableau(integrator), step.K, step.y_old, step.h)
    s = integrator.n_stages - 1           # the stage at C = 1 (scipy's DOP853 tableau)
    y_s = step.y_old + step.h * (step.K[:s].T @ integrator.A[s, :s])
    den = float(np.linalg.norm(step.y_new - y_s))
    num = float(np.linalg.norm(step.K[-1] - step.K[s]))
    return step.h * num / den if den > 0 else 0.0


class AutoWatch(Plain):
    """The watcher of an ``auto`` run: the switches so far and the counters of its rules."""

    plain_fields = ("step", "switches", "clear", "stiff", "nonstiff", "pending", "interval")

    def __init__(self, step: float | None, interval: float):
        self.step = step               # the step the user gave (fixed-step methods), or None
        self.interval = float(interval)  # the run's output interval (s), for the stiff rule
        self.switches: list = []       # [t, from, to, reason], in time order
        self.clear = 0                 # accepted steps in a row clear of singularities
        self.stiff = self.nonstiff = 0
        self.pending = None            # [method, reason] for the next call's start

    # ------------------------------------------------------------------ watching steps

    def attach(self, integrator) -> None:
        integrator.watch = self.after_step

    def after_step(self, integrator) -> None:
        """After an accepted step: decide a switch (rules 1 and 2)."""
        decision = self.pending or self._decide(integrator)
        if decision is None:
            return
        self.pending = decision
        target = getattr(self, "_target", None)
        if target is not None and integrator.t <= target:
            raise _Switch

    def idle(self, integrator) -> bool:
        """Whether ``after_step`` decides and changes nothing after integrator's coming
        steps, so that a run of them may leave it out (``implicit_runs.implicit_run``):
        genalpha's steps feed no rule (its stiffness is 0) once no switch is pending and
        no stiff steps are counted."""
        return integrator.name == GeneralizedAlpha.name and self.pending is None and \
            self.stiff == 0

    def _decide(self, integrator):
        if integrator.name == ALI3P.name:
            c = singular_zone.indicator(integrator, integrator.t, integrator.q)
            self.clear = self.clear + 1 if c >= CLEAR else 0
            if self.clear < CLEAR_STEPS:
                return None
            self.clear = 0
            stiff = stiff_reason(integrator.equations, integrator.t, integrator.q,
                                 integrator.qd, integrator.inputs(integrator.t),
                                 integrator.rtol, self.interval)
            if stiff:
                return None
            return [DOP853P.name, f"the constraint Jacobian is well conditioned again "
                    f"(singularity indicator {c:.2g} >= {CLEAR:g} for {CLEAR_STEPS} steps): "
                    "the singular configuration is passed; dop853p plans later crossings"]
        hl = stiffness(integrator)
        if hl > STIFF_HLAMBDA:
            self.stiff, self.nonstiff = self.stiff + 1, 0
        elif self.stiff:
            self.nonstiff += 1
            if self.nonstiff >= NONSTIFF_STEPS:
                self.stiff = self.nonstiff = 0
        implicit_step = self.step if self.step is not None else GeneralizedAlpha.default_step
        if self.stiff < STIFF_STEPS or not STIFF_STEP_RATIO * integrator.h < implicit_step:
            return None
        self.stiff = self.nonstiff = 0
        to = GeneralizedAlpha.name
        c = singular_zone.indicator(integrator, integrator.t, integrator.q)
        if c < singular_zone.REDUNDANT:     # genalpha's matrix would be singular
            to = ALI3P.name
        return [to, f"stiff: {integrator.name}'s steps are held by stability (h |lambda| = "
                f"{hl:.3g} > {STIFF_HLAMBDA} on {STIFF_STEPS} steps, Hairer's test)"]

    # ------------------------------------------------------------------ switching

    def advance(self, integrator, t_target: float, limit, dense: bool):
        """``integrator.advance`` with the rules of the module docstring; returns the
        integrator that runs at the end (the same one or its successor)."""
        if self.pending is not None and (integrator.out is None or t_target > integrator.t):
            integrator = self.switch(integrator, *self.pending)
        if integrator.interpolates_to(t_target, dense):     # no step: nothing can fail
            integrator.advance(t_target, limit, dense=dense)
            return integrator
        start, first, tried = integrator.rollback_point(), integrator, {integrator.name}
        self._target, failures, halvings = t_target, [], 0
        try:
            while True:
                try:
                    integrator.advance(t_target, limit, dense=dense)
                    return integrator
                except _Switch:
                    integrator = self.switch(integrator, *self.pending)
                except WorkLimitError:
                    raise
                except SolverError as exc:
                    if isinstance(exc, AccuracyError) and halvings < HALVINGS and \
                            self.step is None and not integrator.adaptive and \
                            integrator.name == first.name:
                        halvings += 1
                        step = 0.5 * integrator.h
                        first.set_state(start)
                        integrator = self.switch(first, first.name, f"{exc}; retried from "
                                                 f"t = {first.t:.9g} s with step {step:g} s",
                                                 step)
                        continue
                    failures.append(exc)
                    to = DOP853P.name if integrator.name == ALI3P.name else ALI3P.name
                    if to in tried and len(failures) == 1:
                        raise
                    if to in tried:      # the first method's error, with what was tried
                        raise SolverError(failures[0].reason + "; auto retried: " + "; ".join(
                            str(e) for e in failures[1:]), failures[0].t) from None
                    tried.add(to)
                    first.set_state(start)
                    integrator = self.switch(first, to, f"{exc}; retried from t = "
                                             f"{first.t:.9g} s with {to}")
        finally:
            self._target = None

    def switch(self, old, to: str, reason: str, step: float | None = None):
        """A ``to`` integrator carrying old's state, counters and energy balance; at
        ``step`` (s) when given, else at auto's."""
        cls = AUTO_METHODS[to]
        # ali3p as make_integrator builds auto's choice (step control); genalpha for
        # stiffness at its fixed step, whose steps are not held by stability (the step
        # control follows the stiff spring's oscillation: more steps than dop853p's here)
        options = {"step_control": "adaptive"} if cls is ALI3P else {}
        if step is None:
            step = self.step if self.step is not None else (
                np.inf if adaptive_with(cls, options) else cls.default_step)
        new = cls(old.equations, old.t, old.q, old.qd, step=step, rtol=old.rtol,
                  atol=old.atol, inputs=old.inputs, **options)
        if old.out is not None and old.out.t < old.t:
            new.out = old.out               # the last output, from old's dense output
        new.stats = old.stats
        new.stats.nswitches += 1
        if new.accuracy is not None:        # charge only new's own steps
            new.accuracy.charged = new.stats.nsteps
        if old.audit is not None and new.audit is not None:
            carried = {k: getattr(old.audit, k) for k in old.audit.plain_fields}
            for k in ("method", "rtol", "atol", "factor", "what", "fixed_step"):
                carried[k] = getattr(new.audit, k)
            new.audit.__dict__.update(carried)
        new.picked_by, new.reason = old.picked_by, old.reason
        self.switches.append([float(old.t), old.name, to, reason])
        self.pending, self.clear, self.stiff, self.nonstiff = None, 0, 0, 0
        self.attach(new)
        return new



def switches_of(integrator) -> list[tuple[float, str, str, str]]:
    """The switches of an ``AutoRun`` so far ([] for an integrator run as it is)."""
    return integrator.switches if isinstance(integrator, AutoRun) else []


def method_chain(integrator) -> str:
    """Its method's name, or "auto->" and the method auto picked, then each it switched to."""
    if not getattr(integrator, "picked_by", ""):
        return integrator.name
    switches = switches_of(integrator)
    return "->".join(["auto", *([s[1] for s in switches[:1]] + [s[2] for s in switches]
                                or [integrator.name])])


class AutoRun:
    """What ``Simulation`` runs for ``auto``: the integrator of the moment behind the
    ``Integrator`` interface (attributes are the current integrator's), advanced by its
    ``AutoWatch``. Saved states (``get_state``, ``rollback_point``) hold the integrator's
    fields, its method's name and the watcher's state."""

    def __init__(self, integrator, watch: AutoWatch):
        self.__dict__["current"], self.__dict__["watcher"] = integrator, watch
        watch.attach(integrator)

    def __getattr__(self, name):
        return getattr(self.current, name)

    def __setattr__(self, name, value):
        setattr(self.current, name, value)

    @property
    def switches(self) -> list[tuple[float, str, str, str]]:
        return [tuple(s) for s in self.watcher.switches]

    def advance(self, t_target: float, limit=None, *, dense: bool = False) -> None:
        self.__dict__["current"] = self.watcher.advance(self.current, t_target, limit, dense)

    def get_state(self) -> dict:
        return {**self.current.get_state(), "auto_method": self.current.name,
                "auto_watch": encode(self.watcher)}

    def rollback_point(self) -> dict:
        """Within the process: the integrator object itself too (rebuilding one would
        recompute what its constructor derives from the state, e.g. ali3p's penalty)."""
        return {**self.current.rollback_point(), "auto_method": self.current.name,
                "auto_watch": encode(self.watcher), "auto_object": self.current}

    def set_state(self, state: dict) -> None:
        state = dict(state)
        name, watch = state.pop("auto_method"), decode(state.pop("auto_watch"))
        current = state.pop("auto_object", self.current)
        if current.name != name:
            current = self.watcher.switch(current, name, "")   # an integrator of that method
        watch.attach(current)
        current.set_state(state)
        self.__dict__["current"], self.__dict__["watcher"] = current, watch

