"""The benchmark's cases: scenes, horizons, sweep ranges, references and error functions.

Each ``Case`` is one benchmark problem (docs/accuracy.md lists them with their sources);
its error function measures a run's outputs against the exact solution where one exists
(``closed_forms.py``), otherwise against a converged run.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..errors import MbdfmuError
from ..model.reader import bundled_scene, load_scene
from ..simulation import output_times
from . import closed_forms

# Absolute tolerance of the sweep's adaptive runs, relative to rtol.
ATOL_FACTOR = 1e-2
# Error levels of the summary.
LEVELS = (1e-4, 1e-6, 1e-8)


class BenchError(MbdfmuError):
    """A benchmark that cannot run (unknown scene or method, missing Dask)."""


@dataclass(frozen=True)
class Case:
    """A benchmark scene: the file, the horizon, the sweep ranges and the reference.

    ``steps`` are the fixed steps (s) of fixed-step methods, ``tols`` the rtol of adaptive
    ones (atol = rtol * ATOL_FACTOR); the ``quick_*`` ones are the ``--quick`` sweep.
    ``reference`` says what the error is measured against (shown in the summary).
    ``comm_t_end`` (s), when given, puts the case in the communication-step sweep
    (``comm.py``), whose fixed-step methods run at ``comm_step`` (s), clipped to land on
    each communication point; ``quick_comm_t_end`` is its ``--quick`` horizon.
    ``finer_steps``: (method, steps) pairs, steps added to ``steps`` for that method (the
    compiled implicit methods, whose order 2 needs short steps to reach small errors).
    """

    key: str
    scene: str
    title: str
    t_end: float
    steps: tuple[float, ...]
    tols: tuple[float, ...]
    reference: str
    n_out: int = 20       # output times (errors are the largest over them); fewer if a step is longer
    quick_t_end: float = 1.0
    quick_steps: tuple[float, ...] = (1e-2, 5e-3)
    quick_tols: tuple[float, ...] = (1e-4, 1e-6)
    comm_t_end: float | None = None
    comm_step: float = 1e-3
    quick_comm_t_end: float = 0.2
    finer_steps: tuple[tuple[str, tuple[float, ...]], ...] = ()

    def steps_for(self, method: str) -> tuple[float, ...]:
        """The fixed steps (s) of ``method``'s sweep."""
        return self.steps + dict(self.finer_steps).get(method, ())


TOLS = tuple(10.0 ** -k for k in range(2, 12))  # rtol 1e-2 .. 1e-11
# The communication-step sweep (issue 12): a master's steps, and the rtol of adaptive
# methods there: the default and a tight one (atol by the solver's own rule).
COMM_STEPS = (1e-4, 1e-3, 1e-2, 1e-1)
COMM_TOLS = (1e-6, 1e-10)
# genalpha and ali3p (order 2) on P1 and P2 N = 2 down to an error of about 1e-8 at 10 s
IMPLICIT_FINER = tuple((name, (2e-4, 1e-4, 5e-5, 2e-5, 1e-5)) for name in ("genalpha", "ali3p"))
# P1's genalpha needs one halving below 1e-5 s to pass 1e-8 at 10 s, and so do both on P2
# N = 2 (three steps below 5e-5 in the asymptotic range)
P1_IMPLICIT_FINER = tuple((name, steps + (5e-6,)) for name, steps in IMPLICIT_FINER)

CASES: dict[str, Case] = {c.key: c for c in (
    Case("P1", "pendulum", "P1 pendulum, t = 10 s", 10.0,
         (1e-1, 5e-2, 2e-2, 1e-2, 5e-3, 2e-3, 1e-3, 5e-4), TOLS,
         "exact: elliptic solution (bob position, m)", comm_t_end=2.0,
         finer_steps=P1_IMPLICIT_FINER),
    Case("P2N2", "n_four_bar_2", "P2 N-four-bar, N = 2, t = 10 s", 10.0,
         (1e-1, 5e-2, 2e-2, 1e-2, 5e-3, 2e-3, 1e-3, 5e-4), TOLS,
         "exact: one-DOF reduction at 1e-13 (B0 position, m)", comm_t_end=2.0,
         finer_steps=P1_IMPLICIT_FINER),
    Case("P2N40", "n_four_bar_40", "P2 N-four-bar, N = 40, t = 2.5 s (two singular passes)", 2.5,
         (5e-2, 2e-2, 1e-2, 5e-3), (1e-3, 1e-4, 1e-6, 1e-8),
         "exact: one-DOF reduction at 1e-13 (B0 position, m)", n_out=10,
         quick_t_end=0.2, quick_steps=(2e-2,), quick_tols=(1e-4,), comm_t_end=2.5,
         comm_step=5e-3),
    Case("P3", "andrews", "P3 Andrews' mechanism, t = 0.03 s", 0.03,
         (5e-4, 2e-4, 1e-4, 5e-5, 2e-5, 1e-5, 5e-6, 2e-6), TOLS,
         "converged run (body angles, rad)", n_out=30, quick_t_end=0.003,
         quick_steps=(1e-4, 5e-5), comm_t_end=0.03, comm_step=1e-5, quick_comm_t_end=0.003),
    Case("P4", "slider_crank", "slider-crank (P4), t = 0.04 s (two turns)", 0.04,
         (5e-3, 2e-3, 1e-3, 5e-4, 2e-4, 1e-4, 5e-5, 2e-5), TOLS,
         "exact: P4 closed form (slider and rod centre, m)", quick_t_end=0.004,
         quick_steps=(1e-3, 5e-4)),
    Case("P6", "light_cart_pole", "P6 light cart-pole, t = 2 s (two spikes)", 2.0,
         (1e-2, 1e-3, 1e-4), (1e-2, 1e-4, 1e-6, 1e-8, 1e-10),
         "exact invariants: momentum (cart x / l) and energy (theta'^2 / its peak)",
         comm_t_end=2.0, comm_step=1e-4),
    Case("P8", "gear_pair", "P8 gear pair (coupler), t = 1 s", 1.0,
         (1e-1, 5e-2, 2e-2, 1e-2, 5e-3), TOLS[::3],
         "exact: constant acceleration (both angles, rad)", n_out=10),
    Case("P9", "rack_pinion", "P9 rack and pinion (coupler), t = 1 s", 1.0,
         (1e-1, 5e-2, 2e-2, 1e-2, 5e-3), TOLS[::3],
         "exact: constant acceleration (pinion angle, rad; rack x, m)", n_out=10),
    Case("P10", "rolling_disc", "P10 disc rolling down an incline, t = 1 s", 1.0,
         (1e-1, 5e-2, 2e-2, 1e-2, 5e-3), TOLS[::3],
         "exact: constant acceleration (centre position, m)", n_out=10),
    Case("P11", "slot_rod", "P11 rod on a pin in a horizontal slot, t = 10 s", 10.0,
         (5e-2, 2e-2, 1e-2, 5e-3, 2e-3, 1e-3, 5e-4), TOLS,
         "exact: one-DOF reduction at 1e-13 (rod angle, rad; centre x and y, m)"),
)}
DEFAULT_SCENES = tuple(CASES)


def case_of(key: str) -> Case:
    if key not in CASES:
        raise BenchError(f'unknown bench scene "{key}"; expected one of {", ".join(CASES)}')
    return CASES[key]


# ---------------------------------------------------------------------------- scenes and errors

def case_scene(case: Case):
    """The case's shipped scene."""
    return load_scene(bundled_scene(case.scene))


def length_scale(scene) -> float:
    """The mechanism's size (m), as ``Equations.length_scale``."""
    return max([1.0] + [abs(v) for b in scene.bodies for v in b.position])


def get(out: dict, name: str) -> np.ndarray:
    return np.asarray(out[name], dtype=float)


def _error_P1(case, scene, t, out, ref):
    bob = scene.bodies[0]
    exact = closed_forms.pendulum(t, L=1.0, m=bob.mass, J=bob.inertia)
    return float(np.max(np.hypot(get(out, "bob.x") - exact["x"], get(out, "bob.y") - exact["y"])))


def _B0(out):
    phi = get(out, "crank0.phi")
    return get(out, "crank0.x") + 0.5 * np.cos(phi), get(out, "crank0.y") + 0.5 * np.sin(phi)


def _error_P2(case, scene, t, out, ref):
    x, y = _B0(out)
    return float(np.max(np.hypot(x - ref["x"], y - ref["y"])))


def _error_P4(case, scene, t, out, ref):
    motor = scene.drivers[0].motion
    exact = closed_forms.slider_crank(motor.start + motor.rate * t, r=0.1, l=0.3)
    e_slider = np.abs(get(out, "slider.x") - exact["xB"])
    e_rod = np.hypot(get(out, "rod.x") - exact["rod_x"], get(out, "rod.y") - exact["rod_y"])
    return float(max(e_slider.max(), e_rod.max()))


def _error_P6(case, scene, t, out, ref):
    cart, bob = scene.bodies
    dx = get(out, "bob.x") - get(out, "cart.x")
    dy = get(out, "bob.y") - get(out, "cart.y")
    theta = np.arctan2(dx, -dy)
    inv = closed_forms.cart_pole_invariants(theta, M=cart.mass, m=bob.mass, l=1.0, J=bob.inertia)
    peak = float(closed_forms.cart_pole_invariants(0.0, M=cart.mass, m=bob.mass, l=1.0,
                                                 J=bob.inertia)["theta_dot_sq"])
    e_x = np.abs(get(out, "cart.x") - inv["x"])
    e_w = np.abs(get(out, "bob.omega") ** 2 - inv["theta_dot_sq"]) / peak
    return float(max(e_x.max(), e_w.max()))


def angles(scene, out):
    return np.column_stack([get(out, f"{b.name}.phi") for b in scene.bodies])


def error_converged(case, scene, t, out, ref):
    return float(np.max(np.abs(angles(scene, out) - ref["angles"])))


def _error_geared(coordinate: str, by_mass: bool):
    """P8, P9: the error of a torque-driven input body coupled to an output body: its angle,
    or (``coordinate`` "x", ``by_mass``) a rack's x, whose coordinate's inertia is its mass."""
    def error(case, scene, t, out, ref):
        (body_in, body_out), coupler = scene.bodies, scene.joints[-1]
        exact = closed_forms.geared(
            t, torque=scene.forces[0].value, inertia_in=body_in.inertia,
            inertia_out=body_out.mass if by_mass else body_out.inertia, ratio=coupler.ratio)
        return float(max(np.abs(get(out, f"{body_in.name}.phi") - exact["q_in"]).max(),
                         np.abs(get(out, f"{body_out.name}.{coordinate}") - exact["q_out"]).max()))
    return error


def _error_P10(case, scene, t, out, ref):
    disc, contact = scene.bodies[0], scene.joints[0]
    ux, uy = np.asarray(contact.axis_i) / math.hypot(*contact.axis_i)
    exact = closed_forms.disc_on_incline(
        t, mass=disc.mass, inertia=disc.inertia, radius=contact.radius,
        slope=math.atan2(uy, ux), start=disc.position[0] * ux + disc.position[1] * uy)
    return float(np.max(np.hypot(get(out, "disc.x") - exact["x"], get(out, "disc.y") - exact["y"])))


def _error_P11(case, scene, t, out, ref):
    rod, pin = scene.bodies[0], scene.joints[0].point_j      # the pin at the rod's end
    exact = closed_forms.rod_in_slot(t, mass=rod.mass, length=2 * abs(pin[0]),
                                     inertia=rod.inertia, theta0=rod.angle + math.pi / 2)
    return float(max(np.abs(get(out, "rod.phi") - exact["phi"]).max(),
                     np.abs(get(out, "rod.y") - exact["y"]).max(),
                     np.abs(get(out, "rod.x") - rod.position[0]).max()))


ERRORS = {"P1": _error_P1, "P2N2": _error_P2, "P2N40": _error_P2, "P3": error_converged,
          "P4": _error_P4, "P6": _error_P6, "P8": _error_geared("phi", False),
          "P9": _error_geared("x", True),
          "P10": _error_P10, "P11": _error_P11}
EXACT_P2 = {"P2N2": 2, "P2N40": 40}


def horizon(case: Case, quick: bool) -> tuple[float, np.ndarray]:
    """End time and output times. Runs land exactly on each output time, which caps the
    step of every method: the interval is kept at least the sweep's largest step."""
    t_end = case.quick_t_end if quick else case.t_end
    largest = max(case.quick_steps if quick else case.steps)
    n = max(1, min(case.n_out, int(math.floor(t_end / largest * (1 + 1e-9)))))
    return t_end, output_times(t_end, t_end / n)
