"""The equations of a scene: constraints, Jacobian, gamma, forces, accelerations, reactions.

Coordinates are the seed's absolute coordinates: ``q = [x_1, y_1, phi_1, x_2, ...]``, the
centre of mass and rotation angle of each body (``3 * nb`` entries). The ground is not in
``q``; internally it is a virtual last body at the origin so that one formula serves every
joint, and its three columns are dropped from the Jacobian.

Every joint and driver is built from three constraint primitives, each vectorised over all
its rows (no Python loop per joint):

* ``coincidence`` (2 rows): ``r_i + A_i s_i - r_j - A_j s_j = 0``  (revolute joint);
* ``line`` (1 row): ``u_i . (r_j + A_j s_j - r_i - A_i s_i) - c(t) = 0`` with ``u_i`` a
  body_i-fixed unit vector (translational joint's normal with c = 0; slide driver with the
  axis and c = f(t); body x / y drivers with body_i = ground);
* ``angle`` (1 row): ``phi_j - phi_i - c(t) = 0`` (translational joint's rotation lock;
  revolute driver; body angle driver).

Sign convention (seed eq. 14): ``M q'' + Psi_q^T lam = F``, so the constraint force on the
bodies is ``-Psi_q^T lam``; velocity equation ``Psi_q q' = nu`` (``nu = -Psi_t``);
acceleration equation ``Psi_q q'' = gamma``.
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass

import numpy as np

from . import kernel_jit
from .errors import InputError, SolverError
from .linalg import RANK_TOLERANCE, JacobianPattern, schur_solve
from .motion import InputMotion
from .scene import (GROUND, PointForce, RotationalSpringDamper, Scene, SpringDamper, Torque,
                    _driver_unit)


@dataclass(frozen=True)
class Variable:
    """A named scalar of a simulation: an output or an input, with unit and meaning."""

    name: str
    unit: str
    description: str


KERNELS = ("numpy", "numba")


def _choose_kernel(kernel: str | None) -> str:
    """The constraint kernel: as asked, else ``$MBDFMU_KERNEL``, else numba when installed."""
    kernel = kernel or os.environ.get("MBDFMU_KERNEL") or "auto"
    if kernel == "auto":
        return "numba" if kernel_jit.available() else "numpy"
    if kernel not in KERNELS:
        raise InputError(f"unknown kernel {kernel!r}: choose one of {', '.join(KERNELS)} or auto")
    if kernel == "numba" and kernel_jit.numba is None:
        raise InputError('kernel "numba" needs numba: pip install "mbdfmu[jit]"')
    return kernel


def _independent_of_state(force) -> bool:
    """A torque, or a force at a centre of mass (no moment arm A(phi) s): its generalized
    force does not depend on (q, q'), only on its value or input."""
    return isinstance(force, Torque) or (isinstance(force, PointForce) and not any(force.point))


def _rot90(v: np.ndarray) -> np.ndarray:
    """Rotate 2-vectors (..., 2) by +90 degrees: B s = rot90(A s)."""
    out = np.empty_like(v)
    out[..., 0] = -v[..., 1]
    out[..., 1] = v[..., 0]
    return out


def _rotate(v: np.ndarray, c: np.ndarray, s: np.ndarray) -> np.ndarray:
    """A(phi) v for stacked 2-vectors v (k, 2) and angles given by c = cos, s = sin (k,)."""
    out = np.empty_like(v)
    out[:, 0] = c * v[:, 0] - s * v[:, 1]
    out[:, 1] = s * v[:, 0] + c * v[:, 1]
    return out


def _dot(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Row-wise dot products of (k, 2) arrays."""
    return a[:, 0] * b[:, 0] + a[:, 1] * b[:, 1]


class _Rows:
    """Index arrays of one constraint primitive: bodies, body-fixed data, global rows."""

    def __init__(self):
        self.bi, self.bj, self.si, self.sj, self.u, self.rows = [], [], [], [], [], []

    def add(self, row, bi, bj, si=(0.0, 0.0), sj=(0.0, 0.0), u=(0.0, 0.0)):
        self.rows.append(row), self.bi.append(bi), self.bj.append(bj)
        self.si.append(si), self.sj.append(sj), self.u.append(u)

    def freeze(self):
        self.rows = np.array(self.rows, dtype=int)
        self.bi = np.array(self.bi, dtype=int)
        self.bj = np.array(self.bj, dtype=int)
        self.si = np.array(self.si, dtype=float).reshape(-1, 2)
        self.sj = np.array(self.sj, dtype=float).reshape(-1, 2)
        self.u = np.array(self.u, dtype=float).reshape(-1, 2)
        self.n = len(self.bi)


class System:
    """Equations of motion of a scene in the seed's absolute coordinates.

    Attributes: ``n`` coordinates, ``m`` constraint rows, ``mass`` (n,) diagonal of M,
    ``row_labels`` naming each constraint row, ``outputs`` / ``inputs`` variable tables.
    Run-time inputs are callables set in ``driver_signals[name](t) -> (f, f', f'')`` and
    ``force_signals[name](t) -> values``.
    """

    def __init__(self, scene: Scene, *, kernel: str | None = None):
        self.scene = scene
        nb = len(scene.bodies)
        self.nb, self.n = nb, 3 * nb
        idx = {b.name: k for k, b in enumerate(scene.bodies)}
        idx[GROUND] = nb  # the virtual ground body
        self._idx = idx
        angle0 = {b.name: b.angle for b in scene.bodies} | {GROUND: 0.0}

        self.mass = np.array([[b.mass, b.mass, b.inertia] for b in scene.bodies]).ravel()
        self.minv = 1.0 / self.mass
        g = np.asarray(scene.gravity, dtype=float)
        self.gravity = g
        self.F_gravity = np.array([[b.mass * g[0], b.mass * g[1], 0.0] for b in scene.bodies]).ravel()

        # Constraint rows, in scene order: each joint, then each driver.
        self.coincidence, self.line, self.angle = _Rows(), _Rows(), _Rows()
        self.row_labels: list[str] = []
        self.joint_rows = []           # (nj, 2) rows of each joint
        self.joint_frame = []          # (body index defining the frame, constant angle)
        self.joint_bj = []
        c_const = []                   # constant offsets c of each row
        m = 0
        for j in scene.joints:
            bi, bj = idx[j.body_i], idx[j.body_j]
            if j.type == "revolute":
                self.coincidence.add((m, m + 1), bi, bj, j.point_i, j.point_j)
                self.joint_frame.append((bj, j.frame_angle))
            else:
                axis = np.asarray(j.axis_i) / math.hypot(*j.axis_i)
                normal = (-axis[1], axis[0])
                self.line.add(m, bi, bj, j.point_i, j.point_j, normal)
                self.angle.add(m + 1, bi, bj)
                self.joint_frame.append((bi, math.atan2(axis[1], axis[0]) + j.frame_angle))
            c_const += [0.0, 0.0 if j.type == "revolute" else angle0[j.body_j] - angle0[j.body_i]]
            self.row_labels += [f'joint "{j.name}" ({k})' for k in
                                (("x", "y") if j.type == "revolute" else ("normal", "rotation"))]
            self.joint_rows.append((m, m + 1))
            self.joint_bj.append(bj)
            m += 2
        self.driver_rows, self.driver_motions = [], []
        for d in scene.drivers:
            if d.joint is not None:
                jt = scene.joint(d.joint)
                bi, bj = idx[jt.body_i], idx[jt.body_j]
                if jt.type == "revolute":
                    self.angle.add(m, bi, bj)
                else:
                    axis = np.asarray(jt.axis_i) / math.hypot(*jt.axis_i)
                    self.line.add(m, bi, bj, jt.point_i, jt.point_j, tuple(axis))
            elif d.coordinate == "angle":
                self.angle.add(m, nb, idx[d.body])
            else:
                self.line.add(m, nb, idx[d.body], u=(1.0, 0.0) if d.coordinate == "x" else (0.0, 1.0))
            c_const.append(0.0)
            self.row_labels.append(f'driver "{d.name}"')
            self.driver_rows.append(m)
            self.driver_motions.append(d.motion)
            m += 1
        self.m = m
        for prim in (self.coincidence, self.line, self.angle):
            prim.freeze()
        self.c_const = np.array(c_const, dtype=float)
        self.joint_rows = np.array(self.joint_rows, dtype=int).reshape(-1, 2)
        self.joint_bj = np.array(self.joint_bj, dtype=int)
        self.joint_frame_body = np.array([b for b, _ in self.joint_frame], dtype=int)
        self.joint_frame_angle = np.array([a for _, a in self.joint_frame], dtype=float)
        self.driver_rows = np.array(self.driver_rows, dtype=int)
        self._no_motion = (self.c_const, np.zeros(self.m), np.zeros(self.m))
        self._no_motion_steps = np.array([self._no_motion] * 3)
        for a in (*self._no_motion, self._no_motion_steps):
            a.flags.writeable = False
        self._build_jacobian_pattern()
        # the body_j blocks of each joint's rows in Psi_q's values (reactions, eqs. 9-10)
        self._reaction_entries = self.jacobian_pattern.entries(
            self.joint_rows[:, :, None],
            3 * self.joint_bj[:, None, None] + np.arange(3)[None, None, :])
        self.kernel = _choose_kernel(kernel)
        p = self.jacobian_pattern
        self._jit_pattern = (p.rows, p.cols, p.pair_a, p.pair_b, p.pair_minv, p.band_index,
                             p.perm, p.kd)

        self.driver_signals: dict[str, object] = {}
        self.force_signals: dict[str, object] = {}
        self._forces = [(f, idx.get(getattr(f, "body", None) or "", -1)) for f in scene.forces]
        # gravity, constant torques and constant forces at a centre of mass do not depend
        # on the state: summed once (a force off the centre has a moment arm A(phi) s)
        self._F_constant = self.F_gravity.copy()
        self._state_forces = []
        for f, b in self._forces:
            if _independent_of_state(f) and not f.input:
                self._F_constant[3 * b:3 * b + 3] += (
                    (0.0, 0.0, f.value) if isinstance(f, Torque) else (*f.value, 0.0))
            else:
                self._state_forces.append((f, b))
        self.length_scale = max([1.0] + [abs(v) for b in scene.bodies for v in b.position])
        self.outputs = self._output_table()
        self.inputs = self._input_table()

    # ------------------------------------------------------------------ Jacobian layout

    def _build_jacobian_pattern(self):
        """Psi_q's nonzeros once (``linalg.JacobianPattern``); per evaluation only values.

        The value vector is [constant entries | coincidence angle columns (4 blocks of one
        entry per joint) | line rows (6 blocks)], columns counting the ground's three.
        """
        c, l, a = self.coincidence, self.line, self.angle
        r0, r1 = (c.rows[:, 0], c.rows[:, 1]) if c.n else (np.zeros(0, int),) * 2
        rows = [r0, r1, r0, r1, a.rows, a.rows,                      # constants
                r0, r1, r0, r1,                                      # coincidence, phi
                *([l.rows] * 6)]                                     # line rows
        cols = [3 * c.bi, 3 * c.bi + 1, 3 * c.bj, 3 * c.bj + 1, 3 * a.bj + 2, 3 * a.bi + 2,
                3 * c.bi + 2, 3 * c.bi + 2, 3 * c.bj + 2, 3 * c.bj + 2,
                3 * l.bi, 3 * l.bi + 1, 3 * l.bi + 2, 3 * l.bj, 3 * l.bj + 1, 3 * l.bj + 2]
        self._jac_constants = np.concatenate(
            [np.ones(2 * c.n), -np.ones(2 * c.n), np.ones(a.n), -np.ones(a.n)])
        self._jac_nnz = 4 * c.n + 6 * l.n + self._jac_constants.size
        self.jacobian_pattern = JacobianPattern(np.concatenate(rows), np.concatenate(cols),
                                                self.m, self.n, self.minv)
        # every body-fixed vector that rotates with its body, rotated in one go:
        # coincidence s_i, s_j; line s_i, s_j, u_i
        self._points = np.concatenate([c.si, c.sj, l.si, l.sj, l.u]).reshape(-1, 2)
        self._point_body = np.concatenate([c.bi, c.bj, l.bi, l.bj, l.bi]).astype(np.intp)
        ends = np.cumsum([c.n, c.n, l.n, l.n, l.n])
        self._point_slices = [slice(a, b) for a, b in zip(np.r_[0, ends[:-1]], ends)]
        self._jit_args = (c.rows.reshape(-1, 2), c.bi, c.bj, c.si, c.sj,
                          l.rows, l.bi, l.bj, l.si, l.sj, l.u, a.rows, a.bi, a.bj)

    # ------------------------------------------------------------------ kinematics

    def _poses(self, q):
        """Positions (nb+1, 2), cos and sin of angles (nb+1,), ground last."""
        Q = np.zeros((self.nb + 1, 3))
        Q[: self.nb] = q.reshape(-1, 3)
        return Q[:, :2], np.cos(Q[:, 2]), np.sin(Q[:, 2]), Q[:, 2]

    def _velocities(self, qd):
        V = np.zeros((self.nb + 1, 3))
        V[: self.nb] = qd.reshape(-1, 3)
        return V[:, :2], V[:, 2]

    def motion_values(self, t: float):
        """(c, c', c'') of every constraint row at time t (seed: Psi depends on t by drivers).

        Read-only arrays; without drivers the same three every time."""
        if not self.driver_motions:
            return self._no_motion
        c = self.c_const.copy()
        cd = np.zeros(self.m)
        cdd = np.zeros(self.m)
        for row, motion, d in zip(self.driver_rows, self.driver_motions, self.scene.drivers):
            if isinstance(motion, InputMotion):
                signal = self.driver_signals.get(d.name)
                f = signal(t) if signal is not None else (motion.initial, 0.0, 0.0)
            else:
                f = motion.evaluate(t)
            c[row], cd[row], cdd[row] = f
        for a in (c, cd, cdd):      # one array type for the compiled kernel (one compilation)
            a.flags.writeable = False
        return c, cd, cdd

    def constraints(self, t: float, q: np.ndarray, qd: np.ndarray | None = None,
                    *, extended: bool = False, sparse: bool = False):
        """Psi (m,), Psi_q (m, n) and, with qd, nu (m,) and gamma (m,) (seed eq. 14 rhs).

        Psi_q is a dense array, or with ``sparse`` for a large mechanism a
        ``linalg.SparseJacobian`` (supports ``J @ x``, ``J.T @ y`` and ``schur_solve``).
        With ``extended`` a dense Psi_q keeps the ground's three columns (for reactions).
        """
        Psi, data, nu, gamma = self.constraint_values(t, q, qd)
        pattern = self.jacobian_pattern
        J = pattern.dense_with_ground(data) if extended else pattern.jacobian(data, sparse)
        if qd is None:
            return Psi, J
        return Psi, J, nu, gamma

    def constraint_values(self, t: float, q: np.ndarray, qd: np.ndarray | None = None):
        """Psi (m,), Psi_q's values on ``jacobian_pattern`` (its ``data``), nu and gamma
        (None without qd): ``constraints`` without building Psi_q."""
        if self.kernel == "numba":
            return self._constraint_values_compiled(t, q, qd)
        r, cs, sn, phi = self._poses(q)
        Psi = np.empty(self.m)
        data = np.empty(self._jac_nnz)
        k = self._jac_constants.size
        data[:k] = self._jac_constants
        with_v = qd is not None
        if with_v:
            v, w = self._velocities(qd)
            gamma = np.zeros(self.m)
        c, l, a = self.coincidence, self.line, self.angle
        pb = self._point_body
        rotated = _rotate(self._points, cs[pb], sn[pb])
        Asi_c, Asj_c, Asi_l, Asj_l, u = (rotated[s] for s in self._point_slices)
        if c.n:
            Psi[c.rows] = r[c.bi] + Asi_c - r[c.bj] - Asj_c
            # d(A s)/dphi = B s = rot90(A s)
            data[k:k + 4 * c.n] = np.concatenate([-Asi_c[:, 1], Asi_c[:, 0],
                                                  Asj_c[:, 1], -Asj_c[:, 0]])
            k += 4 * c.n
            if with_v:
                gamma[c.rows] = (Asi_c * (w[c.bi] ** 2)[:, None]
                                 - Asj_c * (w[c.bj] ** 2)[:, None])
        if l.n:
            d = r[l.bj] + Asj_l - r[l.bi] - Asi_l
            Psi[l.rows] = _dot(u, d)
            ru = _rot90(u)
            data[k:] = np.concatenate([-u[:, 0], -u[:, 1],
                                       _dot(ru, d) - _dot(u, _rot90(Asi_l)),
                                       u[:, 0], u[:, 1], _dot(u, _rot90(Asj_l))])
            if with_v:
                wi, wj = w[l.bi], w[l.bj]
                dd = v[l.bj] + wj[:, None] * _rot90(Asj_l) - v[l.bi] - wi[:, None] * _rot90(Asi_l)
                gamma[l.rows] = (wi ** 2 * _dot(u, d)
                                 - 2.0 * wi * _dot(ru, dd)
                                 + _dot(u, Asj_l * (wj ** 2)[:, None]
                                             - Asi_l * (wi ** 2)[:, None]))
        if a.n:
            Psi[a.rows] = phi[a.bj] - phi[a.bi]
        cval, cd, cdd = self.motion_values(t)
        Psi -= cval
        if not with_v:
            return Psi, data, None, None
        return Psi, data, cd, gamma + cdd

    def _constraint_values_compiled(self, t, q, qd):
        """``constraint_values`` through the numba kernel (``kernel_jit.py``), same results."""
        n = self.n
        qe = np.zeros(n + 3)
        qe[:n] = q
        with_v = qd is not None
        qde = np.zeros(n + 3)
        if with_v:
            qde[:n] = qd
        cval, cd, cdd = self.motion_values(t)
        Psi, gamma = np.empty(self.m), np.empty(self.m)
        data = np.empty(self._jac_nnz)
        data[:self._jac_constants.size] = self._jac_constants
        kernel_jit.constraint_terms(qe, qde, cval, *self._jit_args, Psi, data, gamma)
        if not with_v:
            return Psi, data, None, None
        return Psi, data, cd, gamma + cdd

    def constraint_hessian(self, q: np.ndarray, mu: np.ndarray) -> np.ndarray:
        """Geometric stiffness ``d(Psi_q^T mu)/dq = sum_k mu_k d2 Psi_k / dq2`` (n, n), mu fixed.

        The tangent term of the constraint forces that implicit index-3 methods need in their
        iteration matrices. Coincidence rows: ``d2/dphi_i2 = -A_i s_i``, ``d2/dphi_j2 =
        A_j s_j``; line rows (u = A_i u_i, d = r_j + A_j s_j - r_i - A_i s_i):
        ``d2/dr_i dphi_i = -B_i u_i``, ``d2/dr_j dphi_i = B_i u_i``, ``d2/dphi_i2 = -u.(d + A_i
        s_i)``, ``d2/dphi_i dphi_j = u.A_j s_j``, ``d2/dphi_j2 = -u.A_j s_j``; angle rows are
        linear. Symmetric.
        """
        ne = self.n + 3
        H = np.zeros((ne, ne))
        r, cs, sn, _ = self._poses(q)
        c, l = self.coincidence, self.line
        if c.n:
            Asi = _rotate(c.si, cs[c.bi], sn[c.bi])
            Asj = _rotate(c.sj, cs[c.bj], sn[c.bj])
            m2 = mu[c.rows]                                   # (k, 2)
            pi, pj = 3 * c.bi + 2, 3 * c.bj + 2
            np.add.at(H, (pi, pi), -_dot(Asi, m2))
            np.add.at(H, (pj, pj), _dot(Asj, m2))
        if l.n:
            Asi = _rotate(l.si, cs[l.bi], sn[l.bi])
            Asj = _rotate(l.sj, cs[l.bj], sn[l.bj])
            u = _rotate(l.u, cs[l.bi], sn[l.bi])
            ru = _rot90(u)
            d = r[l.bj] + Asj - r[l.bi] - Asi
            m1 = mu[l.rows]
            pi, pj = 3 * l.bi + 2, 3 * l.bj + 2
            for axis in (0, 1):
                xi, xj = 3 * l.bi + axis, 3 * l.bj + axis
                np.add.at(H, (xi, pi), -m1 * ru[:, axis])
                np.add.at(H, (pi, xi), -m1 * ru[:, axis])
                np.add.at(H, (xj, pi), m1 * ru[:, axis])
                np.add.at(H, (pi, xj), m1 * ru[:, axis])
            np.add.at(H, (pi, pi), -m1 * _dot(u, d + Asi))
            np.add.at(H, (pi, pj), m1 * _dot(u, Asj))
            np.add.at(H, (pj, pi), m1 * _dot(u, Asj))
            np.add.at(H, (pj, pj), -m1 * _dot(u, Asj))
        return H[: self.n, : self.n]

    def forces_depend_on_state(self) -> bool:
        """False when F does not depend on (q, q'): gravity, torques and forces at a centre of
        mass only (constant or inputs); then there is no force Jacobian."""
        return not all(_independent_of_state(f) for f in self.scene.forces)

    def force_jacobians(self, t: float, q: np.ndarray, qd: np.ndarray):
        """(dF/dq, dF/dq') (n, n) each, by forward differences; zeros when F is constant."""
        n = self.n
        if not self.forces_depend_on_state():
            return np.zeros((n, n)), np.zeros((n, n))
        F0 = self.forces(t, q, qd)
        out = []
        for x in (q, qd):
            D = np.empty((n, n))
            for k in range(n):
                xk = x.copy()
                delta = _FD_STEP * max(1.0, abs(x[k]))
                xk[k] += delta
                F = self.forces(t, xk, qd) if x is q else self.forces(t, q, xk)
                D[:, k] = (F - F0) / delta
            out.append(D)
        return out[0], out[1]

    # ------------------------------------------------------------------ forces

    def _signal(self, name: str, t: float, size: int):
        signal = self.force_signals.get(name)
        if signal is None:
            return np.zeros(size)
        return np.atleast_1d(np.asarray(signal(t), dtype=float))

    def forces(self, t: float, q: np.ndarray, qd: np.ndarray) -> np.ndarray:
        """Generalized applied forces F (n,): gravity, point forces, torques, springs.

        Gravity, constant torques and constant forces at a centre of mass are summed once
        (``_F_constant``); the rest, one item at a time in scalar arithmetic, which beats
        numpy on 2-vectors.
        """
        F = self._F_constant.copy()
        idx = self._idx
        for f, b in self._state_forces:
            if isinstance(f, PointForce):
                fx, fy = self._signal(f.name, t, 2) if f.input else f.value
                _, _, ax, ay = self._body_point(q, b, f.point)
                F[3 * b] += fx
                F[3 * b + 1] += fy
                F[3 * b + 2] += ax * fy - ay * fx
            elif isinstance(f, Torque):
                F[3 * b + 2] += self._signal(f.name, t, 1)[0]
            elif isinstance(f, SpringDamper):
                bi, bj = idx[f.body_i], idx[f.body_j]
                length, rate, (ux, uy), (aix, aiy), (ajx, ajy) = self._spring_geometry(f, t, q, qd)
                tension = self._spring_tension(f, t, length, rate)
                fx, fy = -tension * ux, -tension * uy  # on body_j: towards body_i when stretched
                if bj < self.nb:
                    F[3 * bj] += fx
                    F[3 * bj + 1] += fy
                    F[3 * bj + 2] += ajx * fy - ajy * fx
                if bi < self.nb:
                    F[3 * bi] -= fx
                    F[3 * bi + 1] -= fy
                    F[3 * bi + 2] -= aix * fy - aiy * fx
            elif isinstance(f, RotationalSpringDamper):
                jt = self.scene.joint(f.joint)
                bi, bj = idx[jt.body_i], idx[jt.body_j]
                phi_i = q[3 * bi + 2] if bi < self.nb else 0.0
                phi_j = q[3 * bj + 2] if bj < self.nb else 0.0
                w_i = qd[3 * bi + 2] if bi < self.nb else 0.0
                w_j = qd[3 * bj + 2] if bj < self.nb else 0.0
                torque = (-f.stiffness * (phi_j - phi_i - f.rest_angle)
                          - f.damping * (w_j - w_i))
                if bj < self.nb:
                    F[3 * bj + 2] += torque
                if bi < self.nb:
                    F[3 * bi + 2] -= torque
        return F

    def _body_point(self, q, b: int, point):
        """Position of body b's centre (x, y) and its arm A s to a body point (ground: b = nb)."""
        if b >= self.nb:
            return 0.0, 0.0, point[0], point[1]
        x, y, phi = q[3 * b], q[3 * b + 1], q[3 * b + 2]
        c, s = math.cos(phi), math.sin(phi)
        return x, y, c * point[0] - s * point[1], s * point[0] + c * point[1]

    def _spring_geometry(self, f: SpringDamper, t, q, qd):
        """Length, its rate, unit vector i->j and the two arms (A s) of a spring-damper."""
        bi, bj = self._idx[f.body_i], self._idx[f.body_j]
        xi, yi, aix, aiy = self._body_point(q, bi, f.point_i)
        xj, yj, ajx, ajy = self._body_point(q, bj, f.point_j)
        dx, dy = xj + ajx - xi - aix, yj + ajy - yi - aiy
        length = math.hypot(dx, dy)
        if length < 1e-12:
            raise SolverError(f'spring "{f.name}" has zero length: its direction is undefined', t)
        ux, uy = dx / length, dy / length
        vi = (qd[3 * bi], qd[3 * bi + 1], qd[3 * bi + 2]) if bi < self.nb else (0.0, 0.0, 0.0)
        vj = (qd[3 * bj], qd[3 * bj + 1], qd[3 * bj + 2]) if bj < self.nb else (0.0, 0.0, 0.0)
        # relative velocity of the points: v_j + w_j rot90(A_j s_j) - v_i - w_i rot90(A_i s_i)
        vx = vj[0] - vj[2] * ajy - vi[0] + vi[2] * aiy
        vy = vj[1] + vj[2] * ajx - vi[1] - vi[2] * aix
        return length, ux * vx + uy * vy, (ux, uy), (aix, aiy), (ajx, ajy)

    def _spring_tension(self, f: SpringDamper, t, length, rate) -> float:
        """k (L - L0) + c L' minus the actuator input (which pushes the points apart)."""
        tension = f.stiffness * (length - f.rest_length) + f.damping * rate
        if f.actuator_input:
            tension -= self._signal(f.name, t, 1)[0]
        return tension

    def spring_states(self, t, q, qd) -> np.ndarray:
        """(length, rate, tension) of every spring-damper, (ns, 3)."""
        rows = []
        for f, _ in self._forces:
            if isinstance(f, SpringDamper):
                length, rate, *_ = self._spring_geometry(f, t, q, qd)
                rows.append((length, rate, self._spring_tension(f, t, length, rate)))
        return np.array(rows, dtype=float).reshape(-1, 3)

    # ------------------------------------------------------------------ dynamics

    def accelerations(self, t: float, q: np.ndarray, qd: np.ndarray, *,
                      baumgarte: tuple[float, float] | None = None):
        """Solve the seed's eq. (14) for q'' (n,) and lam (m,).

        Uses the Schur complement of the diagonal mass matrix,
        ``(Psi_q M^-1 Psi_q^T) lam = Psi_q M^-1 F - gamma``, ``q'' = M^-1 (F - Psi_q^T lam)``;
        at singular configurations or with redundant constraints the minimum-norm lam.
        With ``baumgarte = (alpha, beta)`` the right-hand side is Baumgarte's stabilised
        ``gamma - 2 alpha (Psi_q q' - nu) - beta^2 Psi``.
        """
        F = self.forces(t, q, qd)
        if self.m == 0:
            return self.minv * F, np.zeros(0)
        if self.kernel == "numba" and baumgarte is None:
            qdd, lam, ok = self._accelerations_compiled(t, q, qd, F)
            if ok:
                return qdd, lam
        Psi, J, nu, gamma = self.constraints(t, q, qd, sparse=True)
        if baumgarte is not None:
            alpha, beta = baumgarte
            gamma = gamma - 2.0 * alpha * (J @ qd - nu) - beta * beta * Psi
        lam = schur_solve(J, self.minv, J @ (self.minv * F) - gamma)
        return self.minv * (F - J.T @ lam), lam

    def _accelerations_compiled(self, t, q, qd, F):
        """Eq. 14 in one numba call (any size); ok False near singular (see caller)."""
        n = self.n
        qe, qde = np.zeros(n + 3), np.zeros(n + 3)
        qe[:n], qde[:n] = q, qd
        cval, _, cdd = self.motion_values(t)
        return kernel_jit.accelerations(
            qe, qde, cval, cdd, F, self.minv, RANK_TOLERANCE, self._jit_args,
            self._jac_constants, self.jacobian_pattern.keep, self._jit_pattern)

    @property
    def fused_steps(self) -> bool:
        """Whole steps can run compiled (``kernel_jit.rk4p_steps``): the numba kernel and
        applied forces that do not depend on the state or on inputs."""
        return self.kernel == "numba" and self.m > 0 and not self._state_forces

    def rk4p_steps(self, times, q, qd, f, h: float, audit_state, *, tol: float,
                   max_iter: int, divergence_fraction: float, roundoff: float):
        """Compiled rk4p steps from each of ``times`` with the energy check's running state
        ``audit_state`` (updated in place; see ``kernel_jit.rk4p_steps``)."""
        if self.driver_motions:
            motions = np.array([[self.motion_values(t + a) for a in (0.0, 0.5 * h, h)]
                                for t in times])
        else:
            motions = np.repeat(self._no_motion_steps[None], len(times), axis=0)
        motions.flags.writeable = False   # read-only C arrays everywhere: one compilation
        return kernel_jit.rk4p_steps(
            q, qd, f, h, motions, self._F_constant, self.minv, RANK_TOLERANCE, tol, max_iter,
            self._jit_args, self._jac_constants, self.jacobian_pattern.keep, self._jit_pattern,
            self.mass, audit_state, divergence_fraction, roundoff)

    def kinetic_energy(self, qd: np.ndarray) -> float:
        return 0.5 * float(qd @ (self.mass * qd))

    def potential_energy(self, q: np.ndarray) -> float:
        """Gravity plus springs (J); zero at the origin for gravity."""
        r, cs, sn, phi = self._poses(q)
        energy = -float(self.F_gravity @ q)
        idx = self._idx
        for f, _ in self._forces:
            if isinstance(f, SpringDamper):
                bi, bj = idx[f.body_i], idx[f.body_j]
                Asi = _rotate(np.array([f.point_i]), cs[bi:bi + 1], sn[bi:bi + 1])[0]
                Asj = _rotate(np.array([f.point_j]), cs[bj:bj + 1], sn[bj:bj + 1])[0]
                stretch = np.linalg.norm(r[bj] + Asj - r[bi] - Asi) - f.rest_length
                energy += 0.5 * f.stiffness * stretch ** 2
            elif isinstance(f, RotationalSpringDamper):
                jt = self.scene.joint(f.joint)
                bi, bj = idx[jt.body_i], idx[jt.body_j]
                energy += 0.5 * f.stiffness * (phi[bj] - phi[bi] - f.rest_angle) ** 2
        return energy

    def nonconservative_reason(self) -> str | None:
        """Why the energy of this scene is not conserved, or None when it is.

        Conserved: no drivers (they do work through their multipliers), no inputs, no dampers;
        constant point forces and torques are conservative (their potential is in
        ``total_energy``).
        """
        if self.scene.drivers:
            return f'driver "{self.scene.drivers[0].name}" does work'
        for f in self.scene.forces:
            if getattr(f, "input", False) or getattr(f, "actuator_input", False):
                return f'"{f.name}" is an input'
            if getattr(f, "damping", 0.0):
                return f'"{f.name}" dissipates'
        return None

    def total_energy(self, q: np.ndarray, qd: np.ndarray) -> float:
        """Kinetic energy plus the potential of gravity, springs and constant loads (J).

        Constant in time for a scene with ``nonconservative_reason() is None``: a constant
        torque T on body i has the potential ``-T phi_i``, a constant force F at a body point
        ``-F . (r_i + A_i s)``.
        """
        if not self._state_forces:  # constant generalized forces only: potential -F . q
            return self.kinetic_energy(qd) - float(self._F_constant @ q)
        energy = self.kinetic_energy(qd) + self.potential_energy(q)
        r, cs, sn, phi = self._poses(q)
        for f, b in self._forces:
            if isinstance(f, Torque) and not f.input:
                energy -= f.value * phi[b]
            elif isinstance(f, PointForce) and not f.input:
                As = _rotate(np.array([f.point]), cs[b:b + 1], sn[b:b + 1])[0]
                energy -= f.value[0] * (r[b, 0] + As[0]) + f.value[1] * (r[b, 1] + As[1])
        return energy

    def reactions(self, q: np.ndarray, lam: np.ndarray, t: float = 0.0,
                  data: np.ndarray | None = None) -> np.ndarray:
        """Force and torque each joint exerts on its body_j, in the joint frame (nj, 3).

        Seed eqs. (9), (10): F = -C^T A^T [Psi_r rows]^T lam, T = -Psi_phi lam - (A s) x F,
        here with the body_j blocks of the joint's two Jacobian rows. Revolute joints give
        T = 0; translational joints K1 = 0 along the axis, K2 normal, K3 torque.
        """
        nj = len(self.joint_rows)
        if nj == 0:
            return np.zeros((0, 3))
        if data is None:
            data = self.constraint_values(t, q)[1]
        rows = self.joint_rows
        G = np.append(data, 0.0)[self._reaction_entries]  # (nj, 2, 3): body_j blocks
        gen = -np.einsum("kab,ka->kb", G, lam[rows])  # generalized force on body_j
        r, cs, sn, phi = self._poses(q)
        sj = np.array([j.point_j for j in self.scene.joints], dtype=float)
        Asj = _rotate(sj, cs[self.joint_bj], sn[self.joint_bj])
        torque = gen[:, 2] - (Asj[:, 0] * gen[:, 1] - Asj[:, 1] * gen[:, 0])
        theta = phi[self.joint_frame_body] + self.joint_frame_angle
        c, s = np.cos(theta), np.sin(theta)
        fx = c * gen[:, 0] + s * gen[:, 1]
        fy = -s * gen[:, 0] + c * gen[:, 1]
        return np.stack((fx, fy, torque), axis=1)

    def driver_efforts(self, lam: np.ndarray) -> np.ndarray:
        """Generalized force each driver applies to its body_j: -lam of its row."""
        return -lam[self.driver_rows]

    # ------------------------------------------------------------------ variables

    def _output_table(self) -> list[Variable]:
        out = []
        for b in self.scene.bodies:
            out += [Variable(f"{b.name}.x", "m", f"x of {b.name}'s centre of mass, ground frame"),
                    Variable(f"{b.name}.y", "m", f"y of {b.name}'s centre of mass, ground frame"),
                    Variable(f"{b.name}.phi", "rad", f"rotation angle of {b.name}"),
                    Variable(f"{b.name}.vx", "m/s", f"x velocity of {b.name}'s centre of mass"),
                    Variable(f"{b.name}.vy", "m/s", f"y velocity of {b.name}'s centre of mass"),
                    Variable(f"{b.name}.omega", "rad/s", f"angular velocity of {b.name}")]
        for j in self.scene.joints:
            frame = f"{j.name}'s joint frame"
            out += [Variable(f"{j.name}.Fx", "N", f"force of joint {j.name} on {j.body_j}, x in {frame}"),
                    Variable(f"{j.name}.Fy", "N", f"force of joint {j.name} on {j.body_j}, y in {frame}"),
                    Variable(f"{j.name}.Tz", "N.m", f"torque of joint {j.name} on {j.body_j}")]
        for d in self.scene.drivers:
            _, unit = _driver_unit(self.scene, d)
            target = d.body if d.body is not None else self.scene.joint(d.joint).body_j
            out.append(Variable(f"{d.name}.effort", unit,
                                f"generalized force driver {d.name} applies to {target}"))
        for f in self.scene.forces:
            if isinstance(f, SpringDamper):
                out += [Variable(f"{f.name}.length", "m", f"distance between {f.name}'s points"),
                        Variable(f"{f.name}.velocity", "m/s", f"rate of {f.name}'s length"),
                        Variable(f"{f.name}.tension", "N",
                                 f"force of {f.name} along its line, positive pulling together")]
        out += [Variable("energy.kinetic", "J", "kinetic energy"),
                Variable("energy.potential", "J", "potential energy of gravity and springs"),
                Variable("constraint.position_error", "1", "norm of Psi(q, t)"),
                Variable("constraint.velocity_error", "1", "norm of Psi_q q' - nu")]
        return out

    def _input_table(self) -> list[Variable]:
        out = []
        for d in self.scene.drivers:
            if isinstance(d.motion, InputMotion):
                unit, _ = _driver_unit(self.scene, d)
                out += [Variable(f"{d.name}.position", unit, f"prescribed position of {d.name}"),
                        Variable(f"{d.name}.velocity", f"{unit}/s", "its rate (optional)"),
                        Variable(f"{d.name}.acceleration", f"{unit}/s2", "its second rate (optional)")]
        for f in self.scene.forces:
            if isinstance(f, PointForce) and f.input:
                out += [Variable(f"{f.name}.fx", "N", f"{f.name}, x component, ground frame"),
                        Variable(f"{f.name}.fy", "N", f"{f.name}, y component, ground frame")]
            elif isinstance(f, Torque) and f.input:
                out.append(Variable(f"{f.name}.torque", "N.m", f"torque {f.name} on {f.body}"))
            elif isinstance(f, SpringDamper) and f.actuator_input:
                out.append(Variable(f"{f.name}.actuator", "N",
                                    f"actuator force along {f.name}, positive pushing apart"))
        return out

    def output_values(self, t, q, qd, qdd, lam) -> np.ndarray:
        """Every output of ``self.outputs`` at one instant, in that order."""
        Psi, data, nu, _ = self.constraint_values(t, q, qd)   # one evaluation for all
        J = self.jacobian_pattern.jacobian(data, sparse=True)
        parts = [np.concatenate((q.reshape(-1, 3), qd.reshape(-1, 3)), axis=1).ravel(),
                 self.reactions(q, lam, t, data).ravel(), self.driver_efforts(lam),
                 self.spring_states(t, q, qd).ravel(),
                 [self.kinetic_energy(qd), self.potential_energy(q),
                  float(np.linalg.norm(Psi)), float(np.linalg.norm(J @ qd - nu))]]
        return np.concatenate([np.asarray(p, dtype=float) for p in parts])


# Forward-difference step (relative) of the force Jacobians: about sqrt(machine epsilon).
_FD_STEP = 1.5e-8
