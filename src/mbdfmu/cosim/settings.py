"""How a co-simulation runs (``CosimSettings``, checked once) and how it fails (``CosimError``)."""

from __future__ import annotations

import math
from dataclasses import dataclass

from ..errors import MbdfmuError, SettingError

MASTERS = ("fmpy", "ssp", "libcosim", "ecos")
ALGORITHMS = ("jacobi", "gauss-seidel", "implicit", "ecco")
STARTS = ("exchange", "zero")
JACOBIANS = ("differences", "directional")


class CosimError(MbdfmuError):
    """A co-simulation that cannot go on: an instance refused a step or the master gave up.

    ``t`` is the communication point, ``instance`` the instance that failed (if any).
    """

    def __init__(self, message: str, t: float | None = None, instance: str | None = None):
        self.t, self.instance = t, instance
        prefix = f"t = {t:.9g} s: " if t is not None else ""
        super().__init__(prefix + (f"{instance}: " if instance else "") + message)


class Refused(Exception):
    """An instance refused a step (fmi2Discard or worse): status and logged reason."""

    def __init__(self, member: str, status: int, reason: str, status_name: str):
        super().__init__(f"doStep returned {status_name}: {reason}")
        self.member, self.status, self.reason = member, status, reason


@dataclass(frozen=True)
class CosimSettings:
    """A run of a scenario (None: the scenario's own value).

    ``master``: fmpy, ssp (fmpy's SSP runner), libcosim or ecos (Ecos, from the SSP); ``algorithm``: jacobi or
    gauss-seidel (default: the scenario's for fmpy, jacobi for the others, which have only
    that); ``step`` and ``t_end`` in s; ``variable_step`` (fmpy master only) with its
    ``rtol``, ``atol``, ``h_min``, ``h_max``; ``start``: connected inputs start at the
    upstream outputs ("exchange", as libcosim does) or at 0.0 ("zero", as fmpy's SSP
    runner does); ``extrapolation`` (fmpy master): the order of the polynomial each input
    follows over a step, 0 (zero-order hold), 1 or 2 (``extrapolation.py``); ``jacobian``
    (implicit coupling): the interface Jacobian from finite differences of whole steps
    ("differences") or from the FMUs' directional derivatives ("directional");
    ``fmi_version``: the FMUs built and run, FMI 2.0 or (fmpy master) FMI 3.0.
    """

    master: str = "fmpy"
    algorithm: str | None = None
    step: float | None = None
    t_end: float | None = None
    variable_step: bool = False
    rtol: float | None = None
    atol: float | None = None
    h_min: float | None = None
    h_max: float | None = None
    start: str = "exchange"
    extrapolation: int = 0
    jacobian: str = "differences"
    fmi_version: int = 2

    def __post_init__(self):
        if self.fmi_version not in (2, 3) or isinstance(self.fmi_version, bool):
            raise SettingError("fmi_version", f"fmi_version must be 2 or 3, got {self.fmi_version!r}")
        if self.fmi_version == 3 and self.master != "fmpy":
            raise SettingError("fmi_version", "FMI 3.0 FMUs run with the fmpy master (--master "
                               f"fmpy); {self.master} runs FMI 2.0 here")
        if self.extrapolation not in (0, 1, 2) or isinstance(self.extrapolation, bool):
            raise SettingError("extrapolation", "extrapolation must be 0 (zero-order hold), 1 "
                               f"or 2 (the inputs' polynomial order), got {self.extrapolation!r}")
        if self.extrapolation and self.master != "fmpy":
            raise SettingError("extrapolation", "input extrapolation is the fmpy master's "
                               "(--master fmpy)")
        for name, value, choices in (("master", self.master, MASTERS),
                                     ("algorithm", self.algorithm, ALGORITHMS),
                                     ("start", self.start, STARTS),
                                     ("jacobian", self.jacobian, JACOBIANS)):
            if value is not None and value not in choices:
                raise SettingError(name, f'{name} "{value}" is not one of {", ".join(choices)}')
        for name in ("step", "t_end", "rtol", "atol", "h_min", "h_max"):
            value = getattr(self, name)
            if value is not None and (isinstance(value, bool) or not isinstance(value, (int, float))
                                      or not (math.isfinite(value) and value > 0)):
                raise SettingError(name, f"{name} must be positive and finite, got {value!r}")
        if self.algorithm == "implicit" and (self.master != "fmpy" or self.variable_step):
            raise SettingError("algorithm", 'the implicit coupling is the fmpy master\'s, '
                               "with a fixed step (--master fmpy, no --variable-step)")
        if self.jacobian != "differences" and self.algorithm not in (None, "implicit"):
            raise SettingError("jacobian", "the interface Jacobian is the implicit "
                               "coupling's (--algorithm implicit)")
        if self.algorithm == "ecco" and self.master != "libcosim":
            raise SettingError("algorithm", "ECCO is libcosim's algorithm (--master libcosim)")
        if self.variable_step and self.master != "fmpy":
            raise SettingError("variable_step", "the variable-step master is the fmpy "
                               "master's (--master fmpy)")
        if self.master in ("libcosim", "ecos") and self.start != "exchange":
            raise SettingError("start", f'{self.master} always starts by passing outputs to '
                               'inputs ("exchange")')

    def algorithm_for(self, scenario) -> str:
        """The algorithm that runs: as asked, else the scenario's (fmpy) or jacobi."""
        return self.algorithm or (scenario.algorithm if self.master == "fmpy" else "jacobi")


def fixed_steps(scenario, step: float | None, t_end: float | None, algorithm: str | None,
                master: str) -> tuple[float, float, int]:
    """(h, t_end, steps) of a Jacobi master's fixed-step run; ``t_end`` a whole number of
    steps."""
    algorithm = algorithm or "jacobi"
    if algorithm != "jacobi":
        raise CosimError(f'{master} is a Jacobi master; "{algorithm}" is available with the '
                         "fmpy master")
    h = float(step or scenario.step)
    t_end = float(t_end or scenario.t_end)
    n = round(t_end / h)
    if n < 1 or abs(n * h - t_end) > 1e-9 * t_end:
        raise CosimError(f"t_end {t_end:g} s is not a whole number of steps {h:g} s")
    return h, t_end, n
