"""Run-time inputs as functions of time: held values, tables, and sampled driver positions.

Every signal is a small object called as ``signal(t)``, saved with a run's state as plain
data (``plain.Plain``). Driver signals return ``(f, f', f'')``; force signals return the
force components.

Sampled driver positions (an FMU's inputs, set once per communication step): when the
master gives position, velocity and acceleration at t_n, the motion over the next step is
their Taylor polynomial ``p + v tau + a tau^2 / 2``. When it gives positions only, the
motion is the quadratic through the last three samples, extrapolated over the step: its
acceleration is the samples' second divided difference, which equals the motion's
acceleration at some time among those samples (mean value theorem), so the derived
acceleration never leaves the range the motion's acceleration takes. Its error is of order
h in the communication step h, as with full inputs (whose acceleration is held over the
step). Extrapolating the cubic through four samples (order h^2) was dropped: a linear
acceleration carried past a peak overshoots it, by far at coarse steps (docs/fmu.md).
The difference between the cubic's and the quadratic's acceleration at the end of the
next step estimates the derived acceleration's error (``SampledDriver.error``); it is
reported only above the round-off that differencing the samples leaves in it
(``SampledDriver.error_is_large``), which on a motion of constant rate is all there is.
"""

from __future__ import annotations

import math

import numpy as np

from .errors import InputError
from .plain import Plain

# The fields of a driver input (its motion and the motion's derivatives).
DRIVER_FIELDS = ("position", "velocity", "acceleration")

# Samples of driver position kept to derive its velocity and acceleration (three for the
# quadratic, a fourth for the cubic of the error estimate).
HISTORY_LENGTH = 4

# The derived acceleration's estimated error, as a fraction of the largest acceleration of the
# samples so far, above which it is reported (``SampledDriver.error_is_large``).
LARGE_ERROR = 0.1

# Unit round-offs in each term of the third divided difference of the samples: the
# position's own, the product of three time differences and the division, the sum's. An
# estimated error below this many times EPS times the terms' size is round-off, not motion.
ROUNDOFF_TERMS = 8.0
EPS = float(np.finfo(float).eps)


class Held(Plain):
    """A value held constant until replaced (zero-order hold)."""

    plain_fields = ("value",)

    def __init__(self, value):
        self.value = np.atleast_1d(np.asarray(value, dtype=float))

    def __call__(self, t):
        return self.value

    def at_times(self, times: np.ndarray) -> np.ndarray:
        """The value at each of ``times``: (len(times), components)."""
        return np.broadcast_to(self.value, (len(times), self.value.size))


class LinearTable(Plain):
    """Linear interpolation in a table (values held beyond its ends), as fmpy does."""

    plain_fields = ("times", "values")

    def __init__(self, times, values):
        self.times = np.asarray(times, dtype=float)
        self.values = np.asarray(values, dtype=float).reshape(len(self.times), -1)

    def __call__(self, t):
        return np.array([np.interp(t, self.times, col) for col in self.values.T])


class DriverTable(Plain):
    """A driver position from a table: a C2 cubic spline, or a quintic Hermite spline that
    honours velocity and acceleration columns when the table has them."""

    plain_fields = ("times", "positions", "velocities", "accelerations")

    def __init__(self, times, positions, velocities=None, accelerations=None):
        self.times = np.asarray(times, dtype=float)
        self.positions = np.asarray(positions, dtype=float)
        self.velocities = None if velocities is None else np.asarray(velocities, dtype=float)
        self.accelerations = (None if accelerations is None
                              else np.asarray(accelerations, dtype=float))
        self._curve = None

    @property
    def curve(self):
        if getattr(self, "_curve", None) is None:   # built on first use (not part of the state)
            # scipy.interpolate imported here: a large share of an FMU's cold start otherwise
            from scipy.interpolate import BPoly, CubicSpline
            if self.velocities is not None and self.accelerations is not None:
                derivs = np.stack([self.positions, self.velocities, self.accelerations], axis=1)
                self._curve = BPoly.from_derivatives(self.times, derivs)
            else:
                self._curve = CubicSpline(self.times, self.positions)
        return self._curve

    def __call__(self, t):
        c = self.curve
        return float(c(t)), float(c(t, 1)), float(c(t, 2))


class SampledDriver(Plain):
    """A driver position set at discrete times; derivatives given or from the history."""

    plain_fields = ("times", "positions", "velocity", "acceleration", "fresh", "error",
                    "scale", "reported")

    def __init__(self, initial: float):
        self.times = [0.0]
        self.positions = [float(initial)]
        self.velocity = None
        self.acceleration = None
        self.fresh = False  # no sample set yet: the initial value stands still
        self.error = 0.0    # estimated error of the derived acceleration over the next step
        self.scale = 0.0    # largest derived acceleration so far: the motion's magnitude
        self.reported = False  # the large error was reported (once until it is small again)

    def set(self, t: float, position=None, velocity=None, acceleration=None):
        """Record what the master set at time t (a repeated time replaces the last sample)."""
        if position is not None:
            if not self.fresh:
                self.times, self.positions = [t], [float(position)]
                self.fresh = True
            elif t == self.times[-1]:
                self.positions[-1] = float(position)
            else:
                self.times = (self.times + [t])[-HISTORY_LENGTH:]
                self.positions = (self.positions + [float(position)])[-HISTORY_LENGTH:]
            self._estimate()
        if velocity is not None:
            self.velocity = float(velocity)
        if acceleration is not None:
            self.acceleration = float(acceleration)

    def _quadratic(self):
        """Position, velocity and acceleration at the last sample of the quadratic through
        the last three samples (lower orders while the history fills)."""
        t, p = self.times[-3:], self.positions[-3:]
        if len(t) == 1:
            return p[-1], 0.0, 0.0
        d1 = (p[-1] - p[-2]) / (t[-1] - t[-2])
        if len(t) == 2:
            return p[-1], d1, 0.0
        d0 = (p[1] - p[0]) / (t[1] - t[0])
        a = 2.0 * (d1 - d0) / (t[2] - t[0])
        return p[-1], d1 + 0.5 * a * (t[2] - t[1]), a

    def _cubic_term(self) -> tuple[float, float]:
        """(error, its round-off): the cubic's acceleration through the last four samples
        minus the quadratic's through the last three, at the end of a next step as long as
        the last. In Newton's form the cubic is the quadratic plus f[t0..t3] (t - t1)
        (t - t2) (t - t3), so the difference is 2 f[t0..t3] (3 x - t1 - t2 - t3) at x,
        without the quadratic's acceleration subtracted from a nearly equal number."""
        t, p = self.times, self.positions
        x = t[3] + (t[3] - t[2])
        third = size = 0.0
        for i in range(4):
            w = 1.0
            for j in range(4):
                if j != i:
                    w *= t[i] - t[j]
            third += p[i] / w
            size += abs(p[i] / w)
        k = 2.0 * (3.0 * x - t[1] - t[2] - t[3])
        return third * k, ROUNDOFF_TERMS * EPS * size * abs(k)

    def _estimate(self):
        """The derived acceleration's estimated error (``_cubic_term``) and the largest
        derived acceleration so far."""
        a = self._quadratic()[2]
        self.scale = max(self.scale, abs(a))
        self.error = self._cubic_term()[0] if len(self.times) >= 4 else 0.0

    def error_is_large(self) -> bool:
        """Whether the derived acceleration's estimated error exceeds ``LARGE_ERROR`` of the
        motion's acceleration and the round-off left in the estimate (positions only:
        given derivatives are taken as exact)."""
        derived = self.velocity is None and self.acceleration is None
        if not derived or len(self.times) < 4 or not self.scale > 0.0:
            return False
        return abs(self.error) > max(LARGE_ERROR * self.scale, self._cubic_term()[1])

    def step_motion(self) -> tuple[float, float, float, float]:
        """(t_n, p, v, a): over the next step the motion is ``p + v tau + a tau^2 / 2``
        with tau = t - t_n, the last sample's time (v and a the master's where given, else
        the quadratic's). An FMU's wrapper evaluates the same numbers (ckernel/motions.h)."""
        p, v0, a0 = self._quadratic()
        v = self.velocity if self.velocity is not None else v0
        a = self.acceleration if self.acceleration is not None else a0
        return self.times[-1], p, v, a

    def __call__(self, t):
        tn, p, v, a = self.step_motion()
        tau = t - tn
        return p + v * tau + 0.5 * a * tau * tau, v + a * tau, a


class TaylorInput(Plain):
    """Force inputs that follow their Taylor polynomial from ``t0``:
    ``sum_k coefficients[k] (t - t0)^k / k!`` (an FMU's input with its derivatives)."""

    plain_fields = ("t0", "coefficients")

    def __init__(self, t0: float, value):
        self.t0 = float(t0)
        self.coefficients = np.atleast_2d(np.asarray(value, dtype=float)).copy()

    def set_derivative(self, index: int, order: int, value: float) -> None:
        """The ``order``-th time derivative of component ``index`` at ``t0``."""
        missing = order + 1 - len(self.coefficients)
        if missing > 0:
            self.coefficients = np.vstack([self.coefficients,
                                           np.zeros((missing, self.coefficients.shape[1]))])
        self.coefficients[order, index] = float(value)

    def __call__(self, t):
        # at_times' operations on scalars: at one time, half its cost
        tau, term, total = t - self.t0, 1.0, np.zeros(self.coefficients.shape[1])
        for k, c in enumerate(self.coefficients):
            total = total + c * term
            term = term * tau / (k + 1)
        return total

    def rebased(self, t: float) -> "TaylorInput":
        """The same polynomials from t: each component's value and derivatives at t."""
        tau, orders = t - self.t0, len(self.coefficients)
        at_t = TaylorInput(t, np.zeros(self.coefficients.shape[1]))
        at_t.coefficients = np.array([sum(self.coefficients[j] * tau ** (j - k)
                                          / math.factorial(j - k) for j in range(k, orders))
                                      for k in range(orders)])
        return at_t

    def at_times(self, times: np.ndarray) -> np.ndarray:
        """``self(t)`` at each of ``times`` at once, (len(times), components): the same
        operations on each element, so the same doubles."""
        tau, term = times - self.t0, np.ones(len(times))
        total = np.zeros((len(times), self.coefficients.shape[1]))
        for k, c in enumerate(self.coefficients):
            total = total + c[None, :] * term[:, None]
            term = term * tau / (k + 1)
        return total


def large_error_warnings(drivers: dict, t: float) -> list[str]:
    """One line for each sampled driver whose derived acceleration's estimated error is
    large (``SampledDriver.error_is_large``), once until it is small again."""
    lines = []
    for item, driver in drivers.items():
        if not isinstance(driver, SampledDriver):
            continue
        large = driver.error_is_large()
        if large and not driver.reported:
            lines.append(
                f"t = {t!r} s: {item}.velocity and .acceleration derived from "
                f"{item}.position samples may be off by {abs(driver.error):.3g} "
                f"({abs(driver.error) / driver.scale:.0%} of the motion's acceleration "
                f"{driver.scale:.3g}): give them as inputs or shorten the communication step")
        driver.reported = large
    return lines


def known_ahead(signals) -> bool:
    """Whether input signals are known beyond the current time: functions of time given
    beforehand (tables, ``set_input_signal``), not values set by a master (held, sampled
    or Taylor inputs, which hold only until set again)."""
    return not any(isinstance(s, (SampledDriver, Held, TaylorInput)) for s in signals)


def apply_input_table(sim, table) -> None:
    """Inputs from a structured array with 'time' first (fmpy's layout): forces linearly
    interpolated, driver positions by splines."""
    names = table.dtype.names
    if not names or names[0] != "time":
        raise InputError('an input table needs a "time" column first')
    time = np.asarray(table["time"], dtype=float)
    if time.size == 0:
        raise InputError("the input table has no rows")
    if np.any(np.diff(time) < 0):
        raise InputError("input table: time must not decrease")
    columns = set(names[1:])
    for name in columns:
        sim._split(name)  # unknown names are an error, not silently ignored
        if not np.all(np.isfinite(table[name])):
            raise InputError(f'input table: column "{name}" has non-finite values')
    for item in list(sim._drivers):
        cols = [f"{item}.{k}" for k in DRIVER_FIELDS]
        if cols[0] in columns:
            extra = [table[c] if c in columns else None for c in cols[1:]]
            sim.set_input_signal(item, DriverTable(time, table[cols[0]], *extra))
    for item, fields in sim.equations.layout.fields.items():
        cols = [f"{item}.{k}" for k in fields]
        if any(c in columns for c in cols):
            values = np.column_stack([table[c] if c in columns else np.zeros(len(time))
                                      for c in cols])
            sim.set_input_signal(item, LinearTable(time, values))
