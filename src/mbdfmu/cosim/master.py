"""Co-simulation masters on fmpy's ``FMU2Slave``: Jacobi and Gauss-Seidel with a fixed
communication step, and an error-controlled variable step that rolls back.

One macro step from t to t + h:

* **Jacobi**: every instance gets the outputs of time t on its inputs, then all step.
  Inputs hold over the step (zero-order hold): the coupling error is first order in h.
* **Gauss-Seidel**: the instances step one after the other in the scenario's ``order``;
  each gets the newest outputs (those of t + h from instances already stepped, of t from
  the others). Still first order, usually with a smaller constant and a larger stable step.

**Variable step** (``MasterSettings(variable_step=True)``): each macro step (of either
algorithm) is checked
after the fact. For every connection the input that was held over the step is compared
with the output it stood for at the end of the step (the zero-order hold's extrapolation
against the actual value); scaled by ``atol + rtol * nominal`` (``nominal``: the largest
magnitude of that output so far), the largest of these is the step's coupling error. Above
1, or when an instance discards the step, every instance is rolled back with
``fmi2SetFMUstate`` to the state saved at t and the step is retried smaller; otherwise it is
accepted and the next step is sized to aim at an error of ``SAFETY``. The estimate is
proportional to h, so the step follows ``h_new = h * SAFETY / err``. The scale of an
output is its ``nominal`` value (the scenario's ``[variable_step.nominal]``, like FMI's
nominal attribute), or its largest magnitude so far if that is larger: a signal that
starts at 0 would otherwise be held to ``atol``. A retry whose error
does not shrink with the step (less than the square root of the step ratio) has met a jump
of an output (a set point that steps, a switch): no step size removes it, so the step is
accepted and counted in ``stats["jumps"]``. A step cut below ``h_min`` is taken at
``h_min`` and accepted whatever its (finite) error (``stats["forced"]``), so a jump that the
steps approach without crossing it cannot stall the run; only an instance that refuses
even ``h_min`` ends it.

Start: after every instance's ``fmi2EnterInitializationMode`` the master sets the start
values, then passes outputs to inputs as many times as there are instances (as OSP
libcosim does; enough for any chain of direct feedthrough) and leaves initialization. With
``start="zero"`` it instead sets every connected input to 0.0 before the first step, which
is what fmpy's SSP runner does (its connectors start at 0.0), so the two can be compared
to rounding.
"""

from __future__ import annotations

import math
import shutil
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..errors import MbdfmuError
from ..result import Result
from .scenario import Scenario, check_variables

# Variable step: aim at this fraction of the allowed coupling error.
SAFETY = 0.8
# Largest growth of the step after an accepted step, smallest factor after a rejected one.
MAX_FACTOR = 2.0
MIN_FACTOR = 0.1
# Variable step: a step this much longer than planned may end the run.
LAST_STEP_STRETCH = 1.1
# Variable step: a retried (shorter) step whose error shrank less than the step ratio to
# this power has met a jump of an output (a set point, a switch), not a coupling error,
# which shrinks at least in proportion to the step.
JUMP_EXPONENT = 0.5
# Rejections in a row before the variable-step master gives up.
MAX_REJECTIONS_IN_A_ROW = 40
# fmpy raises FMICallException with these statuses.
OK, WARNING, DISCARD, ERROR, FATAL = 0, 1, 2, 3, 4
STATUS = {OK: "OK", WARNING: "warning", DISCARD: "discard", ERROR: "error", FATAL: "fatal"}


class CosimError(MbdfmuError):
    """A co-simulation that cannot go on: an instance refused a step or the master gave up.

    ``t`` is the communication point, ``instance`` the instance that failed (if any).
    """

    def __init__(self, message: str, t: float | None = None, instance: str | None = None):
        self.t, self.instance = t, instance
        prefix = f"t = {t:.9g} s: " if t is not None else ""
        super().__init__(prefix + (f"{instance}: " if instance else "") + message)


@dataclass(frozen=True)
class MasterSettings:
    """How the fmpy master runs a scenario (None: the scenario's own value)."""

    algorithm: str | None = None
    step: float | None = None
    t_end: float | None = None
    variable_step: bool = False
    rtol: float | None = None
    atol: float | None = None
    h_min: float | None = None
    h_max: float | None = None
    start: str = "exchange"          # or "zero": connected inputs start at 0.0 (fmpy's SSP runner)


# ----------------------------------------------------------------------------- one instance

_MESSAGES: dict[str, list] = {}


def _logger(env, instance, status, category, message):
    # pythonfmu passes the whole message as the format string: no variadic formatting needed
    # (fmpy's addLoggerProxy is process-wide and would take over other masters' loggers).
    name = instance.decode(errors="replace") if instance else ""
    _MESSAGES.setdefault(name, []).append(
        (status, (category or b"").decode(errors="replace"), message.decode(errors="replace")))


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


# ----------------------------------------------------------------------------- the system

class System:
    """The scenario's instances and connections, driven step by step by an algorithm."""

    def __init__(self, scenario: Scenario, fmus: dict[str, Path], record: list[str] | None = None):
        from fmpy import read_model_description

        descriptions = {i.name: read_model_description(str(fmus[i.name]))
                        for i in scenario.instances}
        check_variables(scenario, descriptions)
        self.scenario = scenario
        self.members: dict[str, Member] = {}
        try:
            for inst in scenario.instances:
                self.members[inst.name] = Member(inst.name, fmus[inst.name],
                                                 descriptions[inst.name])
        except Exception:
            self.close()
            raise
        self.connections = list(scenario.connections)
        # Inputs of each member and the outputs that feed them.
        self.inputs_of = {m: [(c.target_variable, c.source) for c in self.connections
                              if c.target_instance == m] for m in self.members}
        self.outputs_of = {m: list(dict.fromkeys(c.source_variable for c in self.connections
                                                 if c.source_instance == m)) for m in self.members}
        self.record = list(record if record is not None else scenario.recorded())
        self.record_of = {m: [r.split(".", 1)[1] for r in self.record if r.split(".", 1)[0] == m]
                          for m in self.members}
        self.units = {r: self.members[r.split(".", 1)[0]].variables[r.split(".", 1)[1]].unit
                      or "" for r in self.record}
        self.out: dict[str, float] = {}     # connected outputs, "instance.variable" -> value
        self.used: dict[str, float] = {}    # the value each input held over the last step
        self.nominal: dict[str, float] = {}  # largest magnitude of each connected output so far
        self.counters = {"steps": 0, "rejected": 0, "doStep": 0, "rollbacks": 0, "jumps": 0,
                         "forced": 0}

    # ------------------------------------------------------------------ exchange

    def read_outputs(self, member: str) -> None:
        names = self.outputs_of[member]
        for n, v in zip(names, self.members[member].get(names)):
            self.out[f"{member}.{n}"] = v

    def write_inputs(self, member: str, zero: bool = False) -> None:
        pairs = self.inputs_of[member]
        values = [0.0 if zero else self.out[src] for _, src in pairs]
        self.members[member].set([dst for dst, _ in pairs], values)
        for (dst, _), v in zip(pairs, values):
            self.used[f"{member}.{dst}"] = v

    def step_member(self, member: str, t: float, h: float) -> None:
        self.counters["doStep"] += 1
        status = self.members[member].do_step(t, h)
        if status > WARNING:
            raise _Refused(member, status, self.members[member].reason())
        self.read_outputs(member)

    def coupling_error(self, rtol: float, atol: float, nominal: dict | None = None) -> float:
        """Largest scaled difference between a held input and the output it stood for;
        the scale of an output is the largest of its ``nominal`` value, its largest
        magnitude so far and its magnitude now."""
        err = 0.0
        nominal = nominal or {}
        for c in self.connections:
            y = self.out[c.source]
            scale = atol + rtol * max(nominal.get(c.source, 0.0),
                                      self.nominal.get(c.source, 0.0), abs(y))
            err = max(err, abs(y - self.used[c.target]) / scale)
        return err

    def update_nominal(self) -> None:
        for name, v in self.out.items():
            self.nominal[name] = max(self.nominal.get(name, 0.0), abs(v))

    # ------------------------------------------------------------------ life cycle

    def initialize(self, t0: float, t_end: float, start: str) -> None:
        members = list(self.members.values())
        for m in members:
            m.fmu.setupExperiment(startTime=t0, stopTime=t_end)
            m.fmu.enterInitializationMode()
            params = self.scenario.instance_parameters(m.name)
            m.set(list(params), list(params.values()))
        for _ in range(len(members) if start == "exchange" else 0):
            for m in self.members:
                self.read_outputs(m)
            for m in self.members:
                self.write_inputs(m)
        for m in members:
            m.fmu.exitInitializationMode()
            failed = [msg for status, _, msg in m.messages if status >= ERROR]
            if failed:
                raise CosimError(f"initialization failed: {failed[-1]}", t0, m.name)
        for m in self.members:
            self.read_outputs(m)
        if start == "zero":
            for m in self.members:
                self.write_inputs(m, zero=True)
        self.update_nominal()

    def sample(self) -> list[float]:
        """The recorded variables now, in ``self.record`` order."""
        values = {}
        for m, names in self.record_of.items():
            values.update(zip((f"{m}.{n}" for n in names), self.members[m].get(names)))
        return [values[r] for r in self.record]

    def get_states(self):
        return {m: member.fmu.getFMUstate() for m, member in self.members.items()}, \
            dict(self.out), dict(self.used)

    def set_states(self, saved) -> None:
        states, out, used = saved
        for m, member in self.members.items():
            member.fmu.setFMUstate(states[m])
        self.out, self.used = dict(out), dict(used)

    def free_states(self, saved) -> None:
        for m, member in self.members.items():
            member.fmu.freeFMUstate(saved[0][m])

    def close(self) -> None:
        for m in self.members.values():
            m.close()


class _Refused(Exception):
    def __init__(self, member: str, status: int, reason: str):
        super().__init__(f"doStep returned {STATUS.get(status, status)}: {reason}")
        self.member, self.status, self.reason = member, status, reason


# ----------------------------------------------------------------------------- algorithms

class Jacobi:
    """All instances step in parallel on the outputs of time t."""

    name = "jacobi"

    def __init__(self, scenario: Scenario):
        self.scenario = scenario

    def step(self, system: System, t: float, h: float, first: bool = False) -> None:
        if not first:  # the first step of a "zero" start keeps the zeros set at initialization
            for m in system.members:
                system.write_inputs(m)
        for m in system.members:
            system.counters["doStep"] += 1
            status = system.members[m].do_step(t, h)
            if status > WARNING:
                raise _Refused(m, status, system.members[m].reason())
        for m in system.members:
            system.read_outputs(m)


class GaussSeidel:
    """Instances step one after the other (``scenario.order``), each on the newest outputs."""

    name = "gauss-seidel"

    def __init__(self, scenario: Scenario):
        self.order = list(scenario.order)

    def step(self, system: System, t: float, h: float, first: bool = False) -> None:
        for m in self.order:
            if not first:
                system.write_inputs(m)
            else:  # the first step of a "zero" start: upstream outputs are new, others zero
                pairs = system.inputs_of[m]
                fresh = [(dst, src) for dst, src in pairs
                         if src.split(".", 1)[0] in self.order[:self.order.index(m)]]
                system.members[m].set([d for d, _ in fresh], [system.out[s] for _, s in fresh])
                for d, s in fresh:
                    system.used[f"{m}.{d}"] = system.out[s]
            system.step_member(m, t, h)


ALGORITHMS = {"jacobi": Jacobi, "gauss-seidel": GaussSeidel}


def algorithm_class(name: str):
    try:
        return ALGORITHMS[name]
    except KeyError:
        raise CosimError(f'unknown algorithm "{name}"; known: {", ".join(ALGORITHMS)}') from None


# ----------------------------------------------------------------------------- runs

@dataclass
class _Run:
    times: list = field(default_factory=list)
    rows: list = field(default_factory=list)
    steps: list = field(default_factory=list)


def run(scenario: Scenario, fmus: dict[str, Path], settings: MasterSettings = MasterSettings(),
        record: list[str] | None = None) -> Result:
    """Run a scenario with the fmpy master; every recorded variable at every communication
    point (t0 included) as a ``Result`` (``stats``: steps, rejections, doStep calls)."""
    algorithm = algorithm_class(settings.algorithm or scenario.algorithm)(scenario)
    h = float(settings.step or scenario.step)
    t_end = float(settings.t_end or scenario.t_end)
    if settings.start not in ("exchange", "zero"):
        raise CosimError(f'start "{settings.start}" is not "exchange" or "zero"')
    if not (h > 0 and t_end > 0 and math.isfinite(h) and math.isfinite(t_end)):
        raise CosimError(f"step {h!r} and t_end {t_end!r} must be positive")
    system = System(scenario, fmus, record)
    out = _Run()
    try:
        system.initialize(0.0, t_end, settings.start)
        out.times.append(0.0)
        out.rows.append(system.sample())
        if settings.variable_step:
            _variable_step(system, algorithm, scenario, settings, h, t_end, out)
        else:
            _fixed_step(system, algorithm, h, t_end, out, zero_start=settings.start == "zero")
    finally:
        system.close()
    stats = dict(system.counters)
    if out.steps:
        stats.update(h_min=float(min(out.steps)), h_max=float(max(out.steps)))
    master = f"fmpy {algorithm.name}" + (" variable-step" if settings.variable_step else "")
    return Result(time=np.array(out.times), names=list(system.record),
                  values=np.array(out.rows, dtype=float).reshape(len(out.times), -1),
                  units=system.units, method=master, stats=stats)


def _fixed_step(system, algorithm, h, t_end, out, zero_start):
    n = max(1, round(t_end / h))
    if abs(n * h - t_end) > 1e-9 * t_end:
        raise CosimError(f"t_end {t_end:g} is not a whole number of steps {h:g}")
    for k in range(n):
        t = k * h  # times are k h, never accumulated
        try:
            algorithm.step(system, t, h, first=zero_start and k == 0)
        except _Refused as exc:
            raise CosimError(str(exc), t, exc.member) from None
        system.counters["steps"] += 1
        out.times.append((k + 1) * h)
        out.rows.append(system.sample())
        out.steps.append(h)


def _variable_step(system, algorithm, scenario, settings, h, t_end, out):
    vs = scenario.variable_step
    rtol = settings.rtol or vs.rtol
    atol = settings.atol or vs.atol
    h_min = settings.h_min or vs.h_min
    h_max = settings.h_max or vs.h_max or 10 * h
    h = min(vs.h_initial or h, h_max)
    t, rejections, rejected_err, rejected_step = 0.0, 0, math.inf, math.inf
    while t < t_end * (1 - 1e-12):
        # A step that would leave less than a tenth of itself before t_end is stretched to
        # t_end (no sliver of a last step).
        last = t + LAST_STEP_STRETCH * h >= t_end * (1 - 1e-12)
        t_next = t_end if last else t + h
        step = t_next - t  # the step is a difference of times: a replay of the times repeats it
        saved = system.get_states()
        try:
            try:
                algorithm.step(system, t, step, first=settings.start == "zero" and t == 0.0)
                err = system.coupling_error(rtol, atol, vs.nominal)
                reason = f"coupling error {err:.3g} > 1"
            except _Refused as exc:
                err, reason = math.inf, str(exc)
            # An error that does not shrink with the step is a jump of an output (a set
            # point, a switch), not a coupling error: accept the step and go on.
            jump = (math.isfinite(err) and rejections > 0
                    and err >= (step / rejected_step) ** JUMP_EXPONENT * rejected_err)
            forced = math.isfinite(err) and step <= h_min * (1 + 1e-9)
            if not err <= 1.0 and not jump and not forced:
                rejected_err, rejected_step = err, step
                system.set_states(saved)
                system.counters["rejected"] += 1
                system.counters["rollbacks"] += 1
                rejections += 1
                factor = MIN_FACTOR if not math.isfinite(err) else max(MIN_FACTOR, SAFETY / err)
                h = step * factor
                if h < h_min:
                    if step <= h_min * (1 + 1e-9) or rejections > MAX_REJECTIONS_IN_A_ROW:
                        raise CosimError(f"an instance refuses even the smallest step "
                                         f"{h_min:g} s (h_min); last: {reason}", t)
                    h = h_min  # the next try is accepted whatever its error (if finite)
                continue
        finally:
            system.free_states(saved)
        if jump or (forced and err > 1.0):
            system.counters["jumps" if jump else "forced"] += 1
            err = 1.0
        rejections, rejected_err, rejected_step = 0, math.inf, math.inf
        t = t_next
        system.counters["steps"] += 1
        system.update_nominal()
        out.times.append(t)
        out.rows.append(system.sample())
        out.steps.append(step)
        h = min(h_max, step * (MAX_FACTOR if err == 0 else min(MAX_FACTOR, SAFETY / err)))
