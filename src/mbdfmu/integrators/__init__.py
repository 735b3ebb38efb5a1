"""Integrators: one small class per method behind one stepping interface (``base.py``).

``METHODS`` maps each name to its class; ``make_integrator`` also accepts a class.
"""

from __future__ import annotations

from ..errors import SolverError
from .ali3p import ALI3P
from .auto import Auto
from .base import Integrator
from .baumgarte import Baumgarte
from .genalpha import GeneralizedAlpha
from .projected_rk import DOP853P, RK45P
from .rk4p import RK4P
from .taylor import Taylor

METHODS: dict[str, type[Integrator]] = {
    cls.name: cls for cls in (Auto, DOP853P, RK45P, RK4P, Taylor, Baumgarte, GeneralizedAlpha,
                              ALI3P)}
DEFAULT_METHOD = "auto"


def method_class(method: str | type[Integrator] | None) -> type[Integrator]:
    """The class of a method given by name (None: the default) or as a class."""
    if method is None:
        return METHODS[DEFAULT_METHOD]
    if isinstance(method, type) and issubclass(method, Integrator):
        return method
    if method not in METHODS:
        raise SolverError(f'unknown method "{method}"; expected one of {", ".join(METHODS)}')
    return METHODS[method]


def make_integrator(method, system, t0, q0, qd0, *, step=None, rtol=None, atol=None,
                    options: dict | None = None) -> Integrator:
    """An integrator of ``method``; ``options`` are its own keyword settings (e.g. Baumgarte's
    alpha and beta), rejected with a clear error when the method has no such setting."""
    cls = method_class(method)
    options = dict(options or {})
    unknown = sorted(set(options) - set(cls.option_names))
    if unknown:
        allowed = ", ".join(cls.option_names) or "none"
        raise SolverError(f'method "{cls.name}" has no option {", ".join(unknown)} '
                          f"(its options: {allowed})")
    return cls(system, t0, q0, qd0, step=step, rtol=rtol, atol=atol, **options)


__all__ = ["METHODS", "DEFAULT_METHOD", "Integrator", "make_integrator", "method_class"]
