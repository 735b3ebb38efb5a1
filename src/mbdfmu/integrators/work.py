"""The work of a run: its counters, and the bounds on one ``advance`` call."""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, fields

from ..errors import WorkLimitError
from ..plain import Plain


@dataclass
class Counters(Plain):
    """Work done, as scipy counts it: steps, rejections, q'' evaluations, projections,
    Newton iterations, iteration-matrix evaluations and factorisations (implicit methods)."""

    nsteps: int = 0
    nrejected: int = 0
    naccel: int = 0
    nprojections: int = 0
    nnewton: int = 0
    njev: int = 0
    nlu: int = 0
    # the run's estimated error (m or rad): fixed-step methods' step-doubling estimate
    # (stated_accuracy.py); 0 where the step control keeps the error instead
    error_estimate: float = 0.0
    nswitches: int = 0             # auto: changes of method (integrators/auto.py)


Counters.plain_fields = tuple(f.name for f in fields(Counters))
Counters.flat_fields = True


class WorkLimit:
    """Bounds on the work of one ``advance`` call: at most ``max_steps`` internal steps
    (accepted and rejected) and ``max_cpu`` CPU seconds of the calling thread, checked
    after every internal step (a fixed-step run longer than ``max_steps`` is refused before
    its first step). None: no bound. ``names`` are the settings' names in messages (an
    FMU's parameters). Exceeding either raises ``WorkLimitError`` (a ``SolverError``);
    ``Simulation.advance`` then restores the state it started from."""

    def __init__(self, max_steps: int | None = None, max_cpu: float | None = None,
                 names: tuple[str, str] = ("max_steps", "max_cpu")):
        self.max_steps, self.max_cpu, self.names = max_steps, max_cpu, names
        self.first, self.deadline = 0, math.inf

    def start(self, stats: "Counters") -> None:
        self.first = stats.nsteps + stats.nrejected
        self.deadline = time.thread_time() + self.max_cpu if self.max_cpu else math.inf

    def check_planned(self, steps: int, h: float, t: float, t_target: float) -> None:
        if self.max_steps is not None and steps > self.max_steps:
            count = steps if steps < 10 ** 9 else f"{float(steps):.3g}"
            raise WorkLimitError(f"reaching t = {t_target:.9g} s takes {count} steps of "
                              f"{h:.3g} s, more than {self.names[0]} = {self.max_steps}", t)

    def check(self, stats: "Counters", t: float, t_target: float) -> None:
        used = stats.nsteps + stats.nrejected - self.first
        if self.max_steps is not None and used >= self.max_steps and t < t_target:
            raise WorkLimitError(f"{used} internal steps did not reach t = {t_target:.9g} s "
                              f"({self.names[0]} = {self.max_steps})", t)
        if time.thread_time() > self.deadline:
            raise WorkLimitError(f"{self.max_cpu:g} CPU seconds did not reach t = "
                              f"{t_target:.9g} s ({self.names[1]} = {self.max_cpu:g})", t)
