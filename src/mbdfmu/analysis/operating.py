"""Operating points and minimal coordinates, shared by the equilibrium solve and the
linearization.

Minimal coordinates by coordinate partitioning (Wehage and Haug 1982): at an operating
point, QR with column pivoting of Psi_q picks ``rank`` dependent coordinates whose columns
are well conditioned; the other ``n - rank`` coordinates are independent and name the
degrees of freedom (``crank.phi``, ``slider.x``). Body angles are preferred as independent
coordinates (their columns are down-weighted in the pivoting), since they are what people
think of as a mechanism's degrees of freedom; when that choice is ill conditioned the
unweighted pivoting decides. Given the independent coordinates z and their rates z', the
dependent ones follow from Psi(q, t) = 0 (Newton on the dependent block) and from
Psi_q q' = nu.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
import scipy.linalg

from ..equations import Equations
from ..errors import SettingError, SolverError
from ..model.motion import ConstantMotion, InputMotion
from ..model.reader import load_scene
from ..model.scene import Scene, has_events
from ..model.variables import InputLayout, InputValues, with_parameters

COORDINATES = ("x", "y", "phi")
RATES = ("vx", "vy", "omega")
# Weight of the angle columns of Psi_q in the pivoting: below 1 so that, among equally good
# choices, x and y become dependent and angles stay independent.
ANGLE_WEIGHT = 0.1
# Condition number of the dependent block above which the angle preference is dropped.
PARTITION_CONDITION_LIMIT = 1e8
# Rank decisions on Psi_q's pivoted R diagonal, relative to the largest.
RANK_RTOL = 1e-9
# Newton iterations for the dependent coordinates, and their stopping increment (relative
# to the mechanism's length scale).
DEPENDENT_MAX_ITER = 50
DEPENDENT_TOL = 1e-15


def prepare(scene: Scene | str | Path, parameters: dict[str, float] | None = None) -> Scene:
    """A scene (loaded from a file or a shipped scene's name) with ``parameters`` set."""
    if not isinstance(scene, Scene):
        scene = load_scene(scene)
    if has_events(scene):     # smooth equations only: a stop or friction would be ignored
        raise SettingError("scene", "equilibrium and linearization do not handle joint "
                           "limits or friction (keys limits, friction)", scene.source)
    return with_parameters(scene, parameters) if parameters else scene


def held_scene(scene: Scene, t: float) -> Scene:
    """The scene with every prescribed motion held at its value at time ``t`` (at rest);
    input-driven drivers stay inputs (at their initial values)."""
    drivers = tuple(d if isinstance(d.motion, InputMotion) else
                    dataclasses.replace(d, motion=ConstantMotion(d.motion.evaluate(t)[0]))
                    for d in scene.drivers)
    return dataclasses.replace(scene, drivers=drivers)


def coordinate_names(scene: Scene) -> list[str]:
    return [f"{b.name}.{c}" for b in scene.bodies for c in COORDINATES]


def rate_names(scene: Scene) -> list[str]:
    return [f"{b.name}.{c}" for b in scene.bodies for c in RATES]


def input_vector(u: InputValues) -> np.ndarray:
    """The inputs as one vector in ``model.variables.inputs`` order: each input driver's
    position, velocity and acceleration, then the force components."""
    return np.concatenate((u.motions.ravel(), u.forces))


def input_values(layout: InputLayout, vector: np.ndarray) -> InputValues:
    k = 3 * len(layout.drivers)
    return InputValues(np.asarray(vector[:k], dtype=float).reshape(-1, 3),
                       np.asarray(vector[k:], dtype=float))


def null_space(J: np.ndarray, n: int) -> np.ndarray:
    """An orthonormal basis (n, n - rank) of the null space of J (m, n)."""
    if J.shape[0] == 0:
        return np.eye(n)
    return scipy.linalg.null_space(J, rcond=RANK_RTOL)


def _pivoted(J: np.ndarray, weights: np.ndarray) -> tuple[np.ndarray, int]:
    _, R, perm = scipy.linalg.qr(J * weights, mode="economic", pivoting=True)
    d = np.abs(np.diag(R))
    rank = int(np.sum(d > RANK_RTOL * max(d.max(initial=0.0), 1e-300)))
    return perm, rank


def partition(J: np.ndarray, n: int) -> tuple[np.ndarray, np.ndarray]:
    """(independent, dependent) coordinate indices at a configuration with Jacobian J."""
    if J.shape[0] == 0:
        return np.arange(n), np.zeros(0, dtype=int)
    # angles preferred as independent; among equals, the first bodies' coordinates
    weights = np.tile([1.0, 1.0, ANGLE_WEIGHT], n // 3) * (1.0 + 1e-3 * np.arange(n) / n)
    for w in (weights, np.ones(n)):
        perm, rank = _pivoted(J, w)
        dependent = np.sort(perm[:rank])
        if np.linalg.cond(J[:, dependent]) < PARTITION_CONDITION_LIMIT:
            break
    independent = np.sort(perm[rank:])
    return independent, dependent


class MinimalCoordinates:
    """The state of a mechanism in independent coordinates at one operating point.

    ``independent`` indices of q (their names in ``names``), chosen at ``q0``; ``state(z,
    z', u)`` gives (q, q') with the dependent coordinates solved from the constraints at
    time ``t``.
    """

    def __init__(self, equations: Equations, t: float, q0: np.ndarray, u0: InputValues):
        self.equations, self.t, self.q0 = equations, t, q0.copy()
        J = equations.constraints(t, q0, u=u0)[1] if equations.m else np.zeros((0, equations.n))
        self.independent, self.dependent = partition(J, equations.n)
        scene = equations.scene
        self.names = [coordinate_names(scene)[i] for i in self.independent]
        self.rate_names = [rate_names(scene)[i] for i in self.independent]

    @property
    def dof(self) -> int:
        return len(self.independent)

    def positions(self, z: np.ndarray, u: InputValues) -> np.ndarray:
        """q with q[independent] = z and the dependent coordinates on Psi(q, t) = 0."""
        eq, dep = self.equations, self.dependent
        q = self.q0.copy()
        q[self.independent] = z
        if not len(dep):
            return q
        tol = DEPENDENT_TOL * eq.length_scale
        for _ in range(DEPENDENT_MAX_ITER):
            Psi, J = eq.constraints(self.t, q, u=u)
            step = np.linalg.lstsq(J[:, dep], -Psi, rcond=None)[0]
            q[dep] += step
            if np.max(np.abs(step)) <= tol:
                return q
        Psi = eq.constraints(self.t, q, u=u)[0]
        if np.max(np.abs(Psi)) > 1e3 * tol:
            raise SolverError("the dependent coordinates cannot be solved near the operating "
                              f"point (constraint residual {np.max(np.abs(Psi)):.3g})", self.t)
        return q

    def velocities(self, q: np.ndarray, zd: np.ndarray, u: InputValues) -> np.ndarray:
        """q' with q'[independent] = z' and Psi_q q' = nu."""
        eq, dep, ind = self.equations, self.dependent, self.independent
        qd = np.zeros(eq.n)
        qd[ind] = zd
        if len(dep):
            _, J, nu, _ = eq.constraints(self.t, q, qd, u)
            qd[dep] = np.linalg.lstsq(J[:, dep], nu - J[:, ind] @ zd, rcond=None)[0]
        return qd

    def state(self, z: np.ndarray, zd: np.ndarray, u: InputValues):
        q = self.positions(z, u)
        return q, self.velocities(q, zd, u)
