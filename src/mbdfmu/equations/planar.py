"""Planar vector helpers on stacked 2-vectors, shared by the equations' numpy code.

``A(phi)`` is a body's rotation matrix [[cos, -sin], [sin, cos]] and ``B = dA/dphi``, so
``B s = rot90(A s)`` (formulation.md, eq. 2).
"""

from __future__ import annotations

import itertools

import numpy as np


def stacked(rows, width: int, dtype=float) -> np.ndarray:
    """``np.array(rows, dtype).reshape(-1, width)`` for rows of ``width`` numbers each (a
    scene's tuples), read as one flat stream: numpy's nested-sequence discovery costs more
    than the copy at setup, once per row."""
    return np.fromiter(itertools.chain.from_iterable(rows), dtype,
                       width * len(rows)).reshape(-1, width)


def rot90(v: np.ndarray) -> np.ndarray:
    """Rotate 2-vectors (..., 2) by +90 degrees."""
    out = np.empty_like(v)
    out[..., 0] = -v[..., 1]
    out[..., 1] = v[..., 0]
    return out


def rotate(v: np.ndarray, c: np.ndarray, s: np.ndarray) -> np.ndarray:
    """A(phi) v for stacked 2-vectors v (k, 2) and angles given by c = cos, s = sin (k,)."""
    out = np.empty_like(v)
    out[:, 0] = c * v[:, 0] - s * v[:, 1]
    out[:, 1] = s * v[:, 0] + c * v[:, 1]
    return out


def dot(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Row-wise dot products of (k, 2) arrays."""
    return a[:, 0] * b[:, 0] + a[:, 1] * b[:, 1]


def poses(q: np.ndarray, nb: int):
    """Positions (nb+1, 2), cos and sin of the angles (nb+1,) and the angles, with the
    ground as a virtual last body at the origin."""
    Q = np.zeros((nb + 1, 3))
    Q[:nb] = q.reshape(-1, 3)
    return Q[:, :2], np.cos(Q[:, 2]), np.sin(Q[:, 2]), Q[:, 2]


def velocities(qd: np.ndarray, nb: int):
    """Velocities (nb+1, 2) and angular velocities (nb+1,), ground last (zero)."""
    V = np.zeros((nb + 1, 3))
    V[:nb] = qd.reshape(-1, 3)
    return V[:, :2], V[:, 2]
