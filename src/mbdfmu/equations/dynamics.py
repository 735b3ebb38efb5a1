"""The equations of motion of a scene: eq. (14) solved for q'' and lam, reactions, outputs.

``Equations`` puts the constraints (``constraints.py``) and the applied forces
(``forces.py``) together with the diagonal mass matrix. Every method is a pure function of
its arguments (t, q, q', the inputs u): nothing is stored between calls, so any integrator
can call them at any stage. Coordinates are absolute: ``q = [x_1, y_1, phi_1, x_2, ...]``,
the centre of mass and angle of each body (formulation.md, eq. 1).
"""

from __future__ import annotations

import copy

import numpy as np

from ..errors import InputError, SettingError
from ..model.scene import RotationalSpringDamper, Scene, has_events
from ..model.variables import TABLES, InputValues, input_layout
from . import ckernel
from .constraints import ConstraintSet
from .forces import AppliedForces
from .planar import poses, rotate, stacked
from .singular import nullspace_accelerations
from .sparsity import RANK_TOLERANCE, schur_solve_checked


class Equations:
    """Equations of motion of a scene (formulation.md, eqs. 12-17).

    ``n`` coordinates, ``m`` constraint rows, ``mass`` (n,) the diagonal of M,
    ``constraints`` the rows and their Jacobian pattern, ``applied`` the forces,
    ``layout`` where each input sits in ``InputValues``, ``length_scale`` (m) the size of
    the mechanism (for tolerances), ``has_events`` whether the scene has end stops or
    friction (``model.scene.has_events``, a scan of its joints: once here). ``sliding``
    ({joint index: direction}) and ``held_rows`` ({joint index: row}) are a contact mode's
    (``limits.ModeEquations``, ``integrators.modes``): none here.
    """

    sliding: dict = {}
    held_rows: dict = {}

    def __init__(self, scene: Scene, *, kernel: str | None = None):
        self.scene = scene
        self.nb = len(scene.bodies)
        self.n = 3 * self.nb
        self.mass = stacked([(b.mass, b.mass, b.inertia) for b in scene.bodies], 3).ravel()
        self.minv = 1.0 / self.mass
        self.layout = input_layout(scene)
        self.has_events = has_events(scene)
        self.no_inputs = self.layout.initial()
        self.constraint_set = ConstraintSet(scene, self.minv, kernel)
        self.applied = AppliedForces(scene, self.mass, self.layout)
        self.m = self.constraint_set.m
        self.kernel = self.constraint_set.kernel
        self.row_labels = self.constraint_set.labels
        self.pattern = self.constraint_set.pattern
        self.length_scale = max([1.0] + [abs(v) for b in scene.bodies for v in b.position])
        c = self.constraint_set
        # the body_j blocks of each joint's rows in Psi_q's values (reactions, eq. 16)
        self._reaction_entries = self.pattern.entries(
            c.joint_rows[:, :, None], 3 * c.joint_bj[:, None, None] + np.arange(3)[None, None, :])
        self._joint_outputs = _joint_output_plan(scene, c, list(self.sliding))
        # the C kernel (kernel "c"): eq. (14), steps and outputs in compiled code
        self.ckernel = ckernel.Kernel(self) if self.kernel == "c" else None

    # ------------------------------------------------------------------ constraints

    def _u(self, u: InputValues | None) -> InputValues:
        return self.no_inputs if u is None else u

    def motion_values(self, t: float, u: InputValues | None = None):
        """(c, c', c'') of every constraint row at t (read-only arrays)."""
        return self.constraint_set.motion_values(t, self._u(u))

    def constraint_values(self, t, q, qd=None, u: InputValues | None = None):
        """Psi (m,), Psi_q's values on ``pattern``, nu and gamma (None without qd)."""
        if getattr(self, "ckernel", None) is None:     # the numpy kernel, or not bound yet
            return self.constraint_set.values(t, q, qd, self._u(u))
        c, cd, cdd = self.motion_values(t, u)
        Psi, data, gamma = self.ckernel.constraint_values(q, qd, c)
        return (Psi, data, None, None) if qd is None else (Psi, data, cd, gamma + cdd)

    def constraints(self, t: float, q: np.ndarray, qd: np.ndarray | None = None,
                    u: InputValues | None = None, *, extended: bool = False,
                    sparse: bool = False):
        """Psi (m,), Psi_q (m, n) and, with qd, nu (m,) and gamma (m,) (eqs. 8-11).

        Psi_q is a dense array, or with ``sparse`` for a large mechanism a
        ``sparsity.SparseJacobian``; with ``extended`` a dense Psi_q keeps the ground's
        three columns last (for reactions).
        """
        Psi, data, nu, gamma = self.constraint_values(t, q, qd, u)
        J = self.pattern.dense_with_ground(data) if extended else self.pattern.jacobian(data, sparse)
        return (Psi, J) if qd is None else (Psi, J, nu, gamma)

    def periodic_angles(self) -> np.ndarray:
        """A mask over q of the body angles that enter every equation only through their
        sine and cosine (not through an angle row of the constraints, e.g. a rotational
        driver or a coupler, nor a rotational spring): shifting one by 2 pi changes nothing,
        so an integrator may keep them wrapped."""
        mask = np.zeros(self.n, dtype=bool)
        mask[2::3] = True
        a = self.constraint_set.angle
        used = set(a.bi.tolist()) | set(a.bj.tolist()) if a.n else set()
        index = {b.name: k for k, b in enumerate(self.scene.bodies)}
        for f in self.scene.forces:
            if isinstance(f, RotationalSpringDamper):
                joint = self.scene.joint(f.joint)
                used |= {index[b] for b in (joint.body_i, joint.body_j) if b in index}
        for b in used:
            if b < self.nb:
                mask[3 * b + 2] = False
        return mask

    def constraint_hessian(self, q: np.ndarray, mu: np.ndarray) -> np.ndarray:
        return self.constraint_set.hessian(q, mu)

    # ------------------------------------------------------------------ forces

    def forces(self, t: float, q: np.ndarray, qd: np.ndarray,
               u: InputValues | None = None) -> np.ndarray:
        return self.applied(t, q, qd, self._u(u))

    def force_jacobians(self, t, q, qd, u: InputValues | None = None):
        return self.applied.jacobians(t, q, qd, self._u(u))

    def forces_depend_on_state(self) -> bool:
        return self.applied.depend_on_state()

    # ------------------------------------------------------------------ eq. (14)

    def accelerations(self, t: float, q: np.ndarray, qd: np.ndarray,
                      u: InputValues | None = None, *,
                      baumgarte: tuple[float, float] | None = None):
        """Solve eq. (14) for q'' (n,) and lam (m,).

        By the Schur complement of the diagonal mass matrix (eq. 15),
        ``(Psi_q M^-1 Psi_q^T) lam = Psi_q M^-1 F - gamma``, ``q'' = M^-1 (F - Psi_q^T lam)``;
        where that is ill-conditioned (near singular configurations, with redundant
        constraints) the null-space solution of ``singular.nullspace_accelerations``, with
        the minimum-norm lam. With ``baumgarte = (alpha, beta)`` the right-hand side is
        Baumgarte's stabilised ``gamma - 2 alpha (Psi_q q' - nu) - beta^2 Psi`` (solved
        with the minimum-norm lam wherever S is ill-conditioned).
        """
        u = self._u(u)
        done = self.kernel_accelerations(t, q, qd, u) if baumgarte is None else None
        if done is not None:
            return done
        return self.python_accelerations(t, q, qd, u, baumgarte=baumgarte)

    def kernel_accelerations(self, t: float, q: np.ndarray, qd: np.ndarray, u: InputValues):
        """(q'', lam) of eq. (14) from the C kernel, or None without one or where it hands
        the case back to the numpy path."""
        if self.ckernel is None:
            return None
        return self.ckernel.accelerations(q, qd, self.motion_values(t, u), u.forces)

    def python_accelerations(self, t: float, q: np.ndarray, qd: np.ndarray, u: InputValues, *,
                             baumgarte: tuple[float, float] | None = None):
        """``accelerations`` on the numpy (or numba) path, never the C kernel's."""
        F = self.applied(t, q, qd, u)
        if self.m == 0:
            return self.minv * F, np.zeros(0)
        if self.kernel == "numba" and baumgarte is None:
            qdd, lam, ok = self._accelerations_compiled(t, q, qd, F, u)
            if ok:
                return qdd, lam
        Psi, J, nu, gamma = self.constraints(t, q, qd, u, sparse=True)
        if baumgarte is not None:
            alpha, beta = baumgarte
            gamma = gamma - 2.0 * alpha * (J @ qd - nu) - beta * beta * Psi
        lam, ok = schur_solve_checked(J, self.minv, J @ (self.minv * F) - gamma)
        if not ok and baumgarte is None:
            dense = J.toarray() if hasattr(J, "toarray") else J
            return nullspace_accelerations(dense, self.minv, F, gamma)
        return self.minv * (F - J.T @ lam), lam

    def _accelerations_compiled(self, t, q, qd, F, u):
        """Eq. (14) in one numba call (any size); ok False near singular (see caller)."""
        n = self.n
        qe, qde = np.zeros(n + 3), np.zeros(n + 3)
        qe[:n], qde[:n] = q, qd
        cval, _, cdd = self.constraint_set.motion_values(t, u)
        c = self.constraint_set
        return c.compiled_accelerations(qe, qde, cval, cdd, F, self.minv, RANK_TOLERANCE,
                                        c.primitives, c.plan)

    # ------------------------------------------------------------------ energies

    def kinetic_energy(self, qd: np.ndarray) -> float:
        return 0.5 * float(qd @ (self.mass * qd))

    def potential_energy(self, q: np.ndarray) -> float:
        """Gravity plus springs (J); zero at the origin for gravity."""
        return self.applied.potential_energy(q)

    def total_energy(self, q: np.ndarray, qd: np.ndarray) -> float:
        """Kinetic energy plus the potential of gravity, springs and constant loads (J);
        constant in time when ``nonconservative_reason()`` is None."""
        if self.applied.is_constant:  # constant generalized forces only: potential -F . q
            return self.kinetic_energy(qd) - float(self.applied.constant @ q)
        return (self.kinetic_energy(qd) + self.applied.potential_energy(q)
                + self.applied.load_potential(q))

    def nonconservative_reason(self) -> str | None:
        return self.applied.nonconservative_reason()

    # ------------------------------------------------------------------ reactions, outputs

    def reactions(self, q: np.ndarray, lam: np.ndarray, t: float = 0.0,
                  data: np.ndarray | None = None) -> np.ndarray:
        """Force and torque each joint exerts on its body_j, in the joint frame (nj, 3),
        scene order; NaN for couplers, which apply efforts (``coupler_efforts``).

        Eq. (16): F = -C^T A^T [Psi_r rows]^T lam, T = -Psi_phi lam - (A s) x F, with the
        body_j blocks of the joint's rows. Revolute joints give T = 0; translational joints
        K1 = 0 along the axis, K2 normal, K3 torque (eq. 17); slots Fx = 0 and T = 0 about
        the pin; rolling joints the contact force (Fx tangential, Fy normal) and T = radius Fx
        about the disc's centre (eq. 28).
        """
        c = self.constraint_set
        out = np.full((len(self.scene.joints), 3), np.nan)
        if len(c.joint_rows) == 0:
            return out
        if data is None:
            data = self.constraint_values(t, q)[1]
        G = np.append(data, 0.0)[self._reaction_entries]       # (nr, 2, 3): body_j blocks
        gen = -np.einsum("kab,ka->kb", G, np.append(lam, 0.0)[c.joint_rows])  # on body_j
        r, cs, sn, phi = poses(q, self.nb)
        Asj = rotate(c.frame_point, cs[c.joint_bj], sn[c.joint_bj])
        torque = gen[:, 2] - (Asj[:, 0] * gen[:, 1] - Asj[:, 1] * gen[:, 0])
        theta = phi[c.frame_body] + c.frame_angle
        co, si = np.cos(theta), np.sin(theta)
        out[c.reaction_joints] = np.stack((co * gen[:, 0] + si * gen[:, 1],
                                           -si * gen[:, 0] + co * gen[:, 1], torque), axis=1)
        return out

    def coupler_efforts(self, lam: np.ndarray) -> np.ndarray:
        """Generalized force each coupler applies on its joint_j's coordinate: -lam of its
        row (eq. 25); -ratio times it acts on joint_i's."""
        return -lam[self.constraint_set.coupler_rows]

    def driver_efforts(self, lam: np.ndarray) -> np.ndarray:
        """Generalized force each driver applies to its body_j: -lam of its row."""
        return -lam[self.constraint_set.driver_rows]

    def joint_outputs(self, q, lam, t: float = 0.0, data=None) -> np.ndarray:
        """Every joint output of ``model.variables.outputs(scene)``, in that order."""
        # a 0 for the limit and friction outputs, which the events layer fills (they
        # depend on the contact mode: integrators/modes.py), then a contact mode's sliding
        # friction forces (limits.ModeEquations)
        values = np.concatenate((self.reactions(q, lam, t, data).ravel(),
                                 self.coupler_efforts(lam), [0.0], self.sliding_forces()))
        return values[self._joint_outputs]

    def sliding_forces(self) -> np.ndarray:
        """The friction forces of the joints that slide (none here: ``ModeEquations``)."""
        return np.zeros(0)

    def output_values(self, t, q, qd, qdd, lam, u: InputValues | None = None) -> np.ndarray:
        """Every output of ``model.variables.outputs(scene)`` at one instant, in that order."""
        u = self._u(u)
        if self.ckernel is not None:
            values = self.ckernel.outputs(q, qd, qdd, lam, self.motion_values(t, u), u.forces)
            if values is not None:
                return values
        Psi, data, nu, _ = self.constraint_values(t, q, qd, u)   # one evaluation for all
        J = self.pattern.jacobian(data, sparse=True)
        parts = [np.concatenate((q.reshape(-1, 3), qd.reshape(-1, 3)), axis=1).ravel(),
                 self.joint_outputs(q, lam, t, data), self.driver_efforts(lam),
                 self.applied.spring_states(t, q, qd, u).ravel(),
                 [self.kinetic_energy(qd), self.potential_energy(q),
                  float(np.linalg.norm(Psi)), float(np.linalg.norm(J @ qd - nu))]]
        return np.concatenate([np.asarray(p, dtype=float) for p in parts])


def for_another_run(eq: Equations, kernel: str | None = None) -> Equations:
    """eq for another run of its scene: the structure (constraints, sparsity, forces, the C
    kernel's tables) shared, read-only; the C kernel's state (its work space, kept
    evaluation and dense reads) the copy's own. ``kernel``: eq's, or None. What makes the
    runs after the first of one scene cheaper (``Simulation(equations)``)."""
    if type(eq) is not Equations:           # a contact mode's (limits.ModeEquations)
        raise InputError("scene: a contact mode's equations cannot start a run; give the "
                         "equations of a Simulation (Simulation.equations) or the scene")
    if kernel is not None and kernel != eq.kernel:
        raise SettingError("kernel", f"kernel: {kernel!r} differs from the {eq.kernel!r} "
                           "kernel of the equations given; leave it out, or give the scene")
    copied = copy.copy(eq)
    copied.__dict__.pop("published_places", None)     # an FMU's, of its own kernel
    if eq.ckernel is not None:
        copied.ckernel = ckernel.Kernel(copied)
    return copied


def _joint_output_plan(scene: Scene, c, sliding: list[int]) -> np.ndarray:
    """Where each joint output sits in [reactions (nj, 3) raveled | coupler efforts | 0 |
    sliding friction forces]: the reaction columns Fx, Fy, Tz a joint type declares in the
    variable table, or its effort, the friction of a joint in ``sliding`` (scene indices,
    in the order of its forces), else 0 (a stop's force, friction: modes.py fills them)."""
    column = {"Fx": 0, "Fy": 1, "Tz": 2}
    coupler = {k: i for i, k in enumerate(c.coupler_joints.tolist())}
    nj = len(scene.joints)
    zero = 3 * nj + len(coupler)
    plan, declared = [], {}
    for k, j in enumerate(scene.joints):
        specs = declared.get(type(j))
        if specs is None:        # each type's outputs once: (place, Spec.applies's condition)
            specs = declared[type(j)] = [
                (s.suffix if s.suffix in ("effort", "friction") else
                 column.get(s.suffix, "zero"), s.condition) for s in TABLES[type(j)].outputs]
        for place, condition in specs:
            if condition is not None and bool(getattr(j, condition[0])) == condition[1]:
                continue
            if place == "effort":
                plan.append(3 * nj + coupler[k])
            elif place == "friction" and k in sliding:
                plan.append(zero + 1 + sliding.index(k))
            elif place in ("zero", "friction"):
                plan.append(zero)
            else:
                plan.append(3 * k + place)
    return np.array(plan, dtype=int)
