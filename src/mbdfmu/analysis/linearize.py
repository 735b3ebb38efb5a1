"""Linearization in minimal coordinates: ``linearize(scene, t=0.0, equilibrium=False)``.

The state is x = (z, z'), the independent coordinates chosen by coordinate partitioning at
the operating point (``operating.MinimalCoordinates``) and their rates; the inputs u are the
scene's inputs, the outputs y the scene's outputs (its ``outputs`` globs, else what its FMU
reports: every body state, joint reaction and driver effort). The nonlinear reduced model

    x' = f(x, u) = (z', z''),   y = h(x, u)

is evaluated by solving the dependent coordinates from the constraints, the dependent rates
from the velocity constraints and (q'', lam) from eq. (14); A, B, C, D are its Jacobians at
the operating point by central differences (step about eps^(1/3) of each variable's scale,
which balances the O(h^2) truncation against the O(eps / h) round-off). The same reduced model is what a
simulation integrates, so A and B agree with finite differences of ``simulate()``.

Operating point: the state a simulation reaches at ``t`` (the assembled initial state at
t = 0), inputs at their initial values; or, with ``equilibrium=True``, the static
equilibrium (``equilibrium.py``) with drivers held at their t = 0 values.

Inputs: a force input (``push.fx``, ``drive.torque``, ``spring.actuator``) is one column
of B and D. An input-driven driver gives three columns, its ``position``, ``velocity`` and
``acceleration``, each with the other two held (the FMU takes the same three); a position
signal p(t) alone enters as B_pos p + B_vel p' + B_acc p''.

Modes: the eigenvalues of A, sorted by natural frequency |lam| / (2 pi) (conjugates
adjacent, positive imaginary part first), with damping ratios -Re(lam) / |lam| (MATLAB's
``damp``: -1 for a real unstable pole, None for a zero eigenvalue).
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..equations import Equations
from ..errors import SettingError
from ..model.scene import Scene
from ..model.variables import inputs, outputs, selected_outputs
from ..simulation import Simulation
from .equilibrium import equilibrium as find_equilibrium
from .operating import MinimalCoordinates, input_values, input_vector, prepare

# Central-difference step relative to each variable's scale: about eps^(1/3).
FD_STEP = 6e-6
# Eigenvalues below this (1/s) count as zero: no frequency, no damping ratio.
ZERO_EIGENVALUE = 1e-9
# Damping ratios below this are round-off of an undamped mode (far below what the central
# differences resolve): reported as 0.
ROUND_OFF_RATIO = 1e-9


@dataclass
class Linearization:
    """x' = A x + B u, y = C x + D u about an operating point (deviations from it).

    ``states``: the independent coordinates then their rates (``crank.phi``,
    ``crank.omega``); ``inputs``, ``outputs``: variable names; ``eigenvalues`` (complex),
    ``frequencies_hz`` and ``damping_ratios`` sorted by frequency; ``t``, ``q``, ``qd``: the
    operating point; ``at_equilibrium`` whether it is the static equilibrium.
    """

    states: list[str]
    inputs: list[str]
    outputs: list[str]
    A: np.ndarray
    B: np.ndarray
    C: np.ndarray
    D: np.ndarray
    eigenvalues: np.ndarray
    frequencies_hz: np.ndarray
    damping_ratios: list[float | None]
    t: float = 0.0
    q: np.ndarray = field(default_factory=lambda: np.zeros(0))
    qd: np.ndarray = field(default_factory=lambda: np.zeros(0))
    at_equilibrium: bool = False
    stability: str = ""

    @property
    def coordinates(self) -> list[str]:
        return self.states[:len(self.states) // 2]

    def to_dict(self) -> dict:
        def rows(M):
            return [[float(v) for v in row] for row in M]
        return {"states": self.states, "inputs": self.inputs, "outputs": self.outputs,
                "A": rows(self.A), "B": rows(self.B), "C": rows(self.C), "D": rows(self.D),
                "eigenvalues": [[float(e.real), float(e.imag)] for e in self.eigenvalues],
                "frequencies_hz": [float(f) for f in self.frequencies_hz],
                "damping_ratios": list(self.damping_ratios),
                "operating_point": {"t": self.t, "equilibrium": self.at_equilibrium,
                                    "q": self.q.tolist(), "qd": self.qd.tolist()},
                "stability": self.stability}

    def write_json(self, path: str | Path) -> Path:
        path = Path(path)
        path.write_text(json.dumps(self.to_dict(), indent=1) + "\n", encoding="utf-8")
        return path


def modes(A: np.ndarray):
    """(eigenvalues, natural frequencies in Hz, damping ratios), sorted by frequency."""
    lam = np.linalg.eigvals(A) if A.size else np.zeros(0, dtype=complex)
    lam = np.asarray(lam, dtype=complex)
    order = sorted(range(len(lam)), key=lambda k: (round(abs(lam[k]), 12), -lam[k].imag,
                                                   lam[k].real))
    lam = lam[order]
    wn = np.abs(lam)
    zeta = [None if w <= ZERO_EIGENVALUE else _clean(-e.real / w) for e, w in zip(lam, wn)]
    return lam, wn / (2 * math.pi), zeta


def _clean(ratio: float) -> float:
    """A damping ratio, with round-off (below ROUND_OFF_RATIO) shown as 0."""
    return 0.0 if abs(ratio) < ROUND_OFF_RATIO else float(ratio)


class _ReducedModel:
    """f(x, u) and h(x, u) of a scene in the minimal coordinates of one operating point."""

    def __init__(self, scene: Scene, t: float, q: np.ndarray, u0):
        self.eq = eq = Equations(scene)
        self.t = t
        self.coords = MinimalCoordinates(eq, t, q, u0)
        names = [v.name for v in outputs(scene)]
        self.output_names = [v.name for v in selected_outputs(scene)]
        self.output_index = [names.index(n) for n in self.output_names]

    def __call__(self, x: np.ndarray, uvec: np.ndarray):
        d = self.coords.dof
        u = input_values(self.eq.layout, uvec)
        q, qd = self.coords.state(x[:d], x[d:], u)
        qdd, lam = self.eq.accelerations(self.t, q, qd, u)
        y = self.eq.output_values(self.t, q, qd, qdd, lam, u)[self.output_index]
        return np.concatenate((x[d:], qdd[self.coords.independent])), y


def _jacobians(model: _ReducedModel, x0: np.ndarray, u0: np.ndarray, scales: np.ndarray):
    """d(f, h)/d(x, u) by central differences: ([A B], [C D])."""
    v0 = np.concatenate((x0, u0))
    nx = len(x0)
    columns_f, columns_h = [], []
    for k in range(len(v0)):
        step = FD_STEP * max(scales[k], abs(v0[k]))
        vp, vm = v0.copy(), v0.copy()
        vp[k] += step
        vm[k] -= step
        fp, hp = model(vp[:nx], vp[nx:])
        fm, hm = model(vm[:nx], vm[nx:])
        columns_f.append((fp - fm) / (2 * step))
        columns_h.append((hp - hm) / (2 * step))
    F = np.array(columns_f).T.reshape(2 * model.coords.dof, len(v0))
    H = np.array(columns_h).T.reshape(len(model.output_names), len(v0))
    return F, H


def _operating_point(scene: Scene, t: float, at_equilibrium: bool):
    """(scene as linearized, t, q, q', stability) of the operating point."""
    if at_equilibrium:
        eq = find_equilibrium(scene)
        return eq.scene, 0.0, eq.q, np.zeros_like(eq.q), eq.stability
    sim = Simulation(scene)
    if t > 0:
        sim.advance(t)
    return scene, sim.t, sim.q.copy(), sim.qd.copy(), ""


def linearize(scene: Scene | str, t: float = 0.0, equilibrium: bool = False,
              parameters: dict[str, float] | None = None) -> Linearization:
    """The mechanism linearized in minimal coordinates at time ``t`` of a run from its
    initial state, or at its static equilibrium (``equilibrium=True``; drivers held at
    their t = 0 values). ``scene``: a Scene, a file or a shipped scene's name;
    ``parameters``: values of its parameters (names as the FMU's)."""
    if isinstance(t, bool) or not isinstance(t, (int, float)) or not (math.isfinite(t) and t >= 0):
        raise SettingError("t", f"the operating time (--at) must be finite and not negative, "
                           f"got {t!r}")
    scene = prepare(scene, parameters)
    scene, t, q, qd, stability = _operating_point(scene, float(t), equilibrium)
    u0 = Equations(scene).layout.initial()
    model = _ReducedModel(scene, t, q, u0)
    ind = model.coords.independent
    x0 = np.concatenate((q[ind], qd[ind]))
    uvec = input_vector(u0)
    length = model.eq.length_scale
    position_scale = np.where(ind % 3 == 2, 1.0, length)
    scales = np.concatenate((position_scale, np.ones(len(ind)), np.ones(len(uvec))))
    F, H = _jacobians(model, x0, uvec, scales)
    nx = len(x0)
    lam, freq, zeta = modes(F[:, :nx])
    if not stability:
        stability = _dynamic_stability(lam)
    return Linearization(
        states=model.coords.names + model.coords.rate_names,
        inputs=[v.name for v in inputs(scene)], outputs=model.output_names,
        A=F[:, :nx], B=F[:, nx:], C=H[:, :nx], D=H[:, nx:], eigenvalues=lam,
        frequencies_hz=freq, damping_ratios=zeta, t=t, q=q, qd=qd,
        at_equilibrium=equilibrium, stability=stability)


def _dynamic_stability(lam: np.ndarray) -> str:
    """Of the linearized motion: asymptotically stable, unstable or marginal."""
    if lam.size == 0:
        return "stable"
    scale = max(float(np.max(np.abs(lam))), 1.0)
    if np.any(lam.real > 1e-7 * scale):
        return "unstable"
    return "stable" if np.all(lam.real < -1e-7 * scale) else "marginal"


__all__ = ["Linearization", "linearize", "modes"]
