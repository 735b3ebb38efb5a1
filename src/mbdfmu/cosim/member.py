"""One FMU instance driven through fmpy's ``FMU2Slave`` for mbdfmu's masters, with its log
messages kept per instance (the reason of a refused step) and the derivative calls the
masters beyond zero-order hold use."""

from __future__ import annotations

import shutil
from pathlib import Path

# fmpy raises FMICallException with the FMI 2.0 status codes (fmpy.fmi2.fmi2OK, ...).
OK, WARNING, DISCARD, ERROR, FATAL = 0, 1, 2, 3, 4
STATUS = {OK: "OK", WARNING: "warning", DISCARD: "discard", ERROR: "error", FATAL: "fatal"}

_MESSAGES: dict[str, list] = {}


def _logger(env, instance, status, category, message):
    # mbdfmu FMUs pass the whole message as the format string, '%' doubled: no variadic
    # formatting needed (fmpy's addLoggerProxy is process-wide and would take over other
    # masters' loggers).
    name = instance.decode(errors="replace") if instance else ""
    text = message.decode(errors="replace").replace("%%", "%")
    _MESSAGES.setdefault(name, []).append(
        (status, (category or b"").decode(errors="replace"), text))


def _callbacks():
    from fmpy.fmi1 import calloc, free
    from fmpy.fmi2 import (fmi2CallbackAllocateMemoryTYPE, fmi2CallbackFreeMemoryTYPE,
                           fmi2CallbackFunctions, fmi2CallbackLoggerTYPE)

    cb = fmi2CallbackFunctions()
    cb.logger = fmi2CallbackLoggerTYPE(_logger)
    cb.allocateMemory = fmi2CallbackAllocateMemoryTYPE(calloc)
    cb.freeMemory = fmi2CallbackFreeMemoryTYPE(free)
    return cb


_CALLBACKS = None
_SERIAL = iter(range(10 ** 12))


class Member:
    """One FMU instance driven through fmpy, with its log messages kept."""

    def __init__(self, name: str, path: Path, description=None):
        global _CALLBACKS
        from fmpy import extract, read_model_description
        from fmpy.fmi2 import FMU2Slave

        if _CALLBACKS is None:
            _CALLBACKS = _callbacks()
        self.name = name
        self.md = description or read_model_description(str(path))
        self.variables = {v.name: v for v in self.md.modelVariables}
        self.vr = {n: v.valueReference for n, v in self.variables.items()}
        self.dir = extract(str(path))
        # The instance name is unique in the process: log messages are sorted by it.
        self.instance_name = f"{name}#{next(_SERIAL)}"
        self.messages = _MESSAGES.setdefault(self.instance_name, [])
        self.fmu = FMU2Slave(guid=self.md.guid, unzipDirectory=self.dir,
                             modelIdentifier=self.md.coSimulation.modelIdentifier,
                             instanceName=self.instance_name)
        self.fmu.instantiate(callbacks=_CALLBACKS, loggingOn=True)

    def set(self, names: list[str], values) -> None:
        if names:
            self.fmu.setReal([self.vr[n] for n in names], [float(v) for v in values])

    def get(self, names: list[str]) -> list[float]:
        return list(self.fmu.getReal([self.vr[n] for n in names])) if names else []

    def set_derivatives(self, names: list[str], orders: list[int], values) -> None:
        """fmi2SetRealInputDerivatives: derivative ``orders[i]`` of input ``names[i]``."""
        if names:
            self.fmu.setRealInputDerivatives([self.vr[n] for n in names], list(orders),
                                             [float(v) for v in values])

    def output_derivatives(self, names: list[str], order: int) -> list[float]:
        """fmi2GetRealOutputDerivatives: derivative ``order`` of each output in ``names``."""
        if not names:
            return []
        return list(self.fmu.getRealOutputDerivatives([self.vr[n] for n in names],
                                                      [order] * len(names)))

    def directional(self, unknowns: list[str], knowns: list[str], seed) -> list[float]:
        """fmi2GetDirectionalDerivative: d(unknowns)/d(knowns) times ``seed``."""
        return list(self.fmu.getDirectionalDerivative([self.vr[n] for n in unknowns],
                                                      [self.vr[n] for n in knowns],
                                                      [float(v) for v in seed]))

    def do_step(self, t: float, h: float) -> int:
        from fmpy.fmi1 import FMICallException

        try:
            self.fmu.doStep(currentCommunicationPoint=t, communicationStepSize=h)
        except FMICallException as exc:
            return exc.status
        return OK

    def reason(self) -> str:
        """The last message the instance logged (the reason of a refused step)."""
        return self.messages[-1][2] if self.messages else "no message logged"

    def close(self) -> None:
        try:
            self.fmu.terminate()
        except Exception:  # noqa: BLE001 - an instance that failed may refuse to terminate
            pass
        self.fmu.freeInstance()
        shutil.rmtree(self.dir, ignore_errors=True)
        _MESSAGES.pop(self.instance_name, None)


