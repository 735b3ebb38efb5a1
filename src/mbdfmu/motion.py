"""Prescribed motions f(t) of drivers, with their first and second time derivatives.

Every motion is a frozen dataclass with ``evaluate(t) -> (f, f', f'')``; none evaluates
strings. ``InputMotion`` takes its values from a signal set at run time (a CSV table in
the CLI, FMU inputs later).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class ConstantMotion:
    """f(t) = value."""

    value: float

    def evaluate(self, t: float) -> tuple[float, float, float]:
        return self.value, 0.0, 0.0


@dataclass(frozen=True)
class LinearMotion:
    """f(t) = start + rate * t."""

    start: float
    rate: float

    def evaluate(self, t: float) -> tuple[float, float, float]:
        return self.start + self.rate * t, self.rate, 0.0


@dataclass(frozen=True)
class HarmonicMotion:
    """f(t) = offset + amplitude * sin(2 pi frequency t + phase); frequency in Hz."""

    offset: float
    amplitude: float
    frequency: float
    phase: float = 0.0

    def evaluate(self, t: float) -> tuple[float, float, float]:
        w = 2.0 * math.pi * self.frequency
        s, c = math.sin(w * t + self.phase), math.cos(w * t + self.phase)
        a = self.amplitude
        return self.offset + a * s, a * w * c, -a * w * w * s


@dataclass(frozen=True)
class PolynomialMotion:
    """f(t) = sum_k coefficients[k] t^k (lowest order first)."""

    coefficients: tuple[float, ...]

    def evaluate(self, t: float) -> tuple[float, float, float]:
        c = np.asarray(self.coefficients, dtype=float)
        p = np.polynomial.Polynomial(c)
        return float(p(t)), float(p.deriv(1)(t)), float(p.deriv(2)(t))


@dataclass(frozen=True)
class InputMotion:
    """f(t) supplied from outside at run time (see ``mbdfmu.signals``)."""

    initial: float = 0.0


MOTION_TYPES: dict[str, tuple[type, tuple[str, ...], dict[str, float]]] = {
    # type name: (class, required keys, optional keys with defaults)
    "constant": (ConstantMotion, ("value",), {}),
    "linear": (LinearMotion, ("start", "rate"), {}),
    "harmonic": (HarmonicMotion, ("offset", "amplitude", "frequency"), {"phase": 0.0}),
    "polynomial": (PolynomialMotion, ("coefficients",), {}),
    "input": (InputMotion, (), {"initial": 0.0}),
}

Motion = ConstantMotion | LinearMotion | HarmonicMotion | PolynomialMotion | InputMotion
