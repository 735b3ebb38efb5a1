"""FMI 2.0 status codes and the two exceptions a model raises to report trouble.

The codes are the values of the C enum ``fmi2Status`` (fmi2FunctionTypes.h); the runtime
returns them to the C wrapper as plain ints.
"""

from __future__ import annotations

OK = 0
WARNING = 1
DISCARD = 2
ERROR = 3
FATAL = 4
PENDING = 5

NAMES = {OK: "fmi2OK", WARNING: "fmi2Warning", DISCARD: "fmi2Discard",
         ERROR: "fmi2Error", FATAL: "fmi2Fatal", PENDING: "fmi2Pending"}


class Discard(Exception):
    """A step (or input) the model refuses but that can be retried.

    Raise it from ``Slave.step`` with the reason, e.g. ``Discard("step 1e3 s exceeds the
    largest step 10 s")``: the FMU returns fmi2Discard, logs the reason and stays at its
    last communication point, so the master may retry with a smaller step or other
    inputs. ``terminate=True`` says the model cannot go on at all (the master reads it
    with fmi2GetBooleanStatus(fmi2Terminated)).
    """

    def __init__(self, reason: str, terminate: bool = False):
        super().__init__(reason)
        self.terminate = terminate


class FmiError(Exception):
    """A call the runtime refuses with fmi2Error (wrong state, bad argument, bad state blob).

    Models do not need it: any exception other than ``Discard`` raised by a model hook
    becomes fmi2Error with the exception's text as the logged reason.
    """
