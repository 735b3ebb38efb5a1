"""One FMU instance driven through fmpy's ``FMU2Slave`` (FMI 2.0) or ``FMU3Slave`` (FMI
3.0) for mbdfmu's masters, with its log messages kept per instance (the reason of a
refused step) and the derivative calls the masters beyond zero-order hold use: the same
methods for both versions (FMI 3.0 takes input derivatives as the derivative inputs
``der(u)``, ``der(u,2)`` its FMU declares, and has no fmi2SetupExperiment)."""

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


def _fmi3_flag(directory: str, attribute: str) -> bool:
    """A boolean attribute of an FMI 3.0 model description's CoSimulation element."""
    import xml.etree.ElementTree as ET

    element = ET.parse(Path(directory) / "modelDescription.xml").getroot().find("CoSimulation")
    return element is not None and element.get(attribute, "false") == "true"


_CALLBACKS = None
_SERIAL = iter(range(10 ** 12))


class Member:
    """One FMU instance driven through fmpy, with its log messages kept."""

    def __init__(self, name: str, path: Path, description=None):
        from fmpy import extract, read_model_description

        self.name = name
        self.md = description or read_model_description(str(path))
        self.variables = {v.name: v for v in self.md.modelVariables}
        self.vr = {n: v.valueReference for n, v in self.variables.items()}
        self.fmi3 = self.md.fmiVersion.startswith("3")
        cs = self.md.coSimulation
        self.max_output_derivative_order = int(getattr(cs, "maxOutputDerivativeOrder", 0) or 0)
        self.provides_directional = bool(getattr(cs, "providesDirectionalDerivative", False))
        self.interpolates_inputs = any(v.startswith("der(") for v in self.vr) if self.fmi3 \
            else bool(getattr(cs, "canInterpolateInputs", False))
        self.dir = extract(str(path))
        if self.fmi3:      # fmpy reads FMI 2.0's attribute name; FMI 3.0's has a final s
            self.provides_directional = _fmi3_flag(self.dir, "providesDirectionalDerivatives")
        # The instance name is unique in the process: log messages are sorted by it.
        self.instance_name = f"{name}#{next(_SERIAL)}"
        self.messages = _MESSAGES.setdefault(self.instance_name, [])
        self.fmu = self._instantiate(cs.modelIdentifier)

    def _instantiate(self, identifier: str):
        global _CALLBACKS
        kwargs = dict(guid=self.md.guid, unzipDirectory=self.dir, modelIdentifier=identifier,
                      instanceName=self.instance_name)
        if self.fmi3:
            from fmpy.fmi3 import FMU3Slave
            fmu = FMU3Slave(**kwargs)
            name = self.instance_name.encode()
            # FMI 3.0's logger has no instance name: one closure per instance (fmpy keeps it)
            fmu.instantiate(loggingOn=True, logMessage=lambda env, status, category, message:
                            _logger(env, name, status, category, message))
            return fmu
        from fmpy.fmi2 import FMU2Slave
        if _CALLBACKS is None:
            _CALLBACKS = _callbacks()
        fmu = FMU2Slave(**kwargs)
        fmu.instantiate(callbacks=_CALLBACKS, loggingOn=True)
        return fmu

    def enter_initialization(self, t0: float, t_end: float) -> None:
        if self.fmi3:
            self.fmu.enterInitializationMode(startTime=t0, stopTime=t_end)
        else:
            self.fmu.setupExperiment(startTime=t0, stopTime=t_end)
            self.fmu.enterInitializationMode()

    def exit_initialization(self) -> None:
        self.fmu.exitInitializationMode()

    def set(self, names: list[str], values) -> None:
        if names:
            setter = self.fmu.setFloat64 if self.fmi3 else self.fmu.setReal
            setter([self.vr[n] for n in names], [float(v) for v in values])

    def get(self, names: list[str]) -> list[float]:
        if not names:
            return []
        getter = self.fmu.getFloat64 if self.fmi3 else self.fmu.getReal
        return list(getter([self.vr[n] for n in names]))

    def set_derivatives(self, names: list[str], orders: list[int], values) -> None:
        """Derivative ``orders[i]`` of input ``names[i]``: fmi2SetRealInputDerivatives, or
        FMI 3.0's derivative inputs ``der(u)`` / ``der(u,2)``."""
        if names and self.fmi3:
            self.set([f"der({n})" if k == 1 else f"der({n},{k})" for n, k in zip(names, orders)],
                     values)
        elif names:
            self.fmu.setRealInputDerivatives([self.vr[n] for n in names], list(orders),
                                             [float(v) for v in values])

    def output_derivatives(self, names: list[str], order: int) -> list[float]:
        """Derivative ``order`` of each output in ``names`` (fmi2GetRealOutputDerivatives,
        fmi3GetOutputDerivatives)."""
        if not names:
            return []
        get = self.fmu.getOutputDerivatives if self.fmi3 else self.fmu.getRealOutputDerivatives
        return list(get([self.vr[n] for n in names], [order] * len(names)))

    def directional(self, unknowns: list[str], knowns: list[str], seed) -> list[float]:
        """fmi2GetDirectionalDerivative: d(unknowns)/d(knowns) times ``seed``."""
        return list(self.fmu.getDirectionalDerivative([self.vr[n] for n in unknowns],
                                                      [self.vr[n] for n in knowns],
                                                      [float(v) for v in seed]))

    def do_step(self, t: float, h: float) -> int:
        from fmpy.fmi1 import FMICallException

        try:
            done = self.fmu.doStep(currentCommunicationPoint=t, communicationStepSize=h)
        except FMICallException as exc:
            return exc.status
        if self.fmi3 and done[1]:        # terminateSimulation: it cannot go on
            return ERROR
        return OK

    def get_state(self):
        return self.fmu.getFMUState() if self.fmi3 else self.fmu.getFMUstate()

    def set_state(self, state) -> None:
        if self.fmi3:
            self.fmu.setFMUState(state)
        else:
            self.fmu.setFMUstate(state)

    def free_state(self, state) -> None:
        if self.fmi3:
            self.fmu.freeFMUState(state)
        else:
            self.fmu.freeFMUstate(state)

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


