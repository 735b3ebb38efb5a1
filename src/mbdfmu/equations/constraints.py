"""The constraints of a scene: Psi(q, t), Psi_q, nu and gamma (formulation.md, eqs. 5-11, 24).

Rows come from ``joints.py`` in scene order: each joint, then each driver; a row sums its
weighted line and angle terms. Psi_q's nonzeros
are fixed per scene (``sparsity.JacobianPattern``); an evaluation fills in their values
with the vectorised numpy kernel here or the numba kernel (``compiled.py``), which give the
same numbers. Sign conventions: velocity equation ``Psi_q q' = nu`` (``nu = -Psi_t``),
acceleration equation ``Psi_q q'' = gamma``.

Everything is a pure function of (t, q, q') and the driver motions c(t): the motion values
of input-driven drivers come in as an argument (``InputValues``), never from stored signals.
"""

from __future__ import annotations

import importlib
import importlib.util
import itertools
import os

import numpy as np

from ..errors import InputError
from ..model.scene import Scene
from ..model.variables import InputValues
from .joints import JOINT_ROWS, RowBuilder, driver_row
from .planar import dot, poses, rot90, rotate, stacked, velocities
from .sparsity import JacobianPattern

KERNELS = ("numpy", "numba", "c")
# Column offsets of the coincidence rows' x, y blocks and of the line rows' six blocks.
_XYXY = np.array([0, 1, 0, 1])
_XYPHI2 = np.array([0, 1, 2, 0, 1, 2])


def numba_installed() -> bool:
    """numba can be imported (found without importing it: importing costs time)."""
    return importlib.util.find_spec("numba") is not None


def choose_kernel(kernel: str | None) -> str:
    """The constraint kernel: as asked, else ``$MBDFMU_KERNEL``, else numba when installed.
    "c" is the C kernel (``ckernel``): eq. (14), projections, whole steps and outputs in C,
    the constraint values themselves on the numpy path."""
    kernel = kernel or os.environ.get("MBDFMU_KERNEL") or "auto"
    if kernel == "auto":
        return "numba" if numba_installed() else "numpy"
    if kernel not in KERNELS:
        raise InputError(f"unknown kernel {kernel!r}: choose one of {', '.join(KERNELS)} or auto")
    if kernel == "numba" and not numba_installed():
        raise InputError('kernel "numba" needs numba: pip install "mbdfmu[jit]"')
    if kernel == "c" and not importlib.import_module(".ckernel", __package__).available():
        raise InputError('kernel "c" needs its compiled library: a C compiler (gcc), or '
                         "MBDFMU_C_KERNEL naming a compiled copy")
    return kernel


def compiled_kernel():
    """The numba kernel module (``compiled.py``), imported on first use only: a scene run on
    the numpy kernel never imports numba."""
    return importlib.import_module(".compiled", __package__)


class ConstraintSet:
    """The constraint rows of a scene and their evaluation.

    ``m`` rows over ``n = 3 nb`` coordinates; ``labels`` name the rows. Joints with
    reactions (every type but the coupler) have their rows in ``joint_rows`` (nr, 2; a
    one-row joint's second entry is ``m``, a row of zeros), ``reaction_joints`` their index
    in the scene, ``joint_bj``, ``frame_*`` their body_j and reaction frame; couplers their
    row in ``coupler_rows`` and index in ``coupler_joints``; ``driver_rows`` the driver rows
    in scene order, split into ``input_rows`` (motion from the inputs) and ``motion_rows``
    ((row, motion) pairs the set evaluates itself); ``pattern`` Psi_q's nonzeros.
    """

    def __init__(self, scene: Scene, minv: np.ndarray, kernel: str | None = None):
        self.kernel = choose_kernel(kernel)
        self.scene, self.nb, self.n = scene, len(scene.bodies), 3 * len(scene.bodies)
        b = RowBuilder(scene)
        reactions, couplers = [], []
        for k, j in enumerate(scene.joints):
            first = b.m
            frame = JOINT_ROWS[type(j)](b, j)
            if frame is None:
                couplers.append((k, first))
            else:
                reactions.append((k, first, b.m - first, b.index[j.body_j], frame))
        self.driver_rows = np.array([driver_row(b, scene, d) for d in scene.drivers], dtype=int)
        for primitive in (b.coincidence, b.line, b.angle):
            primitive.freeze()
        self.coincidence, self.line, self.angle = b.coincidence, b.line, b.angle
        self.m, self.labels = b.m, b.labels
        self.offsets = np.array(b.offsets, dtype=float)
        self.reaction_joints = np.array([r[0] for r in reactions], dtype=int)
        self.joint_rows = stacked([(r[1], r[1] + 1 if r[2] == 2 else self.m)
                                   for r in reactions], 2, int)
        self.joint_bj = np.array([r[3] for r in reactions], dtype=int)
        self.frame_body = np.array([r[4].body for r in reactions], dtype=int)
        self.frame_angle = np.array([r[4].angle for r in reactions], dtype=float)
        self.frame_point = stacked([r[4].point for r in reactions], 2)
        self.coupler_joints = np.array([c[0] for c in couplers], dtype=int)
        self.coupler_rows = np.array([c[1] for c in couplers], dtype=int)
        # which drivers take their motion from the inputs, and which evaluate it themselves
        self.input_rows = np.array([r for r, d in zip(self.driver_rows, scene.drivers)
                                    if d.is_input], dtype=int)
        self.motion_rows = [(r, d.motion) for r, d in zip(self.driver_rows, scene.drivers)
                            if not d.is_input]
        self._last_motion = None
        self._plan_pattern(minv)

    def _plan_pattern(self, minv: np.ndarray) -> None:
        """Psi_q's nonzeros once; per evaluation only values.

        The value vector is [constant entries | coincidence angle columns (4 blocks of one
        entry per row pair) | line terms (6 blocks)], columns counting the ground's three;
        terms of one row in one column (a coupler's, a rolling joint's) are summed by the
        pattern (``JacobianPattern.merged``).
        """
        c, l, a = self.coincidence, self.line, self.angle
        pair = c.rows.reshape(-1, 2).T.ravel()                      # r0, r1
        ij = 3 * np.concatenate((c.bi, c.bi, c.bj, c.bj))            # each block's body
        # in blocks: constants [r0, r1, r0, r1 | angle rows twice], coincidence phi
        # [r0, r1, r0, r1], line rows six times; their columns below, block by block
        rows = np.concatenate((pair, pair, a.rows, a.rows, pair, pair, *(l.rows,) * 6))
        cols = np.concatenate((ij + _XYXY.repeat(c.n), 3 * a.bj + 2, 3 * a.bi + 2, ij + 2,
                               (3 * np.concatenate((l.bi, l.bi, l.bi, l.bj, l.bj, l.bj))
                                + _XYPHI2.repeat(l.n))))
        self._constants = np.concatenate(
            [np.ones(2 * c.n), -np.ones(2 * c.n), a.w, -a.w])
        self._line_weights = None if (l.w == 1.0).all() else np.tile(l.w, 6)
        self._nnz = 4 * c.n + 6 * l.n + self._constants.size
        self.pattern = p = JacobianPattern(rows, cols, self.m, self.n, minv)
        # every body-fixed vector that rotates with its body, rotated in one go:
        # coincidence s_i, s_j; line s_i, s_j, u_i
        self._points = np.concatenate([c.si, c.sj, l.si, l.sj, l.u]).reshape(-1, 2)
        self._point_body = np.concatenate([c.bi, c.bj, l.bi, l.bj, l.bi]).astype(np.intp)
        ends = list(itertools.accumulate((c.n, c.n, l.n, l.n, l.n), initial=0))
        self._point_slices = [slice(s, e) for s, e in zip(ends[:-1], ends[1:])]
        self.compiled = compiled = compiled_kernel() if self.kernel == "numba" else None
        if compiled is not None:
            self.compiled_terms = compiled.direct(compiled.constraint_terms)
            self.compiled_accelerations = compiled.direct(compiled.accelerations)
            self.primitives = compiled.Primitives(
                c.rows.reshape(-1, 2), c.bi, c.bj, c.si, c.sj,
                l.rows, l.bi, l.bj, l.si, l.sj, l.u, l.w, a.rows, a.bi, a.bj, a.w)
            self.plan = compiled.JacobianPlan(self._constants, p.merge, p.size, p.keep, p.rows,
                                              p.cols, p.pair_a, p.pair_b, p.pair_minv,
                                              p.band_index, p.perm, p.kd)

    # ------------------------------------------------------------------ evaluation

    def motion_block(self, times, us) -> np.ndarray:
        """``motion_values`` at several times at once, (k, 3, m): the same numbers, for the
        steps of the C kernel; ``us`` the inputs at each time (None: no input drivers)."""
        out = np.zeros((len(times), 3, self.m))
        out[:, 0, :] = self.offsets
        for row, motion in self.motion_rows:
            out[:, :, row] = [motion.evaluate(t) for t in times]
        if self.input_rows.size:
            out[:, :, self.input_rows] = np.array([u.motions.T for u in us])
        return out

    def motion_values(self, t: float, u: InputValues):
        """(c, c', c'') of every row at time t (formulation.md, eq. 7): the drivers' motions,
        those of input-driven drivers from ``u``. Read-only arrays (one compiled signature);
        the last result is kept and returned again for the same t and input motions."""
        last = self._last_motion
        if last is not None and last[0] == t and (
                not self.input_rows.size or np.array_equal(last[1], u.motions)):
            return last[2]
        c = self.offsets.copy()
        cd, cdd = np.zeros(self.m), np.zeros(self.m)
        for row, motion in self.motion_rows:
            c[row], cd[row], cdd[row] = motion.evaluate(t)
        if self.input_rows.size:
            c[self.input_rows], cd[self.input_rows], cdd[self.input_rows] = u.motions.T
        for a in (c, cd, cdd):
            a.flags.writeable = False
        self._last_motion = (t, u.motions.copy() if self.input_rows.size else None, (c, cd, cdd))
        return c, cd, cdd

    def values(self, t: float, q: np.ndarray, qd: np.ndarray | None, u: InputValues):
        """Psi (m,), Psi_q's values on ``pattern`` (its ``data``), nu and gamma (None
        without qd)."""
        motion = self.motion_values(t, u)
        if self.kernel == "numba":
            Psi, data, gamma = self._values_compiled(q, qd, motion[0])
        else:
            Psi, data, gamma = self._values_numpy(q, qd, motion[0])
        data = self.pattern.merged(data)
        if qd is None:
            return Psi, data, None, None
        return Psi, data, motion[1], gamma + motion[2]

    def _values_numpy(self, q, qd, cval):
        """Psi, the terms' Jacobian values and gamma; rows sum their terms (eq. 24)."""
        r, cs, sn, phi = poses(q, self.nb)
        m = self.m
        Psi, data = np.zeros(m), np.empty(self._nnz)
        k = self._constants.size
        data[:k] = self._constants
        gamma = np.zeros(m) if qd is not None else None
        v, w = velocities(qd, self.nb) if qd is not None else (None, None)
        c, l, a = self.coincidence, self.line, self.angle
        rotated = rotate(self._points, cs[self._point_body], sn[self._point_body])
        Asi_c, Asj_c, Asi_l, Asj_l, u = (rotated[s] for s in self._point_slices)
        if c.n:
            Psi[c.rows] = r[c.bi] + Asi_c - r[c.bj] - Asj_c
            # d(A s)/dphi = B s = rot90(A s)
            data[k:k + 4 * c.n] = np.concatenate([-Asi_c[:, 1], Asi_c[:, 0],
                                                  Asj_c[:, 1], -Asj_c[:, 0]])
            k += 4 * c.n
            if gamma is not None:
                gamma[c.rows] = (Asi_c * (w[c.bi] ** 2)[:, None]
                                 - Asj_c * (w[c.bj] ** 2)[:, None])
        if l.n:
            d = r[l.bj] + Asj_l - r[l.bi] - Asi_l
            _add_rows(Psi, l, l.w * dot(u, d))
            ru = rot90(u)
            data[k:] = np.concatenate([-u[:, 0], -u[:, 1], dot(ru, d) - dot(u, rot90(Asi_l)),
                                       u[:, 0], u[:, 1], dot(u, rot90(Asj_l))])
            if self._line_weights is not None:
                data[k:] *= self._line_weights
            if gamma is not None:
                wi, wj = w[l.bi], w[l.bj]
                dd = v[l.bj] + wj[:, None] * rot90(Asj_l) - v[l.bi] - wi[:, None] * rot90(Asi_l)
                g = (wi ** 2 * dot(u, d) - 2.0 * wi * dot(ru, dd)
                     + dot(u, Asj_l * (wj ** 2)[:, None] - Asi_l * (wi ** 2)[:, None]))
                _add_rows(gamma, l, l.w * g)
        if a.n:
            _add_rows(Psi, a, a.w * (phi[a.bj] - phi[a.bi]))
        return Psi - cval, data, gamma

    def _values_compiled(self, q, qd, cval):
        """``_values_numpy`` through the numba kernel (``compiled.py``), same results."""
        n = self.n
        qe, qde = np.zeros(n + 3), np.zeros(n + 3)
        qe[:n] = q
        if qd is not None:
            qde[:n] = qd
        Psi, gamma = np.empty(self.m), np.empty(self.m)
        data = np.empty(self._nnz)
        data[:self._constants.size] = self._constants
        self.compiled_terms(qe, qde, cval, self.primitives, Psi, data, gamma)
        return Psi, data, (gamma if qd is not None else None)

    def hessian(self, q: np.ndarray, mu: np.ndarray) -> np.ndarray:
        """Geometric stiffness ``d(Psi_q^T mu)/dq = sum_k mu_k d2 Psi_k / dq2`` (n, n), mu
        fixed (formulation.md, eq. 20): the tangent term of the constraint forces in the
        implicit methods' iteration matrices. Symmetric; angle terms are linear, line terms
        count with their weight."""
        ne = self.n + 3
        H = np.zeros((ne, ne))
        r, cs, sn, _ = poses(q, self.nb)
        c, l = self.coincidence, self.line
        if c.n:
            # d2/dphi_i2 = -A_i s_i, d2/dphi_j2 = A_j s_j
            Asi, Asj = rotate(c.si, cs[c.bi], sn[c.bi]), rotate(c.sj, cs[c.bj], sn[c.bj])
            m2 = mu[c.rows]
            pi, pj = 3 * c.bi + 2, 3 * c.bj + 2
            np.add.at(H, (pi, pi), -dot(Asi, m2))
            np.add.at(H, (pj, pj), dot(Asj, m2))
        if l.n:
            self._line_hessian(H, r, cs, sn, mu)
        return H[: self.n, : self.n]

    def _line_hessian(self, H, r, cs, sn, mu) -> None:
        """Line rows (u = A_i u_i, d = r_j + A_j s_j - r_i - A_i s_i): d2/dr_i dphi_i = -B_i u_i,
        d2/dr_j dphi_i = B_i u_i, d2/dphi_i2 = -u.(d + A_i s_i), d2/dphi_i dphi_j = u.A_j s_j,
        d2/dphi_j2 = -u.A_j s_j."""
        l = self.line
        Asi, Asj = rotate(l.si, cs[l.bi], sn[l.bi]), rotate(l.sj, cs[l.bj], sn[l.bj])
        u = rotate(l.u, cs[l.bi], sn[l.bi])
        ru = rot90(u)
        d = r[l.bj] + Asj - r[l.bi] - Asi
        m1 = mu[l.rows] * l.w
        pi, pj = 3 * l.bi + 2, 3 * l.bj + 2
        for axis in (0, 1):
            xi, xj = 3 * l.bi + axis, 3 * l.bj + axis
            for a_, b_, sign in ((xi, pi, -1.0), (pi, xi, -1.0), (xj, pi, 1.0), (pi, xj, 1.0)):
                np.add.at(H, (a_, b_), sign * m1 * ru[:, axis])
        np.add.at(H, (pi, pi), -m1 * dot(u, d + Asi))
        np.add.at(H, (pi, pj), m1 * dot(u, Asj))
        np.add.at(H, (pj, pi), m1 * dot(u, Asj))
        np.add.at(H, (pj, pj), -m1 * dot(u, Asj))


def _add_rows(target: np.ndarray, primitive, values: np.ndarray) -> None:
    """Add each term's value to its row: by index when the primitive's rows are distinct,
    else summed (a row made of several terms of one primitive, eq. 24)."""
    if primitive.repeats:
        target += np.bincount(primitive.rows, values, minlength=target.size)
    else:
        target[primitive.rows] += values
