"""The implicit coupling's interface Jacobian from the FMUs' directional derivatives
(``CosimSettings(jacobian="directional")``), in place of finite differences of whole steps.

At the communication point t each instance with inputs is linearized by
``fmi2GetDirectionalDerivative`` (one call per known: its continuous states and its
connected inputs), giving x' = A x + B u and y = C x + D u for its continuous states x,
connected inputs u and connected outputs y. Over a step h the inputs ramp from their value
at t to the iterate Y (input derivatives of order 1) or, for an FMU that cannot
interpolate, hold Y; the linear system's exact response to that is

    dx(t + h)/dY = int_0^h exp(A (h - s)) B w(s) ds,   w(s) = s / h (ramp) or 1 (hold),

read off one matrix exponential of the augmented system (Van Loan's construction), and
dy(t + h)/dY = C dx(t + h)/dY + D. Scattered onto the connections this is dG/dY of
``implicit.py``. It is exact for linear FMUs and a first-order approximation otherwise:
Newton's iteration then converges linearly instead of quadratically, with one Jacobian per
macro step and no extra steps of the FMUs.
"""

from __future__ import annotations

import numpy as np
from scipy.linalg import expm

from .settings import CosimError


def check_members(system) -> None:
    """Every instance with inputs must provide directional derivatives."""
    for m, pairs in system.inputs_of.items():
        if pairs and not system.members[m].provides_directional:
            raise CosimError('the implicit coupling with jacobian="directional" needs '
                             "directional derivatives (providesDirectionalDerivative) from "
                             "every instance with inputs", instance=m)


def linearization(member, inputs: list[str], outputs: list[str]):
    """(A, B, C, D) of ``member`` at its communication point: its continuous states (the
    variables its state derivatives name), ``inputs`` and ``outputs`` by name."""
    # (FMI 3.0's derivative inputs der(u) also name what they are the derivative of)
    derivatives = [v for v in member.md.modelVariables
                   if v.derivative is not None and v.causality != "input"]
    states = [v.derivative.name for v in derivatives]
    unknowns = [v.name for v in derivatives] + list(outputs)
    knowns = states + list(inputs)
    columns = np.array([member.directional(unknowns, [k], [1.0]) for k in knowns]).T
    columns = columns.reshape(len(unknowns), len(knowns))
    n = len(states)
    return columns[:n, :n], columns[:n, n:], columns[n:, :n], columns[n:, n:]


def step_sensitivity(A, B, h: float, ramp: bool) -> np.ndarray:
    """dx(t + h)/dY of x' = A x + B u with u ramping from 0 to Y over h (``ramp``) or held
    at Y: blocks of exp(M h) for M = [[A, B, 0], [0, 0, I/h], [0, 0, 0]] (ramp) or
    [[A, B], [0, 0]] (hold)."""
    n, p = B.shape
    if n == 0:
        return np.zeros((0, p))
    if ramp:
        M = np.zeros((n + 2 * p, n + 2 * p))
        M[:n, :n], M[:n, n:n + p], M[n:n + p, n + p:] = A, B, np.eye(p) / h
        return expm(M * h)[:n, n + p:]
    M = np.zeros((n + p, n + p))
    M[:n, :n], M[:n, n:] = A, B
    return expm(M * h)[:n, n:]


def interface_jacobian(system, sources: list[str], h: float) -> np.ndarray:
    """I - dG/dY at the instances' current communication point (module docstring)."""
    index = {s: j for j, s in enumerate(sources)}
    jac = np.eye(len(sources))
    for m, pairs in system.inputs_of.items():
        outputs = [s for s in sources if s.split(".", 1)[0] == m]
        if not pairs or not outputs:
            continue
        member = system.members[m]
        inputs = [dst for dst, _ in pairs]
        A, B, C, D = linearization(member, inputs, [s.split(".", 1)[1] for s in outputs])
        S = step_sensitivity(A, B, h, system.extrapolation.interpolates[m])
        dy = C @ S + D if len(S) else D
        if not np.all(np.isfinite(dy)):
            raise CosimError("the directional derivatives are not finite", instance=m)
        rows = [index[s] for s in outputs]
        for k, (_, src) in enumerate(pairs):
            jac[rows, index[src]] -= dy[:, k]
    system.counters["jacobians"] = system.counters.get("jacobians", 0) + 1
    return jac
