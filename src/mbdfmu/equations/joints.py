"""Constraint rows of each joint type and driver, built from three primitives.

Every joint and driver is made of rows of three kinds (formulation.md, eqs. 5-7), each
evaluated for all its rows at once by ``constraints.py`` and ``compiled.py``:

* ``coincidence`` (2 rows): ``r_i + A_i s_i - r_j - A_j s_j = 0``;
* ``line`` (1 row): ``w u_i . (r_j + A_j s_j - r_i - A_i s_i)`` with ``u_i`` a body_i-fixed
  unit vector;
* ``angle`` (1 row): ``w (phi_j - phi_i)``.

A row is the sum of its terms minus its motion c(t) (eq. 24): most rows have one term of
weight w = 1; a coupler's row adds two joints' coordinate terms (eq. 25) and a rolling
joint's no-slip row a line term and an angle term (eq. 27). A joint type is one function
here (``JOINT_ROWS``) that adds its rows and says in which frame its reactions are reported,
plus (if it has a coordinate) one in ``COORDINATE_ROWS`` that adds its coordinate's term
to a row: what drivers and couplers use. ``joint_coordinate`` and ``joint_rate`` give a
coordinate's value and rate. Bodies are indices; the ground is the virtual body ``nb`` at
the origin.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np

from ..model.scene import (GROUND, CouplerJoint, Driver, RevoluteJoint, RollingJoint, Scene,
                           SlotJoint, TranslationalJoint)
from .planar import stacked


class Primitive:
    """Index arrays of one row primitive: bodies, body-fixed vectors, global row numbers and
    the weight of each term (several terms may add up to one row)."""

    def __init__(self):
        self.bi, self.bj, self.si, self.sj, self.u, self.rows, self.w = [], [], [], [], [], [], []

    def add(self, row, bi, bj, si=(0.0, 0.0), sj=(0.0, 0.0), u=(0.0, 0.0), w=1.0):
        self.rows.append(row), self.bi.append(bi), self.bj.append(bj)
        self.si.append(si), self.sj.append(sj), self.u.append(u), self.w.append(float(w))

    def freeze(self) -> None:
        self.rows = np.array(self.rows, dtype=int)
        self.bi = np.array(self.bi, dtype=int)
        self.bj = np.array(self.bj, dtype=int)
        self.si, self.sj, self.u = stacked(self.si, 2), stacked(self.sj, 2), stacked(self.u, 2)
        self.w = np.array(self.w, dtype=float)
        self.n = len(self.bi)
        flat = self.rows.ravel().tolist()
        self.repeats = len(set(flat)) < self.n   # a row with several terms


class ReactionFrame(NamedTuple):
    """The frame of a joint's reported reactions: ``body``'s frame turned by ``angle``;
    ``point`` (body_j-fixed) is where the reaction force acts, for the torque. (A named
    tuple: one is made per joint at every setup, cheaper than a frozen dataclass.)"""

    body: int
    angle: float
    point: tuple[float, float] = (0.0, 0.0)


class RowBuilder:
    """Adds rows in scene order: numbers them, labels them, keeps their constant offsets.

    ``poses0`` are the bodies' initial (x, y, angle) as the scene gives them: the reference
    of the rows that hold a value "at its initial value"."""

    def __init__(self, scene: Scene):
        self.scene = scene
        self.index = {b.name: k for k, b in enumerate(scene.bodies)} | {GROUND: len(scene.bodies)}
        self.poses0 = ({b.name: (*b.position, b.angle) for b in scene.bodies}
                       | {GROUND: (0.0, 0.0, 0.0)})
        self.angle0 = {name: pose[2] for name, pose in self.poses0.items()}
        self.coincidence, self.line, self.angle = Primitive(), Primitive(), Primitive()
        self.m = 0
        self.labels: list[str] = []
        self.offsets: list[float] = []

    def bodies(self, item) -> tuple[int, int]:
        return self.index[item.body_i], self.index[item.body_j]

    def pair_poses(self, item) -> tuple[tuple, tuple]:
        """The initial poses of an item's body_i and body_j."""
        return self.poses0[item.body_i], self.poses0[item.body_j]

    def take(self, labels: list[str], offsets: list[float]) -> int:
        """Reserve len(labels) rows; returns the first."""
        first = self.m
        self.m += len(labels)
        self.labels += labels
        self.offsets += offsets
        return first


def _unit(axis) -> np.ndarray:
    return np.asarray(axis, dtype=float) / math.hypot(*axis)


def _normal(axis) -> tuple[float, float]:
    """The unit axis turned by +90 degrees."""
    u = _unit(axis)
    return (-u[1], u[0])


def _axis_angle(axis) -> float:
    return math.atan2(axis[1], axis[0])


def revolute_rows(b: RowBuilder, j: RevoluteJoint) -> ReactionFrame:
    bi, bj = b.bodies(j)
    m = b.take([f'joint "{j.name}" (x)', f'joint "{j.name}" (y)'], [0.0, 0.0])
    b.coincidence.add((m, m + 1), bi, bj, j.point_i, j.point_j)
    return ReactionFrame(bj, j.frame_angle, j.point_j)


def translational_rows(b: RowBuilder, j: TranslationalJoint) -> ReactionFrame:
    """The normal offset of point_j from the axis line is zero; the relative angle keeps its
    initial value."""
    bi, bj = b.bodies(j)
    m = b.take([f'joint "{j.name}" (normal)', f'joint "{j.name}" (rotation)'],
               [0.0, b.angle0[j.body_j] - b.angle0[j.body_i]])
    b.line.add(m, bi, bj, j.point_i, j.point_j, _normal(j.axis_i))
    b.angle.add(m + 1, bi, bj)
    return ReactionFrame(bi, _axis_angle(j.axis_i) + j.frame_angle, j.point_j)


def slot_rows(b: RowBuilder, j: SlotJoint) -> ReactionFrame:
    """The pin point_j stays on the slot's line (formulation.md, eq. 26): the translational
    joint's normal row without its angle row."""
    bi, bj = b.bodies(j)
    m = b.take([f'joint "{j.name}" (normal)'], [0.0])
    b.line.add(m, bi, bj, j.point_i, j.point_j, _normal(j.axis_i))
    return ReactionFrame(bi, _axis_angle(j.axis_i) + j.frame_angle, j.point_j)


def rolling_rows(b: RowBuilder, j: RollingJoint) -> ReactionFrame:
    """The disc's centre at ``radius`` on the left of the line, and no slip (formulation.md,
    eq. 27): ``u . (r_j - r_i - A_i s_i) + radius (phi_j - phi_i)`` keeps its initial value."""
    bi, bj = b.bodies(j)
    pi, pj = b.poses0[j.body_i], b.poses0[j.body_j]
    u = _unit(j.axis_i)
    rolled = (_line_value(pi, pj, j.point_i, (0.0, 0.0), u)
              + j.radius * (pj[2] - pi[2]))
    m = b.take([f'joint "{j.name}" (normal)', f'joint "{j.name}" (rolling)'],
               [j.radius, rolled])
    b.line.add(m, bi, bj, j.point_i, (0.0, 0.0), _normal(j.axis_i))
    b.line.add(m + 1, bi, bj, j.point_i, (0.0, 0.0), tuple(u))
    b.angle.add(m + 1, bi, bj, w=j.radius)
    return ReactionFrame(bi, _axis_angle(j.axis_i))


def coupler_rows(b: RowBuilder, j: CouplerJoint) -> None:
    """``q_j - ratio q_i`` keeps its initial value (formulation.md, eq. 25): joint_j's
    coordinate term with weight 1 plus joint_i's with weight -ratio. No reaction frame: its
    output is the effort, -lam."""
    ji, jj = b.scene.joint(j.joint_i), b.scene.joint(j.joint_j)
    start = (joint_coordinate(jj, *b.pair_poses(jj))
             - j.ratio * joint_coordinate(ji, *b.pair_poses(ji)))
    row = b.take([f'coupler "{j.name}"'], [start])
    COORDINATE_ROWS[type(jj)](b, jj, row)
    COORDINATE_ROWS[type(ji)](b, ji, row, -j.ratio)
    return None


def revolute_coordinate(b: RowBuilder, j: RevoluteJoint, row: int, w: float = 1.0) -> None:
    """w (phi_j - phi_i) added to ``row``."""
    b.angle.add(row, *b.bodies(j), w=w)


def translational_coordinate(b: RowBuilder, j: TranslationalJoint, row: int,
                             w: float = 1.0) -> None:
    """w (r_Pj - r_Pi) . u_i added to ``row``."""
    b.line.add(row, *b.bodies(j), j.point_i, j.point_j, tuple(_unit(j.axis_i)), w=w)


JOINT_ROWS = {RevoluteJoint: revolute_rows, TranslationalJoint: translational_rows,
              SlotJoint: slot_rows, RollingJoint: rolling_rows, CouplerJoint: coupler_rows}
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


# ----------------------------------------------------------------------------- coordinates

def _point(pose, s) -> np.ndarray:
    c, sn = math.cos(pose[2]), math.sin(pose[2])
    return np.array([pose[0] + c * s[0] - sn * s[1], pose[1] + sn * s[0] + c * s[1]])


def _line_value(pose_i, pose_j, s_i, s_j, u) -> float:
    """(r_j + A_j s_j - r_i - A_i s_i) . A_i u (eq. 6) at poses (x, y, angle)."""
    c, sn = math.cos(pose_i[2]), math.sin(pose_i[2])
    axis = np.array([c * u[0] - sn * u[1], sn * u[0] + c * u[1]])
    return float(axis @ (_point(pose_j, s_j) - _point(pose_i, s_i)))


def joint_coordinate(joint, pose_i, pose_j) -> float:
    """A joint's coordinate at the poses (x, y, angle) of its bodies: ``phi_j - phi_i``
    (revolute, rad) or ``(r_Pj - r_Pi) . u_i`` (translational, m)."""
    if isinstance(joint, RevoluteJoint):
        return float(pose_j[2] - pose_i[2])
    return _line_value(pose_i, pose_j, joint.point_i, joint.point_j, _unit(joint.axis_i))


def joint_rate(joint, pose_i, pose_j, velocity_i, velocity_j) -> float:
    """The coordinate's time derivative; velocities (vx, vy, omega). For a translational
    joint ``d/dt (u_i . d) = omega_i rot90(u_i) . d + u_i . d'`` (eq. 3)."""
    if isinstance(joint, RevoluteJoint):
        return float(velocity_j[2] - velocity_i[2])
    u = _unit(joint.axis_i)
    c, sn = math.cos(pose_i[2]), math.sin(pose_i[2])
    axis = np.array([c * u[0] - sn * u[1], sn * u[0] + c * u[1]])
    d = _point(pose_j, joint.point_j) - _point(pose_i, joint.point_i)
    v = [np.asarray(vel[:2]) + vel[2] * np.array([pose[1] - p[1], p[0] - pose[0]])
         for pose, vel, p in ((pose_i, velocity_i, _point(pose_i, joint.point_i)),
                              (pose_j, velocity_j, _point(pose_j, joint.point_j)))]
    return float(velocity_i[2] * (axis[0] * d[1] - axis[1] * d[0]) + axis @ (v[1] - v[0]))
