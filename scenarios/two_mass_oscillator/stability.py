"""Stability of the two-mass oscillator's co-simulation, in closed form.

Both FMUs integrate exactly, so one macro step of a master is a linear map of the
co-simulation's state: the two masses' states and the input polynomials each FMU holds
(an output with direct feedthrough, such as the coupling force, reads them). Its matrix
``M(h)`` is built here column by column from the subsystems' matrix exponentials and the
master's rules (FMI 2.0 semantics, as mbdfmu's fmpy master applies them):

* Jacobi: every input gets its source's output at t (and, with extrapolation order p, its
  derivatives 1..p at t); all step.
* Gauss-Seidel (mass1 first): mass1 as Jacobi; mass2 gets mass1's output at t + h, held
  (p = 0), or the polynomial from the output at t (and its derivative, p = 2) that ends at
  the output at t + h.

The co-simulation is stable where the spectral radius of ``M(h)`` is below 1; the largest
stable step is where it first crosses 1. Independent of mbdfmu's master and FMU code
(numpy and scipy only).
"""

from __future__ import annotations

import math

import numpy as np
from scipy.linalg import expm

INPUTS = ("force", "x_other", "v_other")
K = 3                                  # coefficients per input: value, d1, d2
N = 2 * (2 + K * len(INPUTS))          # two masses: state (2) and inputs (3 x 3)


class Mass:
    """One oscillator FMU: x' = A x + B u, outputs x, v, coupling force."""

    def __init__(self, m, c, d, cc, dc):
        self.a = np.array([[0.0, 1.0], [-(c + cc) / m, -(d + dc) / m]])
        self.b = np.array([[0.0, 0.0, 0.0], [1.0 / m, cc / m, dc / m]])
        self.c = {"x": np.array([1.0, 0.0]), "v": np.array([0.0, 1.0]),
                  "coupling_force": np.array([cc, dc])}
        self.d = {"x": np.zeros(3), "v": np.zeros(3), "coupling_force": np.array([0.0, -cc, -dc])}

    def step(self, s, u, h):
        """State after h with inputs u (3 x K Taylor coefficients at the step's start)."""
        n = 2 + K * 3
        f = np.zeros((n, n))
        f[:2, :2] = self.a
        for j in range(3):
            first = 2 + K * j
            f[:2, first] = self.b[:, j]
            for k in range(K - 1):
                f[first + k, first + k + 1] = 1.0
        z = np.concatenate([s, u.reshape(-1)])
        return (expm(f * h) @ z)[:2]

    def output(self, name, s, u, order=0):
        """Output ``name`` (order 0) or its time derivative (1, 2), inputs ``u`` now."""
        ds = [s, self.a @ s + self.b @ u[:, 0]]
        ds.append(self.a @ ds[1] + self.b @ u[:, 1])
        return float(self.c[name] @ ds[order] + self.d[name] @ u[:, order])


def shift(u, h):
    """Taylor coefficients of the input polynomials continued by h."""
    out = np.zeros_like(u)
    for k in range(K):
        out[:, k] = sum(u[:, j] * h ** (j - k) / math.factorial(j - k) for j in range(k, K))
    return out


def macro_step(masses, connections, z, h, algorithm, p):
    """One macro step of the linear co-simulation state z (see ``N``)."""
    s = [z[0:2], z[2 + K * 3:4 + K * 3]]
    u = [z[2:2 + K * 3].reshape(3, K).copy(), z[4 + K * 3:].reshape(3, K).copy()]

    def source(i, name, order=0, state=None):
        return masses[i].output(name, s[i] if state is None else state, u[i], order)

    connected = {(ti, inp) for _, (ti, inp) in connections}
    for i in (0, 1):                     # an input nobody drives stays 0 (as in the scenario)
        for j, name in enumerate(INPUTS):
            if (i, name) not in connected:
                u[i][j] = 0.0
    new_s, starts = list(s), {}
    for i in (0, 1):
        for (si, out), (ti, inp) in connections:
            if ti == i:
                starts[(si, out)] = [source(si, out, k) for k in range(p + 1)]
    for i in (0, 1):
        for (si, out), (ti, inp) in connections:
            if ti != i:
                continue
            j = INPUTS.index(inp)
            y = starts[(si, out)]
            coeffs = y + [0.0] * (K - len(y))
            if algorithm == "gauss-seidel" and si < i:      # the source stepped already
                u_end = shift(u[si], h)
                end = masses[si].output(out, new_s[si], u_end)
                if p == 0:
                    coeffs = [end, 0.0, 0.0]
                elif p == 1:
                    coeffs = [y[0], (end - y[0]) / h, 0.0]
                else:
                    coeffs = [y[0], y[1], 2 * (end - y[0] - y[1] * h) / h ** 2]
            u[i][j] = coeffs
        new_s[i] = masses[i].step(s[i], u[i], h)
    u = [shift(u[0], h), shift(u[1], h)]
    return np.concatenate([new_s[0], u[0].reshape(-1), new_s[1], u[1].reshape(-1)])


def amplification(masses, connections, h, algorithm="jacobi", p=0) -> np.ndarray:
    """M(h): column k is the macro step of the k-th unit vector."""
    return np.column_stack([macro_step(masses, connections, e, h, algorithm, p)
                            for e in np.eye(N)])


def spectral_radius(masses, connections, h, algorithm="jacobi", p=0) -> float:
    return float(np.abs(np.linalg.eigvals(amplification(masses, connections, h, algorithm,
                                                          p))).max())


def largest_stable_step(masses, connections, algorithm="jacobi", p=0, h_max=1.0,
                        points=400) -> float:
    """The first h (on a log grid from 1e-5 s, refined by bisection) where the spectral
    radius exceeds 1; ``h_max`` if it never does below it."""
    grid = np.geomspace(1e-5, h_max, points)
    previous = grid[0]
    for h in grid:
        if spectral_radius(masses, connections, h, algorithm, p) > 1.0:
            lo, hi = previous, h
            for _ in range(40):
                mid = math.sqrt(lo * hi)
                if spectral_radius(masses, connections, mid, algorithm, p) > 1.0:
                    hi = mid
                else:
                    lo = mid
            return lo
        previous = h
    return h_max


def from_scenario(scenario):
    """(masses, connections) of a two_mass_oscillator scenario (start values as given)."""
    p = scenario.parameters

    def mass(i):
        g = lambda k, default=0.0: float(p.get(f"mass{i}.{k}", default))  # noqa: E731
        return Mass(g("m", 1.0), g("c", 100.0), g("d", 0.1), g("cc"), g("dc"))

    index = {"mass1": 0, "mass2": 1}
    connections = [((index[c.source_instance], c.source_variable),
                    (index[c.target_instance], c.target_variable)) for c in scenario.connections]
    return [mass(1), mass(2)], connections


def start_state(masses, connections, states, p=0) -> np.ndarray:
    """The co-simulation state z at t0 after the master's start: every input holds its
    source's output and, with extrapolation order p, the source's derivatives 1..p, all
    consistent (an output that reads an input has derivatives that need the input's, so
    the exchange is repeated until the chain has settled)."""
    s = [np.asarray(x, dtype=float) for x in states]
    u = [np.zeros((3, K)), np.zeros((3, K))]
    for _ in range(2 * (p + 1)):
        for (si, out), (ti, inp) in connections:
            u[ti][INPUTS.index(inp)][:p + 1] = [masses[si].output(out, s[si], u[si], k)
                                                for k in range(p + 1)]
    return np.concatenate([s[0], u[0].reshape(-1), s[1], u[1].reshape(-1)])


def positions(masses, connections, z, h, n, algorithm="jacobi", p=0) -> np.ndarray:
    """x1 and x2 at t0 + k h, k = 0..n, of the co-simulation started at z (n x 2 rows)."""
    out = [(z[0], z[2 + K * 3])]
    for _ in range(n):
        z = macro_step(masses, connections, z, h, algorithm, p)
        out.append((z[0], z[2 + K * 3]))
    return np.array(out)
