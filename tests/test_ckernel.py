"""The C kernel (kernel "c", what FMUs run) gives the numpy kernel's numbers to round-off:
eq. 14, the outputs, whole steps of rk4p and of the embedded pairs, for every joint type,
input-driven drivers and forces, springs and dampers; run states stay plain data and
replay bit for bit. References are the numpy kernel and the dense augmented solve of
eq. 14 (test_kernel.augmented_solve), never the C kernel's own output.
"""

from __future__ import annotations

import math
import tomllib

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

import mbdfmu
from mbdfmu.bench.closed_forms import n_four_bar_B0
from mbdfmu.equations import Equations, ckernel, dynamics
from mbdfmu.equations.projection import assemble
from mbdfmu.equations.singular import nullspace_accelerations, singularity_indicator
from mbdfmu.model import scene_from_dict

from test_kernel import SCENES, augmented_solve, n_four_bar, scene

pytestmark = pytest.mark.skipif(not ckernel.available(), reason="no C compiler for the kernel")

# Every kind of force and input on three bodies: a crank with a spring-damper whose actuator
# is an input and a force input off its centre, a block on a guide moved by an input driver,
# a bob on the block with a rotational spring-damper and a torque input.
KITCHEN_SINK = """
name = "KitchenSink"
gravity = [0.0, -9.81]
[[body]]
name = "crank"
mass = 1.0
inertia = 0.1
position = [0.5, 0.0]
[[body]]
name = "block"
mass = 2.0
inertia = 0.05
position = [2.0, 0.0]
[[body]]
name = "bob"
mass = 0.5
inertia = 0.01
position = [2.0, -0.5]
angle = -1.5707963267948966
[[joint]]
name = "pin"
type = "revolute"
body_i = "ground"
body_j = "crank"
point_j = [-0.5, 0.0]
[[joint]]
name = "guide"
type = "translational"
body_i = "ground"
axis_i = [1.0, 0.0]
body_j = "block"
[[joint]]
name = "hinge"
type = "revolute"
body_i = "block"
body_j = "bob"
point_j = [-0.5, 0.0]
[[driver]]
name = "move"
joint = "guide"
motion = { type = "input", initial = 2.0 }
[[force]]
name = "cyl"
type = "spring_damper"
body_i = "crank"
point_i = [0.5, 0.0]
body_j = "block"
point_j = [0.0, 0.1]
stiffness = 200.0
damping = 3.0
rest_length = 1.0
actuator_input = true
[[force]]
name = "tors"
type = "rotational_spring_damper"
joint = "hinge"
stiffness = 5.0
damping = 0.2
rest_angle = 0.1
[[force]]
name = "push"
type = "force"
body = "crank"
point = [0.3, 0.05]
input = true
[[force]]
name = "twist"
type = "torque"
body = "bob"
input = true
"""
# the scenes with end stops and friction: their own equations, each joint free
ALL = SCENES + ["kitchen_sink", "pendulum_torque", "andrews", "slider_stop", "crane_stop",
               "incline_slide"]


def any_scene(name):
    if name == "kitchen_sink":
        return scene_from_dict(tomllib.loads(KITCHEN_SINK), source="kitchen_sink")
    return scene(name)


def random_inputs(system: Equations, rng) -> mbdfmu.model.variables.InputValues:
    u = system.no_inputs
    motions = u.motions + rng.normal(scale=0.05, size=u.motions.shape)
    return type(u)(motions, rng.normal(scale=3.0, size=u.forces.shape))


def both_kernels_at_a_random_state(name, data, spread: float):
    """(numpy Equations, C Equations, t, q, q', inputs): q the assembly moved by ``spread``
    (normal), q' and the inputs random, t in [0, 1]."""
    plain, fast = Equations(any_scene(name), kernel="numpy"), Equations(any_scene(name), kernel="c")
    rng = np.random.default_rng(data.draw(st.integers(0, 2**31)))
    q0, _ = assemble(plain)
    q = q0 + rng.normal(scale=spread, size=q0.size)
    qd = rng.normal(scale=2.0, size=q0.size)
    return plain, fast, data.draw(st.floats(0.0, 1.0)), q, qd, random_inputs(plain, rng)


@pytest.mark.parametrize("name", ALL)
@settings(max_examples=10, deadline=None)
@given(data=st.data())
def test_c_kernel_equals_numpy_kernel(name, data):
    plain, fast, t, q, qd, u = both_kernels_at_a_random_state(name, data, 0.01)
    qdd, lam = plain.accelerations(t, q, qd, u)
    qdd_c, lam_c = fast.accelerations(t, q, qd, u)
    # round-off of two Cholesky orders, amplified by S's condition, about 1 / indicator:
    # nearly redundant rows (the parallelogram moved off its assembly) reach indicators of
    # 1e-5, where 2000 random states differed by up to 3.1e5 eps / indicator
    indicator = singularity_indicator(plain.constraints(t, q, u=u)[1])
    rtol = 1e-7 + 1e6 * np.finfo(float).eps / max(indicator, 1e-300)
    scale = max(1.0, np.abs(qdd).max())
    np.testing.assert_allclose(qdd_c, qdd, rtol=rtol, atol=rtol * scale)
    np.testing.assert_allclose(lam_c, lam, rtol=rtol, atol=rtol * max(1.0, np.abs(lam).max()))
    y, y_c = plain.output_values(t, q, qd, qdd, lam, u), fast.output_values(t, q, qd, qdd, lam, u)
    np.testing.assert_allclose(y_c, y, rtol=1e-12, atol=1e-12 * max(1.0, np.nanmax(np.abs(y))))


@pytest.mark.parametrize("name", ALL)
@settings(max_examples=10, deadline=None)
@given(data=st.data())
def test_c_constraint_values_are_the_numpy_ones(name, data):
    """Psi, Psi_q's values, nu and gamma that Python's own code reads (velocity jumps,
    indicators) come from the C kernel where the equations have it: against the numpy
    path's at random states, inputs and times."""
    plain, fast, t, q, qd, u = both_kernels_at_a_random_state(name, data, 0.1)
    for with_qd in (None, qd):
        got, expected = fast.constraint_values(t, q, with_qd, u), plain.constraint_values(
            t, q, with_qd, u)
        for a, b in zip(got, expected):
            if b is None:
                assert a is None
            else:
                np.testing.assert_allclose(a, b, rtol=1e-13,
                                           atol=1e-13 * max(1.0, np.abs(b).max(initial=0.0)))


@pytest.mark.parametrize("name", ALL + ["n_four_bar_40"])
def test_c_singularity_indicator_is_the_numpy_one(name):
    """The C indicator against singular.singularity_indicator on the same Psi_q (dense and
    banded), away from and right at P2's singular configuration (cranks horizontal)."""
    from mbdfmu.integrators.singular_zone import REDUNDANT
    sc = n_four_bar(40) if name == "n_four_bar_40" else any_scene(name)
    plain, fast = Equations(sc, kernel="numpy"), Equations(sc, kernel="c")
    rng = np.random.default_rng(3)
    q0, _ = assemble(plain)
    for q in (q0, q0 + rng.normal(scale=0.01, size=q0.size)):
        u = plain.no_inputs
        expected = singularity_indicator(plain.constraints(0.0, q, u=u, sparse=True)[1])
        got = fast.ckernel.singularity_indicator(q, plain.motion_values(0.0, u))
        if expected < REDUNDANT:      # rank-deficient S: its last pivot is round-off
            assert got < REDUNDANT
        else:
            # Cholesky's round-off on the last pivot d (relative to the largest): about
            # eps / d, which a nearly redundant row (the parallelogram) makes large
            assert got == pytest.approx(expected, rel=1e-9, abs=1e-14 / expected)


def test_c_kernel_accelerations_match_the_dense_augmented_solve():
    system = Equations(scene("slider_crank"), kernel="c")
    q0, qd0 = assemble(system)
    qdd_ref, lam_ref = augmented_solve(system, 0.01, q0, qd0)
    qdd, lam = system.accelerations(0.01, q0, qd0)
    np.testing.assert_allclose(qdd, qdd_ref, rtol=1e-8, atol=1e-8 * np.abs(qdd_ref).max())
    np.testing.assert_allclose(lam, lam_ref, rtol=1e-8, atol=1e-8 * np.abs(lam_ref).max())


def drive(sim: mbdfmu.Simulation, steps: int, h: float):
    """Inputs that change every communication step (those the scene has), then a step."""
    rows, t0 = [], sim.t
    for k in range(steps):
        t = t0 + k * h
        for name in sim.input_names:
            if name.endswith("position"):
                sim.set_input(name, 2.0 + 0.1 * np.sin(5 * t))
            else:
                sim.set_input(name, 2.0 * np.cos(3 * t + len(name)))
        sim.advance(t0 + (k + 1) * h)
        rows.append(sim.output_vector())
    return np.array(rows)


@pytest.mark.parametrize("method", ["rk4p", "dop853p", "rk45p"])
@pytest.mark.parametrize("name", ["kitchen_sink", "slider_crank", "andrews", "slider_force",
                                  "rolling_disc", "gear_pair", "slot_rod", "mechanisms"])
def test_c_steps_follow_the_numpy_steps(name, method):
    """Whole steps in C, with inputs set between steps: the same run to round-off (adaptive
    methods: their step sequence may part at round-off, so to a fraction of rtol)."""
    runs = []
    for kernel in ("numpy", "c"):
        # rk4p states a loose accuracy here (its step-doubling estimate on Andrews' squeezer
        # at 0.5 ms exceeds the default's): this compares the kernels, not the accuracy
        tolerances = dict(rtol=0.1) if method == "rk4p" else dict(rtol=1e-8, atol=1e-10)
        sim = mbdfmu.Simulation(any_scene(name), method=method, step=5e-4, kernel=kernel,
                                **tolerances)
        runs.append((drive(sim, 40, 2e-3), vars(sim.integrator.stats)))
    (plain, stats), (fast, stats_c) = runs
    scale = np.maximum(1.0, np.nanmax(np.abs(plain), axis=0))
    assert np.nanmax(np.abs(fast - plain) / scale) < (1e-9 if method == "rk4p" else 1e-6)
    if method == "rk4p":
        # the same counts of steps, evaluations, projections; the step-doubling estimate
        # (stated_accuracy.py) to round-off
        estimate, estimate_c = stats.pop("error_estimate"), stats_c.pop("error_estimate")
        assert stats_c == stats
        assert estimate_c == pytest.approx(estimate, rel=1e-6)


def test_c_kernel_runs_replay_bit_for_bit_from_a_saved_state():
    sim = mbdfmu.Simulation(any_scene("kitchen_sink"), method="dop853p", kernel="c")
    drive(sim, 5, 1e-3)
    state = sim.get_state()
    first = drive(sim, 10, 1e-3)
    sim.set_state(state)
    assert np.array_equal(drive(sim, 10, 1e-3), first)


def test_minimum_norm_solves_are_the_numpy_kernels():
    """Redundant rows (the parallelogram) and singular crossings (P2 N = 2's cranks pass
    the horizontal near t = 0.79 s) take eq. 14's minimum-norm multipliers: the C kernel's
    (pivoted Cholesky with lstsq's cut-off) are the numpy kernel's to round-off."""
    for name, method, t_end in (("parallelogram", "rk4p", 0.05), ("n_four_bar_2", "rk4p", 1.0)):
        plain, fast = (mbdfmu.simulate(scene(name), t_end=t_end, method=method, kernel=k,
                                       output_interval=1e-2) for k in ("numpy", "c"))
        for a, b in ((plain.q, fast.q), (plain.qd, fast.qd), (plain.lam, fast.lam)):
            np.testing.assert_allclose(b, a, rtol=1e-9, atol=1e-9 * max(1.0, np.abs(a).max()))


@pytest.mark.parametrize("kappa", [1.0, 1e3, 1e6])
def test_the_dense_minimum_norm_solve_is_the_pseudo_inverse(kappa):
    """The projections' solve where S is singular (pivoted_min_norm in solve.h, through
    its test entry ``mbd_min_norm_solve``) against the pseudo-inverse built from S's own
    eigenvectors: S = Q diag(ev) Q^T of rank r with its nonzero eigenvalues spread over
    kappa, plus eigenvalues at 1e-14 of the largest, which the cut-off (1e-10) drops as
    lstsq does; right-hand sides in S's range (a projection's) and not. The error stays
    within the problem's conditioning: 100 kappa times eps, plus the dropped eigenvalues'
    1e-14 where there are some (they perturb S by that much)."""
    import ctypes
    solve = ckernel.library().mbd_min_norm_solve
    solve.argtypes = [ctypes.c_long] + [ctypes.c_void_p] * 3 + [ctypes.c_double]
    rng = np.random.default_rng(7)
    for _ in range(100):
        m = int(rng.integers(2, 40))
        r = int(rng.integers(1, m + 1))
        tiny = int(rng.integers(0, m - r + 1))
        Q, _ = np.linalg.qr(rng.standard_normal((m, m)))
        ev = np.geomspace(1.0, 1.0 / kappa, r) * 10.0 ** rng.uniform(-3, 3)
        S = (Q[:, :r + tiny] * np.r_[ev, np.full(tiny, 1e-14 * ev[0])]) @ Q[:, :r + tiny].T
        for b in (rng.standard_normal(m), S @ rng.standard_normal(m)):
            x = np.zeros(m)
            assert solve(m, S.ctypes.data, b.ctypes.data, x.ctypes.data, 1e-10) == 1
            exact = (Q[:, :r] / ev) @ (Q[:, :r].T @ b)
            level = 2.2e-16 + (1e-14 if tiny else 0.0)
            assert np.linalg.norm(x - exact) <= 100 * kappa * level * np.linalg.norm(exact)


def test_singular_accelerations_are_solved_in_c_as_numpy_solves_them(monkeypatch):
    """Where S is singular at every state (the parallelogram's redundant row) eq. 14 is
    solved in C in the null-space form (nullspace.h), never handed to the numpy path; the
    run is the numpy kernel's (LAPACK's SVD) to round-off."""
    plain = mbdfmu.simulate(scene("parallelogram"), t_end=0.05, method="rk4p", kernel="numpy")

    def refused(*args):
        raise AssertionError("the C kernel handed eq. 14 back to the numpy path")
    monkeypatch.setattr(dynamics, "nullspace_accelerations", refused)
    fast = mbdfmu.simulate(scene("parallelogram"), t_end=0.05, method="rk4p", kernel="c")
    for a, b in ((plain.q, fast.q), (plain.qd, fast.qd), (plain.qdd, fast.qdd),
                 (plain.lam, fast.lam)):
        np.testing.assert_allclose(b, a, rtol=1e-12, atol=1e-12 * max(1.0, np.abs(a).max()))


def p2_state(system, theta: float, rate: float):
    """P2's state with every crank at angle theta from the horizontal, turning at rate."""
    q, qd = np.empty(system.n), np.empty(system.n)
    c, s = math.cos(theta), math.sin(theta)
    for k, body in enumerate(system.scene.bodies):
        if body.name.startswith("crank"):
            x0 = float(body.name[5:])
            q[3 * k: 3 * k + 3] = (x0 + 0.5 * c, 0.5 * s, theta)
            qd[3 * k: 3 * k + 3] = (-0.5 * s * rate, 0.5 * c * rate, rate)
        else:
            x0 = float(body.name[7:])
            q[3 * k: 3 * k + 3] = (x0 + 0.5 + c, s, 0.0)
            qd[3 * k: 3 * k + 3] = (-s * rate, c * rate, 0.0)
    return q, qd


@pytest.mark.parametrize("theta", [0.0, 1e-9, 1e-7, 1e-5])
def test_c_null_space_solve_at_p2s_crossing_is_lapacks_svd(theta):
    """P2 N = 2 at and next to its singular crossing (the cranks horizontal, Psi_q losing
    rank 2), where S's Cholesky is refused: C's complete orthogonal decomposition (pivoted
    QR, then RZ) gives singular.py's (LAPACK's SVD) q'' and lam within the problem's
    conditioning, eps / theta (exactly singular: to round-off), and q'' meets the
    acceleration constraints Psi_q q'' = gamma."""
    system = Equations(n_four_bar(2), kernel="c")
    q, qd = p2_state(system, theta, -2.0)
    _, J, _, gamma = system.constraints(0.0, q, qd)
    F = system.forces(0.0, q, qd)
    qdd_ref, lam_ref = nullspace_accelerations(J, system.minv, F, gamma)
    qdd, lam = system.ckernel.accelerations(q, qd, system.motion_values(0.0),
                                            system.no_inputs.forces)
    conditioning = 1e-14 / theta if theta else 1e-14
    np.testing.assert_allclose(qdd, qdd_ref, rtol=0, atol=conditioning * np.abs(qdd_ref).max())
    np.testing.assert_allclose(lam, lam_ref, rtol=0,
                               atol=10 * conditioning * np.abs(lam_ref).max())
    np.testing.assert_allclose(J @ qdd, gamma, rtol=0, atol=1e-13 * max(1.0, np.abs(gamma).max()))


def test_p2s_adaptive_run_crosses_in_c_and_reaches_the_reduction(monkeypatch):
    """P2 N = 2 with dop853p at rtol 2e-5 over 10 s has a stage on the crossing where S is
    singular (near t = 5.09 s): the C run solves it (it used to hand the whole step back
    to Python) and B0 ends within the run's tolerance of the exact one-degree-of-freedom
    reduction (its error there rides on the round-off of that stage's solve: 1.5e-7 m in C,
    1.3e-6 m on the numpy kernel)."""
    def refused(*args):
        raise AssertionError("the C kernel handed eq. 14 back to the numpy path")
    monkeypatch.setattr(dynamics, "nullspace_accelerations", refused)
    sim = mbdfmu.Simulation("n_four_bar_2", kernel="c", method="dop853p", rtol=2e-5, atol=4e-7)
    sim.advance(10.0)
    out = sim.outputs()
    b0 = n_four_bar_B0([10.0], 2)
    phi = out["crank0.phi"]
    error = math.hypot(out["crank0.x"] + 0.5 * math.cos(phi) - float(b0["x"][-1]),
                       out["crank0.y"] + 0.5 * math.sin(phi) - float(b0["y"][-1]))
    assert error < 2e-5


def test_the_kernel_digest_covers_every_header():
    # the compiled library is cached by the digest of SOURCES: a header left out would let
    # an edit of it run a stale library
    from pathlib import Path

    from mbdfmu.equations.ckernel import build

    folder = Path(build.__file__).parent
    assert sorted(p.name for p in folder.glob("*.[ch]")) == sorted(build.SOURCES)
