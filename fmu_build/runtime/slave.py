"""``Slave``: the generic FMI 2.0 co-simulation slave the C wrapper talks to.

A model module defines one subclass (named by the FMU's config, ``Model`` by default)
and implements only what the model does:

1. ``step(time, step_size)`` (required): advance the model from ``time`` to
   ``time + step_size`` (seconds), reading inputs from and writing outputs to
   ``self.values``. Raise ``Discard(reason)`` for a step that may be retried (it must then
   leave the model unchanged); any other exception is an fmi2Error.
2. ``calculate()``: outputs that follow inputs within a communication point (direct
   feedthrough) or the time, computed before a get that follows a set or a step (the
   model's ``step`` then need not write them).
3. ``initialize()``: compute the internal state and the calculated outputs from the
   parameters and inputs in ``self.values``. Called when fmi2ExitInitializationMode
   needs it and before a get in Initialization Mode after a set (so it must be
   repeatable).
4. ``save_state()`` / ``restore_state(tree)``: the model's own state beyond
   ``self.values`` as a tree of dict, list, str, int, float, bool, None and numpy arrays
   (both copied by the base). Default: no own state. ``check_state(tree)`` returns why a
   tree read from bytes cannot be restored (types, shapes), or None.
5. optional: ``setup()`` (once, at instantiation), ``on_terminate()``, ``on_free()``,
   ``directional_derivative``, ``set_input_derivatives``, ``output_derivatives``.

``self.set_since_step`` holds the values the host set since the last successful
fmi2DoStep (name -> value; also since instantiation or fmi2Reset), e.g. to tell an input
set again to the same value from one left alone; the base empties it after each step.

The model reads ``self.time`` (s), ``self.start_time``, ``self.stop_time``,
``self.tolerance`` (fmi2SetupExperiment's relative tolerance, or None),
``self.resources`` (the FMU's resources folder) and logs with ``self.log(text)``. Names
the base uses, which a model must not assign: ``values``, ``set_since_step``,
``variables``, ``time``, ``start_time``, ``stop_time``, ``tolerance``, ``resources``,
``instance_name``, ``guid``, ``log_queue``, ``fast_real``, ``fast_step``, ``fast_time``,
``take_log``, ``fmi_sync`` and everything starting with ``_fmi`` or ``fmi2_``.

The ``fmi2_*`` methods form the protocol with the C wrapper (one per FMI function, see
``docs/fmu_runtime.md``). Each returns ``(status, payload)`` and never raises.
"""

from __future__ import annotations

import math
from pathlib import Path

from . import access, status
from .log import LogQueue
from .real_cache import FastStepProtocol, FastSteps, RealCache
from .machine import ALLOWED, State, fmi_function, refusal
from .derivatives import DerivativeProtocol
from .fmi3 import Fmi3Protocol, fmi3_text
from .snapshot import StateProtocol
from .status import Discard, FmiError
from .variables import VariableTable

# Relative tolerance between the master's communication point and the instance's time.
TIME_TOLERANCE = 1e-9
# FMI 2.0 fmi2StatusKind values and which fmi2Get*Status function answers each.
DO_STEP_STATUS, PENDING_STATUS, LAST_SUCCESSFUL_TIME, TERMINATED = range(4)
STATUS_ANSWERS = {("Real", LAST_SUCCESSFUL_TIME), ("Boolean", TERMINATED)}
# States where getting and setting values is allowed (the same for every type).
GET_STATES, SET_STATES = ALLOWED["fmi2GetReal"], ALLOWED["fmi2SetReal"]


class Slave(StateProtocol, DerivativeProtocol, Fmi3Protocol, FastStepProtocol):
    """Base class of every model; see the module docstring for what a model implements."""

    def __init__(self, instance_name: str, guid: str, resources: str, variables: VariableTable,
                 log_categories: dict[str, str], logging_on: bool, default_start: float = 0.0,
                 fmi_version: int = 2):
        self.instance_name = instance_name
        self.guid = guid
        self.resources = Path(resources)
        self.variables = variables
        self._fmi_log = LogQueue(log_categories, logging_on,
                                 translate=fmi3_text if fmi_version == 3 else None)
        self.log_queue = self._fmi_log.pending   # watched by the C wrapper
        self._fmi_default_start = default_start
        self._fmi_calculates = type(self).calculate is not Slave.calculate
        self._fmi_reals = RealCache(variables)
        self.fast_real = self._fmi_reals.address        # read by the C wrapper
        self._fmi_fast_steps = FastSteps()
        self.fast_step = self._fmi_fast_steps.address   # read by the C wrapper
        self._fmi_restart()
        self.setup()

    # ----- what a model implements (defaults) ------------------------------------------
    def setup(self) -> None:
        """Once, at instantiation: read resources, build what never changes."""

    def initialize(self) -> None:
        """Derive the internal state and calculated values from ``self.values``."""

    # True: ``step`` leaves every calculated value current, so ``calculate`` follows sets only
    # (and a step's values can be served by the wrapper without Python)
    STEP_CALCULATES = False

    def calculate(self) -> None:
        """Outputs with direct feedthrough: compute them in ``self.values`` from the inputs
        and the state at ``self.time``. Called (when overridden) before a get that follows
        a set or a step in Step Complete; Initialization Mode calls ``initialize``."""

    def step(self, time: float, step_size: float) -> None:
        """Advance from ``time`` by ``step_size`` seconds (required)."""
        raise NotImplementedError(f"{type(self).__name__} does not implement step()")

    def save_state(self):
        """The model's own state beyond ``self.values`` (a tree; see the module docstring)."""
        return None

    def restore_state(self, tree) -> None:
        """Restore what ``save_state`` returned (a copy the model may keep)."""

    def check_state(self, tree) -> str | None:
        """Why ``tree`` (read from bytes by fmi2DeSerializeFMUstate) cannot be restored."""
        return None

    def on_terminate(self) -> None:
        """At fmi2Terminate."""

    def on_free(self) -> None:
        """At fmi2FreeInstance: release outside resources."""

    def log(self, text: str, category: str = "logAll") -> None:
        """Queue a debug message (status fmi2OK) for the host's logger."""
        self._fmi_log.emit(status.OK, category, text)

    def warn(self, text: str) -> None:
        """Queue a warning (status fmi2Warning) for the host's logger: the call still
        succeeds, but the master should know."""
        self._fmi_log.emit(status.WARNING, "logStatusWarning", text)

    @property
    def time(self) -> float:
        """The current communication point (s)."""
        return self._fmi_time

    # ----- internal ----------------------------------------------------------------------
    def _fmi_restart(self) -> None:
        """The state right after fmi2Instantiate (also what fmi2Reset returns to)."""
        self._fmi_reals.invalidate()
        self._fmi_state = State.INSTANTIATED
        self.values = self.variables.start_values()
        self.set_since_step: dict[str, object] = {}
        self._fmi_at(self._fmi_default_start)
        self.start_time = self._fmi_default_start
        self.stop_time = self.tolerance = None
        self._fmi_dirty = True
        self._fmi_stale = False
        self._fmi_terminate = False

    def _fmi_at(self, t: float) -> None:
        """The instance's time is ``t`` (and so is its independent variable, FMI 3.0)."""
        self._fmi_time = t
        if self.variables.independent:
            self.values[self.variables.independent] = t

    def _fmi_error(self, reason: str) -> int:
        """Log ``reason``, enter the Error state, and return fmi2Error."""
        self._fmi_log.status(status.ERROR, reason)
        self._fmi_state = State.ERROR
        return status.ERROR

    def _fmi_refresh(self) -> None:
        if self._fmi_dirty:
            self.initialize()
            self._fmi_dirty = False

    def take_log(self) -> list:
        """The queued messages ``(status, category, text)``, for the C wrapper."""
        return self._fmi_log.take()

    # ----- the protocol ------------------------------------------------------------------
    def fmi2_reject(self, function: str, reason: str):
        """A call the C wrapper refused (a NULL pointer, a non-finite time)."""
        return self._fmi_error(f"{function}: {reason}"), None

    @fmi_function("fmi2SetDebugLogging")
    def fmi2_set_debug_logging(self, logging_on: bool, names: tuple):
        names = tuple(n.decode("utf-8", "replace") if isinstance(n, bytes) else n for n in names)
        reason = self._fmi_log.set_debug_logging(bool(logging_on), names)
        return (status.OK, None) if reason is None else (self._fmi_error(reason), None)

    @fmi_function("fmi2SetupExperiment")
    def fmi2_setup_experiment(self, tolerance_defined, tolerance, start, stop_defined, stop):
        checks = [("startTime", start)] + ([("stopTime", stop)] if stop_defined else [])
        for label, value in checks:
            if not math.isfinite(value):
                raise FmiError(f"{label} = {value} is not finite")
        if stop_defined and stop < start:
            raise FmiError(f"stopTime {stop} is before startTime {start}")
        if tolerance_defined and not (math.isfinite(tolerance) and tolerance > 0):
            raise FmiError(f"tolerance = {tolerance} is not a positive finite number")
        self._fmi_at(float(start))
        self.start_time = float(start)
        self.stop_time = float(stop) if stop_defined else None
        self.tolerance = float(tolerance) if tolerance_defined else None
        return status.OK, None

    @fmi_function("fmi2EnterInitializationMode")
    def fmi2_enter_initialization_mode(self):
        self._fmi_state = State.INITIALIZATION_MODE
        return status.OK, None

    @fmi_function("fmi2ExitInitializationMode")
    def fmi2_exit_initialization_mode(self):
        try:
            self._fmi_refresh()
        except Discard as exc:   # there is no smaller step to retry with
            raise FmiError(f"initialization failed: {exc}") from None
        self._fmi_state = State.STEP_COMPLETE
        return status.OK, None

    @fmi_function("fmi2Terminate")
    def fmi2_terminate(self):
        self._fmi_state = State.TERMINATED
        self.on_terminate()
        return status.OK, None

    @fmi_function("fmi2Reset")
    def fmi2_reset(self):
        self._fmi_restart()
        return status.OK, None

    @fmi_function("fmi2FreeInstance")
    def fmi2_free_instance(self):
        self.on_free()
        return status.OK, None

    def fmi2_get(self, type_name: str, vrs: tuple):
        """fmi2GetReal/Integer/Boolean/String; payload: a tuple of values (String: bytes)."""
        if self._fmi_state == State.STEP_COMPLETE and not self._fmi_stale:
            values = access.fast_get(self, type_name, vrs)
            if values is not None:
                return status.OK, values
        function = "fmi2Get" + type_name
        if self._fmi_state not in GET_STATES:
            skipped = tuple(access.SKIPPED[type_name] for _ in vrs)
            return self._fmi_error(refusal(function, self._fmi_state)), skipped
        try:
            if self._fmi_state == State.INITIALIZATION_MODE:
                self._fmi_refresh()
            elif self._fmi_stale:
                self._fmi_stale = False
                self.calculate()
            code, values = access.get_values(self, type_name, vrs)
        except BaseException as exc:  # noqa: B902 - nothing may reach the C side
            skipped = tuple(access.SKIPPED[type_name] for _ in vrs)
            return self._fmi_error(f"{function}: {type(exc).__name__}: {exc}"), skipped
        if code == status.ERROR:
            self._fmi_state = State.ERROR
        return code, values

    def fmi2_set(self, type_name: str, vrs: tuple, values: tuple):
        """fmi2SetReal/Integer/Boolean/String (String values: bytes)."""
        if self._fmi_state == State.STEP_COMPLETE and access.fast_set(self, type_name, vrs, values):
            self._fmi_stale = self._fmi_calculates
            return status.OK, None
        function = "fmi2Set" + type_name
        if self._fmi_state not in SET_STATES:
            return self._fmi_error(refusal(function, self._fmi_state)), None
        try:
            code = access.set_values(self, type_name, vrs, values)
        except BaseException as exc:  # noqa: B902
            return self._fmi_error(f"{function}: {type(exc).__name__}: {exc}"), None
        if self._fmi_state in (State.INSTANTIATED, State.INITIALIZATION_MODE):
            self._fmi_dirty = True
        self._fmi_stale = self._fmi_calculates
        if code == status.ERROR:
            self._fmi_state = State.ERROR
        return code, None

    @fmi_function("fmi2DoStep")
    def fmi2_do_step(self, time: float, step_size: float, no_set_prior: bool):
        now = self._fmi_time
        if not math.isfinite(time):
            raise FmiError(f"currentCommunicationPoint = {time} is not finite")
        if not (math.isfinite(step_size) and step_size > 0):
            raise FmiError(f"communicationStepSize = {step_size} must be positive and finite")
        if abs(time - now) > TIME_TOLERANCE * max(abs(now), abs(time)):
            raise FmiError(f"currentCommunicationPoint {time!r} is not the FMU's time {now!r} "
                           f"(relative tolerance {TIME_TOLERANCE})")
        end = time + step_size
        if not math.isfinite(end):
            raise FmiError(f"the time after the step, {time} + {step_size}, is not finite")
        if self.variables.input_derivatives:
            self._fmi_push_input_derivatives()
        self.step(time, step_size)
        self._fmi_at(end)
        self.set_since_step.clear()
        self._fmi_stale = self._fmi_calculates and not self.STEP_CALCULATES
        if not self._fmi_stale:       # fmi2GetReal served by the wrapper until the next call
            self._fmi_reals.publish(self.values)
        return status.OK, None

    @fmi_function("fmi2CancelStep")
    def fmi2_cancel_step(self):
        return status.ERROR, None  # unreachable: the machine allows CancelStep in no state

    def fmi2_get_status(self, type_name: str, kind: int):
        """fmi2Get{,Real,Integer,Boolean,String}Status; type_name "" for fmi2GetStatus."""
        function = f"fmi2Get{type_name}Status"
        reason = refusal("fmi2GetStatus", self._fmi_state)
        if reason is not None:
            return self._fmi_error(reason.replace("fmi2GetStatus", function)), None
        if (type_name, kind) not in STATUS_ANSWERS:
            self._fmi_log.status(status.DISCARD, f"{function}: status kind {kind} cannot be "
                                         "retrieved (this FMU runs fmi2DoStep synchronously)")
            return status.DISCARD, None
        return status.OK, self._fmi_time if kind == LAST_SUCCESSFUL_TIME else self._fmi_terminate
