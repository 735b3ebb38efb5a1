"""The registry of methods: each name and its class, and ``auto``'s stand-in."""

from __future__ import annotations

from ..errors import SettingError
from .ali3p import ALI3P
from .base import Integrator
from .baumgarte import Baumgarte
from .genalpha import GeneralizedAlpha
from .minimal import MinimalCoordinates
from .projected_rk import DOP853P, RK45P
from .rk4p import RK4P
from .taylor import Taylor

METHODS: dict[str, type[Integrator]] = {
    cls.name: cls for cls in (DOP853P, RK45P, RK4P, Taylor, Baumgarte, GeneralizedAlpha, ALI3P,
                                MinimalCoordinates)}
AUTO = "auto"
METHOD_NAMES = (AUTO, *METHODS)
SUMMARIES = {AUTO: "picks per scene: rk4p without degrees of freedom, ali3p for "
                   "redundant/singular constraints, genalpha for stiff springs, else dop853p; "
                   "says why"} | {name: cls.summary for name, cls in METHODS.items()}


class Auto(Integrator):
    """Stands for ``auto`` where a class is expected: it has no options of its own."""

    name = AUTO
    summary = SUMMARIES[AUTO]


def method_class(method) -> type[Integrator]:
    """The class of a method given by name or as a class (``Auto`` for "auto")."""
    if isinstance(method, type) and issubclass(method, Integrator):
        return method
    if method == AUTO:
        return Auto
    if method not in METHODS:
        raise SettingError("method", f'unknown method "{method}"; expected one of '
                           f"{', '.join(METHOD_NAMES)}")
    return METHODS[method]
