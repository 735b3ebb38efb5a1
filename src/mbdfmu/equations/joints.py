"""Constraint rows of each joint type and driver, built from three primitives.

Every joint and driver is made of rows of three kinds (formulation.md, eqs. 5-7), each
evaluated for all its rows at once by ``constraints.py`` and ``compiled.py``:

* ``coincidence`` (2 rows): ``r_i + A_i s_i - r_j - A_j s_j = 0``;
* ``line`` (1 row): ``u_i . (r_j + A_j s_j - r_i - A_i s_i) - c(t) = 0`` with ``u_i`` a
  body_i-fixed unit vector;
* ``angle`` (1 row): ``phi_j - phi_i - c(t) = 0``.

A joint type is one function here (``JOINT_ROWS``) that adds its rows and says in which
frame its reactions are reported, plus (if it can be driven) one in ``COORDINATE_ROWS``
that adds the row of its coordinate. Bodies are indices; the ground is the virtual body
``nb`` at the origin.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..model.scene import GROUND, Driver, RevoluteJoint, Scene, TranslationalJoint


class Primitive:
    """Index arrays of one row primitive: bodies, body-fixed vectors, global row numbers."""

    def __init__(self):
        self.bi, self.bj, self.si, self.sj, self.u, self.rows = [], [], [], [], [], []

    def add(self, row, bi, bj, si=(0.0, 0.0), sj=(0.0, 0.0), u=(0.0, 0.0)):
        self.rows.append(row), self.bi.append(bi), self.bj.append(bj)
        self.si.append(si), self.sj.append(sj), self.u.append(u)

    def freeze(self) -> None:
        self.rows = np.array(self.rows, dtype=int)
        self.bi = np.array(self.bi, dtype=int)
        self.bj = np.array(self.bj, dtype=int)
        self.si = np.array(self.si, dtype=float).reshape(-1, 2)
        self.sj = np.array(self.sj, dtype=float).reshape(-1, 2)
        self.u = np.array(self.u, dtype=float).reshape(-1, 2)
        self.n = len(self.bi)


@dataclass(frozen=True)
class ReactionFrame:
    """The frame of a joint's reported reactions: ``body``'s frame turned by ``angle``."""

    body: int
    angle: float


class RowBuilder:
    """Adds rows in scene order: numbers them, labels them, keeps their constant offsets."""

    def __init__(self, scene: Scene):
        self.index = {b.name: k for k, b in enumerate(scene.bodies)} | {GROUND: len(scene.bodies)}
        self.angle0 = {b.name: b.angle for b in scene.bodies} | {GROUND: 0.0}
        self.coincidence, self.line, self.angle = Primitive(), Primitive(), Primitive()
        self.m = 0
        self.labels: list[str] = []
        self.offsets: list[float] = []

    def bodies(self, item) -> tuple[int, int]:
        return self.index[item.body_i], self.index[item.body_j]

    def take(self, labels: list[str], offsets: list[float]) -> int:
        """Reserve len(labels) rows; returns the first."""
        first = self.m
        self.m += len(labels)
        self.labels += labels
        self.offsets += offsets
        return first


def _unit(axis) -> np.ndarray:
    return np.asarray(axis, dtype=float) / math.hypot(*axis)


def revolute_rows(b: RowBuilder, j: RevoluteJoint) -> ReactionFrame:
    bi, bj = b.bodies(j)
    m = b.take([f'joint "{j.name}" (x)', f'joint "{j.name}" (y)'], [0.0, 0.0])
    b.coincidence.add((m, m + 1), bi, bj, j.point_i, j.point_j)
    return ReactionFrame(bj, j.frame_angle)


def translational_rows(b: RowBuilder, j: TranslationalJoint) -> ReactionFrame:
    """The normal offset of point_j from the axis line is zero; the relative angle keeps its
    initial value."""
    bi, bj = b.bodies(j)
    axis = _unit(j.axis_i)
    m = b.take([f'joint "{j.name}" (normal)', f'joint "{j.name}" (rotation)'],
               [0.0, b.angle0[j.body_j] - b.angle0[j.body_i]])
    b.line.add(m, bi, bj, j.point_i, j.point_j, (-axis[1], axis[0]))
    b.angle.add(m + 1, bi, bj)
    return ReactionFrame(bi, math.atan2(axis[1], axis[0]) + j.frame_angle)


def revolute_coordinate(b: RowBuilder, j: RevoluteJoint, row: int) -> None:
    """phi_j - phi_i = c(t)."""
    b.angle.add(row, *b.bodies(j))


def translational_coordinate(b: RowBuilder, j: TranslationalJoint, row: int) -> None:
    """(r_Pj - r_Pi) . u_i = c(t)."""
    b.line.add(row, *b.bodies(j), j.point_i, j.point_j, tuple(_unit(j.axis_i)))


JOINT_ROWS = {RevoluteJoint: revolute_rows, TranslationalJoint: translational_rows}
COORDINATE_ROWS = {RevoluteJoint: revolute_coordinate,
                   TranslationalJoint: translational_coordinate}


def driver_row(b: RowBuilder, scene: Scene, d: Driver) -> int:
    """The row of a driver: its joint's coordinate, or a body's x, y or angle."""
    row = b.take([f'driver "{d.name}"'], [0.0])
    if d.joint is not None:
        joint = scene.joint(d.joint)
        COORDINATE_ROWS[type(joint)](b, joint, row)
    elif d.coordinate == "angle":
        b.angle.add(row, b.index[GROUND], b.index[d.body])
    else:
        b.line.add(row, b.index[GROUND], b.index[d.body],
                   u=(1.0, 0.0) if d.coordinate == "x" else (0.0, 1.0))
    return row
