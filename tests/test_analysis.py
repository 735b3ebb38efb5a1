"""Linearization and static equilibrium against closed forms, through Python and through
the CLI's --json; A and B against finite differences of simulate()."""

import json
import math

import numpy as np
import pytest
import scipy.linalg
from scipy.optimize import brentq

import mbdfmu
from mbdfmu.cli import main

G = 9.81

SPRING_MASS_DAMPER = """
name = "SpringMassDamper"
gravity = [0.0, -9.81]
[[body]]
name = "mass"
mass = {m}
inertia = 0.01
position = [0.3, 0.0]
[[joint]]
name = "guide"
type = "translational"
body_i = "ground"
axis_i = [1.0, 0.0]
body_j = "mass"
[[force]]
name = "spring"
type = "spring_damper"
body_i = "ground"
body_j = "mass"
stiffness = {k}
damping = {c}
rest_length = 0.25
[[force]]
name = "push"
type = "force"
body = "mass"
input = true
"""

# A uniform arm pinned at one end with a torsional spring (rest angle 0: horizontal),
# sagging under gravity: k theta = -m g a cos(theta).
SPRING_ARM = """
name = "SpringArm"
[[body]]
name = "arm"
mass = {m}
inertia = {inertia}
position = [{a}, 0.0]
[[joint]]
name = "pivot"
type = "revolute"
body_i = "ground"
body_j = "arm"
point_j = [-{a}, 0.0]
[[force]]
name = "spring"
type = "rotational_spring_damper"
joint = "pivot"
stiffness = {k}
"""

# A mass on a vertical guide hanging from a spring: static deflection m g / k.
VERTICAL_SPRING = """
name = "VerticalSpring"
[[body]]
name = "mass"
mass = {m}
inertia = 0.01
position = [0.0, -0.5]
[[joint]]
name = "guide"
type = "translational"
body_i = "ground"
axis_i = [0.0, 1.0]
body_j = "mass"
[[force]]
name = "spring"
type = "spring_damper"
body_i = "ground"
body_j = "mass"
stiffness = {k}
rest_length = 0.5
"""


def _scene(tmp_path, text, **values):
    path = tmp_path / "scene.toml"
    path.write_text(text.format(**values))
    return path


def _cli_json(tmp_path, *args):
    out = tmp_path / "out.json"
    assert main([*args, "--json", str(out)]) == 0
    return json.loads(out.read_text())


# ---------------------------------------------------------------------------- frequencies

def test_compound_pendulum_frequency_python_and_cli(tmp_path):
    # rod_pendulum: m = 1, L = 1, I = m L^2 / 12 about its centre, pivot a = L / 2 away;
    # it starts horizontal, the equilibrium is hanging down.
    m, a, inertia = 1.0, 0.5, 1.0 / 12.0
    exact = math.sqrt(m * G * a / (inertia + m * a * a)) / (2 * math.pi)
    lin = mbdfmu.linearize("rod_pendulum", equilibrium=True)
    assert lin.states == ["rod.phi", "rod.omega"]
    np.testing.assert_allclose(lin.frequencies_hz, [exact, exact], rtol=1e-6)
    assert lin.damping_ratios == [0.0, 0.0]
    data = _cli_json(tmp_path, "linearize", "rod_pendulum", "--equilibrium")
    np.testing.assert_allclose(data["frequencies_hz"], [exact, exact], rtol=1e-6)
    # --set with the FMU's names: a heavier rod of the same shape has the same frequency,
    # a longer pivot distance (inertia kept) another one
    data = _cli_json(tmp_path, "linearize", "rod_pendulum", "--equilibrium",
                     "--set", "rod.inertia=0.2")
    np.testing.assert_allclose(data["frequencies_hz"][0],
                               math.sqrt(m * G * a / (0.2 + m * a * a)) / (2 * math.pi), rtol=1e-6)


def test_double_pendulum_of_point_masses_frequencies(tmp_path):
    # equal point masses m and lengths l: omega^2 = (g / l)(2 -+ sqrt 2); the bobs' inertia
    # set to 1e-8 (a point mass up to 1e-8 relative)
    exact = np.sqrt(G * np.array([2 - math.sqrt(2), 2 + math.sqrt(2)])) / (2 * math.pi)
    data = _cli_json(tmp_path, "linearize", "double_pendulum", "--equilibrium",
                     "--set", "bob1.inertia=1e-8", "--set", "bob2.inertia=1e-8")
    assert data["states"] == ["bob1.phi", "bob2.phi", "bob1.omega", "bob2.omega"]
    np.testing.assert_allclose(data["frequencies_hz"], np.repeat(exact, 2), rtol=1e-6)
    # the shipped scene (inertia 1e-6 on each bob) against the exact two-link model with it
    J = 1e-6
    M = np.array([[2 + J, 1.0], [1.0, 1 + J]])
    K = G * np.diag([2.0, 1.0])
    with_inertia = np.sqrt(scipy.linalg.eigvalsh(K, M)) / (2 * math.pi)
    lin = mbdfmu.linearize("double_pendulum", equilibrium=True)
    np.testing.assert_allclose(lin.frequencies_hz, np.repeat(with_inertia, 2), rtol=1e-8)


@pytest.mark.parametrize("m, k, c", [(2.0, 800.0, 8.0), (0.5, 50.0, 9.0)])
def test_spring_mass_damper_frequency_damping_and_B(tmp_path, m, k, c):
    path = _scene(tmp_path, SPRING_MASS_DAMPER, m=m, k=k, c=c)
    wn, zeta = math.sqrt(k / m), c / (2 * math.sqrt(k * m))
    for data in (mbdfmu.linearize(path, equilibrium=True).to_dict(),
                 _cli_json(tmp_path, "linearize", str(path), "--equilibrium")):
        assert data["states"] == ["mass.x", "mass.vx"]
        assert data["inputs"] == ["push.fx", "push.fy"]
        np.testing.assert_allclose(data["frequencies_hz"], [wn / (2 * math.pi)] * 2, rtol=1e-6)
        np.testing.assert_allclose(data["damping_ratios"], [zeta] * 2, rtol=1e-6)
        np.testing.assert_allclose(data["A"], [[0, 1], [-k / m, -c / m]], rtol=1e-7, atol=1e-9)
        np.testing.assert_allclose(data["B"], [[0, 0], [1 / m, 0]], atol=1e-9)
        x = data["outputs"].index("mass.x")
        np.testing.assert_allclose(data["C"][x], [1, 0], atol=1e-9)


# ---------------------------------------------------------------------------- equilibrium

def test_static_deflection_of_a_spring_loaded_arm(tmp_path):
    m, a, k = 2.0, 0.4, 30.0
    path = _scene(tmp_path, SPRING_ARM, m=m, a=a, k=k, inertia=m * (2 * a) ** 2 / 12)
    theta = brentq(lambda th: k * th + m * G * a * math.cos(th), -math.pi / 2, 0.0)
    exact = {"x": a * math.cos(theta), "y": a * math.sin(theta), "phi": theta}
    eq = mbdfmu.equilibrium(path)
    assert eq.stable and eq.coordinates == ["arm.phi"]
    np.testing.assert_allclose(eq.positions["arm"], [exact["x"], exact["y"], exact["phi"]],
                               rtol=1e-8, atol=1e-12)
    data = _cli_json(tmp_path, "equilibrium", str(path))
    for key, value in exact.items():
        assert data["bodies"]["arm"][key] == pytest.approx(value, rel=1e-8, abs=1e-12)
    assert data["stability"] == "stable" and data["residual"] < 1e-9
    # stiffer spring through --set: the deflection follows k
    k2 = 90.0
    theta2 = brentq(lambda th: k2 * th + m * G * a * math.cos(th), -math.pi / 2, 0.0)
    data = _cli_json(tmp_path, "equilibrium", str(path), "--set", f"spring.stiffness={k2}")
    assert data["bodies"]["arm"]["phi"] == pytest.approx(theta2, rel=1e-8)


def test_vertical_spring_static_deflection_and_written_scene(tmp_path):
    m, k = 3.0, 1200.0
    path = _scene(tmp_path, VERTICAL_SPRING, m=m, k=k)
    out = tmp_path / "rest.toml"
    assert main(["equilibrium", str(path), "-o", str(out), "--set", "mass.mass=4"]) == 0
    rest = mbdfmu.load_scene(out)
    # the written scene has the --set mass and rests where the spring carries it
    assert rest.body("mass").mass == 4.0
    assert rest.body("mass").position[1] == pytest.approx(-0.5 - 4.0 * G / k, rel=1e-10)
    assert mbdfmu.equilibrium(rest).iterations == 0      # already there
    assert mbdfmu.equilibrium(path).positions["mass"][1] == pytest.approx(-0.5 - m * G / k,
                                                                          rel=1e-10)


def test_unstable_equilibrium_is_reported(capsys):
    # n_four_bar_2 starts with its cranks upright: an equilibrium, unstable under gravity
    eq = mbdfmu.equilibrium("n_four_bar_2")
    assert eq.stability == "unstable" and eq.stiffness.min() < 0
    assert main(["equilibrium", "n_four_bar_2"]) == 0
    assert "UNSTABLE" in capsys.readouterr().out
    lin = mbdfmu.linearize("n_four_bar_2", equilibrium=True)
    assert lin.stability == "unstable" and lin.eigenvalues.real.max() > 0


def test_no_equilibrium_exits_2_with_one_line(tmp_path, capsys):
    path = tmp_path / "free.toml"
    path.write_text('name = "Free"\n[[body]]\nname = "stone"\nmass = 1.0\ninertia = 0.1\n'
                    'position = [0.0, 0.0]\n')
    assert main(["equilibrium", str(path)]) == 2
    err = capsys.readouterr().err.strip()
    assert "\n" not in err and "no static equilibrium" in err


def test_neutral_equilibrium_and_zero_modes():
    eq = mbdfmu.equilibrium("slider_force")
    assert eq.stability == "neutral"
    lin = mbdfmu.linearize("slider_force")
    assert lin.damping_ratios == [None, None]
    np.testing.assert_allclose(lin.B, [[0, 0], [0.5, 0]], atol=1e-9)   # 1 / (2 kg)


# ---------------------------------------------------------------------------- against simulate

DAMPED_PENDULUM = """
name = "DampedPendulum"
[[body]]
name = "rod"
mass = 1.0
inertia = 0.08333333333333333
position = [{x}, {y}]
angle = {phi}
velocity = [{vx}, {vy}]
angular_velocity = {w}
[[joint]]
name = "pivot"
type = "revolute"
body_i = "ground"
body_j = "rod"
point_j = [-0.5, 0.0]
[[force]]
name = "damper"
type = "rotational_spring_damper"
joint = "pivot"
stiffness = 2.0
damping = 0.3
[[force]]
name = "drive"
type = "torque"
body = "rod"
input = true
"""


def _pendulum(tmp_path, phi, w, name="p.toml"):
    c, s = math.cos(phi), math.sin(phi)
    path = tmp_path / name
    path.write_text(DAMPED_PENDULUM.format(x=0.5 * c, y=0.5 * s, phi=phi, vx=-0.5 * s * w,
                                           vy=0.5 * c * w, w=w))
    return path


def _initial_rate(tmp_path, phi, w, torque=0.0):
    """(phi', w') at t = 0 from simulate(): its first output row."""
    result = mbdfmu.simulate(_pendulum(tmp_path, phi, w), t_end=1e-6, output_interval=1e-6,
                             inputs={"drive": lambda t: np.array([torque])})
    return np.array([result["rod.omega"][0], result.qdd[0, 2]])


def test_A_and_B_against_finite_differences_of_simulate(tmp_path):
    # off equilibrium and moving: the linearization of the nonlinear model at that point
    phi0, w0, h = -0.9, 1.7, 1e-5
    lin = mbdfmu.linearize(_pendulum(tmp_path, phi0, w0))
    assert lin.states == ["rod.phi", "rod.omega"] and lin.inputs == ["drive.torque"]
    A = np.column_stack([(_initial_rate(tmp_path, phi0 + h, w0) -
                          _initial_rate(tmp_path, phi0 - h, w0)) / (2 * h),
                         (_initial_rate(tmp_path, phi0, w0 + h) -
                          _initial_rate(tmp_path, phi0, w0 - h)) / (2 * h)])
    B = (_initial_rate(tmp_path, phi0, w0, h) - _initial_rate(tmp_path, phi0, w0, -h)) / (2 * h)
    np.testing.assert_allclose(lin.A, A, rtol=1e-6, atol=1e-8)
    np.testing.assert_allclose(lin.B[:, 0], B, rtol=1e-6, atol=1e-8)
    # and the closed form of this pendulum: phi'' = (-k (phi) - c w - m g a cos(phi)
    # + T) / (I + m a^2)
    J = 1.0 / 12 + 0.25
    closed = [[0, 1], [(-2.0 + G * 0.5 * math.sin(phi0)) / J, -0.3 / J]]
    np.testing.assert_allclose(lin.A, closed, rtol=1e-7, atol=1e-9)
    np.testing.assert_allclose(lin.B[:, 0], [0, 1 / J], rtol=1e-7, atol=1e-9)


def test_linear_response_matches_simulated_small_motion(tmp_path):
    # at the equilibrium: a small step of the input torque, simulated, against the
    # linear model's step response x(T) = A^-1 (e^{AT} - I) B du
    lin = mbdfmu.linearize(_pendulum(tmp_path, -1.2, 0.0), equilibrium=True)
    du, T = 1e-4, 0.8
    phi_eq = lin.q[2]
    path = _pendulum(tmp_path, phi_eq, 0.0, "eq.toml")
    result = mbdfmu.simulate(path, t_end=T, rtol=1e-11, atol=1e-13,
                             inputs={"drive": lambda t: np.array([du])})
    x = np.array([result["rod.phi"][-1] - phi_eq, result["rod.omega"][-1]])
    A, B = lin.A, lin.B[:, 0]
    linear = np.linalg.solve(A, (scipy.linalg.expm(A * T) - np.eye(2)) @ B * du)
    np.testing.assert_allclose(x, linear, rtol=1e-3, atol=1e-10)   # O(du) nonlinearity
