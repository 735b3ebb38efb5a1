"""Co-simulation masters on fmpy's ``FMU2Slave`` / ``FMU3Slave`` (``member.py``): Jacobi and Gauss-Seidel with a fixed
communication step, and an error-controlled variable step that rolls back.

One macro step from t to t + h:

* **Jacobi**: every instance gets the outputs of time t on its inputs, then all step.
  Inputs hold over the step (zero-order hold): the coupling error is first order in h.
* **Gauss-Seidel**: the instances step one after the other in the scenario's ``order``;
  each gets the newest outputs (those of t + h from instances already stepped, of t from
  the others). Still first order, usually with a smaller constant and a larger stable step.

**Variable step** (``CosimSettings(variable_step=True)``, ``variable_step.py``): each
macro step (of either algorithm) is checked
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

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..result import Result
from .scenario import Scenario, check_variables
from .settings import CosimError, CosimSettings, Refused

from .extrapolation import Extrapolation
from .implicit import Implicit
from .member import ERROR, STATUS, WARNING, Member


# ----------------------------------------------------------------------------- the system

class CoupledSystem:
    """The scenario's instances and connections, driven step by step by an algorithm."""

    def __init__(self, scenario: Scenario, fmus: dict[str, Path], record: list[str] | None = None,
                 extrapolation: int = 0):
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
        self.extrapolation = Extrapolation(self, extrapolation)
        self.start: dict[str, float] = {}   # connected outputs at the macro step's start
        self.counters = {"steps": 0, "rejected": 0, "doStep": 0, "rollbacks": 0, "jumps": 0,
                         "forced": 0}

    # ------------------------------------------------------------------ exchange

    def read_outputs(self, member: str, t: float, derivatives: bool = True) -> None:
        """The connected outputs of ``member`` at time ``t`` (and their derivatives when
        inputs are extrapolated)."""
        names = self.outputs_of[member]
        for n, v in zip(names, self.members[member].get(names)):
            self.out[f"{member}.{n}"] = v
        if derivatives:
            self.extrapolation.read(member, names, t)

    def begin_step(self) -> None:
        """Remember the connected outputs (and derivatives) where the macro step starts."""
        self.start = dict(self.out)
        self.extrapolation.begin_step()

    def out_at_start(self, source: str) -> float:
        return self.start.get(source, self.out[source])

    def write_inputs(self, member: str, h: float | None = None, zero: bool = False,
                     new: dict | None = None) -> None:
        """Set ``member``'s connected inputs for a step ``h``: the upstream outputs at the
        step's start (0.0 with ``zero``), held or, with extrapolation, with derivatives
        (``new``: the values at t + h of sources already stepped, Gauss-Seidel)."""
        pairs = self.inputs_of[member]
        if self.extrapolation.order and h is not None and not zero:
            values = [self.out_at_start(src) for _, src in pairs]
        else:
            values = [0.0 if zero else (new or {}).get(src, self.out[src]) for _, src in pairs]
        self.members[member].set([dst for dst, _ in pairs], values)
        for (dst, _), v in zip(pairs, values):
            self.used[f"{member}.{dst}"] = v
        if h is not None and not zero:
            self.extrapolation.set_inputs(member, pairs, h, new)

    def step_member(self, member: str, t: float, h: float, derivatives: bool = True) -> None:
        """doStep(t, h) on ``member``, then read its connected outputs at t + h."""
        self.counters["doStep"] += 1
        status = self.members[member].do_step(t, h)
        if status > WARNING:
            raise Refused(member, status, self.members[member].reason(), STATUS.get(status, status))
        self.read_outputs(member, t + h, derivatives)

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
            m.enter_initialization(t0, t_end)
            params = self.scenario.instance_parameters(m.name)
            m.set(list(params), list(params.values()))
        for _ in range(len(members) if start == "exchange" else 0):
            for m in self.members:
                self.read_outputs(m, t0, derivatives=False)
            for m in self.members:
                self.write_inputs(m)
        for m in members:
            m.exit_initialization()
            failed = [msg for status, _, msg in m.messages if status >= ERROR]
            if failed:
                raise CosimError(f"initialization failed: {failed[-1]}", t0, m.name)
        for m in self.members:
            self.read_outputs(m, t0)
        if start == "zero":
            for m in self.members:
                self.write_inputs(m, zero=True)
        else:
            self.extrapolation.settle(t0)
        self.update_nominal()

    def sample(self) -> list[float]:
        """The recorded variables now, in ``self.record`` order."""
        values = {}
        for m, names in self.record_of.items():
            values.update(zip((f"{m}.{n}" for n in names), self.members[m].get(names)))
        return [values[r] for r in self.record]

    def get_states(self):
        return {m: member.get_state() for m, member in self.members.items()}, \
            dict(self.out), dict(self.used), self.extrapolation.snapshot()

    def set_states(self, saved) -> None:
        states, out, used, extrapolation = saved
        for m, member in self.members.items():
            member.set_state(states[m])
        self.out, self.used = dict(out), dict(used)
        self.extrapolation.restore(extrapolation)

    def free_states(self, saved) -> None:
        for m, member in self.members.items():
            member.free_state(saved[0][m])

    def close(self) -> None:
        for m in self.members.values():
            m.close()


# ----------------------------------------------------------------------------- algorithms

class Jacobi:
    """All instances step in parallel on the outputs of time t."""

    name = "jacobi"

    def __init__(self, scenario: Scenario):
        self.scenario = scenario

    def step(self, system: CoupledSystem, t: float, h: float, first: bool = False) -> None:
        system.begin_step()
        if not first:  # the first step of a "zero" start keeps the zeros set at initialization
            for m in system.members:
                system.write_inputs(m, h)
        # inputs are all written before any member steps, so reading each member's outputs
        # right after its step is still Jacobi
        for m in system.members:
            system.step_member(m, t, h)


class GaussSeidel:
    """Instances step one after the other (``scenario.order``), each on the newest outputs."""

    name = "gauss-seidel"

    def __init__(self, scenario: Scenario):
        self.order = list(scenario.order)

    def step(self, system: CoupledSystem, t: float, h: float, first: bool = False) -> None:
        system.begin_step()
        for k, m in enumerate(self.order):
            if not first:
                stepped = set(self.order[:k])
                system.write_inputs(m, h, new={s: v for s, v in system.out.items()
                                               if s.split(".", 1)[0] in stepped})
            else:  # the first step of a "zero" start: upstream outputs are new, others zero
                pairs = system.inputs_of[m]
                fresh = [(dst, src) for dst, src in pairs
                         if src.split(".", 1)[0] in self.order[:self.order.index(m)]]
                system.members[m].set([d for d, _ in fresh], [system.out[s] for _, s in fresh])
                for d, s in fresh:
                    system.used[f"{m}.{d}"] = system.out[s]
            system.step_member(m, t, h)


ALGORITHMS = {"jacobi": Jacobi, "gauss-seidel": GaussSeidel, "implicit": Implicit}


def algorithm_class(name: str):
    try:
        return ALGORITHMS[name]
    except KeyError:
        raise CosimError(f'unknown algorithm "{name}"; known: {", ".join(ALGORITHMS)}') from None


# ----------------------------------------------------------------------------- runs

@dataclass
class RunRecord:
    """What a run collects: communication points, recorded rows and the steps taken."""

    times: list = field(default_factory=list)
    rows: list = field(default_factory=list)
    steps: list = field(default_factory=list)


def run_fmpy(scenario: Scenario, fmus: dict[str, Path],
             settings: CosimSettings = CosimSettings(),
             record: list[str] | None = None) -> Result:
    """Run a scenario with the fmpy master; every recorded variable at every communication
    point (t0 included) as a ``Result`` (``stats``: steps, rejections, doStep calls)."""
    from .variable_step import run_variable_step   # the fixed-step runs do not need it

    name = settings.algorithm_for(scenario)
    if settings.jacobian != "differences" and name != "implicit":
        raise CosimError(f'the interface Jacobian is the implicit coupling\'s; {scenario.name} '
                         f'runs "{name}" (--algorithm implicit)')
    algorithm = (Implicit(scenario, settings.jacobian) if name == "implicit"
                 else algorithm_class(name)(scenario))
    h = float(settings.step or scenario.step)
    t_end = float(settings.t_end or scenario.t_end)
    # (the implicit master's first guess extrapolates with the outputs' first derivatives)
    order = settings.extrapolation or (1 if algorithm.name == "implicit" else 0)
    system = CoupledSystem(scenario, fmus, record, extrapolation=order)
    out = RunRecord()
    try:
        system.initialize(0.0, t_end, settings.start)
        out.times.append(0.0)
        out.rows.append(system.sample())
        if settings.variable_step:
            run_variable_step(system, algorithm, scenario, settings, h, t_end, out)
        else:
            _fixed_step(system, algorithm, h, t_end, out, zero_start=settings.start == "zero")
    finally:
        system.close()
    stats = dict(system.counters)
    if out.steps:
        stats.update(h_min=float(min(out.steps)), h_max=float(max(out.steps)))
    master = f"fmpy {algorithm.name}" + (" variable-step" if settings.variable_step else "") \
        + (f" extrapolation {settings.extrapolation}" if settings.extrapolation else "") \
        + (f" {settings.jacobian} jacobian" if algorithm.name == "implicit" else "")
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
        except Refused as exc:
            raise CosimError(str(exc), t, exc.member) from None
        system.counters["steps"] += 1
        out.times.append((k + 1) * h)
        out.rows.append(system.sample())
        out.steps.append(h)
