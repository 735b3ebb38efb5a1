"""Inputs beyond zero-order hold: each connected input follows a polynomial over the
macro step, passed to the FMU as input derivatives (FMI 2.0 fmi2SetRealInputDerivatives,
``canInterpolateInputs``).

With ``order`` p (1 or 2) the input set at t is the source's output y(t) with its first p
time derivatives, so the input over [t, t + h] is the Taylor polynomial
``y + y' tau + y'' tau^2 / 2`` (extrapolation): a local error O(h^(p+1)) per step, a global
coupling error O(h^(p+1)) where zero-order hold gives O(h). The derivatives are the
source's own (``fmi2GetRealOutputDerivatives``, when its ``maxOutputDerivativeOrder``
reaches p), else backward differences of the source's outputs at the last p + 1
communication points (lower orders while that history fills).

Under Gauss-Seidel an input whose source has already stepped to t + h interpolates
instead: the polynomial from y(t) (and y'(t) for p = 2) that ends at y(t + h).
"""

from __future__ import annotations

import math

import numpy as np

ORDERS = (0, 1, 2)


class Extrapolation:
    """The derivatives of every connected output at the current communication point, and
    the polynomial each input follows; ``order`` 0 is zero-order hold (nothing to do)."""

    def __init__(self, system, order: int):
        self.system, self.order = system, int(order)
        self.derivatives: dict[str, list[float]] = {}   # source -> [y', y''][:order]
        self.start: dict[str, list[float]] = {}          # the same at the step's start
        self.history: dict[str, list[tuple[float, float]]] = {}  # source -> [(t, y)]
        self.provides = {m: member.max_output_derivative_order
                         for m, member in system.members.items()}
        self.interpolates = {m: member.interpolates_inputs for m, member in system.members.items()}

    # ------------------------------------------------------------------ outputs

    def read(self, member: str, names: list[str], t: float) -> None:
        """Record the derivatives of ``member``'s connected outputs at time ``t`` (just read
        into ``system.out``)."""
        if not self.order or not names:
            return
        keys = [f"{member}.{n}" for n in names]
        for key in keys:
            past = [p for p in self.history.get(key, []) if p[0] < t - 1e-12 * max(1.0, t)]
            self.history[key] = (past + [(t, self.system.out[key])])[-(self.order + 1):]
        if self.provides[member] >= self.order:
            fmu = self.system.members[member]
            columns = [fmu.output_derivatives(names, k) for k in range(1, self.order + 1)]
            for j, key in enumerate(keys):
                self.derivatives[key] = [c[j] for c in columns]
        else:
            for key in keys:
                self.derivatives[key] = backward_derivatives(self.history[key], self.order)

    def settle(self, t0: float) -> None:
        """At the start, pass every source's derivatives to the inputs it feeds and read
        the derivatives again, as many rounds as it takes a chain of direct feedthrough:
        an output that reads an input (a coupling force from the other body's position)
        has derivatives that need the input's, and the inputs have none before this. The
        start's derivatives carry no step's error; left inconsistent, their error of O(1)
        over the first step costs an order (the two-mass oscillator with p = 2: order 2)."""
        if not self.order:
            return
        system = self.system
        for _ in range(len(system.members) * self.order):
            for member, pairs in system.inputs_of.items():
                if pairs and self.interpolates[member]:
                    names = [dst for dst, _ in pairs for _ in range(self.order)]
                    orders = [k for _ in pairs for k in range(1, self.order + 1)]
                    values = [d for _, src in pairs for d in self.derivatives.get(
                        src, [0.0] * self.order)]
                    system.members[member].set_derivatives(names, orders, values)
            for member in system.members:
                self.read(member, system.outputs_of[member], t0)

    def begin_step(self) -> None:
        """Keep the derivatives of the macro step's start (Gauss-Seidel reads new ones)."""
        self.start = {k: list(v) for k, v in self.derivatives.items()}

    def snapshot(self):
        return ({k: list(v) for k, v in self.derivatives.items()},
                {k: list(v) for k, v in self.history.items()})

    def restore(self, saved) -> None:
        self.derivatives = {k: list(v) for k, v in saved[0].items()}
        self.history = {k: list(v) for k, v in saved[1].items()}

    # ------------------------------------------------------------------ inputs

    def coefficients(self, source: str, h: float, new: float | None = None) -> list[float]:
        """[y', y''][:order] of the polynomial an input follows over a step h: the source's
        Taylor terms, or, given the source's ``new`` value at t + h (Gauss-Seidel), the
        interpolating polynomial."""
        y, d = self.system.out_at_start(source), self.start.get(source, [])
        d = list(d) + [0.0] * (self.order - len(d))
        if new is None:
            return d[:self.order]
        if self.order == 1:
            return [(new - y) / h]
        return [d[0], 2.0 * (new - y - d[0] * h) / (h * h)]

    def set_inputs(self, member: str, pairs, h: float, new: dict | None = None) -> None:
        """Input derivatives of ``member`` for the step (its values are set already)."""
        if not self.order or not pairs or not self.interpolates[member]:
            return
        names, orders, values = [], [], []
        for dst, src in pairs:
            coeffs = self.coefficients(src, h, None if new is None else new.get(src))
            for k, c in enumerate(coeffs, start=1):
                names.append(dst)
                orders.append(k)
                values.append(c)
            y0 = self.system.out_at_start(src)
            end = y0 + sum(c * h ** k / math.factorial(k) for k, c in enumerate(coeffs, 1))
            self.system.used[f"{member}.{dst}"] = end
        self.system.members[member].set_derivatives(names, orders, values)


def backward_derivatives(points: list[tuple[float, float]], order: int) -> list[float]:
    """Derivatives 1..order at the last point of the polynomial through ``points`` (the
    last order + 1 of them; fewer give lower orders, the missing ones 0)."""
    t = np.array([p[0] for p in points])
    y = np.array([p[1] for p in points])
    degree = min(order, len(points) - 1)
    if degree == 0:
        return [0.0] * order
    span = t[-1] - t[0]
    c = np.polynomial.polynomial.polyfit((t - t[-1]) / span, y, degree)
    out = [float(np.polynomial.polynomial.polyder(c, k)[0] / span ** k)
           if k <= degree else 0.0 for k in range(1, order + 1)]
    return out
