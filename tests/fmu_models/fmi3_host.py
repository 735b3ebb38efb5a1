"""One FMI 3.0 instance through fmpy's FMU3Slave with every log message kept, and the runs
that compare an FMI 3.0 FMU with the FMI 2.0 FMU of the same scene in fmpy and Ecos."""

from __future__ import annotations

from pathlib import Path

import numpy as np
from fmpy import extract, read_model_description, simulate_fmu
from fmpy.fmi1 import FMICallException
from fmpy.fmi3 import FMU3Slave, fmi3LogMessageCallback

OK, WARNING, DISCARD, ERROR, FATAL = range(5)


class Host3:
    """An FMI 3.0 instance, logging on, messages kept as (status, category, text)."""

    def __init__(self, path: Path, name: str = "a"):
        self.md = read_model_description(str(path))
        self.vr = {v.name: v.valueReference for v in self.md.modelVariables}
        self.messages: list[tuple[int, str, str]] = []
        self._logger = fmi3LogMessageCallback(
            lambda env, status, category, text: self.messages.append(
                (status, category.decode(), text.decode())))
        self.fmu = FMU3Slave(guid=self.md.guid, unzipDirectory=extract(str(path)),
                             modelIdentifier=self.md.coSimulation.modelIdentifier,
                             instanceName=name)
        self.fmu.instantiate(loggingOn=True, logMessage=self._logger)
        self.t = 0.0

    def init(self, **values):
        self.fmu.enterInitializationMode(startTime=0.0)
        if values:
            self.set(**values)
        self.fmu.exitInitializationMode()
        return self

    def set(self, **values) -> None:
        names = list(values)
        self.fmu.setFloat64([self.vr[n] for n in names], [float(values[n]) for n in names])

    def get(self, *names) -> list[float]:
        return list(self.fmu.getFloat64([self.vr[n] for n in names]))

    def step(self, h: float) -> tuple:
        """(status, terminate, lastSuccessfulTime) of fmi3DoStep from the instance's time."""
        try:
            _, terminate, _, last = self.fmu.doStep(self.t, h)
        except FMICallException as exc:
            return exc.status, None, None
        self.t = last
        return OK, terminate, last

    def status(self, call) -> int:
        """The status of ``call(self.fmu)`` (fmpy raises above Warning)."""
        try:
            call(self.fmu)
            return OK
        except FMICallException as exc:
            return exc.status

    def last(self) -> tuple[int, str, str]:
        return self.messages[-1]


def outputs(path: Path) -> list[str]:
    return [v.name for v in read_model_description(str(path)).modelVariables
            if v.causality == "output"]


def fmpy_run(path: Path, t_end: float, h: float) -> dict[str, np.ndarray]:
    r = simulate_fmu(str(path), stop_time=t_end, output_interval=h)
    return {n: np.asarray(r[n], dtype=float) for n in r.dtype.names}


def ecospy_run(path: Path, t_end: float, h: float) -> dict[str, np.ndarray]:
    from ecospy.EcosSimulation import EcosSimulation
    from ecospy.EcosSimulationStructure import EcosSimulationStructure

    structure = EcosSimulationStructure()
    structure.add_model("a", str(path))
    simulation = EcosSimulation(structure=structure, step_size=h)
    simulation.init()
    names, rows = outputs(path), []
    for k in range(round(t_end / h) + 1):
        if k:
            simulation.step(1)
        rows.append([simulation.get_time()] + [simulation.get_real(f"a::{n}") for n in names])
    simulation.terminate()
    simulation.free()
    return dict(zip(["time"] + names, np.array(rows).T))


def largest_difference(a: dict, b: dict) -> float:
    """Largest difference relative to max(1, |value|) over the common columns."""
    names = [n for n in a if n in b]
    assert len(names) > 1 and len(a["time"]) == len(b["time"])
    return max(float(np.max(np.abs(a[n] - b[n]) / np.maximum(1.0, np.abs(a[n]))))
               for n in names)
