"""Prescribed motions f(t) of drivers, with their first and second time derivatives.

Every motion is a frozen dataclass with ``evaluate(t) -> (f, f', f'')``; none evaluates
strings. Its fields are its scene keys (``motion = { type = "linear", start = 0, rate = 1 }``).
``InputMotion`` takes its values from outside at run time (a CSV table in the CLI, FMU
inputs): the simulation owns those values and passes them to the equations.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from .toml_table import key


@dataclass(frozen=True)
class ConstantMotion:
    """f(t) = value."""

    value: float = key("float")

    def evaluate(self, t: float) -> tuple[float, float, float]:
        return self.value, 0.0, 0.0


@dataclass(frozen=True)
class LinearMotion:
    """f(t) = start + rate * t."""

    start: float = key("float")
    rate: float = key("float")

    def evaluate(self, t: float) -> tuple[float, float, float]:
        return self.start + self.rate * t, self.rate, 0.0


@dataclass(frozen=True)
class HarmonicMotion:
    """f(t) = offset + amplitude * sin(2 pi frequency t + phase); frequency in Hz."""

    offset: float = key("float")
    amplitude: float = key("float")
    frequency: float = key("float", nonnegative=True)
    phase: float = key("float", 0.0)

    def evaluate(self, t: float) -> tuple[float, float, float]:
        w = 2.0 * math.pi * self.frequency
        s, c = math.sin(w * t + self.phase), math.cos(w * t + self.phase)
        a = self.amplitude
        return self.offset + a * s, a * w * c, -a * w * w * s


@dataclass(frozen=True)
class PolynomialMotion:
    """f(t) = sum_k coefficients[k] t^k (lowest order first)."""

    coefficients: tuple[float, ...] = key("floats")

    def evaluate(self, t: float) -> tuple[float, float, float]:
        p = np.polynomial.Polynomial(np.asarray(self.coefficients, dtype=float))
        return float(p(t)), float(p.deriv(1)(t)), float(p.deriv(2)(t))


@dataclass(frozen=True)
class InputMotion:
    """f(t) supplied from outside at run time; ``initial`` until the first value arrives."""

    initial: float = key("float", 0.0)


MOTION_TYPES: dict[str, type] = {
    "constant": ConstantMotion,
    "linear": LinearMotion,
    "harmonic": HarmonicMotion,
    "polynomial": PolynomialMotion,
    "input": InputMotion,
}

Motion = ConstantMotion | LinearMotion | HarmonicMotion | PolynomialMotion | InputMotion
