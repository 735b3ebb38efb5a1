"""The FMI 2.0 co-simulation state machine (FMI 2.0 standard, section 4.2.4).

Each FMI function may be called in the states listed in ``ALLOWED``; the table follows
the standard's figure and the masks of the Reference FMUs, with two documented choices:

* fmi2DoStep that returns fmi2Discard computes nothing: the instance stays in Step
  Complete at its last communication point, so the master may call fmi2DoStep again
  (smaller step, other inputs) without restoring a state first. ``STEP_FAILED`` is
  therefore never entered; it is listed so the table reads like the standard.
* after fmi2Error (state ``ERROR``) only getting values, the status functions,
  fmi2SetFMUstate (restoring a state taken earlier, as the standard suggests),
  fmi2SetDebugLogging, fmi2Reset and fmi2FreeInstance are accepted.
"""

from __future__ import annotations

import functools

import numpy as np

from . import status
from .status import Discard, FmiError


class State:
    """An instance's states: plain strings (the names used in messages), not an Enum,
    because every FMI call tests membership in a set of states and an Enum member's hash
    is computed in Python (a third of a microsecond per call)."""

    INSTANTIATED = "Instantiated"
    INITIALIZATION_MODE = "Initialization Mode"
    STEP_COMPLETE = "Step Complete"
    STEP_FAILED = "Step Failed"
    TERMINATED = "Terminated"
    ERROR = "Error"
    ALL = (INSTANTIATED, INITIALIZATION_MODE, STEP_COMPLETE, STEP_FAILED, TERMINATED, ERROR)


_I, _M, _C, _F, _T, _E = (State.INSTANTIATED, State.INITIALIZATION_MODE, State.STEP_COMPLETE,
                          State.STEP_FAILED, State.TERMINATED, State.ERROR)
_ANY = frozenset(State.ALL)
_GET = frozenset({_M, _C, _F, _T, _E})
_SET = frozenset({_I, _M, _C})

ALLOWED: dict[str, frozenset[str]] = {
    "fmi2SetDebugLogging": _ANY,
    "fmi2SetupExperiment": frozenset({_I}),
    "fmi2EnterInitializationMode": frozenset({_I}),
    "fmi2ExitInitializationMode": frozenset({_M}),
    "fmi2Terminate": frozenset({_C, _F}),
    "fmi2Reset": _ANY,
    "fmi2FreeInstance": _ANY,
    "fmi2GetReal": _GET, "fmi2GetInteger": _GET, "fmi2GetBoolean": _GET, "fmi2GetString": _GET,
    "fmi2SetReal": _SET, "fmi2SetInteger": _SET, "fmi2SetBoolean": _SET, "fmi2SetString": _SET,
    "fmi2GetFMUstate": _ANY - {_E},
    "fmi2SetFMUstate": _ANY,
    "fmi2SerializeFMUstate": _ANY,
    "fmi2DeSerializeFMUstate": _ANY,
    "fmi2GetDirectionalDerivative": frozenset({_M, _C, _F, _T}),
    "fmi2SetRealInputDerivatives": frozenset({_I, _M, _C}),
    "fmi2GetRealOutputDerivatives": frozenset({_C, _F, _T}),
    "fmi2DoStep": frozenset({_C}),
    "fmi2CancelStep": frozenset(),   # only while a step is pending, which never happens
    "fmi2GetStatus": frozenset({_C, _F, _T, _E}),
}


def allowed_states(function: str) -> frozenset[str]:
    """The states ``function`` may be called in; a get or set of a type FMI 2.0 lacks
    (FMI 3.0's fmi3GetFloat32, ...) like the other gets and sets."""
    if function in ALLOWED:
        return ALLOWED[function]
    return _GET if function.startswith("fmi2Get") else _SET


def refusal(function: str, state: str) -> str | None:
    """Why ``function`` may not be called in ``state``, or None when it may."""
    allowed = allowed_states(function)
    if state in allowed:
        return None
    if state == State.ERROR:
        return (f"{function} refused: an earlier call returned fmi2Error; call fmi2Reset "
                "(or fmi2SetFMUstate with a state taken before) to go on")
    if not allowed:
        return f"{function} is not allowed: this FMU never returns fmi2Pending"
    where = ", ".join(s for s in State.ALL if s in allowed)
    return f"{function} is not allowed in state {state} (allowed in: {where})"


def fmi_function(name: str):
    """Decorate a protocol method: state check, status from exceptions, Error state.
    numpy's floating-point warnings are off inside (``np.errstate``, local to the calling
    thread): a diverging state would print RuntimeWarnings to the host's stderr, while the
    solver's own checks already stop the call with fmi2Error and a logged reason."""
    def decorate(method):
        allowed = ALLOWED[name]

        @functools.wraps(method)
        def call(self, *args):
            if self._fmi_state not in allowed:
                return self._fmi_error(refusal(name, self._fmi_state)), None
            try:
                with np.errstate(all="ignore"):
                    return method(self, *args)
            except Discard as exc:
                self._fmi_terminate |= exc.terminate
                self._fmi_log.status(status.DISCARD, f"{name}: {exc}")
                return status.DISCARD, None
            except FmiError as exc:
                return self._fmi_error(f"{name}: {exc}"), None
            except BaseException as exc:  # noqa: B902 - nothing may reach the C side
                return self._fmi_error(f"{name}: {type(exc).__name__}: {exc}"), None
        return call
    return decorate
