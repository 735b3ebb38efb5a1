"""End stops and Coulomb friction in the equations: one contact mode at a time.

A mode says, for each joint with ``limits`` or ``friction``, whether it rests against a
stop or sticks (its coordinate then held by a constant driver row: ``model.limits``) and in
which direction each sliding joint slides. ``ModeEquations`` are the ``Equations`` of the
scene with those rows, plus the sliding friction as a generalized force on each sliding
joint's coordinate (formulation.md eqs. 29-31). The events that change the mode are found by
``integrators/events.py``.
"""

from __future__ import annotations

import math

import numpy as np

from ..errors import SolverError
from ..model.scene import RevoluteJoint, Scene
from .dynamics import Equations
from .sparsity import schur_solve

# Fixed-point iterations of the sliding force against the reactions it changes (eq. 31),
# and their relative tolerance.
FRICTION_MAX_ITER = 60
FRICTION_TOL = 1e-14


def body_poses(q: np.ndarray, index: int | None) -> tuple[float, float, float]:
    """(x, y, angle) of body ``index`` in q, the ground's (None) at the origin."""
    return (0.0, 0.0, 0.0) if index is None else tuple(q[3 * index:3 * index + 3].tolist())


class Coordinate:
    """A joint's coordinate (scene contract: ``phi_j - phi_i`` or ``(r_Pj - r_Pi) . u_i``),
    its gradient in q and its rate, evaluated from q and q' (eqs. 29-30)."""

    def __init__(self, scene: Scene, joint):
        index = {b.name: k for k, b in enumerate(scene.bodies)}
        self.joint = joint
        self.i, self.j = index.get(joint.body_i), index.get(joint.body_j)
        self.revolute = isinstance(joint, RevoluteJoint)
        if not self.revolute:
            u = np.asarray(joint.axis_i, dtype=float)
            self.u = tuple((u / math.hypot(*u)).tolist())
        self.n = 3 * len(scene.bodies)

    def gradient(self, q: np.ndarray) -> np.ndarray:
        g = np.zeros(self.n)
        if self.revolute:
            if self.j is not None:
                g[3 * self.j + 2] += 1.0
            if self.i is not None:
                g[3 * self.i + 2] -= 1.0
            return g
        on_i, on_j = self._translational_entries(q)
        if self.j is not None:
            g[3 * self.j:3 * self.j + 3] = on_j
        if self.i is not None:
            g[3 * self.i:3 * self.i + 3] += on_i
        return g

    def _translational_entries(self, q: np.ndarray):
        """The gradient's entries on body i's (x, y, angle) and on body j's."""
        (xi, yi, ai), (xj, yj, aj) = body_poses(q, self.i), body_poses(q, self.j)
        ci, si, cj, sj = math.cos(ai), math.sin(ai), math.cos(aj), math.sin(aj)
        u0, u1 = self.u
        a0, a1 = ci * u0 - si * u1, si * u0 + ci * u1          # the axis, turned with body i
        (pi0, pi1), (pj0, pj1) = self.joint.point_i, self.joint.point_j
        ai0, ai1 = ci * pi0 - si * pi1, si * pi0 + ci * pi1     # the points, turned
        aj0, aj1 = cj * pj0 - sj * pj1, sj * pj0 + cj * pj1
        d0, d1 = xj + aj0 - xi - ai0, yj + aj1 - yi - ai1
        return ((-a0, -a1, (-a1 * d0 + a0 * d1) - (a0 * -ai1 + a1 * ai0)),
                (a0, a1, a0 * -aj1 + a1 * aj0))

    def value(self, q: np.ndarray) -> float:
        if self.revolute:
            return body_poses(q, self.j)[2] - body_poses(q, self.i)[2]
        (xi, yi, ai), (xj, yj, aj) = body_poses(q, self.i), body_poses(q, self.j)
        ci, si, cj, sj = math.cos(ai), math.sin(ai), math.cos(aj), math.sin(aj)
        (pi0, pi1), (pj0, pj1) = self.joint.point_i, self.joint.point_j
        dx = xj + cj * pj0 - sj * pj1 - xi - ci * pi0 + si * pi1
        dy = yj + sj * pj0 + cj * pj1 - yi - si * pi0 - ci * pi1
        return (ci * self.u[0] - si * self.u[1]) * dx + (si * self.u[0] + ci * self.u[1]) * dy

    def rate(self, q: np.ndarray, qd: np.ndarray) -> float:
        if self.revolute:      # the gradient's two entries: the angles' rates
            return body_poses(qd, self.j)[2] - body_poses(qd, self.i)[2]
        on_i, on_j = self._translational_entries(q)
        vi, vj = body_poses(qd, self.i), body_poses(qd, self.j)
        return (on_j[0] * vj[0] + on_j[1] * vj[1] + on_j[2] * vj[2]
                + on_i[0] * vi[0] + on_i[1] * vi[1] + on_i[2] * vi[2])


def friction_bound(eq: Equations, k: int, q: np.ndarray, lam: np.ndarray) -> float:
    """Eq. 31: the friction magnitude joint ``k`` (scene index) can give, from its reaction."""
    joint = eq.scene.joints[k]
    f = joint.friction
    fx, fy, _ = eq.reactions(q, lam)[k]
    if isinstance(joint, RevoluteJoint):
        return f.coulomb + f.coefficient * f.radius * math.hypot(fx, fy)
    # the normal reaction: the joint frame is the axis turned by frame_angle
    normal = fx * math.sin(joint.frame_angle) + fy * math.cos(joint.frame_angle)
    return f.coulomb + f.coefficient * abs(normal)


class _PlusFriction:
    """The scene's applied forces plus the sliding friction of the current evaluation.

    Never constant: the friction follows the state."""

    is_constant = False

    def __init__(self, base, sliding: bool):
        self.base, self.extra, self.sliding = base, None, sliding

    def __getattr__(self, name):
        return getattr(self.base, name)

    def __call__(self, t, q, qd, u):
        F = self.base(t, q, qd, u)
        return F if self.extra is None else F + self.extra

    def depend_on_state(self) -> bool:
        return True

    def nonconservative_reason(self) -> str | None:
        return "Coulomb friction slides" if self.sliding else self.base.nonconservative_reason()


class ModeEquations(Equations):
    """``Equations`` of a mode's scene (its held coordinates as driver rows after the
    scene's own rows) with ``sliding``: {joint index: direction +1 or -1} sliding joints.

    The friction force of a sliding joint, ``-direction (F0 + mu r |F|)`` (eq. 31), depends
    on the reactions it changes: eq. (14) is solved with a guess, the force updated from
    the reactions, until it no longer changes (``last_friction`` keeps it). The C kernel
    iterates in C (``ckernel/friction.h``), the same way."""

    def __init__(self, scene: Scene, sliding: dict[int, int], *, kernel: str | None = None):
        self.sliding = dict(sliding)          # before the C kernel, which reads it
        super().__init__(scene, kernel=kernel)
        self.coordinates = {k: Coordinate(scene, scene.joints[k]) for k in self.sliding}
        self.direction = np.array([float(d) for d in self.sliding.values()])
        self._last_friction = -self.direction * np.array(
            [scene.joints[k].friction.coulomb for k in self.sliding])
        self.applied = _PlusFriction(self.applied, bool(self.sliding))

    def sliding_forces(self) -> np.ndarray:
        return np.array(self.last_friction, dtype=float)

    @property
    def last_friction(self) -> np.ndarray:
        """The friction forces of the last evaluation (N, or N m on revolute joints)."""
        return self._last_friction if self.ckernel is None else self.ckernel.sliding_forces

    @last_friction.setter
    def last_friction(self, value: np.ndarray) -> None:
        if self.ckernel is None:
            self._last_friction = value
        else:
            self.ckernel.sliding_forces[:] = value

    def accelerations(self, t, q, qd, u=None, *, baumgarte=None):
        if not self.sliding:
            return super().accelerations(t, q, qd, u, baumgarte=baumgarte)
        u = self._u(u)
        done = self.kernel_accelerations(t, q, qd, u) if baumgarte is None else None
        if done is not None:            # the C kernel iterates the friction itself
            return done
        grads = [c.gradient(q) for c in self.coordinates.values()]
        f = self.last_friction.copy()
        for _ in range(FRICTION_MAX_ITER):
            self.applied.extra = sum(fk * g for fk, g in zip(f, grads))
            try:
                qdd, lam = self.python_accelerations(t, q, qd, u, baumgarte=baumgarte)
            finally:
                self.applied.extra = None
            new = -self.direction * np.array([friction_bound(self, k, q, lam)
                                              for k in self.sliding])
            if np.all(np.abs(new - f) <= FRICTION_TOL * (1.0 + np.abs(new))):
                self.last_friction = f
                return qdd, lam
            f = new
        names = ", ".join(self.scene.joints[k].name for k in self.sliding)
        raise SolverError(f"the sliding friction of {names} does not converge against its "
                          "reactions (coefficient x radius too large for this mechanism)", t)


def velocity_jump(eq: Equations, t: float, q: np.ndarray, qd: np.ndarray, gradient: np.ndarray,
                  rate_after: float, u=None) -> np.ndarray:
    """Eq. 32: the q' closest in kinetic energy to ``qd`` that meets ``eq``'s constraints and
    gives the coordinate of ``gradient`` the rate ``rate_after`` (Newton's impact law)."""
    if eq.m:
        _, J, nu, _ = eq.constraints(t, q, qd, u)
        J, target = np.vstack((J, gradient)), np.append(nu, rate_after)
    else:
        J, target = gradient[None, :], np.array([rate_after])
    return qd - eq.minv * (J.T @ schur_solve(J, eq.minv, J @ qd - target))
