"""How the embedded pairs start: y' and the singularity indicator at the start
(``start_in_c``: one C call where there is a C kernel), and the starting step (Hairer,
Norsett and Wanner, Solving ODEs I, II.4): ``initial_step(rk)``, in the C kernel where the
inputs hold over the first step (the same double: its sums in numpy's order,
``Kernel.initial_step``), else in numpy."""

from __future__ import annotations

import math

import numpy as np

from ..equations.dynamics import Equations
from .c_steps import held_forces


def initial_step(rk) -> float:
    """The first step of ``rk`` (a ProjectedRK) from its state (t, q, q', f): one evaluation
    of y' at y + h0 f, counted."""
    h = initial_step_in_c(rk)
    if h is not None:
        rk.stats.naccel += 1
        return h
    y = np.concatenate((rk.q, rk.qd))
    scale = rk._scale(y, y)
    d0 = _rms(y / scale)
    d1 = _rms(rk.f / scale)
    h0 = 1e-6 if d0 < 1e-5 or d1 < 1e-5 else 0.01 * d0 / d1
    h0 = min(h0, rk.max_step)
    f1 = rk._rhs_y(rk.t + h0, y + h0 * rk.f)
    d2 = _rms((f1 - rk.f) / scale) / h0
    h1 = (max(1e-6, h0 * 1e-3) if d1 <= 1e-15 and d2 <= 1e-15
          else (0.01 / max(d1, d2)) ** (1.0 / (rk.order + 1)))
    return min(100 * h0, h1, rk.max_step)


def start_in_c(rk) -> tuple[np.ndarray, float] | None:
    """(y', the singularity indicator) at rk's state in one C call, its evaluation counted:
    what ``_rhs`` and ``singular_zone.indicator`` give, where the equations' accelerations
    are eq. (14)'s own (not a contact mode's); else None."""
    eq = rk.equations
    if eq.ckernel is None or type(eq).accelerations is not Equations.accelerations:
        return None
    u = rk.inputs(rk.t)
    done = eq.ckernel.start(rk.q, rk.qd, eq.motion_values(rk.t, u), u.forces)
    if done is None:
        return None
    rk.stats.naccel += 1
    return np.concatenate((rk.qd, done[0])), done[1]


def initial_step_in_c(rk) -> float | None:
    """``initial_step`` in the C kernel where the inputs hold over the first step (no
    drivers, the force inputs held), its evaluation not counted; else None."""
    eq = rk.equations
    if eq.ckernel is None or eq.scene.drivers or eq.layout.drivers:
        return None
    forces = held_forces(rk) if eq.ckernel.nf else None
    if eq.ckernel.nf and forces is None:
        return None
    return eq.ckernel.initial_step(np.concatenate((rk.q, rk.qd)), rk.f, eq.motion_values(rk.t),
                                   forces, (rk.local_tolerance, rk.rtol, rk.atol), rk.max_step,
                                   rk.order)


def _rms(v: np.ndarray) -> float:
    """np.sqrt(np.mean(v ** 2)) to the last bit (the same sum and division), without
    np.mean's dispatch."""
    return math.sqrt(np.add.reduce(v * v) / v.size)
