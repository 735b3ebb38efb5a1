"""Dense output of the embedded Runge-Kutta pairs: the solution between a step's ends.

The interpolants are scipy's (``scipy.integrate.RK45`` and ``DOP853``): for Dormand-Prince
5(4) a quartic from the step's stages (Shampine, "Some practical Runge-Kutta formulas",
Math. Comp. 46 (1986)), free; for DOP853 Hairer's interpolant of order 7 (Hairer, Norsett,
Wanner, Solving ODEs I, sec. II.6), which costs three more stages, evaluated only for
steps that hold an output time. The step's data are kept as plain arrays (``DenseStep``)
so that they are part of a run's state.
"""

from __future__ import annotations

import numpy as np

from ..plain import Plain
from .tableaux import DOP853_A_EXTRA, DOP853_C_EXTRA, DOP853_D


class DenseStep(Plain):
    """One accepted step from (t_old, y_old) over h, with its stage derivatives K (the last
    row f at the unprojected end y_new) and, once an output inside it was asked for, the
    coefficients of its interpolant."""

    plain_fields = ("t_old", "h", "y_old", "y_new", "K", "coefficients")
    flat_fields = True

    def __init__(self, t_old: float, h: float, y_old: np.ndarray, y_new: np.ndarray,
                 K: np.ndarray):
        self.t_old, self.h = float(t_old), float(h)
        self.y_old, self.y_new, self.K = y_old, y_new, K
        self.coefficients = None

    def contains(self, t: float) -> bool:
        return self.t_old <= t <= self.t_old + self.h


def rk45_interpolant(step: DenseStep, P: np.ndarray) -> np.ndarray:
    """Coefficients Q (n, 4) of y(t_old + x h) = y_old + h Q [x, x^2, x^3, x^4]."""
    return step.K.T @ P


def rk45_value(step: DenseStep, x: float) -> np.ndarray:
    powers = np.cumprod(np.full(step.coefficients.shape[1], x))
    return step.y_old + step.h * (step.coefficients @ powers)


def dop853_interpolant(step: DenseStep, rhs) -> np.ndarray:
    """Coefficients F (7, n) of DOP853's interpolant; ``rhs(t, y)`` gives the three extra
    stages (scipy's ``DOP853._dense_output_impl``)."""
    first = step.K.shape[0]                       # n_stages + 1 (the last: f at y_new)
    K = np.empty((first + len(DOP853_C_EXTRA), step.y_old.size))
    K[:first] = step.K
    h = step.h
    for s, (a, node) in enumerate(zip(DOP853_A_EXTRA, DOP853_C_EXTRA), start=first):
        K[s] = rhs(step.t_old + node * h, step.y_old + h * (K[:s].T @ a[:s]))
    delta = step.y_new - step.y_old
    F = np.empty((3 + DOP853_D.shape[0], delta.size))
    F[0] = delta
    F[1] = h * K[0] - delta
    F[2] = 2.0 * delta - h * (step.K[-1] + K[0])
    F[3:] = h * (DOP853_D @ K)
    return F


def dop853_value(step: DenseStep, x: float) -> np.ndarray:
    """scipy's ``Dop853DenseOutput`` at x in [0, 1]: the rows, from the last, alternately
    multiplied by x and 1 - x; as one product with each row's weight."""
    F = step.coefficients
    factors = [x if i % 2 == 0 else 1.0 - x for i in range(F.shape[0])]
    weights = np.cumprod(factors[::-1])         # row r's weight: the factors from its turn on
    return step.y_old + weights @ F
