"""Applied forces of a scene: F(t, q, q', u), their Jacobians, spring states and energies.

F (n,) holds the generalized forces of gravity, point forces, torques and springs on the
absolute coordinates (formulation.md, eq. 12); inputs (``InputValues.forces``) come in as
an argument. Sign: ``M q'' + Psi_q^T lam = F``.
"""

from __future__ import annotations

import math

import numpy as np

from ..errors import SolverError
from ..model.scene import GROUND, PointForce, RotationalSpringDamper, Scene, SpringDamper, Torque
from ..model.variables import InputLayout, InputValues

# Forward-difference step (relative) of the force Jacobians: about sqrt(machine epsilon).
FD_STEP = 1.5e-8
# A spring shorter than this (m) has no direction.
MIN_SPRING_LENGTH = 1e-12


def independent_of_state(force) -> bool:
    """A torque, or a force at a centre of mass (no moment arm A(phi) s): its generalized
    force does not depend on (q, q'), only on its value or input."""
    return isinstance(force, Torque) or (isinstance(force, PointForce) and not any(force.point))


class AppliedForces:
    """The applied forces of a scene; ``constant`` (n,) is the part that never changes."""

    def __init__(self, scene: Scene, mass: np.ndarray, layout: InputLayout):
        self.scene, self.nb, self.n = scene, len(scene.bodies), 3 * len(scene.bodies)
        self.index = {b.name: k for k, b in enumerate(scene.bodies)} | {GROUND: self.nb}
        self.layout = layout
        g = np.asarray(scene.gravity, dtype=float)
        self.gravity = np.array([[mass[3 * k] * g[0], mass[3 * k] * g[1], 0.0]
                                 for k in range(self.nb)]).ravel()
        # gravity, constant torques and constant forces at a centre of mass do not depend
        # on the state: summed once (a force off the centre has a moment arm A(phi) s)
        self.constant = self.gravity.copy()
        self.state_forces = []
        for f in scene.forces:
            if independent_of_state(f) and not f.input:
                b = self.index[f.body]
                self.constant[3 * b:3 * b + 3] += (
                    (0.0, 0.0, f.value) if isinstance(f, Torque) else (*f.value, 0.0))
            else:
                self.state_forces.append(f)

    @property
    def is_constant(self) -> bool:
        """F never changes: gravity, constant torques and constant forces at centres only."""
        return not self.state_forces

    def depend_on_state(self) -> bool:
        """F depends on (q, q'): forces off a centre of mass, springs, dampers."""
        return not all(independent_of_state(f) for f in self.scene.forces)

    def _input(self, u: InputValues, name: str) -> np.ndarray:
        return u.forces[self.layout.forces[name]]

    def __call__(self, t: float, q: np.ndarray, qd: np.ndarray, u: InputValues) -> np.ndarray:
        """Generalized applied forces F (n,), one item at a time in scalar arithmetic (which
        beats numpy on 2-vectors)."""
        F = self.constant.copy()
        for f in self.state_forces:
            if isinstance(f, PointForce):
                b = self.index[f.body]
                fx, fy = self._input(u, f.name) if f.input else f.value
                _, _, ax, ay = self.body_point(q, b, f.point)
                F[3 * b:3 * b + 3] += (fx, fy, ax * fy - ay * fx)
            elif isinstance(f, Torque):
                F[3 * self.index[f.body] + 2] += self._input(u, f.name)[0]
            elif isinstance(f, SpringDamper):
                self._add_spring(F, f, t, q, qd, u)
            elif isinstance(f, RotationalSpringDamper):
                self._add_torsion(F, f, q, qd)
        return F

    def _add_spring(self, F, f: SpringDamper, t, q, qd, u) -> None:
        bi, bj = self.index[f.body_i], self.index[f.body_j]
        length, rate, (ux, uy), (aix, aiy), (ajx, ajy) = self.spring_geometry(f, t, q, qd)
        tension = self.spring_tension(f, length, rate, u)
        fx, fy = -tension * ux, -tension * uy  # on body_j: towards body_i when stretched
        if bj < self.nb:
            F[3 * bj:3 * bj + 3] += (fx, fy, ajx * fy - ajy * fx)
        if bi < self.nb:
            F[3 * bi:3 * bi + 3] -= (fx, fy, aix * fy - aiy * fx)

    def _add_torsion(self, F, f: RotationalSpringDamper, q, qd) -> None:
        joint = self.scene.joint(f.joint)
        bi, bj = self.index[joint.body_i], self.index[joint.body_j]
        phi_i, w_i = (q[3 * bi + 2], qd[3 * bi + 2]) if bi < self.nb else (0.0, 0.0)
        phi_j, w_j = (q[3 * bj + 2], qd[3 * bj + 2]) if bj < self.nb else (0.0, 0.0)
        torque = -f.stiffness * (phi_j - phi_i - f.rest_angle) - f.damping * (w_j - w_i)
        if bj < self.nb:
            F[3 * bj + 2] += torque
        if bi < self.nb:
            F[3 * bi + 2] -= torque

    def body_point(self, q, b: int, point):
        """Position of body b's centre (x, y) and its arm A s to a body point (ground: b = nb)."""
        if b >= self.nb:
            return 0.0, 0.0, point[0], point[1]
        x, y, phi = q[3 * b], q[3 * b + 1], q[3 * b + 2]
        c, s = math.cos(phi), math.sin(phi)
        return x, y, c * point[0] - s * point[1], s * point[0] + c * point[1]

    def spring_geometry(self, f: SpringDamper, t, q, qd):
        """Length, its rate, unit vector i->j and the two arms (A s) of a spring-damper."""
        bi, bj = self.index[f.body_i], self.index[f.body_j]
        xi, yi, aix, aiy = self.body_point(q, bi, f.point_i)
        xj, yj, ajx, ajy = self.body_point(q, bj, f.point_j)
        dx, dy = xj + ajx - xi - aix, yj + ajy - yi - aiy
        length = math.hypot(dx, dy)
        if length < MIN_SPRING_LENGTH:
            raise SolverError(f'spring "{f.name}" has zero length: its direction is undefined', t)
        ux, uy = dx / length, dy / length
        vi = qd[3 * bi:3 * bi + 3] if bi < self.nb else (0.0, 0.0, 0.0)
        vj = qd[3 * bj:3 * bj + 3] if bj < self.nb else (0.0, 0.0, 0.0)
        # relative velocity of the points: v_j + w_j rot90(A_j s_j) - v_i - w_i rot90(A_i s_i)
        vx = vj[0] - vj[2] * ajy - vi[0] + vi[2] * aiy
        vy = vj[1] + vj[2] * ajx - vi[1] - vi[2] * aix
        return length, ux * vx + uy * vy, (ux, uy), (aix, aiy), (ajx, ajy)

    def spring_tension(self, f: SpringDamper, length, rate, u: InputValues) -> float:
        """k (L - L0) + c L' minus the actuator input (which pushes the points apart)."""
        tension = f.stiffness * (length - f.rest_length) + f.damping * rate
        if f.actuator_input:
            tension -= self._input(u, f.name)[0]
        return tension

    def spring_states(self, t, q, qd, u: InputValues) -> np.ndarray:
        """(length, rate, tension) of every spring-damper, (ns, 3), in scene order."""
        rows = []
        for f in self.scene.forces:
            if isinstance(f, SpringDamper):
                length, rate, *_ = self.spring_geometry(f, t, q, qd)
                rows.append((length, rate, self.spring_tension(f, length, rate, u)))
        return np.array(rows, dtype=float).reshape(-1, 3)

    def jacobians(self, t: float, q: np.ndarray, qd: np.ndarray, u: InputValues):
        """(dF/dq, dF/dq') (n, n) each, by forward differences; zeros when F is constant."""
        n = self.n
        if not self.depend_on_state():
            return np.zeros((n, n)), np.zeros((n, n))
        F0 = self(t, q, qd, u)
        out = []
        for x in (q, qd):
            D = np.empty((n, n))
            for k in range(n):
                xk = x.copy()
                delta = FD_STEP * max(1.0, abs(x[k]))
                xk[k] += delta
                F = self(t, xk, qd, u) if x is q else self(t, q, xk, u)
                D[:, k] = (F - F0) / delta
            out.append(D)
        return out[0], out[1]

    def potential_energy(self, q: np.ndarray) -> float:
        """Gravity plus springs (J); zero at the origin for gravity."""
        energy = -float(self.gravity @ q)
        for f in self.scene.forces:
            if isinstance(f, SpringDamper):
                bi, bj = self.index[f.body_i], self.index[f.body_j]
                xi, yi, aix, aiy = self.body_point(q, bi, f.point_i)
                xj, yj, ajx, ajy = self.body_point(q, bj, f.point_j)
                stretch = math.hypot(xj + ajx - xi - aix, yj + ajy - yi - aiy) - f.rest_length
                energy += 0.5 * f.stiffness * stretch ** 2
            elif isinstance(f, RotationalSpringDamper):
                joint = self.scene.joint(f.joint)
                bi, bj = self.index[joint.body_i], self.index[joint.body_j]
                phi_i = q[3 * bi + 2] if bi < self.nb else 0.0
                phi_j = q[3 * bj + 2] if bj < self.nb else 0.0
                energy += 0.5 * f.stiffness * (phi_j - phi_i - f.rest_angle) ** 2
        return energy

    def load_potential(self, q: np.ndarray) -> float:
        """Potential of the constant point forces and torques (J): ``-T phi`` for a torque,
        ``-F . (r + A s)`` for a force at a body point."""
        energy = 0.0
        for f in self.scene.forces:
            if isinstance(f, Torque) and not f.input:
                energy -= f.value * q[3 * self.index[f.body] + 2]
            elif isinstance(f, PointForce) and not f.input:
                x, y, ax, ay = self.body_point(q, self.index[f.body], f.point)
                energy -= f.value[0] * (x + ax) + f.value[1] * (y + ay)
        return energy

    def nonconservative_reason(self) -> str | None:
        """Why the energy of this scene is not conserved, or None when it is.

        Conserved: no drivers (they do work through their multipliers), no inputs, no
        dampers; constant point forces and torques are conservative (``load_potential``).
        """
        if self.scene.drivers:
            return f'driver "{self.scene.drivers[0].name}" does work'
        for f in self.scene.forces:
            if getattr(f, "input", False) or getattr(f, "actuator_input", False):
                return f'"{f.name}" is an input'
            if getattr(f, "damping", 0.0):
                return f'"{f.name}" dissipates'
        return None
