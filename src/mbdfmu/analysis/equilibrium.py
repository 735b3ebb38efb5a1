"""Static equilibrium on the constraint manifold: ``equilibrium(scene)``.

The mechanism at rest with its drivers held at their t = 0 values and its inputs at their
initial values: find q with Psi(q) = 0 and ``F(q) - Psi_q^T lam = 0`` (eq. 14 with q' = 0,
q'' = 0). Every applied force at rest derives from a potential W (gravity, springs,
constant point forces and torques, held inputs), so the equilibria are the stationary
points of W on the manifold Psi(q) = 0. In an orthonormal basis V of the manifold's
tangent space (the null space of Psi_q) the reduced gradient is ``g = -V^T F`` and the
reduced stiffness is ``K = V^T (-dF/dq + sum_k lam_k d2 Psi_k/dq2) V`` with the
least-squares multipliers ``Psi_q^T lam = F`` (the geometric stiffness term is what makes a
hanging pendulum stiff).

1. Newton's method from the initial positions, ``dz = -K^-1 g``, each step taken along V and
   put back on the manifold by the mass-weighted projection. When the steps shrink from the
   first one on (the start is near an equilibrium), this finds the nearest equilibrium,
   stable or not.
2. Otherwise a trust-region Newton minimisation of W from the initial positions (the exact
   trust-region step from K's eigen-decomposition, steps accepted on the actual decrease of
   W): it goes downhill to a stable equilibrium, through points where K is singular or
   indefinite (a pendulum released from the horizontal).

Stability: the eigenvalues of K. All positive: stable; one negative: unstable; zero
(within round-off) and none negative: neutral (a direction in which the mechanism can move
without force, such as a slider on a horizontal guide).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..equations import Equations
from ..equations.projection import ASSEMBLY_MAX_ITER, ASSEMBLY_TOL, assemble
from ..errors import SolverError
from ..model.scene import Scene
from .operating import MinimalCoordinates, coordinate_names, held_scene, null_space, prepare

MAX_ITER = 200
NEWTON_ITER = 12
# Converged when the reduced gradient is below this fraction of the forces involved and the
# last step below this fraction of the mechanism's size.
GRADIENT_RTOL = 1e-11
STEP_RTOL = 1e-11
# Central-difference step of dF/dq, relative to max(1, |q_k|): about eps^(1/3).
FD_STEP = 6e-6
# Stiffness eigenvalues within this fraction of the largest (or of the force scale per
# length) count as zero.
NEUTRAL_RTOL = 1e-7
# The Newton phase is tried when its first step is shorter than this (times the length
# scale; radians for angles).
NEWTON_REACH = 0.25


@dataclass
class Equilibrium:
    """A static equilibrium: ``q`` (n,), each body's ``(x, y, phi)`` in ``positions``,
    ``stability`` ("stable", "unstable" or "neutral"), the reduced ``stiffness`` eigenvalues
    (N/m or N.m/rad along the orthonormal tangent directions), the ``residual`` (largest
    unbalanced generalized force on the manifold, N or N.m) and ``constraint_residual`` (the
    largest |Psi|), how it was found (``method``, ``iterations``) and the ``coordinates``
    that are independent there."""

    scene: Scene
    q: np.ndarray
    lam: np.ndarray
    stability: str
    stiffness: np.ndarray
    residual: float
    constraint_residual: float
    method: str
    iterations: int
    coordinates: list[str] = field(default_factory=list)

    @property
    def positions(self) -> dict[str, tuple[float, float, float]]:
        return {b.name: tuple(float(v) for v in self.q[3 * k:3 * k + 3])
                for k, b in enumerate(self.scene.bodies)}

    @property
    def stable(self) -> bool:
        return self.stability == "stable"

    def to_dict(self) -> dict:
        return {"bodies": {n: dict(zip(("x", "y", "phi"), p)) for n, p in self.positions.items()},
                "stability": self.stability, "stiffness_eigenvalues": self.stiffness.tolist(),
                "residual": self.residual, "constraint_residual": self.constraint_residual,
                "independent_coordinates": self.coordinates, "method": self.method,
                "iterations": self.iterations}


class _Statics:
    """The reduced gradient, stiffness and potential of a held scene at rest."""

    def __init__(self, equations: Equations):
        self.eq = equations
        self.u = equations.layout.initial()
        self.zero = np.zeros(equations.n)
        self.tol = ASSEMBLY_TOL * equations.length_scale

    def force(self, q: np.ndarray) -> np.ndarray:
        return self.eq.forces(0.0, q, self.zero, self.u)

    def potential(self, q: np.ndarray) -> float:
        applied = self.eq.applied
        return applied.potential_energy(q) + applied.load_potential(q)

    def force_jacobian(self, q: np.ndarray) -> np.ndarray:
        """dF/dq (n, n) at rest by central differences."""
        n = self.eq.n
        D = np.empty((n, n))
        for k in range(n):
            h = FD_STEP * max(1.0, abs(q[k]))
            qp, qm = q.copy(), q.copy()
            qp[k] += h
            qm[k] -= h
            D[:, k] = (self.force(qp) - self.force(qm)) / (2 * h)
        return D

    def reduced(self, q: np.ndarray):
        """(g, K, V, lam, force scale) at q: gradient, stiffness, tangent basis, multipliers."""
        eq = self.eq
        F = self.force(q)
        J = eq.constraints(0.0, q, u=self.u)[1] if eq.m else np.zeros((0, eq.n))
        V = null_space(J, eq.n)
        lam = np.linalg.lstsq(J.T, F, rcond=None)[0] if eq.m else np.zeros(0)
        H = -self.force_jacobian(q)
        if eq.m:
            H = H + eq.constraint_hessian(q, lam)
        K = V.T @ H @ V
        K = 0.5 * (K + K.T)
        # the size of the forces that balance: gravity and the others apart (their sum
        # vanishes at an equilibrium without constraints along it)
        gravity = eq.applied.gravity
        scale = max(float(np.max(np.abs(part), initial=0.0))
                    for part in (gravity, F - gravity, J.T @ lam))
        return -V.T @ F, K, V, lam, scale

    def retract(self, q: np.ndarray) -> np.ndarray:
        """The nearest point of the manifold (Newton with the minimum-norm correction,
        not mass-weighted: statics has no masses, and a tiny inertia must not decide)."""
        eq, q = self.eq, q.copy()
        for _ in range(ASSEMBLY_MAX_ITER):
            if not eq.m:
                return q
            Psi, J = eq.constraints(0.0, q, u=self.u)
            if np.max(np.abs(Psi)) <= self.tol:
                return q
            q -= np.linalg.lstsq(J, Psi, rcond=None)[0]
        raise SolverError("the step left the constraint manifold too far to return", 0.0)

    def converged(self, g: np.ndarray, K: np.ndarray, scale: float) -> bool:
        """The reduced force is below GRADIENT_RTOL of the forces and the Newton step it
        asks for (in the stiff directions) below STEP_RTOL of the size."""
        if scale == 0.0 or g.size == 0:
            return True
        if np.max(np.abs(g)) > GRADIENT_RTOL * scale:
            return False
        h, U = np.linalg.eigh(K)
        stiff = np.abs(h) > NEUTRAL_RTOL * max(float(np.max(np.abs(h))), 1e-300)
        newton = (U.T @ g)[stiff] / h[stiff]
        return bool(np.linalg.norm(newton) <= STEP_RTOL * self.eq.length_scale)


def _trust_step(g: np.ndarray, K: np.ndarray, radius: float, gtol: float,
                htol: float) -> np.ndarray:
    """The step minimising g.dz + dz.K dz / 2 with |dz| <= radius (exact, by K's
    eigen-decomposition). Gradient components below ``gtol`` count as zero and curvatures
    within ``htol`` of the lowest as equal, so a neutral direction (no stiffness, no force)
    is left alone; along a negative curvature without gradient (the 'hard case') the step
    goes the whole radius."""
    h, U = np.linalg.eigh(K)
    gp = U.T @ g
    gp[np.abs(gp) <= gtol] = 0.0

    def step(mu):
        return np.divide(-gp, h + mu, out=np.zeros_like(gp), where=gp != 0.0)

    if h[0] > htol and np.linalg.norm(step(0.0)) <= radius:
        return U @ step(0.0)                     # Newton's step
    lo = max(0.0, -h[0])
    if not np.any(gp[h <= h[0] + htol]):          # no force along the lowest curvature
        dz = step(lo)
        if np.linalg.norm(dz) <= radius:
            if h[0] < -htol:
                dz[0] += np.sqrt(max(radius ** 2 - float(dz @ dz), 0.0))
            return U @ dz
    hi = lo + np.linalg.norm(gp) / radius + htol
    for _ in range(200):                          # |dz(mu)| decreases in mu: bisection
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if np.linalg.norm(step(mid)) > radius else (lo, mid)
    return U @ step(hi)


def _newton(statics: _Statics, q: np.ndarray):
    """Newton's method from q; (q, iterations) when the steps shrink to convergence, else
    None."""
    previous = np.inf
    for it in range(NEWTON_ITER):
        g, K, V, _, scale = statics.reduced(q)
        if statics.converged(g, K, scale):
            return q, it
        h, U = np.linalg.eigh(K)
        gp = U.T @ g
        stiff = np.abs(h) > NEUTRAL_RTOL * max(float(np.max(np.abs(h))), scale / statics.eq.length_scale)
        if np.any(np.abs(gp[~stiff]) > GRADIENT_RTOL * scale):
            return None             # a force along a direction without stiffness: no Newton
        dz = U[:, stiff] @ (-gp[stiff] / h[stiff])
        step = float(np.linalg.norm(dz))
        limit = NEWTON_REACH * statics.eq.length_scale if it == 0 else 0.5 * previous
        if not np.isfinite(step) or step > limit:
            return None
        try:
            q = statics.retract(q + V @ dz)
        except SolverError:
            return None
        previous = step
    return None


def _minimise(statics: _Statics, q: np.ndarray):
    """Trust-region Newton minimisation of the potential from q; (q, iterations)."""
    radius = 0.5 * statics.eq.length_scale
    W = statics.potential(q)
    for it in range(MAX_ITER):
        g, K, V, _, scale = statics.reduced(q)
        if statics.converged(g, K, scale):
            return q, it
        dz = _trust_step(g, K, radius, GRADIENT_RTOL * scale,
                         NEUTRAL_RTOL * max(float(np.max(np.abs(K), initial=0.0)),
                                            scale / statics.eq.length_scale))
        predicted = -(g @ dz + 0.5 * dz @ K @ dz)
        try:
            trial = statics.retract(q + V @ dz)
            W_trial = statics.potential(trial)
        except SolverError:
            radius *= 0.25
            continue
        actual = W - W_trial
        small = abs(predicted) <= 1e-13 * (abs(W) + scale * statics.eq.length_scale)
        ratio = 1.0 if small else actual / predicted
        if ratio < 0.25:
            radius *= 0.25
        elif ratio > 0.75 and np.linalg.norm(dz) > 0.9 * radius:
            radius = min(2 * radius, 1e3 * statics.eq.length_scale)
        if ratio > 0.1 or (small and actual > -1e-13 * (abs(W) + 1.0)):
            q, W = trial, W_trial
        if np.max(np.abs(q)) > 1e6 * statics.eq.length_scale:
            break
    raise SolverError(f"no static equilibrium found near the initial positions: after {it + 1} "
                      f"steps the potential energy still falls (|reduced force| "
                      f"{np.max(np.abs(g), initial=0.0):.3g}, largest coordinate "
                      f"{np.max(np.abs(q)):.3g}): the loads are not balanced by the joints "
                      "and springs", 0.0)


def classify(stiffness: np.ndarray, scale: float, length: float) -> str:
    """stable, unstable or neutral from the reduced stiffness eigenvalues."""
    if stiffness.size == 0:
        return "stable"
    tol = NEUTRAL_RTOL * max(float(np.max(np.abs(stiffness))), scale / length, 1e-300)
    if np.min(stiffness) < -tol:
        return "unstable"
    return "neutral" if np.min(stiffness) <= tol else "stable"


def equilibrium(scene: Scene | str, parameters: dict[str, float] | None = None) -> Equilibrium:
    """The static equilibrium nearest the scene's initial positions, drivers held at their
    t = 0 values, inputs at their initial values, velocities zero.

    ``scene``: a Scene, a scene file or a shipped scene's name; ``parameters``: values of
    the scene's parameters (names as the FMU's). Raises ``SolverError`` when no equilibrium
    is found (an unbalanced load), ``AssemblyError`` when the scene cannot be assembled.
    """
    scene = held_scene(prepare(scene, parameters), 0.0)
    eq = Equations(scene)
    statics = _Statics(eq)
    q0, _ = assemble(eq, 0.0, statics.u)
    found = _newton(statics, q0)
    method = "newton"
    if found is None:
        found, method = _minimise(statics, q0), "trust-region minimisation of the potential"
    q, iterations = found
    g, K, V, lam, scale = statics.reduced(q)
    stiffness = np.linalg.eigvalsh(K) if K.size else np.zeros(0)
    Psi = eq.constraints(0.0, q, u=statics.u)[0] if eq.m else np.zeros(0)
    coords = MinimalCoordinates(eq, 0.0, q, statics.u).names
    return Equilibrium(scene=scene, q=q, lam=lam,
                       stability=classify(stiffness, scale, eq.length_scale),
                       stiffness=stiffness, residual=float(np.max(np.abs(g), initial=0.0)),
                       constraint_residual=float(np.max(np.abs(Psi), initial=0.0)),
                       method=method, iterations=iterations, coordinates=coords)


__all__ = ["Equilibrium", "equilibrium", "coordinate_names"]
