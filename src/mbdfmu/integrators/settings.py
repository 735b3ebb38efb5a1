"""``SolverSettings``: the one place where a run's solver settings are defaulted and checked.

Every entry point builds one (the scene's ``[simulation]`` table, ``simulate()``,
``Simulation``, the CLI's flags, the FMU's ``solver.*`` parameters), before any work, the
way scipy's ``validate_tol`` and ``validate_max_step`` run before a solver starts. A bad
value raises ``SettingError`` (a ``ValueError``) naming the setting as the caller spelled it
(``--step``, ``rtol``, ``solver.rtol``) and where it came from.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from typing import Any

from ..errors import SettingError, suggest
from .base import Integrator
from .registry import METHOD_NAMES, method_class

DEFAULT_METHOD = "auto"
DEFAULT_RTOL = 1e-6
DEFAULT_ATOL = 1e-8
# atol, when not given, is at most this times rtol: a tighter rtol than the default is not
# capped by the default atol (positions of metre-sized mechanisms are O(1)).
ATOL_PER_RTOL = 1e-2
# The accuracy a fixed-step method states and keeps (or stops: stated_accuracy.py) when
# rtol and atol are not given: loose, since its step is the user's statement of the
# accuracy wanted; the checks then catch gross errors only.
FIXED_STEP_RTOL = 1e-3
FIXED_STEP_ATOL = 1e-5
# Output points of a run when neither the call nor the scene gives an output interval.
DEFAULT_OUTPUT_POINTS = 500
FIELDS = ("method", "step", "rtol", "atol", "options", "output_interval")


def adaptive_with(cls, options: dict) -> bool:
    """Whether method ``cls`` controls its step with these options (its own settings):
    the adaptive methods always, genalpha and ali3p with step_control = "adaptive"."""
    if "step_control" in cls.option_names:
        return options.get("step_control", "fixed") == "adaptive"
    return cls.adaptive


def _positive(value: Any, name: str, where: str, unit: str = "") -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise SettingError(name, f"{name} must be a number, got {value!r}", where)
    value = float(value)
    if not (math.isfinite(value) and value > 0.0):
        raise SettingError(name, f"{name} must be positive and finite{unit}, got {value!r}",
                           where)
    return value


@dataclass(frozen=True)
class SolverSettings:
    """How a run integrates: ``method`` (a name of ``METHOD_NAMES`` or an ``Integrator``
    class), ``step`` (s; the fixed step, or the largest step of adaptive methods; None:
    the method's default), ``rtol``, ``atol`` (adaptive methods' tolerances, fixed-step
    methods' stated accuracy; see ``tolerances_for``), ``options`` (the method's own
    settings) and ``output_interval`` (s; None: the run's length over
    ``DEFAULT_OUTPUT_POINTS``). ``given`` lists the fields set explicitly."""

    method: Any = DEFAULT_METHOD
    step: float | None = None
    rtol: float = DEFAULT_RTOL
    atol: float = DEFAULT_ATOL
    options: dict = field(default_factory=dict)
    output_interval: float | None = None
    given: frozenset = frozenset()

    def updated(self, where: str = "", names: dict[str, str] | None = None,
                **values) -> SolverSettings:
        """A copy with the given values (None: keep this one's), each checked; ``names``
        maps a field to the name the caller uses for it (a CLI flag, an FMU parameter)."""
        names = names or {}
        changes = {}
        for key, value in values.items():
            if key not in FIELDS:
                raise SettingError(key, f"unknown solver setting {key!r}{suggest(key, FIELDS)}",
                                   where)
            if value is not None:
                changes[key] = _check(key, value, names.get(key, key), where)
        if not changes:
            return self            # nothing new to check (frozen: the same settings)
        out = replace(self, given=self.given | frozenset(changes), **changes)
        if "method" in changes or "options" in changes:
            out.method_class.check_options(out.options, names.get("options", "options"), where)
        return out

    @property
    def method_class(self) -> type[Integrator]:
        return method_class(self.method)

    @property
    def method_name(self) -> str:
        return self.method if isinstance(self.method, str) else self.method.name

    def step_for(self, cls, options: dict | None = None) -> float:
        """The step a method runs with (with ``options``, default this run's): the given
        one, else the method's default (fixed step), or no limit (adaptive: ``step`` is the
        largest step)."""
        if self.step is not None:
            return self.step
        adaptive = adaptive_with(cls, self.options if options is None else options)
        return math.inf if adaptive else cls.default_step

    def tolerances_for(self, cls, chosen: bool = False,
                       options: dict | None = None) -> tuple[float, float]:
        """(rtol, atol) a method runs with. Adaptive methods, and any method ``auto`` chose
        (the run was asked for rtol, whatever ran it): rtol, and atol as given, else
        min(DEFAULT_ATOL, ATOL_PER_RTOL rtol). Fixed-step methods the user named (their
        stated accuracy): the values given, else FIXED_STEP_RTOL and min(FIXED_STEP_ATOL,
        ATOL_PER_RTOL rtol)."""
        given = self.given
        if adaptive_with(cls, self.options if options is None else options) or chosen:
            rtol, atol = self.rtol, DEFAULT_ATOL
        else:
            rtol = self.rtol if "rtol" in given else FIXED_STEP_RTOL
            atol = FIXED_STEP_ATOL
        if "atol" in given:
            return rtol, self.atol
        return rtol, min(atol, ATOL_PER_RTOL * rtol)

    def output_interval_for(self, t_end: float) -> float:
        return self.output_interval or t_end / DEFAULT_OUTPUT_POINTS


def _check(key: str, value: Any, name: str, where: str):
    if key == "method":
        if isinstance(value, type) and issubclass(value, Integrator):
            return value
        if not isinstance(value, str) or value not in METHOD_NAMES:
            hint = suggest(value, METHOD_NAMES) if isinstance(value, str) else ""
            raise SettingError(name, f'{name} "{value}" is not a method{hint}; methods: '
                               f"{', '.join(METHOD_NAMES)}", where)
        return value
    if key == "options":
        if not isinstance(value, dict):
            raise SettingError(name, f"{name} must be a table of the method's settings, "
                               f"got {value!r}", where)
        return dict(value)
    if key == "rtol":
        value = _positive(value, name, where)
        if value >= 1.0:
            raise SettingError(name, f"{name} must be below 1, got {value!r}", where)
        return value
    return _positive(value, name, where, " (s)" if key != "atol" else "")


def settings_from_scene(scene) -> SolverSettings:
    """The scene's ``[simulation]`` values as checked ``SolverSettings``."""
    s = scene.simulation
    return SolverSettings().updated(
        f"{scene.source}: simulation", method=s.method, step=s.step, rtol=s.rtol, atol=s.atol,
        options=s.options or None, output_interval=s.output_interval)
