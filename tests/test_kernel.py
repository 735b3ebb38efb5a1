"""The fast paths give the answers of the plain ones: numba kernel = numpy kernel, banded
sparse solves = dense solves of eq. 14, lean rollback = full state.

References are independent computations: a dense solve of the augmented eq. 14 with numpy,
the pseudo-inverse for minimum-norm multipliers, and P2's exact one-DOF reduction.
"""

from __future__ import annotations

import math
import tomllib

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

import mbdfmu
from mbdfmu.equations.constraints import numba_installed
from mbdfmu.equations import sparsity as linalg
from mbdfmu.equations.projection import assemble
from mbdfmu.errors import InputError, SolverError
from mbdfmu.model import scene_from_dict
from mbdfmu.scenes.generate_n_four_bar import scene_text
from mbdfmu.equations import Equations

import exact_solutions as ref
import joint_scenes
from conftest import SCENES as SCENE_DIR


def scene(name):
    if name in joint_scenes.BUILT:     # the new joints' test scenes (joint_scenes.py)
        return joint_scenes.BUILT[name]()
    return mbdfmu.load_scene(SCENE_DIR / f"{name}.toml")

needs_numba = pytest.mark.skipif(not numba_installed(), reason="numba not installed")
SCENES = ["slider_crank", "andrews", "four_bar", "parallelogram", "slider_force",
          "double_pendulum", "n_four_bar_2", "gear_pair", "rack_pinion", "rolling_disc",
          "slot_rod", "mechanisms", "two_sliders"]


def n_four_bar(n: int):
    return scene_from_dict(tomllib.loads(scene_text(n)), source=f"<P2 N = {n}>")


def augmented_solve(system: Equations, t, q, qd):
    """q'' and lam from the dense augmented matrix [[M, J^T], [J, 0]] of eq. 14 (numpy):
    its minimum-norm least-squares solution, so redundant constraints get the minimum-norm
    lam (q'' is unique either way)."""
    _, J, _, gamma = system.constraints(t, q, qd)
    F = system.forces(t, q, qd)
    n, m = system.n, system.m
    A = np.block([[np.diag(system.mass), J.T], [J, np.zeros((m, m))]])
    x = np.linalg.lstsq(A, np.concatenate((F, gamma)), rcond=1e-12)[0]
    return x[:n], x[n:]


@needs_numba
@pytest.mark.parametrize("name", SCENES)
@settings(max_examples=15, deadline=None)
@given(data=st.data())
def test_numba_kernel_equals_numpy_kernel(name, data):
    plain, fast = Equations(scene(name), kernel="numpy"), Equations(scene(name), kernel="numba")
    q0, qd0 = assemble(plain)
    rng = np.random.default_rng(data.draw(st.integers(0, 2**31)))
    q = q0 + rng.normal(scale=0.3, size=q0.size)
    qd = rng.normal(scale=2.0, size=q0.size)
    t = data.draw(st.floats(0.0, 1.0))
    for a, b in zip(plain.constraints(t, q, qd), fast.constraints(t, q, qd)):
        np.testing.assert_allclose(b, a, rtol=1e-13, atol=1e-13)
    np.testing.assert_allclose(fast.constraints(t, q, extended=True)[1],
                               plain.constraints(t, q, extended=True)[1], atol=1e-13)
    qdd_ref, lam_ref = augmented_solve(plain, t, q0, qd)
    for system in (plain, fast):
        qdd, lam = system.accelerations(t, q0, qd)
        for x, x_ref in ((qdd, qdd_ref), (lam, lam_ref)):
            np.testing.assert_allclose(x, x_ref, rtol=1e-8, atol=1e-8 * max(1.0, np.abs(x_ref).max()))


def test_kernel_choice_errors_name_the_choices():
    with pytest.raises(InputError, match="numpy, numba"):
        Equations(scene("pendulum"), kernel="fortran")


@pytest.mark.parametrize("kernel", ["numpy", pytest.param("numba", marks=needs_numba)])
def test_banded_accelerations_equal_the_augmented_solve(kernel):
    system = Equations(n_four_bar(40), kernel=kernel)
    assert system.pattern.banded and system.pattern.kd < 20
    q, qd = assemble(system)
    rng = np.random.default_rng(1)
    qd = qd + rng.normal(scale=0.5, size=qd.size)   # any velocity: gamma changes, not J
    qdd_ref, lam_ref = augmented_solve(system, 0.0, q, qd)
    qdd, lam = system.accelerations(0.0, q, qd)
    np.testing.assert_allclose(qdd, qdd_ref, atol=1e-9 * np.abs(qdd_ref).max())
    np.testing.assert_allclose(lam, lam_ref, atol=1e-9 * np.abs(lam_ref).max())


def test_banded_products_equal_dense_products():
    system = Equations(n_four_bar(20))
    q, qd = assemble(system)
    _, Js = system.constraints(0.0, q, sparse=True)
    _, Jd = system.constraints(0.0, q)
    assert isinstance(Js, linalg.SparseJacobian)
    np.testing.assert_array_equal(Js.toarray(), Jd)
    x, y = np.arange(system.n, dtype=float), np.arange(system.m, dtype=float)
    np.testing.assert_allclose(Js @ x, Jd @ x, rtol=1e-14)
    np.testing.assert_allclose(Js.T @ y, Jd.T @ y, rtol=1e-14)


@pytest.mark.parametrize("name", SCENES + ["P2 N = 20"])
def test_band_plan_assembles_the_schur_complement_of_the_dense_jacobian(name):
    # S = J M^-1 J^T from the plan's pairs of entries (what the C kernel factorises) against
    # numpy's product of the dense Jacobian, in the plan's row order, and nothing outside
    # the band it claims
    system = Equations(n_four_bar(20) if name == "P2 N = 20" else scene(name))
    q, _ = assemble(system)
    _, J = system.constraints(0.0, q)
    S_ref = (J * system.minv) @ J.T
    p = system.pattern
    band = p.schur_band(system.constraint_values(0.0, q)[1][p.keep])
    perm = p.perm
    assert sorted(perm.tolist()) == list(range(system.m))
    S = np.zeros((system.m, system.m))
    for d in range(p.kd + 1):
        j = np.arange(system.m - d)
        S[j + d, j] = S[j, j + d] = band[d, : system.m - d]
    np.testing.assert_allclose(S, S_ref[np.ix_(perm, perm)], rtol=1e-13,
                               atol=1e-13 * np.abs(S_ref).max())


def test_banded_min_norm_at_the_singular_crossing_equals_the_pseudo_inverse():
    # P2 with the cranks horizontal: Psi_q loses rank N; lam is the minimum-norm solution
    N = 40
    system = Equations(n_four_bar(N), kernel="numpy")
    theta, rate = 0.0, -2.0
    q = np.empty(system.n)
    qd = np.empty(system.n)
    for k, body in enumerate(system.scene.bodies):
        if body.name.startswith("crank"):
            x0 = float(body.name[5:])
            q[3 * k: 3 * k + 3] = (x0 + 0.5 * math.cos(theta), 0.5 * math.sin(theta), theta)
            qd[3 * k: 3 * k + 3] = (-0.5 * math.sin(theta) * rate, 0.5 * math.cos(theta) * rate, rate)
        else:
            x0 = float(body.name[7:])
            q[3 * k: 3 * k + 3] = (x0 + 0.5 + math.cos(theta), math.sin(theta), 0.0)
            qd[3 * k: 3 * k + 3] = (-math.sin(theta) * rate, math.cos(theta) * rate, 0.0)
    Psi, J, _, gamma = system.constraints(0.0, q, qd)
    assert np.abs(Psi).max() < 1e-12
    sv = np.linalg.svd(J, compute_uv=False)
    assert sv[-N] < 1e-10 * sv[0]                  # rank loss N, as P2 says
    F = system.forces(0.0, q, qd)
    JMi = J * system.minv
    b = JMi @ F - gamma
    lam_ref = np.linalg.pinv(JMi @ J.T, rcond=1e-10) @ b
    qdd_ref = system.minv * (F - J.T @ lam_ref)
    qdd, lam = system.accelerations(0.0, q, qd)
    np.testing.assert_allclose(lam, lam_ref, atol=1e-6 * np.abs(lam_ref).max())
    np.testing.assert_allclose(qdd, qdd_ref, atol=1e-6 * np.abs(qdd_ref).max())
    # (At this instant eq. 14 has a family of solutions, N extra instantaneous degrees of
    # freedom; the minimum-norm one is not the physical motion's, which the integrators
    # recover from the neighbouring steps: see the run below.)


def test_p2_n20_banded_run_follows_the_reduction_through_a_crossing():
    # the banded path (m = 122) in a whole run, through the first singular crossing
    t_end = 1.0
    sim = mbdfmu.Simulation(n_four_bar(20), method="rk4p", step=1e-3)
    assert sim.equations.pattern.banded
    sim.advance(t_end)
    b0 = (sim.q[0] + 0.5 * math.cos(sim.q[2]), sim.q[1] + 0.5 * math.sin(sim.q[2]))
    exact = ref.n_four_bar(np.array([t_end]), 20)
    assert math.hypot(b0[0] - exact["B0_x"][-1], b0[1] - exact["B0_y"][-1]) < 1e-6


def test_failed_advance_rolls_back_to_the_exact_state():
    # the general step path (the compiled run of steps does not call _step_impl)
    sim = mbdfmu.Simulation(scene("slider_crank"), method="rk4p", step=1e-3, kernel="numpy")
    sim.advance(0.01)
    before = (sim.t, sim.q.copy(), sim.qd.copy(), sim.integrator.stats.nsteps)
    calls = []

    def half_done_then_fail(h):   # changes the state in place, as a step may, then fails
        if calls:
            sim.integrator.q += 1.0
            sim.integrator.qd *= 2.0
            raise SolverError("forced failure", sim.t)
        calls.append(h)
        return type(sim.integrator)._step_impl(sim.integrator, h)

    sim.integrator._step_impl = half_done_then_fail
    with pytest.raises(SolverError):
        sim.advance(0.02)
    assert len(calls) == 1                       # one step was taken, then undone
    assert sim.t == before[0]
    np.testing.assert_array_equal(sim.q, before[1])
    np.testing.assert_array_equal(sim.qd, before[2])
    assert sim.integrator.stats.nsteps == before[3]


@needs_numba
@pytest.mark.parametrize("name", ["n_four_bar_2", "four_bar", "pendulum", "double_pendulum",
                                  "rack_pinion", "rolling_disc", "slot_rod", "mechanisms"])
def test_compiled_rk4p_steps_equal_the_general_steps(name):
    runs = {}
    for kernel in ("numba", "numpy"):
        sim = mbdfmu.Simulation(scene(name), method="rk4p", step=1e-3, kernel=kernel)
        assert sim.integrator.compiled_steps == (kernel == "numba")
        sim.advance(0.3)                                  # 300 steps, compiled in one call
        runs[kernel] = sim.integrator
    fast, plain = runs["numba"], runs["numpy"]
    assert fast.t == plain.t and fast.stats.nsteps == plain.stats.nsteps == 300
    for a, b in ((fast.q, plain.q), (fast.qd, plain.qd), (fast.f, plain.f)):
        # round-off only (the double pendulum is chaotic: 3e-9 after 300 steps)
        np.testing.assert_allclose(a, b, rtol=1e-8, atol=1e-8)
    if plain.audit is not None:                           # the energy check's running state
        assert fast.audit.checks == plain.audit.checks
        for field in ("kinetic_max", "potential_swing", "magnitude", "last_energy"):
            assert getattr(fast.audit, field) == pytest.approx(getattr(plain.audit, field),
                                                              rel=1e-9, abs=1e-12)


@needs_numba
def test_compiled_rk4p_fails_where_the_general_path_fails_and_says_the_same():
    # steps far too coarse: the run stops at the same step on both paths, for the same
    # reason (the energy check of the stated accuracy, or the position projection)
    for name, h in (("pendulum", 1.0), ("n_four_bar_2", 0.7)):
        messages = {}
        for kernel in ("numba", "numpy"):
            sim = mbdfmu.Simulation(scene(name), method="rk4p", step=h, kernel=kernel)
            with pytest.raises(SolverError, match=r"^t = .* s: rk4p: ") as info:
                sim.advance(20.0)
            # the time and the failure; which joint is worst may differ by round-off in a
            # diverging Newton iteration
            messages[kernel] = str(info.value).split(': joint "')[0]
        assert messages["numba"] == messages["numpy"]


@needs_numba
def test_only_state_dependent_or_input_forces_take_the_general_path():
    # a spring; an input force; gravity and a constant force at the slider's centre
    def compiled_steps(name, kernel):
        return mbdfmu.Simulation(scene(name), method="rk4p", kernel=kernel).integrator.compiled_steps

    assert not compiled_steps("andrews", "numba")
    assert not compiled_steps("slider_force", "numba")
    assert compiled_steps("slider_crank", "numba")
    assert not compiled_steps("slider_crank", "numpy")


PUSHED_SLIDER = """
name = "Pushed"
gravity = [0.0, -9.81]
[[body]]
name = "slider"
mass = 2.0
inertia = 0.1
position = [0.0, 0.0]
angle = 0.0
velocity = [0.5, 0.0]
[[joint]]
name = "guide"
type = "translational"
body_i = "ground"
point_i = [0.0, 0.0]
axis_i = [1.0, 0.0]
body_j = "slider"
point_j = [0.0, 0.0]
[[force]]
name = "push"
type = "force"
body = "slider"
point = [0.0, 0.0]
value = [3.0, 7.0]
"""


@pytest.mark.parametrize("kernel", ["numba", "numpy"])
def test_constant_force_at_a_centre_is_a_constant_generalized_force(kernel):
    if kernel == "numba" and not numba_installed():
        pytest.skip("numba not installed")
    sim = mbdfmu.Simulation(scene_from_dict(tomllib.loads(PUSHED_SLIDER)), method="rk4p",
                            step=1e-2, kernel=kernel)
    assert sim.integrator.compiled_steps == (kernel == "numba")
    sim.advance(2.0)
    out = sim.outputs()
    # x = x0 + v0 t + F t^2 / (2 m); the guide carries F_y - m g and no moment
    assert out["slider.x"] == pytest.approx(0.5 * 2.0 + 3.0 * 4.0 / 4.0, rel=1e-12)
    assert out["slider.vx"] == pytest.approx(0.5 + 3.0 * 2.0 / 2.0, rel=1e-12)
    assert abs(out["slider.y"]) < 1e-12 and abs(out["slider.phi"]) < 1e-12
    assert out["guide.Fy"] == pytest.approx(2.0 * 9.81 - 7.0, rel=1e-12)
    assert abs(out["guide.Fx"]) < 1e-12 and abs(out["guide.Tz"]) < 1e-12


def _reversed_joints(name):
    """The scene with every joint's body_i and body_j (and points) swapped: the ground
    becomes body_j, whose Jacobian block is in the virtual ground columns."""
    data = tomllib.loads((SCENE_DIR / f"{name}.toml").read_text())
    for j in data["joint"]:
        if j["type"] == "revolute":
            j["body_i"], j["body_j"] = j["body_j"], j["body_i"]
            j["point_i"], j["point_j"] = j["point_j"], j["point_i"]
    return scene_from_dict(data, source=f"<{name} reversed>")


@pytest.mark.parametrize("kernel", ["numpy", "numba"])
@pytest.mark.parametrize("name", SCENES + ["pendulum", "reversed pendulum", "reversed four_bar"])
def test_reaction_blocks_gathered_from_the_pattern_equal_the_dense_jacobian(name, kernel):
    if kernel == "numba" and not numba_installed():
        pytest.skip("numba not installed")
    sc = _reversed_joints(name.split()[1]) if name.startswith("reversed") else scene(name)
    system = Equations(sc, kernel=kernel)
    rng = np.random.default_rng(7)
    q, lam = rng.normal(size=system.n), rng.normal(size=system.m)
    _, J = system.constraints(0.3, q, extended=True)        # dense, ground columns last
    J = np.vstack((J, np.zeros(J.shape[1])))               # row m: a one-row joint's second
    cols = 3 * system.constraint_set.joint_bj[:, None, None] + np.arange(3)[None, None, :]
    blocks = J[system.constraint_set.joint_rows[:, :, None], cols]
    data = system.constraint_values(0.3, q)[1]
    np.testing.assert_array_equal(np.append(data, 0.0)[system._reaction_entries], blocks)
    np.testing.assert_array_equal(system.reactions(q, lam, 0.3),
                                  system.reactions(q, lam, 0.3, data))
    if name.startswith("reversed"):
        assert (system.constraint_set.joint_bj == system.nb).any()


@needs_numba
def test_each_compiled_function_has_one_signature_whatever_the_scene():
    # driven and undriven scenes, the general and the compiled rk4p paths, projections and
    # outputs: every call has the same argument types, so a fresh install compiles once
    for name, method in (("slider_crank", "rk4p"), ("pendulum", "rk4p"),
                         ("four_bar", "dop853p"), ("andrews", "rk4p")):
        sim = mbdfmu.Simulation(scene(name), method=method, step=1e-3, kernel="numba")
        sim.advance(0.01)
        sim.output_vector()
    from mbdfmu.equations import compiled as kernel_jit
    from mbdfmu.integrators import rk4p_compiled

    for module, name in ((kernel_jit, "constraint_terms"), (kernel_jit, "terms"),
                         (kernel_jit, "jac_mul"), (kernel_jit, "jac_t_mul"),
                         (kernel_jit, "schur_solve"), (kernel_jit, "accelerations"),
                         (rk4p_compiled, "rk4p_step"), (rk4p_compiled, "rk4p_steps")):
        # 0 when only called from compiled callers loaded from numba's disk cache
        assert len(getattr(module, name).signatures) <= 1, name
