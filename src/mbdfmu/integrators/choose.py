"""``auto``: choose a method for a scene at the start of a run, and say which and why.

``choose_method`` applies these rules, in order, to the scene and its assembled state at
t0 (no more model than the scene needs); the run then uses the chosen class like any
named method (scipy keeps the choice outside the solver classes too):

0. No degrees of freedom (every coordinate follows from the constraints and drivers, as in
   the driven slider-crank): the position projection fixes the motion to its tolerance
   whatever the integrator, whose prediction only starts Newton close; so the cheapest
   one, ``rk4p`` at its step.
1. A singular configuration at t0: the constraint Jacobian loses rank there
   (``projection.rank_report``) but regains it a little way along the motion
   (MOVE_FRACTION of the mechanism's size), or the smallest singular value of its
   independent rows is below NEAR_SINGULAR of the largest: ``ali3p``, whose iteration
   matrix stays non-singular there while eq. (14) has no unique multipliers. Rank that
   stays lost as the mechanism moves is redundancy, not a singular configuration.
2. A spring or damper much faster than the output interval (period 2 pi sqrt(m / k) or time
   constant m / c below STIFF_FRACTION of it, with m the lightest body it acts on), or much
   faster than the step the accuracy needs (``_accuracy_step``: an explicit method's stable
   step, about half that period, STIFF_STEP_RATIO times below the step dop853p would take
   for rtol on the motion at t0, so that stability, not accuracy, would set its cost and
   that cost would grow as sqrt(k)): ``genalpha``, implicit, whose cost per simulated
   second does not depend on k, and which damps what the output cannot show instead of
   resolving it with tiny explicit steps; ``ali3p`` if the constraints are also redundant
   (genalpha's matrix would be singular). Chosen by auto, both control their step
   (``implicit_control.py``), so the run meets rtol as with dop853p. A spring stretched at t0 makes the motion's own
   time scale short (its acceleration enters it), so its visible oscillation stays with
   dop853p, which resolves it.
3. Otherwise ``dop853p``: adaptive, high order, coordinate projection. Consistent redundant
   constraints stay here (eq. 14's minimum-norm multipliers handle them), and so does a
   huge mass ratio (beyond MASS_RATIO): its fast transients are physical and must be
   resolved, not damped; dop853p's step control includes the energy of each step and its
   energy audit stops a run that still drifts (``energy_audit.py``). docs/accuracy.md has
   the measurements behind these rules.

It looks at t0 only: a mechanism that reaches a singular configuration later gets dop853p,
whose failure message then points at ali3p.
"""

from __future__ import annotations

import math

import numpy as np

from ..equations.projection import project_positions, project_velocities, rank_report
from ..errors import SolverError
from ..model.scene import RotationalSpringDamper, SpringDamper
from .ali3p import ALI3P
from .base import Integrator
from .genalpha import GeneralizedAlpha
from .projected_rk import DOP853P
from .rk4p import RK4P

# Smallest singular value of Psi_q relative to its largest that counts as nearly singular.
NEAR_SINGULAR = 1e-6
# How far (relative to the mechanism's size) auto moves the mechanism to tell a singular
# configuration (rank regained) from redundant constraints (rank still lost).
MOVE_FRACTION = 1e-3
# A spring period (or damper time constant) below this fraction of the output interval is stiff.
STIFF_FRACTION = 0.01
# Stiff when an explicit method's stable step is this many times below its accuracy step.
STIFF_STEP_RATIO = 10.0
# Order of the explicit method whose accuracy step is estimated (dop853p's 8).
EXPLICIT_ORDER = 8
# Body mass ratio above which the reason warns of fast transients (P6's light cart).
MASS_RATIO = 1e4


def _fastest_force(equations) -> tuple[float, str] | None:
    """(time scale in s, force name) of the fastest spring or damper, or None."""
    scene = equations.scene
    masses = {b.name: (b.mass, b.inertia) for b in scene.bodies}
    fastest = None
    for f in scene.forces:
        if isinstance(f, SpringDamper):
            m = min(masses[b][0] for b in (f.body_i, f.body_j) if b in masses)
            k, c = f.stiffness, f.damping
        elif isinstance(f, RotationalSpringDamper):
            joint = scene.joint(f.joint)
            m = min(masses[b][1] for b in (joint.body_i, joint.body_j) if b in masses)
            k, c = f.stiffness, f.damping
        else:
            continue
        scales = ([2 * math.pi * math.sqrt(m / k)] if k > 0 else []) + ([m / c] if c > 0 else [])
        for tau in scales:
            if fastest is None or tau < fastest[0]:
                fastest = (tau, f.name)
    return fastest


def _accuracy_step(equations, t0: float, q0: np.ndarray, u, rtol: float) -> float:
    """The step (s) an order-8 method needs for ``rtol`` on the motion at t0, or inf.

    The motion's time scale is the shorter of sqrt(L / a) and L / v, with L the mechanism's
    size and a, v the largest acceleration (gravity included) and speed of a body point at
    t0; a local error ~ (h / T)^9 below rtol gives h = T rtol^(1/9).
    """
    scene = equations.scene
    qd0 = np.array([[*b.velocity, b.angular_velocity] for b in scene.bodies],
                   dtype=float).ravel()
    size = equations.length_scale
    try:
        if equations.m:
            qd0 = project_velocities(equations, t0, q0, qd0, u)
        qdd0 = equations.accelerations(t0, q0, qd0, u)[0]
    except SolverError:
        return math.inf

    def largest(v):
        v = np.asarray(v, dtype=float).reshape(-1, 3)
        return float(max(np.max(np.abs(v[:, :2]), initial=0.0),
                         size * np.max(np.abs(v[:, 2]), initial=0.0)))

    accel = max(largest(qdd0), math.hypot(*scene.gravity))
    speed = largest(qd0)
    scales = ([math.sqrt(size / accel)] if accel > 0 else []) + ([size / speed] if speed > 0 else [])
    return min(scales) * rtol ** (1.0 / (EXPLICIT_ORDER + 1)) if scales else math.inf


def _rank_after_moving(equations, t0: float, q0: np.ndarray, u) -> int:
    """Rank of Psi_q a little way along the motion from q0 (along q', or q'' from rest).

    Redundant constraints (the parallelogram's third crank) stay redundant as the mechanism
    moves; a singular configuration (cranks of a four-bar in line) is left at once.
    """
    qd0 = np.array([[*b.velocity, b.angular_velocity] for b in equations.scene.bodies],
                   dtype=float).ravel()
    qd0 = project_velocities(equations, t0, q0, qd0, u)
    direction = qd0 if np.any(qd0) else equations.accelerations(t0, q0, qd0, u)[0]
    size = float(np.max(np.abs(direction)))
    if size == 0.0:
        return rank_report(equations, t0, q0).rank
    q1 = q0 + (MOVE_FRACTION * equations.length_scale / size) * direction
    try:
        q1, _ = project_positions(equations, t0, q1, tol=1e-12 * equations.length_scale, u=u)
    except SolverError:
        return rank_report(equations, t0, q0).rank
    return rank_report(equations, t0, q1).rank


def choose_method(equations, t0: float, q0: np.ndarray, output_interval: float,
                  u=None, rtol: float = 1e-6) -> tuple[type[Integrator], str]:
    """The method for this scene and the reason, by the rules of this module; ``u`` the
    inputs at t0, ``output_interval`` (s) the time between the outputs the run reports and
    ``rtol`` the run's relative tolerance."""
    notes = []
    redundant = ()
    if equations.m:
        report = rank_report(equations, t0, q0)
        redundant = report.redundant
        if report.dof == 0 and not redundant:
            return RK4P, ("no degrees of freedom (the drivers prescribe the whole motion): "
                          "the projections give it, so the cheapest method, rk4p")
        if redundant and _rank_after_moving(equations, t0, q0, u) > report.rank:
            return ALI3P, (f"the constraint Jacobian loses rank {len(redundant)} at t = {t0:g} "
                           "and regains it as the mechanism moves (a singular configuration): "
                           "ali3p passes singular configurations")
        _, J = equations.constraints(t0, q0, u=u)
        sv = np.linalg.svd(J, compute_uv=False)[: report.rank]  # without the redundant rows
        if sv.size and sv[-1] < NEAR_SINGULAR * sv[0]:
            return ALI3P, (f"the constraint Jacobian is nearly singular at t = {t0:g} (singular "
                           f"values {sv[-1]:.2g} / {sv[0]:.2g}): ali3p passes singular "
                           "configurations")
        if redundant:
            notes.append("redundant constraints (" + ", ".join(redundant) + " repeat others) "
                         "are handled by eq. 14's minimum-norm multipliers")
    fastest = _fastest_force(equations)
    interval = output_interval
    stiff = ""
    if fastest is not None and fastest[0] < STIFF_FRACTION * interval:
        stiff = (f'force "{fastest[1]}" acts on a time scale of {fastest[0]:.2g} s, far below '
                 f"the output interval {interval:.2g} s (stiff)")
    elif fastest is not None:
        needed = _accuracy_step(equations, t0, q0, u, rtol)
        if STIFF_STEP_RATIO * fastest[0] / 2 < needed:
            stiff = (f'force "{fastest[1]}" acts on a time scale of {fastest[0]:.2g} s: an '
                     f"explicit method would be held to steps near {fastest[0] / 2:.2g} s by "
                     f"stability where rtol = {rtol:g} needs about {needed:.2g} s (stiff)")
    if stiff:
        if redundant:
            return ALI3P, (stiff + " and the constraints are redundant: implicit ali3p, whose "
                           "iteration matrix stays non-singular")
        return GeneralizedAlpha, stiff + ": implicit genalpha damps it"
    masses = equations.mass[0::3]
    ratio = float(masses.max() / masses.min())
    if ratio > MASS_RATIO:
        notes.append(f"body masses differ by {ratio:.2g}x: fast transients are likely; they "
                     "are physical and must be resolved, not damped: dop853p, whose step "
                     "control includes the energy (it stops with a reason if it cannot)")
    return DOP853P, "; ".join(notes) or "smooth scene (no singular constraints, nothing stiff)"
