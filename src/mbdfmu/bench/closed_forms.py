"""Exact references of the benchmark problems, used by ``mbdfmu bench`` at run time.

Closed forms only, of the benchmark problems in docs/accuracy.md (P1, P2, P4, P6) and
docs/problems.md (P8-P11: couplers, rolling, a pin in a slot), with
numpy and scipy: nothing here calls the solver, so the solver cannot leak into its own
reference. (``tests/exact_solutions.py`` is the tests' independent set; this is the package's.)
Conventions: SI units, gravity ``g`` in -y, pendulum angles from the downward vertical,
crank angles from +x.
"""

from __future__ import annotations

import math

import numpy as np
from scipy.integrate import solve_ivp
from scipy.special import ellipj, ellipk

G = 9.81
# rtol = atol of the P2 one-degree-of-freedom integration (P2: "1e-13 gives B0 to ~1e-12").
REDUCTION_TOL = 1e-13


def pendulum(t, *, L=1.0, m=1.0, J=0.0, g=G, theta0=math.pi / 2) -> dict:
    """P1: a mass ``m`` (own inertia ``J``) on a massless link ``L``, released at rest.

    ``sin(theta/2) = k sn(K(k^2) - w0 t | k^2)``, ``k = sin(theta0/2)``,
    ``w0 = sqrt(m g L / (m L^2 + J))``. Returns arrays like ``t``: ``theta`` (rad),
    ``theta_dot`` (rad/s), ``x``, ``y`` (m, pivot at the origin), and the scalar ``period`` (s).
    """
    t = np.asarray(t, dtype=float)
    w0 = math.sqrt(m * g * L / (m * L * L + J))
    k = math.sin(theta0 / 2.0)
    K = ellipk(k * k)
    sn, cn, _dn, _ph = ellipj(K - w0 * t, k * k)
    theta = 2.0 * np.arcsin(np.clip(k * sn, -1.0, 1.0))
    return {"theta": theta, "theta_dot": -2.0 * k * w0 * cn,
            "x": L * np.sin(theta), "y": -L * np.cos(theta), "period": 4.0 * K / w0}


def n_four_bar_B0(t, N: int, *, m=1.0, L=1.0, g=G, theta0=math.pi / 2,
                  theta_dot0=-1.0) -> dict:
    """P2: B0 (top of the first crank) of the N-four-bar from the exact one-DOF reduction.

    ``Meff theta'' = -C cos(theta)``, ``Meff = m L^2 ((N+1)/3 + N)``,
    ``C = m g L ((N+1)/2 + N)``, theta(0) = theta0 (P2: pi/2), theta'(0) = theta_dot0 (P2:
    -1), ``B0 = L (cos, sin)(theta)``; integrated by DOP853 at 1e-13. ``t`` sorted, >= 0.
    Returns ``theta``, ``x``, ``y``.
    """
    t = np.atleast_1d(np.asarray(t, dtype=float))
    meff = m * L * L * ((N + 1) / 3.0 + N)
    c = m * g * L * ((N + 1) / 2.0 + N)
    y0 = [float(theta0), float(theta_dot0)]
    theta = np.empty_like(t)
    later = t > 0
    theta[~later] = y0[0]
    if later.any():
        sol = solve_ivp(lambda _t, y: [y[1], -c * math.cos(y[0]) / meff], (0.0, float(t[-1])),
                        y0, method="DOP853", t_eval=t[later], rtol=REDUCTION_TOL,
                        atol=REDUCTION_TOL)
        theta[later] = sol.y[0]
    return {"theta": theta, "x": L * np.cos(theta), "y": L * np.sin(theta)}


def slider_crank(theta, *, r: float, l: float) -> dict:
    """P4: centred slider-crank kinematics from the crank angle ``theta`` (rad, from +x).

    ``sin(phi) = -(r/l) sin(theta)``, ``x_B = r cos(theta) + l cos(phi)``; the rod's centre
    (uniform rod) is half-way between the crank pin A and the slider pin B.
    Returns ``phi`` (rad), ``xB`` (m), ``rod_x``, ``rod_y`` (m).
    """
    th = np.asarray(theta, dtype=float)
    phi = np.arcsin(-(r / l) * np.sin(th))
    xB = r * np.cos(th) + l * np.cos(phi)
    return {"phi": phi, "xB": xB, "rod_x": r * np.cos(th) + 0.5 * l * np.cos(phi),
            "rod_y": r * np.sin(th) + 0.5 * l * np.sin(phi)}


def cart_pole_invariants(theta, *, M: float, m: float, l: float, J=0.0, g=G,
                         theta0=math.pi / 2) -> dict:
    """P6: what zero horizontal momentum and energy fix, as functions of the pole angle.

    Cart position ``x = m l (sin theta0 - sin theta) / (M + m)`` and
    ``theta'^2 = 2 m g l (cos theta - cos theta0) / (m l^2 (M + m sin^2 theta)/(M + m) + J)``
    (``J`` the bob's own inertia; J = 0 gives P6's formula). Returns ``x`` and ``theta_dot_sq``.
    """
    theta = np.asarray(theta, dtype=float)
    denom = m * l * l * (M + m * np.sin(theta) ** 2) / (M + m) + J
    return {"x": m * l * (math.sin(theta0) - np.sin(theta)) / (M + m),
            "theta_dot_sq": 2.0 * m * g * l * (np.cos(theta) - math.cos(theta0)) / denom}


def geared(t, *, torque: float, inertia_in: float, inertia_out: float, ratio: float) -> dict:
    """P8, P9: a torque on an input of inertia ``inertia_in`` coupled to an output (inertia or
    mass ``inertia_out``) whose coordinate moves ``ratio`` times the input's, from rest and
    zero: the reduced inertia is ``inertia_in + ratio^2 inertia_out``. Returns ``q_in``,
    ``q_out`` (rad or m)."""
    t = np.asarray(t, dtype=float)
    q_in = 0.5 * torque / (inertia_in + ratio ** 2 * inertia_out) * t ** 2
    return {"q_in": q_in, "q_out": ratio * q_in}


def disc_on_incline(t, *, mass: float, inertia: float, radius: float, slope: float,
                    start: float, g=G) -> dict:
    """P10: a disc rolling from rest at ``start`` (m along the line through the origin at
    ``slope``), its centre ``radius`` on the line's left: it accelerates down the line at
    g sin(slope) m r^2 / (m r^2 + J). Returns the centre ``x``, ``y`` and the angle ``phi``."""
    t = np.asarray(t, dtype=float)
    along = start - 0.5 * g * math.sin(slope) * mass * radius ** 2 / (
        mass * radius ** 2 + inertia) * t ** 2
    c, s = math.cos(slope), math.sin(slope)
    return {"x": along * c - radius * s, "y": along * s + radius * c,
            "phi": (start - along) / radius}


def rod_in_slot(t, *, mass=1.0, length=1.0, inertia=None, g=G, theta0=0.3) -> dict:
    """P11: a uniform rod whose top end slides in a frictionless horizontal slot, from rest
    ``theta0`` off the vertical. Its centre keeps x and sits at y = -(L/2) cos theta; with
    k = m L^2 / 4 the energy gives (k sin^2 theta + J) theta'' = -k sin theta cos theta
    theta'^2 - m g (L/2) sin theta, integrated by DOP853 at REDUCTION_TOL. ``t`` sorted,
    >= 0. Returns ``theta``, ``y`` (centre) and ``phi`` (body angle theta - pi/2)."""
    t = np.atleast_1d(np.asarray(t, dtype=float))
    J = mass * length ** 2 / 12.0 if inertia is None else inertia
    k, weight = mass * length ** 2 / 4.0, mass * g * length / 2.0

    def rhs(_t, y):
        sn, cs = math.sin(y[0]), math.cos(y[0])
        return [y[1], -(k * sn * cs * y[1] ** 2 + weight * sn) / (k * sn * sn + J)]

    theta = np.full_like(t, theta0)
    later = t > 0
    if later.any():
        sol = solve_ivp(rhs, (0.0, float(t[-1])), [theta0, 0.0], method="DOP853",
                        t_eval=t[later], rtol=REDUCTION_TOL, atol=REDUCTION_TOL)
        theta[later] = sol.y[0]
    return {"theta": theta, "y": -0.5 * length * np.cos(theta), "phi": theta - math.pi / 2}
