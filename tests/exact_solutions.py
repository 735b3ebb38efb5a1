"""Exact and independent reference solutions for the benchmark problems.

Everything here is computed from the problem statements in ``docs/problems.md``
(P1..P7) and textbook mechanics, with numpy and scipy only: nothing imports mbdfmu, so a bug in
the solver cannot leak into its own reference. Conventions follow that file: SI units, angles in
radians, gravity ``g`` acting in -y, pendulum angles ``theta`` measured from the downward vertical
(a point at distance ``L`` from the pivot sits at ``L (sin theta, -cos theta)``), crank angles in
P2, P4 and P5 measured from +x.

Scene helpers at the end parse scene TOML files with ``tomllib`` and evaluate joint residuals
with their own small kinematics, again independently of mbdfmu.
"""
from __future__ import annotations

import math
import tomllib
from pathlib import Path

import numpy as np
from scipy.integrate import solve_ivp
from scipy.special import ellipj, ellipk

G = 9.81  # m/s^2, the benchmarks' gravity
ODE_TOL = 1e-13  # rtol = atol of every reference integration (P2 asks for 1e-13)


def _rot(phi):
    """Rotation matrix A(phi) = [[cos, -sin], [sin, cos]] (FORMULATION.md, body to ground)."""
    c, s = math.cos(phi), math.sin(phi)
    return np.array([[c, -s], [s, c]])


def _perp(v):
    """The vector v turned by +90 degrees: omega x v for a planar rotation rate omega = 1."""
    return np.array([-v[1], v[0]])


def _integrate(rhs, t, y0, tol, what):
    """DOP853 from t = 0 through the sorted, non-negative times ``t``; returns y at ``t``."""
    t = np.atleast_1d(np.asarray(t, dtype=float))
    if t.size == 0 or t[0] < 0 or np.any(np.diff(t) < 0):
        raise ValueError(f"{what}: times must be sorted and non-negative")
    y0 = np.asarray(y0, dtype=float)
    out = np.empty((y0.size, t.size))
    at_start = t == 0.0
    out[:, at_start] = y0[:, None]
    if at_start.all():
        return out
    sol = solve_ivp(rhs, (0.0, float(t[-1])), y0, method="DOP853", t_eval=t[~at_start],
                    rtol=tol, atol=tol)
    if not sol.success:
        raise RuntimeError(f"{what} failed: {sol.message}")
    out[:, ~at_start] = sol.y
    return out


# --------------------------------------------------------------------------------------------
# P1: simple and compound pendulum
# --------------------------------------------------------------------------------------------

def compound_pendulum(t, *, m, Lc, J, g=G, theta0=math.pi / 2):
    """Exact motion of a rigid body swinging about a fixed pivot, released at rest at ``theta0``.

    Source: P1 of BENCHMARK_PROBLEMS.md (IFToMM benchmark A01) generalised from a point mass to a
    rigid body: with the pivot inertia ``I = m Lc^2 + J`` the equation ``I theta'' = -m g Lc sin
    theta`` is the simple pendulum with ``w0 = sqrt(m g Lc / I)``, whose solution is
    ``sin(theta/2) = k sn(K(k^2) - w0 t | k^2)``, ``k = sin(theta0/2)`` (e.g. Lawden, *Elliptic
    Functions and Applications*, sec. 5.2). Differentiating, ``theta' = -2 k w0 cn(...)``.
    The pivot force on the body follows from Newton's law for the centre of mass:
    towards the pivot ``N = m g cos theta + m Lc theta'^2``; perpendicular, in the direction of
    increasing theta, ``T = m g sin theta J / I``.

    Parameters: ``t`` times (s, array-like); ``m`` mass (kg); ``Lc`` pivot-to-centre-of-mass
    distance (m); ``J`` inertia about the centre of mass (kg m^2); ``g``; ``theta0`` (rad,
    |theta0| < pi). Returns a dict of arrays shaped like ``t``: ``theta``, ``theta_dot``,
    ``theta_ddot``, ``x``, ``y`` (centre of mass, pivot at the origin), ``vx``, ``vy``,
    ``force_to_pivot`` (N) and ``force_perp`` (N), plus scalars ``w0`` and ``period``.
    """
    t = np.asarray(t, dtype=float)
    inertia = m * Lc**2 + J
    w0 = math.sqrt(m * g * Lc / inertia)
    k = math.sin(theta0 / 2.0)
    mk = k * k
    K = ellipk(mk)
    sn, cn, _dn, _ph = ellipj(K - w0 * t, mk)
    theta = 2.0 * np.arcsin(np.clip(k * sn, -1.0, 1.0))
    theta_dot = -2.0 * k * w0 * cn
    theta_ddot = -w0**2 * np.sin(theta)
    st, ct = np.sin(theta), np.cos(theta)
    return {
        "theta": theta,
        "theta_dot": theta_dot,
        "theta_ddot": theta_ddot,
        "x": Lc * st,
        "y": -Lc * ct,
        "vx": Lc * ct * theta_dot,
        "vy": Lc * st * theta_dot,
        "force_to_pivot": m * g * ct + m * Lc * theta_dot**2,
        "force_perp": m * g * st * J / inertia,
        "w0": w0,
        "period": 4.0 * K / w0,
    }


def simple_pendulum(t, *, L=1.0, m=1.0, J=0.0, g=G, theta0=math.pi / 2):
    """P1 (IFToMM A01): point mass ``m`` on a massless link ``L``, released at rest at theta0.

    Source: BENCHMARK_PROBLEMS.md P1, exact elliptic solution; ``J`` is the inertia of the bob
    about its own centre (a tiny one when the bob is modelled as a body), entering through
    ``w0 = sqrt(m g L / (m L^2 + J))``. Returns ``compound_pendulum``'s dict with ``x``, ``y`` the
    bob's position and ``tension`` (N, the rod force on the bob towards the pivot; for J = 0 it is
    ``m g (3 cos theta - 2 cos theta0)``).
    """
    out = compound_pendulum(t, m=m, Lc=L, J=J, g=g, theta0=theta0)
    out["tension"] = out["force_to_pivot"]
    return out


def rod_pendulum_closed_form(theta, *, m=1.0, L=1.0, g=G, theta0=math.pi / 2):
    """Uniform rod pinned at one end, released at rest at theta0: the formulas as printed in P1.

    Source: BENCHMARK_PROBLEMS.md P1 (rigid body version): ``theta'^2 = (3 g / L)(cos theta -
    cos theta0)``; pivot force on the rod along the rod towards the pivot
    ``m g (5/2 cos theta - 3/2 cos theta0)``; perpendicular, towards increasing theta,
    ``m g sin(theta) / 4``. Takes ``theta`` (array-like); returns a dict ``theta_dot_sq``,
    ``force_to_pivot``, ``force_perp``.
    """
    theta = np.asarray(theta, dtype=float)
    c0 = math.cos(theta0)
    return {
        "theta_dot_sq": 3.0 * g / L * (np.cos(theta) - c0),
        "force_to_pivot": m * g * (2.5 * np.cos(theta) - 1.5 * c0),
        "force_perp": m * g * np.sin(theta) / 4.0,
    }


# --------------------------------------------------------------------------------------------
# P2: N-four-bar and other parallel-crank mechanisms
# --------------------------------------------------------------------------------------------

def parallel_cranks(t, *, n_cranks, crank_mass, L, coupler_mass, g=G, theta0=math.pi / 2,
                    theta_dot0=-1.0):
    """One-degree-of-freedom reduction of parallel uniform cranks under translating couplers.

    Source: BENCHMARK_PROBLEMS.md P2 (IFToMM A02). On the true solution all cranks stay parallel
    (angle ``theta`` from +x) and the couplers translate with the crank tips, so
    ``Meff theta'' = -C cos theta`` with ``Meff = n m L^2 / 3 + Mc L^2`` and
    ``C = g L (n m / 2 + Mc)``, ``n`` cranks of mass ``m`` and length ``L`` and couplers of total
    mass ``Mc``. Integrated with scipy's DOP853 at rtol = atol = 1e-13.

    Returns a dict of arrays at ``t`` (sorted, starting at or after 0): ``theta``, ``theta_dot``,
    ``tip_x``, ``tip_y`` (top of the crank pinned at the origin, i.e. B0 of P2), ``energy``
    (``Meff theta'^2 / 2 + C sin theta``, constant on the exact solution), plus ``Meff``, ``C``.
    """
    t = np.atleast_1d(np.asarray(t, dtype=float))
    meff = n_cranks * crank_mass * L**2 / 3.0 + coupler_mass * L**2
    cgl = g * L * (n_cranks * crank_mass / 2.0 + coupler_mass)

    def rhs(_t, y):
        return [y[1], -cgl * math.cos(y[0]) / meff]

    theta, theta_dot = _integrate(rhs, t, [theta0, theta_dot0], ODE_TOL, "P2 reduction")
    return {
        "theta": theta,
        "theta_dot": theta_dot,
        "tip_x": L * np.cos(theta),
        "tip_y": L * np.sin(theta),
        "energy": 0.5 * meff * theta_dot**2 + cgl * np.sin(theta),
        "Meff": meff,
        "C": cgl,
    }


def n_four_bar(t, N, *, m=1.0, L=1.0, g=G):
    """P2 (IFToMM A02): position of B0, the top of the first crank, of the N-four-bar.

    Source: BENCHMARK_PROBLEMS.md P2: ``Meff = m L^2 ((N+1)/3 + N)``, ``C = m g L ((N+1)/2 + N)``,
    theta(0) = pi/2, theta'(0) = -1, ``B0 = L (cos theta, sin theta)``; this is
    ``parallel_cranks`` with N+1 cranks and N couplers of mass m. Returns its dict, with
    ``B0_x``, ``B0_y`` added.
    """
    out = parallel_cranks(t, n_cranks=N + 1, crank_mass=m, L=L, coupler_mass=N * m, g=g,
                          theta0=math.pi / 2, theta_dot0=-1.0)
    out["B0_x"], out["B0_y"] = out["tip_x"], out["tip_y"]
    return out


# --------------------------------------------------------------------------------------------
# P4: slider-crank
# --------------------------------------------------------------------------------------------

def slider_crank(theta, w, *, r, l, crank_mass, crank_inertia, rod_mass, rod_inertia,
                 slider_mass, gravity=(0.0, -G), load=(0.0, 0.0)):
    """Kinematics and required driving torque of a centred slider-crank at constant crank rate.

    Source: BENCHMARK_PROBLEMS.md P4 for the kinematics (phi the rod angle from +x, ``x_B`` the
    slider); the centres of mass are the mid-points of uniform crank and rod (crank centre at
    ``r/2``, rod centre half-way between crank pin A and slider pin B) and the slider's pin B.
    The driving torque comes from the power balance over all bodies,
    ``tau w = dT/dt - sum m g.v - F_load.v_B`` with ``dT/dt = sum (m v.a + J omega alpha)``,
    the crank's angular acceleration being zero.

    Parameters: ``theta`` crank angle(s) (rad, array-like); ``w`` crank rate (rad/s); lengths
    (m), masses (kg), inertias about the centres of mass (kg m^2); ``gravity`` and ``load``
    (force on the slider) as 2-vectors in the ground frame. Returns a dict of arrays: ``phi``,
    ``phi_d``, ``phi_dd``, ``xB``, ``xB_d``, ``xB_dd``; per body ``<b>_x``, ``<b>_y``, ``<b>_vx``,
    ``<b>_vy``, ``<b>_ax``, ``<b>_ay``, ``<b>_omega`` for b in crank, rod, slider; ``kinetic``
    (J), ``power_gravity`` and ``power_load`` (W, on the mechanism), ``torque`` (N m);
    joint forces in the ground frame from Newton-Euler, each shaped (2, ...): ``force_O`` (ground
    on crank), ``force_A`` (crank on rod), ``force_B`` (rod on slider); ``guide_normal`` (guide on
    slider, along +y) and ``torque_newton_euler``, the torque again from the crank's moment
    balance (it must equal ``torque``).
    """
    th = np.asarray(theta, dtype=float)
    st, ct = np.sin(th), np.cos(th)
    sphi = -(r / l) * st
    phi = np.arcsin(sphi)
    cphi = np.cos(phi)
    phi_d = -r * ct * w / (l * cphi)
    xB = r * ct + l * cphi
    xB_d = -r * w * st - l * phi_d * sphi
    phi_dd = (r * w**2 * st + l * phi_d**2 * sphi) / (l * cphi)
    xB_dd = -r * w**2 * ct - l * phi_d**2 * cphi - l * phi_dd * sphi

    # centres of mass: position, velocity, acceleration (crank at constant rate w)
    crank = dict(x=0.5 * r * ct, y=0.5 * r * st,
                 vx=-0.5 * r * w * st, vy=0.5 * r * w * ct,
                 ax=-0.5 * r * w**2 * ct, ay=-0.5 * r * w**2 * st,
                 omega=np.full_like(th, w), alpha=np.zeros_like(th))
    rod = dict(x=r * ct + 0.5 * l * cphi, y=r * st + 0.5 * l * sphi,
               vx=-r * w * st - 0.5 * l * phi_d * sphi,
               vy=r * w * ct + 0.5 * l * phi_d * cphi,
               ax=-r * w**2 * ct - 0.5 * l * (phi_dd * sphi + phi_d**2 * cphi),
               ay=-r * w**2 * st + 0.5 * l * (phi_dd * cphi - phi_d**2 * sphi),
               omega=phi_d, alpha=phi_dd)
    slider = dict(x=xB, y=np.zeros_like(th), vx=xB_d, vy=np.zeros_like(th),
                  ax=xB_dd, ay=np.zeros_like(th),
                  omega=np.zeros_like(th), alpha=np.zeros_like(th))
    bodies = {"crank": (crank, crank_mass, crank_inertia),
              "rod": (rod, rod_mass, rod_inertia),
              "slider": (slider, slider_mass, 0.0)}

    out = {"phi": phi, "phi_d": phi_d, "phi_dd": phi_dd, "xB": xB, "xB_d": xB_d,
           "xB_dd": xB_dd}
    kinetic = np.zeros_like(th)
    dT = np.zeros_like(th)
    p_grav = np.zeros_like(th)
    gx, gy = gravity
    for name, (k, mass, inertia) in bodies.items():
        for key in ("x", "y", "vx", "vy", "ax", "ay", "omega"):
            out[f"{name}_{key}"] = k[key]
        kinetic += 0.5 * mass * (k["vx"]**2 + k["vy"]**2) + 0.5 * inertia * k["omega"]**2
        dT += mass * (k["vx"] * k["ax"] + k["vy"] * k["ay"]) + inertia * k["omega"] * k["alpha"]
        p_grav += mass * (gx * k["vx"] + gy * k["vy"])
    p_load = load[0] * xB_d  # the slider moves along x only
    out["kinetic"] = kinetic
    out["power_gravity"] = p_grav
    out["power_load"] = p_load
    out["torque"] = (dT - p_grav - p_load) / w

    # Joint forces by Newton-Euler, from the slider inwards (ground frame, N):
    # slider along x: m_s xB'' = F_Bx + load_x (the guide takes no force along the guide);
    # rod moment about its centre: d x F_B = -J_r alpha_r - (d/2) x m_r (a_G - g), d = B - A;
    # rod: F_A = m_r (a_G - g) + F_B; crank: F_O = m_c (a_c - g) + F_A;
    # slider across the guide: N = m_s (0 - g_y) - F_By.
    def cross(ux, uy, vx, vy):
        return ux * vy - uy * vx

    dx, dy = l * cphi, l * sphi
    mr_ax, mr_ay = rod_mass * (rod["ax"] - gx), rod_mass * (rod["ay"] - gy)
    fbx = slider_mass * xB_dd - load[0]
    rhs = -rod_inertia * phi_dd - cross(0.5 * dx, 0.5 * dy, mr_ax, mr_ay)
    fby = (rhs + dy * fbx) / dx
    fax, fay = mr_ax + fbx, mr_ay + fby
    fox = crank_mass * (crank["ax"] - gx) + fax
    foy = crank_mass * (crank["ay"] - gy) + fay
    out["force_B"] = np.array([fbx, fby])      # on the slider, from the rod
    out["force_A"] = np.array([fax, fay])      # on the rod, from the crank
    out["force_O"] = np.array([fox, foy])      # on the crank, from the ground
    out["guide_normal"] = -slider_mass * gy - load[1] - fby   # on the slider, +y
    # the same torque from the crank's moment balance about O (alpha = 0):
    # tau = r_A x F_A + r_c x m_c (a_c - g)
    out["torque_newton_euler"] = (cross(r * ct, r * st, fax, fay)
                                  + cross(crank["x"], crank["y"],
                                          crank_mass * (crank["ax"] - gx),
                                          crank_mass * (crank["ay"] - gy)))
    return out


# --------------------------------------------------------------------------------------------
# P5: four-bar (Freudenstein)
# --------------------------------------------------------------------------------------------

def freudenstein(theta2, w2, *, a, b, c, d, branch=-1):
    """Coupler and rocker angles and rates of a four-bar from the crank angle (Freudenstein).

    Source: BENCHMARK_PROBLEMS.md P5 (Norton, *Design of Machinery*, sec. 4.5 and 6.7): crank a
    (theta2) pinned at the origin, coupler b (theta3), rocker c (theta4) pinned at (d, 0);
    ``branch = -1`` takes the "-" root of both half-angle equations (the open circuit),
    ``branch = +1`` the crossed one. Angles are wrapped to (-pi, pi].
    Returns a dict ``theta3``, ``theta4``, ``w3``, ``w4`` (arrays like theta2).
    """
    th2 = np.asarray(theta2, dtype=float)
    K1, K2, K3 = d / a, d / c, (a * a - b * b + c * c + d * d) / (2 * a * c)
    K4, K5 = d / b, (c * c - d * d - a * a - b * b) / (2 * a * b)
    c2, s2 = np.cos(th2), np.sin(th2)
    A = c2 - K1 - K2 * c2 + K3
    B = -2.0 * s2
    C = K1 - (K2 + 1.0) * c2 + K3
    D = c2 - K1 + K4 * c2 + K5
    E = -2.0 * s2
    F = K1 + (K4 - 1.0) * c2 + K5
    th4 = 2.0 * np.arctan2(-B + branch * np.sqrt(B * B - 4 * A * C), 2 * A)
    th3 = 2.0 * np.arctan2(-E + branch * np.sqrt(E * E - 4 * D * F), 2 * D)
    th3 = np.angle(np.exp(1j * th3))
    th4 = np.angle(np.exp(1j * th4))
    w3 = a * w2 * np.sin(th4 - th2) / (b * np.sin(th3 - th4))
    w4 = a * w2 * np.sin(th2 - th3) / (c * np.sin(th4 - th3))
    return {"theta3": th3, "theta4": th4, "w3": w3, "w4": w4}


# --------------------------------------------------------------------------------------------
# P6: light cart-pole
# --------------------------------------------------------------------------------------------

def cart_pole_invariants(theta, *, M, m, l, J=0.0, g=G, theta0=math.pi / 2):
    """Exact quadratures of the cart-pole released at rest (zero horizontal momentum).

    Source: BENCHMARK_PROBLEMS.md P6, extended by the bob's own inertia ``J`` (the bob modelled
    as a body turning with the pole). Momentum ``(M+m) x' + m l cos(theta) theta' = 0`` gives
    ``x = m l (sin theta0 - sin theta) / (M + m)`` (cart position), and energy gives
    ``theta'^2 = 2 m g l (cos theta - cos theta0) / (m l^2 (M + m sin^2 theta)/(M + m) + J)``,
    which for J = 0 is P6's ``2 g (M+m)(cos theta - cos theta0) / (l (M + m sin^2 theta))``.
    Note that J = 1e-6 halves theta'^2 at the bottom when M = 1e-6.
    Returns a dict ``theta_dot_sq``, ``x``.
    """
    theta = np.asarray(theta, dtype=float)
    denom = m * l * l * (M + m * np.sin(theta)**2) / (M + m) + J
    return {
        "theta_dot_sq": 2.0 * m * g * l * (np.cos(theta) - math.cos(theta0)) / denom,
        "x": m * l * (math.sin(theta0) - np.sin(theta)) / (M + m),
    }


# --------------------------------------------------------------------------------------------
# P7: double pendulum
# --------------------------------------------------------------------------------------------

def _double_pendulum_matrices(th1, th2, w1, w2, m1, m2, l1, l2, J1, J2, g):
    c12 = math.cos(th1 - th2)
    s12 = math.sin(th1 - th2)
    mass = np.array([[(m1 + m2) * l1**2 + J1, m2 * l1 * l2 * c12],
                     [m2 * l1 * l2 * c12, m2 * l2**2 + J2]])
    rhs = np.array([-m2 * l1 * l2 * s12 * w2**2 - (m1 + m2) * g * l1 * math.sin(th1),
                    m2 * l1 * l2 * s12 * w1**2 - m2 * g * l2 * math.sin(th2)])
    return mass, rhs


def double_pendulum_energy(th1, th2, w1, w2, *, m1=1.0, m2=1.0, l1=1.0, l2=1.0, J1=0.0, J2=0.0,
                           g=G):
    """Total energy of the double pendulum (P7), potential datum y = 0 at the pivot.

    Source: BENCHMARK_PROBLEMS.md P7 and the textbook Lagrangian (e.g. Goldstein, ch. 1): bobs at
    ``p1 = l1 (sin th1, -cos th1)``, ``p2 = p1 + l2 (sin th2, -cos th2)``, angles from the
    downward vertical; each bob, of inertia J about itself, turns with its own link.
    ``E = 1/2 [(m1+m2) l1^2 + J1] w1^2 + m2 l1 l2 cos(th1-th2) w1 w2 + 1/2 (m2 l2^2 + J2) w2^2
    - (m1+m2) g l1 cos th1 - m2 g l2 cos th2``. Array-like arguments broadcast.
    """
    th1, th2, w1, w2 = (np.asarray(v, dtype=float) for v in (th1, th2, w1, w2))
    kin = (0.5 * ((m1 + m2) * l1**2 + J1) * w1**2
           + m2 * l1 * l2 * np.cos(th1 - th2) * w1 * w2
           + 0.5 * (m2 * l2**2 + J2) * w2**2)
    pot = -(m1 + m2) * g * l1 * np.cos(th1) - m2 * g * l2 * np.cos(th2)
    return kin + pot


def double_pendulum(t, *, m1=1.0, m2=1.0, l1=1.0, l2=1.0, J1=0.0, J2=0.0, g=G,
                    th1=math.pi / 2, th2=math.pi / 2, w1=0.0, w2=0.0):
    """P7: double pendulum trajectory from the Lagrange equations, DOP853 at 1e-13.

    Source: BENCHMARK_PROBLEMS.md P7; equations of motion ``M(th) th'' = f(th, w)`` of the
    Lagrangian in ``double_pendulum_energy`` (bob inertias J1, J2 included). Chaotic: only a few
    seconds are meaningful for trajectory comparisons. Returns a dict of arrays at ``t``:
    ``th1``, ``th2``, ``w1``, ``w2``, ``x1``, ``y1``, ``x2``, ``y2``, ``energy``.
    """
    t = np.atleast_1d(np.asarray(t, dtype=float))
    par = (m1, m2, l1, l2, J1, J2, g)

    def rhs(_t, y):
        mass, f = _double_pendulum_matrices(y[0], y[1], y[2], y[3], *par)
        acc = np.linalg.solve(mass, f)
        return [y[2], y[3], acc[0], acc[1]]

    a1, a2, v1, v2 = _integrate(rhs, t, [th1, th2, w1, w2], ODE_TOL, "P7 reference")
    x1, y1 = l1 * np.sin(a1), -l1 * np.cos(a1)
    return {"th1": a1, "th2": a2, "w1": v1, "w2": v2, "x1": x1, "y1": y1,
            "x2": x1 + l2 * np.sin(a2), "y2": y1 - l2 * np.cos(a2),
            "energy": double_pendulum_energy(a1, a2, v1, v2, m1=m1, m2=m2, l1=l1, l2=l2,
                                             J1=J1, J2=J2, g=g)}


# --------------------------------------------------------------------------------------------
# P3: Andrews' squeezing mechanism
# --------------------------------------------------------------------------------------------

ANDREWS = {  # BENCHMARK_PROBLEMS.md P3 (Hairer & Wanner II, sec. VII.7; IVP test set "andrews")
    "m": (.04325, .00365, .02373, .00706, .07050, .00706, .05498),
    "i": (2.194e-6, 4.410e-7, 5.255e-6, 5.667e-7, 1.169e-5, 5.667e-7, 1.912e-5),
    "O": (0.0, 0.0), "A": (-.06934, -.00227), "B": (-.03635, .03273), "C": (.014, .072),
    "c0": 4530.0, "l0": .07785, "mom": .033,
    "d": .028, "da": .0115, "e": .02, "ea": .01421, "rr": .007, "ra": .00092, "ss": .035,
    "sa": .01874, "sb": .01043, "sc": .018, "sd": .02, "ta": .02308, "tb": .00916, "u": .04,
    "ua": .01228, "ub": .00449, "zf": .02, "zt": .04, "fa": .01421,
    # consistent initial relative angles, all velocities zero (test set, 30 digits)
    "beta": -0.0617138900142764496358948458001, "Theta": 0.0,
    "gamma": 0.455279819163070380255912382449, "Phi": 0.222668390165885884674473185609,
    "delta": 0.487364979543842550225598953530, "Omega": -0.222668390165885884674473185609,
    "epsilon": 1.23054744454982119249735015568,
}

# Published initial accelerations of the test set (Mazzia & Magherini, "Test Set for IVP
# Solvers", problem andrews, initial values w(1), w(2)): beta'' and Theta'' at t = 0.
ANDREWS_BETA_DDOT0 = 14222.4439199541138705911625887
ANDREWS_THETA_DDOT0 = -10666.8329399655854029433719415
# Published reference solution at t = 0.03 s of the same test set (beta, Theta, gamma, Phi,
# delta, Omega, epsilon); tests/test_references.py reproduces it with andrews_trajectory.
ANDREWS_T_END = 0.03
ANDREWS_AT_T_END = {
    "beta": 15.81077119629904, "Theta": -15.75637105984298, "gamma": 0.04082224013073101,
    "Phi": -0.5347301163226948, "delta": 0.5244099658805304, "Omega": 0.5347301163226948,
    "epsilon": 1.048080741042263,
}


def andrews_points():
    """Body-fixed points of P3's seven bodies, relative to each centre of mass (P3's table).

    Returns a list of seven dicts (bodies 1..7) mapping point name to a 2-vector.
    """
    p = ANDREWS
    ra, rr, da, d = p["ra"], p["rr"], p["da"], p["d"]
    sa, sb, sc, sd, ss = p["sa"], p["sb"], p["sc"], p["sd"], p["ss"]
    e, ea, ta, tb, zt = p["e"], p["ea"], p["ta"], p["tb"], p["zt"]
    zf, fa, u, ua, ub = p["zf"], p["fa"], p["u"], p["ua"], p["ub"]
    pts = [
        {"O": (-ra, 0.0), "F": (rr - ra, 0.0)},
        {"F": (da, 0.0), "E": (da - d, 0.0)},
        {"B": (-sb, sa), "E": (-sb, sa - ss), "D": (sd - sb, sa - sc)},
        {"G": (0.0, e - ea), "E": (0.0, -ea)},
        {"A": (-ta, -tb), "G": (zt - ta, -tb)},
        {"H": (-(zf - fa), 0.0), "E": (fa, 0.0)},
        {"A": (ub, ua), "H": (ub, ua - u)},
    ]
    return [{k: np.array(v) for k, v in body.items()} for body in pts]


# The ten revolute joints of P3 as (body_i, point_i, body_j, point_j); body 0 is the ground.
ANDREWS_JOINTS = (
    (0, "O", 1, "O"), (1, "F", 2, "F"), (0, "B", 3, "B"), (2, "E", 3, "E"), (0, "A", 5, "A"),
    (5, "G", 4, "G"), (2, "E", 4, "E"), (0, "A", 7, "A"), (7, "H", 6, "H"), (2, "E", 6, "E"),
)


def andrews_initial_state():
    """Absolute centre-of-mass positions and angles of P3's bodies at t = 0.

    Source: BENCHMARK_PROBLEMS.md P3. Absolute angles from the relative ones: body 1 beta,
    2 beta+Theta, 3 gamma, 4 Phi+delta, 5 delta, 6 Omega+epsilon, 7 epsilon. Each centre is placed
    by chaining a joint from a body already placed (ground O -> 1 -> 2; ground B -> 3;
    ground A -> 5 -> 4; ground A -> 7 -> 6); the joints 2E-3E, 2E-4E and 2E-6E then close only if
    the data are consistent, which ``andrews_joint_residuals`` checks.
    Returns ``(positions, angles)``: arrays of shape (7, 2) and (7,).
    """
    p = ANDREWS
    angles = np.array([p["beta"], p["beta"] + p["Theta"], p["gamma"], p["Phi"] + p["delta"],
                       p["delta"], p["Omega"] + p["epsilon"], p["epsilon"]])
    pts = andrews_points()
    pos = np.zeros((7, 2))

    def place(body, point, target):
        pos[body - 1] = np.asarray(target) - _rot(angles[body - 1]) @ pts[body - 1][point]

    def at(body, point):
        return pos[body - 1] + _rot(angles[body - 1]) @ pts[body - 1][point]

    place(1, "O", p["O"])
    place(2, "F", at(1, "F"))
    place(3, "B", p["B"])
    place(5, "A", p["A"])
    place(4, "G", at(5, "G"))
    place(7, "A", p["A"])
    place(6, "H", at(7, "H"))
    return pos, angles


def andrews_joint_residuals(pos, angles):
    """Residuals (shape (10, 2), m) of P3's ten revolute joints for body positions and angles."""
    pts = andrews_points()
    ground = {"O": np.array(ANDREWS["O"]), "A": np.array(ANDREWS["A"]),
              "B": np.array(ANDREWS["B"])}

    def at(body, point):
        if body == 0:
            return ground[point]
        return pos[body - 1] + _rot(angles[body - 1]) @ pts[body - 1][point]

    return np.array([at(bi, pi) - at(bj, pj) for bi, pi, bj, pj in ANDREWS_JOINTS])


def andrews_accelerations(pos, angles, vel, omega):
    """Accelerations and multipliers of P3 in absolute coordinates (own Cartesian assembly).

    Solves ``[[M, Phi_q^T], [Phi_q, 0]] [q''; lam] = [F; gamma]`` for q = (x_1, y_1, phi_1, ...,
    x_7, y_7, phi_7) with the ten revolute joints, the spring C-D (stiffness c0, rest length l0)
    and the torque ``mom`` on body 1 (BENCHMARK_PROBLEMS.md P3). Independent of mbdfmu; used to
    check the published initial accelerations and as the right-hand side of
    ``andrews_trajectory``. ``vel`` (7, 2) and ``omega`` (7,) are the body velocities; only
    omega enters (the spring is undamped). Returns ``(qdd, lam)`` with shapes (21,), (20,).
    """
    p = ANDREWS
    pts = andrews_points()
    n = 21
    mass = np.zeros(n)
    for k in range(7):
        mass[3 * k:3 * k + 2] = p["m"][k]
        mass[3 * k + 2] = p["i"][k]
    force = np.zeros(n)
    force[2] += p["mom"]
    # spring from ground C to point D of body 3
    A3 = _rot(angles[2])
    sD = A3 @ pts[2]["D"]
    rD = pos[2] + sD
    dvec = rD - np.array(p["C"])
    length = float(np.linalg.norm(dvec))
    unit = dvec / length
    f_on_3 = -p["c0"] * (length - p["l0"]) * unit  # pulls D back towards C when stretched
    force[6:8] += f_on_3
    force[8] += sD[0] * f_on_3[1] - sD[1] * f_on_3[0]
    jac = np.zeros((20, n))
    gamma = np.zeros(20)
    for row, (bi, pi, bj, pj) in enumerate(ANDREWS_JOINTS):
        r = 2 * row
        for body, point, sign in ((bi, pi, 1.0), (bj, pj, -1.0)):
            if body == 0:
                continue
            k = body - 1
            s = _rot(angles[k]) @ pts[k][point]
            jac[r:r + 2, 3 * k:3 * k + 2] = sign * np.eye(2)
            jac[r:r + 2, 3 * k + 2] = sign * _perp(s)
            gamma[r:r + 2] += sign * omega[k]**2 * s  # -(d/dt Phi_q) q' = +omega^2 s per body
    aug = np.zeros((n + 20, n + 20))
    aug[:n, :n] = np.diag(mass)
    aug[:n, n:] = jac.T
    aug[n:, :n] = jac
    sol = np.linalg.solve(aug, np.concatenate([force, gamma]))
    return sol[:n], sol[n:]


def andrews_trajectory(t):
    """P3 reference trajectory from the own Cartesian model, integrated at rtol = atol = 1e-12.

    Index-1 formulation (``andrews_accelerations``) started on the consistent state, without
    projection: over 0.03 s at this tolerance the joints drift by less than 1e-14 m. The relative
    angles are read from the absolute ones. Returns a dict of arrays at ``t``:
    ``beta``, ``Theta``, ``gamma``, ``Phi``, ``delta``, ``Omega``, ``epsilon`` and ``q`` (21, len(t)).
    """
    t = np.atleast_1d(np.asarray(t, dtype=float))
    pos0, ang0 = andrews_initial_state()

    def unpack(y):
        q, v = y[:21].reshape(7, 3), y[21:].reshape(7, 3)
        return q[:, :2], q[:, 2], v[:, :2], v[:, 2]

    def rhs(_t, y):
        pos, ang, vel, om = unpack(y)
        qdd, _lam = andrews_accelerations(pos, ang, vel, om)
        return np.concatenate([y[21:], qdd])

    y0 = np.concatenate([np.column_stack([pos0, ang0]).ravel(), np.zeros(21)])
    q = _integrate(rhs, t, y0, 1e-12, "P3 reference")[:21]
    ang = q[2::3]
    return {"beta": ang[0], "Theta": ang[1] - ang[0], "gamma": ang[2], "Phi": ang[3] - ang[4],
            "delta": ang[4], "Omega": ang[5] - ang[6], "epsilon": ang[6], "q": q}


# --------------------------------------------------------------------------------------------
# Scene files: independent parsing and joint residuals
# --------------------------------------------------------------------------------------------

# --------------------------------------------------------------------------------------------
# P8-P11: couplers, rolling, a pin in a slot
# --------------------------------------------------------------------------------------------

def geared_pair(t, *, torque, J_in, inertia_out, ratio):
    """P8 and P9: an input of inertia ``J_in`` driven by ``torque`` and geared to an output of
    inertia (or mass) ``inertia_out`` moving ``ratio`` times the input's coordinate, from
    rest. Virtual power with q_out' = ratio q_in': ``(J_in + ratio^2 inertia_out) q_in'' =
    torque``; the output needs the generalized force ``inertia_out q_out''``. Returns
    ``alpha`` (input acceleration), ``q_in``, ``q_out`` (from 0) and ``effort`` (on the
    output's coordinate)."""
    t = np.asarray(t, dtype=float)
    alpha = torque / (J_in + ratio * ratio * inertia_out)
    return {"alpha": alpha, "q_in": 0.5 * alpha * t * t, "q_out": 0.5 * ratio * alpha * t * t,
            "effort": inertia_out * ratio * alpha}


def rolling_incline(t, *, m, J, r, slope, s0, g=G):
    """P10: a disc (mass m, inertia J, radius r) rolling without slipping from rest at s0 on a
    line through the origin at angle ``slope``, its centre r above it. Newton along the line
    and about the centre with the contact friction f (up the slope) and normal N:
    ``m s'' = f - m g sin a``, ``J phi'' = r f``, ``s' = -r phi'`` give
    ``s'' = -g sin a / (1 + J / (m r^2))``, ``f = m g sin a J / (J + m r^2)``, ``N = m g cos a``.
    Returns s, the centre (x, y), the angle turned ``phi = -(s - s0) / r``, f and N."""
    t = np.asarray(t, dtype=float)
    sa, ca = math.sin(slope), math.cos(slope)
    acc = -g * sa / (1.0 + J / (m * r * r))
    s = s0 + 0.5 * acc * t * t
    return {"s": s, "x": s * ca - r * sa, "y": s * sa + r * ca, "phi": -(s - s0) / r,
            "friction": m * g * sa * J / (J + m * r * r), "normal": m * g * ca, "acc": acc}


def slot_rod(t, *, m=1.0, L=1.0, J=None, g=G, theta0=0.3):
    """P11: a uniform rod (inertia ``J`` about its centre, ``m L^2 / 12`` by default) whose top
    end is a pin in a frictionless horizontal slot (a massless slider), released at rest
    ``theta0`` from the downward vertical. No horizontal force acts: the centre keeps its x.
    With a = L / 2 and the centre at y = -a cos theta, Lagrange's equation is
    ``(m a^2 sin^2 theta + J) theta'' + m a^2 sin theta cos theta theta'^2 + m g a sin theta = 0``
    (small oscillations: omega^2 = m g a / J = 6 g / L for the uniform rod); the pin's vertical
    force on the rod is ``m (g + y'')``. Integrated by DOP853 at ODE_TOL.
    Returns theta, theta_dot, theta_ddot, x, y (centre), phi (body angle, theta - pi/2), Fy."""
    J = m * L * L / 12.0 if J is None else J
    a = 0.5 * L

    def accel(th, w):
        return -(m * a * a * math.sin(th) * math.cos(th) * w * w + m * g * a * math.sin(th)) / (
            m * a * a * math.sin(th) ** 2 + J)

    th, w = _integrate(lambda _t, y: [y[1], accel(y[0], y[1])], t, [theta0, 0.0], ODE_TOL,
                       "slot rod reduction")
    acc = np.array([accel(x, v) for x, v in zip(th, w)])
    ydd = a * (np.cos(th) * w * w + np.sin(th) * acc)
    return {"theta": th, "theta_dot": w, "theta_ddot": acc,
            "x": np.full_like(th, a * math.sin(theta0)), "y": -a * np.cos(th),
            "phi": th - math.pi / 2, "Fy": m * (g + ydd)}


SCENES = Path(__file__).resolve().parent.parent / "scenes"


def load_toml(path):
    """Parse a scene file with the standard library only. Returns the raw dict."""
    with open(path, "rb") as fh:
        return tomllib.load(fh)


def _body_table(scene):
    table = {"ground": {"position": [0.0, 0.0], "angle": 0.0, "velocity": [0.0, 0.0],
                        "angular_velocity": 0.0}}
    for b in scene.get("body", []):
        table[b["name"]] = b
    return table


def _point_state(body, point):
    """Global position and velocity of a body-fixed point (point relative to the CoM)."""
    s = _rot(float(body["angle"])) @ np.asarray(point, dtype=float)
    r = np.asarray(body["position"], dtype=float) + s
    v = (np.asarray(body.get("velocity", [0.0, 0.0]), dtype=float)
         + float(body.get("angular_velocity", 0.0)) * _perp(s))
    return r, v


def _coordinate(jt, bodies):
    """A revolute or translational joint's coordinate and its rate at the initial state:
    ``phi_j - phi_i``, or ``(r_Pj - r_Pi) . u_i`` with ``u_i`` the unit axis in the ground frame."""
    bi, bj = bodies[jt["body_i"]], bodies[jt["body_j"]]
    wi, wj = float(bi.get("angular_velocity", 0.0)), float(bj.get("angular_velocity", 0.0))
    if jt["type"] == "revolute":
        return float(bj["angle"]) - float(bi["angle"]), wj - wi
    ri, vi = _point_state(bi, jt.get("point_i", [0.0, 0.0]))
    rj, vj = _point_state(bj, jt.get("point_j", [0.0, 0.0]))
    axis = np.asarray(jt["axis_i"], dtype=float)
    u = _rot(float(bi["angle"])) @ (axis / np.linalg.norm(axis))
    return float(u @ (rj - ri)), float(u @ (vj - vi) + (wi * _perp(u)) @ (rj - ri))


def _line_residuals(jt, bi, bj, offset):
    """Signed distance of point_j from the line through point_i along axis_i (positive on its
    left) minus ``offset``, its rate, and the line's unit axis and normal."""
    ri, vi = _point_state(bi, jt.get("point_i", [0.0, 0.0]))
    rj, vj = _point_state(bj, jt.get("point_j", [0.0, 0.0]))
    axis = np.asarray(jt["axis_i"], dtype=float)
    u = _rot(float(bi["angle"])) @ (axis / np.linalg.norm(axis))
    normal = _perp(u)
    wi = float(bi.get("angular_velocity", 0.0))
    return (normal @ (rj - ri) - offset, normal @ (vj - vi) + (wi * _perp(normal)) @ (rj - ri),
            u, normal)


def rolling_slip(bi, bj, u, normal, radius):
    """Tangential velocity of the disc's material point at the contact, relative to the line
    body's material point there (zero when it rolls): C = r_disc - radius n."""
    contact = np.asarray(bj["position"], dtype=float) - radius * normal
    v_disc = (np.asarray(bj.get("velocity", [0.0, 0.0]), dtype=float)
              + float(bj.get("angular_velocity", 0.0)) * _perp(contact - bj["position"]))
    v_line = (np.asarray(bi.get("velocity", [0.0, 0.0]), dtype=float)
              + float(bi.get("angular_velocity", 0.0)) * _perp(contact - bi["position"]))
    return float(u @ (v_disc - v_line))


def joint_residuals(scene):
    """Position and velocity residuals of every joint of a parsed scene, at its initial state.

    Revolute: ``r_i + A_i s_i - r_j - A_j s_j`` (2 rows, m) and its time derivative.
    Translational: the offset of point_j from the line through point_i along ``axis_i`` (m), and
    the relative rotation ``phi_j - phi_i`` (rad, the scenes keep it at 0), with derivatives.
    Slot: the offset alone. Rolling: the disc centre's distance from the line minus the radius,
    and the contact point's slip velocity. Coupler: 0 by definition at the start (its
    coordinates are measured from there), and ``q_j' - ratio q_i'``.
    Returns ``{joint name: (position residual array, velocity residual array)}``.
    """
    bodies = _body_table(scene)
    joints = {jt["name"]: jt for jt in scene.get("joint", [])}
    out = {}
    for jt in joints.values():
        if jt["type"] == "coupler":
            (_, wi), (_, wj) = (_coordinate(joints[jt[k]], bodies) for k in ("joint_i", "joint_j"))
            out[jt["name"]] = (np.zeros(1), np.array([wj - jt["ratio"] * wi]))
            continue
        bi, bj = bodies[jt["body_i"]], bodies[jt["body_j"]]
        if jt["type"] == "revolute":
            ri, vi = _point_state(bi, jt["point_i"])
            rj, vj = _point_state(bj, jt.get("point_j", [0.0, 0.0]))
            out[jt["name"]] = (ri - rj, vi - vj)
        elif jt["type"] in ("translational", "slot"):
            pos, vel, _, _ = _line_residuals(jt, bi, bj, 0.0)
            wi = float(bi.get("angular_velocity", 0.0))
            wj = float(bj.get("angular_velocity", 0.0))
            if jt["type"] == "slot":
                out[jt["name"]] = (np.array([pos]), np.array([vel]))
            else:
                out[jt["name"]] = (np.array([pos, float(bj["angle"]) - float(bi["angle"])]),
                                   np.array([vel, wj - wi]))
        elif jt["type"] == "rolling":
            pos, vel, u, normal = _line_residuals(jt, bi, bj, jt["radius"])
            out[jt["name"]] = (np.array([pos]),
                               np.array([vel, rolling_slip(bi, bj, u, normal, jt["radius"])]))
        else:
            raise ValueError(f"unknown joint type {jt['type']!r}")
    return out
