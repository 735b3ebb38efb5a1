"""The equations against independent computations: finite differences of Psi give the
Jacobian and gamma; the augmented system (seed eq. 14) solved densely gives q'' and lam."""

import numpy as np
import pytest
from hypothesis import given, settings, strategies as st

import mbdfmu
from mbdfmu.equations.projection import assemble, project_velocities
from mbdfmu.equations import Equations

import joint_scenes
from conftest import SCENES

SCENE_FILES = ["slider_crank", "four_bar", "andrews", "light_cart_pole", "double_pendulum",
               "slider_force", "n_four_bar_2", "gear_pair", "rack_pinion", "rolling_disc",
               "slot_rod", "mechanisms", "two_sliders"]


def _systems():
    return {name: Equations(joint_scenes.BUILT[name]() if name in joint_scenes.BUILT
                            else mbdfmu.load_scene(SCENES / f"{name}.toml"))
            for name in SCENE_FILES}


SYSTEMS = _systems()


def _state(system, seed):
    rng = np.random.default_rng(seed)
    q = rng.normal(size=system.n)
    qd = rng.normal(size=system.n)
    return q, qd


@pytest.mark.parametrize("name", SCENE_FILES)
@settings(max_examples=15, deadline=None)
@given(seed=st.integers(0, 2**32 - 1))
def test_jacobian_is_the_derivative_of_psi(name, seed):
    system = SYSTEMS[name]
    q, _ = _state(system, seed)
    t = 0.37
    _, J = system.constraints(t, q)
    eps = 1e-6
    for k in range(system.n):
        dq = np.zeros(system.n)
        dq[k] = eps
        col = (system.constraints(t, q + dq)[0] - system.constraints(t, q - dq)[0]) / (2 * eps)
        np.testing.assert_allclose(J[:, k], col, atol=1e-7, rtol=1e-6)


@pytest.mark.parametrize("name", SCENE_FILES)
@settings(max_examples=15, deadline=None)
@given(seed=st.integers(0, 2**32 - 1))
def test_gamma_is_minus_the_second_derivative_along_q_dot(name, seed):
    """Along q + s q' (time frozen) Psi'' = (Psi_q q')_q q' = -(gamma - c''): gamma holds the
    velocity terms of the acceleration equation plus the drivers' second derivatives."""
    system = SYSTEMS[name]
    q, qd = _state(system, seed)
    t = 0.0
    _, _, nu, gamma = system.constraints(t, q, qd)
    c, cd, cdd = system.motion_values(t)
    h = 1e-4
    # Psi along the straight path q + s qd at frozen time: second derivative = -(gamma - c'')
    psi = [system.constraints(t, q + s * qd)[0] for s in (-h, 0.0, h)]
    second = (psi[0] - 2 * psi[1] + psi[2]) / h**2
    np.testing.assert_allclose(second, -(gamma - cdd), atol=2e-5, rtol=1e-5)


@pytest.mark.parametrize("name", SCENE_FILES)
def test_accelerations_solve_the_augmented_system(name):
    system = SYSTEMS[name]
    q0, qd0 = assemble(system)
    qd0 = qd0 + project_velocities(system, 0.0, q0, _state(system, 7)[1])  # not at rest
    qdd, lam = system.accelerations(0.0, q0, qd0)
    _, J, _, gamma = system.constraints(0.0, q0, qd0)
    F = system.forces(0.0, q0, qd0)
    K = np.block([[np.diag(system.mass), J.T], [J, np.zeros((system.m, system.m))]])
    if np.linalg.matrix_rank(J) < system.m:
        pytest.skip("redundant: lam is not unique")
    x = np.linalg.solve(K, np.concatenate((F, gamma)))  # eq. (14), dense
    np.testing.assert_allclose(qdd, x[: system.n], atol=1e-9 * (1 + np.abs(x).max()))
    np.testing.assert_allclose(lam, x[system.n:], atol=1e-9 * (1 + np.abs(x).max()))


def test_revolute_reaction_reduces_to_the_seed_closed_form():
    """Seed: for a revolute joint, (Fx, Fy, Tz) = -(l_k cos q3 + l_k+1 sin q3,
    -l_k sin q3 + l_k+1 cos q3, 0) on body i with Psi_r_i = +I. Our body_j has
    Psi_r_j = -I, so the same rotation of +lam appears."""
    system = SYSTEMS["double_pendulum"]
    q = np.array([0.3, -0.9, 0.4, 1.1, -1.2, -0.7])
    lam = np.array([1.5, -2.0, 0.25, 3.0])
    R = system.reactions(q, lam)
    for k, (r0, r1) in enumerate(system.constraint_set.joint_rows):
        bj = system.constraint_set.joint_bj[k]
        phi = q[3 * bj + 2]
        expected = [lam[r0] * np.cos(phi) + lam[r1] * np.sin(phi),
                    -lam[r0] * np.sin(phi) + lam[r1] * np.cos(phi), 0.0]
        np.testing.assert_allclose(R[k], expected, atol=1e-14)
