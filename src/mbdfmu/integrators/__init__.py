"""Integrators: one small class per method behind one stepping interface (``base.py``).

``METHODS`` maps each method's name to its class; ``METHOD_NAMES`` adds ``auto``, which is
not a method but a choice among them (``choose.py``). ``make_integrator`` builds the
integrator of a ``SolverSettings`` (or of a method name or class and keyword settings).
"""

from __future__ import annotations

import numpy as np

from .base import Integrator
from .choose import choose_method
from .implicit_control import STEP_CONTROL
from .registry import AUTO, METHOD_NAMES, METHODS, SUMMARIES, Auto, method_class
from .settings import DEFAULT_METHOD, SolverSettings

def make_integrator(method, equations, t0: float, q0: np.ndarray, qd0: np.ndarray,
                    settings: SolverSettings | None = None, *, inputs=None,
                    output_interval: float | None = None, **values):
    """The integrator of ``method`` (a name, a class, or None for ``settings.method``) with
    the settings given (checked here), starting from (t0, q0, qd0).

    For ``auto`` the method is chosen first (``choose_method``, with ``output_interval``);
    the integrator then carries ``picked_by = "auto"`` and ``reason``.
    """
    settings = (settings or SolverSettings()).updated(method=method, **values)
    cls = method_class(settings.method)
    reason = ""
    if cls is Auto:
        interval = output_interval or settings.output_interval or 1.0
        u = inputs(t0) if inputs is not None else None
        cls, reason = choose_method(equations, t0, np.asarray(q0, dtype=float), interval, u,
                                    rtol=settings.rtol)
    options = dict(settings.options)
    if reason and STEP_CONTROL.name in cls.option_names:
        options[STEP_CONTROL.name] = "adaptive"    # auto's implicit methods control their step
    rtol, atol = settings.tolerances_for(cls, chosen=bool(reason), options=options)
    integrator = cls(equations, t0, q0, qd0, step=settings.step_for(cls, options), rtol=rtol,
                     atol=atol, inputs=inputs, **options)
    integrator.picked_by = AUTO if reason else ""
    integrator.reason = reason
    return integrator


__all__ = ["METHODS", "METHOD_NAMES", "SUMMARIES", "DEFAULT_METHOD", "Integrator",
           "SolverSettings", "make_integrator", "method_class", "choose_method"]
