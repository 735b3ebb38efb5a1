"""Directional derivatives of eq. (14) and of the output vector at one state and input:
what a scene FMU's fmi2GetDirectionalDerivative (fmi3GetDirectionalDerivative) returns
(docs/fmu.md, "Directional derivatives").

``directional(eq, t, q, qd, u, dq, dqd, du)`` gives, along the direction ``(dq, dqd, du)``
of the state and the inputs, the derivatives of the accelerations q'' (eq. 14) and, with
``outputs``, of ``Equations.output_values``. They are central differences of the
equations themselves along the direction (no step is integrated), at ``eps`` and ``eps /
2`` with Richardson's extrapolation: the O(eps^2) term cancels, leaving O(eps^4) and
round-off of about 1e-16 |f| / eps. ``eps`` is ``DELTA`` times the smallest ratio of a
perturbed component's size (at least 1) to its direction component, so no component moves
by more than ``DELTA`` of its size, whatever the direction's length and units. Outputs that are not differentiable (the constraint-error
norms, zero on the constraints) come out as the symmetric difference: 0 there.
"""

from __future__ import annotations

import numpy as np

from ..model.variables import InputValues

# Relative size of the finite-difference step along a direction (Richardson: eps, eps / 2).
DELTA = 1e-3


def _along(u: InputValues, du: InputValues | None, e: float) -> InputValues:
    if du is None:
        return u
    return InputValues(u.motions + e * du.motions, u.forces + e * du.forces)


def _scale(q, qd, u: InputValues, dq, dqd, du: InputValues | None) -> float:
    """The step along the direction: DELTA times the smallest ratio of a perturbed
    component's size (at least 1) to its direction component, so that no component moves
    by more than DELTA of its size (a direction mixing metres, radians and newtons)."""
    parts = [(q, dq), (qd, dqd)]
    if du is not None:
        parts += [(u.motions.ravel(), du.motions.ravel()), (u.forces, du.forces)]
    ratios = [float(np.min(np.maximum(1.0, np.abs(x[d != 0])) / np.abs(d[d != 0])))
              for x, d in parts if np.any(d != 0)]
    return DELTA * min(ratios) if ratios else 0.0


def directional(eq, t: float, q: np.ndarray, qd: np.ndarray, u: InputValues,
                dq: np.ndarray, dqd: np.ndarray, du: InputValues | None = None,
                outputs: bool = False):
    """(d q'' (n,), d outputs or None) along (dq, dqd, du) at (t, q, qd, u); see the
    module docstring. ``du`` None: the inputs are not perturbed."""
    eps = _scale(q, qd, u, dq, dqd, du)
    if eps == 0.0:
        zero_out = np.zeros(len(eq.output_values(t, q, qd, *eq.accelerations(t, q, qd, u), u))) \
            if outputs else None
        return np.zeros(eq.n), zero_out

    def at(e):
        qe, qde, ue = q + e * dq, qd + e * dqd, _along(u, du, e)
        qdd, lam = eq.accelerations(t, qe, qde, ue)
        out = eq.output_values(t, qe, qde, qdd, lam, ue) if outputs else None
        return qdd, out

    def central(e):
        (a1, y1), (a0, y0) = at(e), at(-e)
        return (a1 - a0) / (2 * e), None if y1 is None else (y1 - y0) / (2 * e)

    (a_h, y_h), (a_h2, y_h2) = central(eps), central(eps / 2)
    richardson = (lambda coarse, fine: (4 * fine - coarse) / 3)
    return richardson(a_h, a_h2), None if y_h is None else richardson(y_h, y_h2)
