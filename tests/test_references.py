"""Checks of the references themselves (tests/exact_solutions.py) and of the scene files' data.

Nothing here imports mbdfmu: these tests establish that the numbers the solver is later compared
with are right, and that every scene starts on its constraints with the intended data.
"""
import importlib.util
import math

import numpy as np
import pytest
from scipy.integrate import solve_ivp

import exact_solutions as ref

SCENE_FILES = sorted(ref.SCENES.glob("*.toml"))
BODY_KEYS = ("name", "mass", "inertia", "position", "angle", "velocity", "angular_velocity")
JOINT_KEYS = ("name", "type", "body_i", "point_i", "axis_i", "body_j", "point_j", "radius",
              "frame_angle", "limits", "restitution", "friction")
COUPLER_KEYS = ("name", "type", "joint_i", "joint_j", "ratio")


def _fd(f, x, h):
    """Central difference of a function of one variable."""
    return (f(x + h) - f(x - h)) / (2 * h)


# ------------------------------------------------------------------------------------ P1 ---

def test_p1_period_matches_benchmark():
    out = ref.simple_pendulum([0.0])
    assert out["period"] == pytest.approx(2.3678419475762374, rel=1e-15, abs=0)


def test_p1_bob_inertia_lengthens_period_by_sqrt_factor():
    T0 = ref.simple_pendulum([0.0])["period"]
    T1 = ref.simple_pendulum([0.0], J=1e-6)["period"]
    assert T1 / T0 == pytest.approx(math.sqrt(1.0 + 1e-6), rel=1e-15)


@pytest.mark.parametrize("J", [0.0, 1e-6, 0.3])
def test_p1_elliptic_solution_matches_direct_integration(J):
    t = np.linspace(0.0, 10.0, 101)
    ex = ref.simple_pendulum(t, J=J)
    inertia = 1.0 + J

    def rhs(_t, y):
        return [y[1], -ref.G * math.sin(y[0]) / inertia]

    sol = solve_ivp(rhs, (0, 10), [math.pi / 2, 0.0], method="DOP853", t_eval=t,
                    rtol=1e-13, atol=1e-13)
    np.testing.assert_allclose(ex["theta"], sol.y[0], rtol=0, atol=1e-10)
    np.testing.assert_allclose(ex["theta_dot"], sol.y[1], rtol=0, atol=1e-9)


def test_p1_start_half_period_and_tension():
    out = ref.simple_pendulum([0.0])
    T = out["period"]
    half = ref.simple_pendulum([0.0, T / 4, T / 2])
    assert half["theta"][0] == pytest.approx(math.pi / 2, abs=1e-15)
    assert half["theta_dot"][0] == pytest.approx(0.0, abs=1e-15)
    assert half["x"][0] == pytest.approx(1.0) and half["y"][0] == pytest.approx(0.0, abs=1e-15)
    assert half["theta"][1] == pytest.approx(0.0, abs=1e-12)          # bottom at T/4
    assert half["theta"][2] == pytest.approx(-math.pi / 2, abs=1e-7)  # far side at T/2
    # P1's printed tension m g (3 cos theta - 2 cos theta0) for J = 0
    t = np.linspace(0, 3, 31)
    o = ref.simple_pendulum(t)
    np.testing.assert_allclose(o["tension"], ref.G * 3 * np.cos(o["theta"]), atol=1e-11)
    bottom = ref.simple_pendulum([T / 4])["tension"][0]
    assert bottom == pytest.approx(3 * ref.G, rel=1e-12)  # 3 m g at the bottom


def test_compound_pendulum_rates_are_derivatives():
    h = 1e-5
    t = np.linspace(0.1, 3.0, 7)
    f = lambda s: ref.compound_pendulum(s, m=1, Lc=0.5, J=1 / 12)
    out = f(t)
    np.testing.assert_allclose(_fd(lambda s: f(s)["theta"], t, h), out["theta_dot"], atol=1e-8)
    np.testing.assert_allclose(_fd(lambda s: f(s)["theta_dot"], t, h), out["theta_ddot"],
                               atol=1e-7)
    np.testing.assert_allclose(_fd(lambda s: f(s)["x"], t, h), out["vx"], atol=1e-8)
    np.testing.assert_allclose(_fd(lambda s: f(s)["y"], t, h), out["vy"], atol=1e-8)


def test_compound_pendulum_pivot_force_is_newtons_law():
    """Pivot force + gravity = m a of the centre of mass, a from finite differences."""
    m, Lc, J, h = 2.0, 0.7, 0.05, 2e-5
    t = np.linspace(0.1, 2.0, 9)
    f = lambda s: ref.compound_pendulum(s, m=m, Lc=Lc, J=J, theta0=2.0)
    o = f(t)
    ax = _fd(lambda s: f(s)["vx"], t, h)
    ay = _fd(lambda s: f(s)["vy"], t, h)
    th = o["theta"]
    e_r = np.array([np.sin(th), -np.cos(th)])   # from pivot to centre of mass
    e_t = np.array([np.cos(th), np.sin(th)])    # increasing theta
    force = -o["force_to_pivot"] * e_r + o["force_perp"] * e_t
    np.testing.assert_allclose(force[0], m * ax, rtol=0, atol=1e-6)
    np.testing.assert_allclose(force[1] - m * ref.G, m * ay, rtol=0, atol=1e-6)


def test_rod_pendulum_compound_form_equals_printed_formulas():
    t = np.linspace(0, 5, 51)
    o = ref.compound_pendulum(t, m=1.0, Lc=0.5, J=1 / 12)
    p = ref.rod_pendulum_closed_form(o["theta"])
    np.testing.assert_allclose(o["theta_dot"]**2, p["theta_dot_sq"], atol=1e-10)
    np.testing.assert_allclose(o["force_to_pivot"], p["force_to_pivot"], atol=1e-10)
    np.testing.assert_allclose(o["force_perp"], p["force_perp"], atol=1e-12)


# ------------------------------------------------------------------------------------ P2 ---

@pytest.mark.parametrize("N", [1, 2, 40])
def test_p2_reduction_conserves_energy_and_starts_right(N):
    t = np.linspace(0, 20, 2001)
    o = ref.n_four_bar(t, N)
    assert o["Meff"] == pytest.approx((N + 1) / 3 + N)
    assert o["C"] == pytest.approx(ref.G * ((N + 1) / 2 + N))
    assert np.ptp(o["energy"]) < 1e-11 * abs(o["energy"]).max()
    assert (o["B0_x"][0], o["B0_y"][0]) == pytest.approx((0.0, 1.0), abs=1e-15)
    # B0 starts with x' = 1 m/s: B0_x ~ t for small t
    early = ref.n_four_bar([1e-4], N)
    assert early["B0_x"][0] / 1e-4 == pytest.approx(1.0, abs=1e-3)


def test_p2_twenty_horizontal_crossings_in_twenty_seconds():
    t = np.linspace(0, 20, 200001)
    c = np.cos(ref.n_four_bar(t, 2)["theta"])
    assert np.count_nonzero(np.sign(c[1:]) != np.sign(c[:-1])) == 20


@pytest.mark.parametrize("N", [2, 40])
def test_p2_scene_kinetic_energy_matches_reduction(N):
    scene = ref.load_toml(ref.SCENES / f"n_four_bar_{N}.toml")
    kin = sum(0.5 * b["mass"] * np.dot(b["velocity"], b["velocity"])
              + 0.5 * b["inertia"] * b["angular_velocity"]**2 for b in scene["body"])
    o = ref.n_four_bar([0.0], N)
    assert kin == pytest.approx(0.5 * o["Meff"] * 1.0**2, rel=1e-14)
    assert len(scene["body"]) == 2 * N + 1 and len(scene["joint"]) == 3 * N + 1


def test_p2_generator_reproduces_committed_files():
    spec = importlib.util.spec_from_file_location("gen", ref.SCENES / "generate_n_four_bar.py")
    gen = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(gen)
    for n in (2, 40):
        assert gen.scene_text(n) == (ref.SCENES / f"n_four_bar_{n}.toml").read_text()


def test_parallelogram_reduction_and_scene_agree():
    scene = ref.load_toml(ref.SCENES / "parallelogram.toml")
    kin = sum(0.5 * b["mass"] * np.dot(b["velocity"], b["velocity"])
              + 0.5 * b["inertia"] * b["angular_velocity"]**2 for b in scene["body"])
    o = ref.parallel_cranks(np.linspace(0, 10, 1001), n_cranks=3, crank_mass=1.0, L=1.0,
                            coupler_mass=2.0, theta0=-math.pi / 3, theta_dot0=1.0)
    assert kin == pytest.approx(0.5 * o["Meff"], rel=1e-14)
    assert np.ptp(o["energy"]) < 1e-11 * abs(o["energy"]).max()
    # never reaches the singular horizontal (|theta| stays above 55 degrees below it)
    assert o["theta"].max() < math.radians(-55) and o["theta"].min() > math.radians(-125)


# ------------------------------------------------------------------------------------ P4 ---

SC = dict(r=0.1, l=0.3, crank_mass=0.2, crank_inertia=1.6667e-4, rod_mass=0.2,
          rod_inertia=1.5e-3, slider_mass=0.4, load=(-10.0, 0.0))
W = 314.1592653589793


def test_p4_kinematics_close_the_loop_and_differentiate():
    th = np.linspace(0, 2 * np.pi, 37)
    o = ref.slider_crank(th, W, **SC)
    # pin B at the rod's end lies on the x axis at x_B
    np.testing.assert_allclose(0.1 * np.sin(th) + 0.3 * np.sin(o["phi"]), 0, atol=1e-16)
    np.testing.assert_allclose(0.1 * np.cos(th) + 0.3 * np.cos(o["phi"]), o["xB"], atol=1e-16)
    h = 1e-6  # in time; theta = W t
    f = lambda s: ref.slider_crank(W * s, W, **SC)
    t = th / W
    for pos, vel in (("phi", "phi_d"), ("phi_d", "phi_dd"), ("xB", "xB_d"), ("xB_d", "xB_dd"),
                     ("rod_x", "rod_vx"), ("rod_y", "rod_vy"), ("rod_vx", "rod_ax"),
                     ("rod_vy", "rod_ay"), ("crank_vx", "crank_ax")):
        d = _fd(lambda s: f(s)[pos], t, h)
        scale = np.abs(o[vel]).max()
        np.testing.assert_allclose(d, o[vel], atol=1e-6 * scale, err_msg=f"d{pos}/dt")


def test_p4_torque_equals_energy_rate_balance():
    """tau w = dT/dt - P_gravity - P_load, dT/dt by finite differences of T."""
    h = 1e-7
    t = np.linspace(0.0, 0.02, 41)
    f = lambda s: ref.slider_crank(W * s, W, **SC)
    o = f(t)
    dT = _fd(lambda s: f(s)["kinetic"], t, h)
    P_grav = -ref.G * sum(m * o[f"{b}_vy"] for b, m in (("crank", 0.2), ("rod", 0.2),
                                                           ("slider", 0.4)))
    P_load = -10.0 * o["xB_d"]
    np.testing.assert_allclose(o["torque"] * W, dT - P_grav - P_load,
                               atol=1e-6 * np.abs(dT).max())


def test_p4_torque_by_virtual_work_of_inertia_forces():
    """Independent check: tau = sum (m a - m g - F).dr/dtheta + J alpha dphi/dtheta."""
    th = np.linspace(0, 2 * np.pi, 25)
    o = ref.slider_crank(th, W, **SC)
    tau = 0.0
    for b, m, J in (("crank", 0.2, 1.6667e-4), ("rod", 0.2, 1.5e-3), ("slider", 0.4, 0.0)):
        fx = m * o[f"{b}_ax"] - (-10.0 if b == "slider" else 0.0)
        fy = m * o[f"{b}_ay"] + m * ref.G
        tau = tau + (fx * o[f"{b}_vx"] + fy * o[f"{b}_vy"]) / W
    tau = tau + 1.5e-3 * o["phi_dd"] * o["phi_d"] / W
    np.testing.assert_allclose(o["torque"], tau, atol=1e-9 * np.abs(tau).max())


def test_p4_newton_euler_torque_equals_power_balance_torque():
    """The reaction chain (slider -> rod -> crank) reproduces the energy-balance torque."""
    th = np.linspace(0, 2 * np.pi, 61)
    o = ref.slider_crank(th, W, **SC)
    np.testing.assert_allclose(o["torque_newton_euler"], o["torque"],
                               atol=1e-10 * np.abs(o["torque"]).max())
    # slider at rest at a dead centre with the crank at 0: B carries the load plus inertia
    assert o["force_B"][0][0] == pytest.approx(0.4 * o["xB_dd"][0] + 10.0)


# ------------------------------------------------------------------------------------ P5 ---

FB = dict(a=0.1, b=0.35, c=0.3, d=0.4)


def test_p5_freudenstein_closes_loop_and_rates_differentiate():
    th2 = np.linspace(0, 2 * np.pi, 73)
    o = ref.freudenstein(th2, 2 * np.pi, **FB)
    loop = (0.1 * np.exp(1j * th2) + 0.35 * np.exp(1j * o["theta3"])
            - 0.3 * np.exp(1j * o["theta4"]) - 0.4)
    assert np.abs(loop).max() < 1e-15
    h = 1e-7
    for ang, rate in (("theta3", "w3"), ("theta4", "w4")):
        d = _fd(lambda s: ref.freudenstein(2 * np.pi * s, 2 * np.pi, **FB)[ang], th2 / (2 * np.pi),
                h)
        np.testing.assert_allclose(d, o[rate], atol=1e-6)
    # open branch: coupler and rocker above the ground link, rocker between 1.77 and 2.47 rad
    assert o["theta4"].min() > 1.76 and o["theta4"].max() < 2.48


# ------------------------------------------------------------------------------------ P6 ---

def test_p6_invariants():
    M, m, l = 1e-6, 1.0, 1.0
    th = np.linspace(-1.5, 1.5, 31)
    j0 = ref.cart_pole_invariants(th, M=M, m=m, l=l)
    printed = 2 * ref.G * (M + m) * (np.cos(th) - 0.0) / (l * (M + m * np.sin(th)**2))
    np.testing.assert_allclose(j0["theta_dot_sq"], printed, rtol=1e-13)
    assert math.sqrt(ref.cart_pole_invariants(0.0, M=M, m=m, l=l)["theta_dot_sq"]) == \
        pytest.approx(4.4e3, rel=0.01)  # P6's spike
    # energy with J: from x(theta) by finite differences, kinetic + potential = 0
    J = 1e-6
    o = ref.cart_pole_invariants(th, M=M, m=m, l=l, J=J)
    w = np.sqrt(o["theta_dot_sq"])
    dxdth = _fd(lambda a: ref.cart_pole_invariants(a, M=M, m=m, l=l, J=J)["x"], th, 1e-6)
    xd = dxdth * w
    bvx, bvy = xd + l * np.cos(th) * w, l * np.sin(th) * w
    energy = 0.5 * M * xd**2 + 0.5 * m * (bvx**2 + bvy**2) + 0.5 * J * w**2 - m * ref.G * np.cos(th)
    np.testing.assert_allclose(energy, 0.0, atol=1e-7)
    # zero horizontal momentum
    np.testing.assert_allclose(M * xd + m * bvx, 0.0, atol=1e-9 * np.abs(m * l * w).max())


# ------------------------------------------------------------------------------------ P7 ---

def test_p7_energy_conserved_and_zero():
    t = np.linspace(0, 10, 1001)
    o = ref.double_pendulum(t, J1=1e-6, J2=1e-6)
    np.testing.assert_allclose(o["energy"], 0.0, atol=1e-9)
    assert (o["x2"][0], o["y2"][0]) == pytest.approx((2.0, 0.0), abs=1e-15)


def test_p7_reduces_to_single_pendulum_when_second_mass_vanishes():
    t = np.linspace(0, 3, 31)
    o = ref.double_pendulum(t, m2=1e-12)
    s = ref.simple_pendulum(t)
    np.testing.assert_allclose(o["th1"], s["theta"], atol=1e-9)


# ------------------------------------------------------------------------------------ P3 ---

def test_p3_initial_configuration_closes_all_ten_joints():
    pos, ang = ref.andrews_initial_state()
    assert np.abs(ref.andrews_joint_residuals(pos, ang)).max() < 1e-15


def test_p3_own_model_reproduces_published_initial_accelerations():
    pos, ang = ref.andrews_initial_state()
    qdd, _lam = ref.andrews_accelerations(pos, ang, np.zeros((7, 2)), np.zeros(7))
    assert qdd[2] == pytest.approx(ref.ANDREWS_BETA_DDOT0, rel=1e-11)
    assert qdd[5] - qdd[2] == pytest.approx(ref.ANDREWS_THETA_DDOT0, rel=1e-11)


def test_p3_own_model_reproduces_published_solution_at_end():
    o = ref.andrews_trajectory([ref.ANDREWS_T_END])
    for key, value in ref.ANDREWS_AT_T_END.items():
        assert o[key][-1] == pytest.approx(value, abs=5e-9), key
    q = o["q"][:, -1].reshape(7, 3)
    assert np.abs(ref.andrews_joint_residuals(q[:, :2], q[:, 2])).max() < 1e-12


def test_p3_scene_matches_reference_data():
    scene = ref.load_toml(ref.SCENES / "andrews.toml")
    pos, ang = ref.andrews_initial_state()
    assert scene["gravity"] == [0.0, 0.0]
    for k, b in enumerate(scene["body"]):
        assert b["mass"] == ref.ANDREWS["m"][k] and b["inertia"] == ref.ANDREWS["i"][k]
        np.testing.assert_allclose(b["position"], pos[k], rtol=0, atol=1e-17)
        assert b["angle"] == pytest.approx(ang[k], abs=1e-16)
        assert b["velocity"] == [0.0, 0.0] and b["angular_velocity"] == 0.0
    pts = ref.andrews_points()
    names = [b["name"] for b in scene["body"]]
    ground = {"O": ref.ANDREWS["O"], "A": ref.ANDREWS["A"], "B": ref.ANDREWS["B"]}
    assert len(scene["joint"]) == 10
    for jt, (bi, pi, bj, pj) in zip(scene["joint"], ref.ANDREWS_JOINTS):
        exp_i = ground[pi] if bi == 0 else pts[bi - 1][pi]
        assert jt["body_i"] == ("ground" if bi == 0 else names[bi - 1])
        assert jt["body_j"] == names[bj - 1]
        np.testing.assert_allclose(jt["point_i"], exp_i, atol=1e-17)
        np.testing.assert_allclose(jt["point_j"], pts[bj - 1][pj], atol=1e-17)
    spring, mom = scene["force"]
    assert spring["stiffness"] == 4530.0 and spring["rest_length"] == 0.07785
    assert spring["damping"] == 0.0 and spring["body_j"] == names[2]
    np.testing.assert_allclose(spring["point_i"], ref.ANDREWS["C"])
    np.testing.assert_allclose(spring["point_j"], pts[2]["D"], atol=1e-17)
    assert mom["type"] == "torque" and mom["body"] == names[0] and mom["value"] == 0.033


# ---------------------------------------------------------------------- all scene files ---

def test_expected_scenes_exist():
    names = {p.stem for p in SCENE_FILES}
    assert names >= {"pendulum", "rod_pendulum", "double_pendulum", "slider_crank", "four_bar",
                     "n_four_bar_2", "n_four_bar_40", "andrews", "light_cart_pole",
                     "parallelogram", "pendulum_torque", "slider_force", "gear_pair",
                     "rack_pinion", "rolling_disc", "slot_rod", "slider_stop", "incline_stick",
                     "incline_slide", "crane_stop"}


@pytest.mark.parametrize("path", SCENE_FILES, ids=lambda p: p.stem)
def test_scene_layout_is_uniform(path):
    text = path.read_text()
    assert text.startswith("# Source: "), "header comment first"
    assert "# Expect: " in text.split("\nname = ")[0], "header states what to expect"
    scene = ref.load_toml(path)
    assert list(scene)[:3] == ["name", "description", "gravity"]
    assert scene["name"].isidentifier()
    assert scene["description"] and "\n" not in scene["description"]
    assert len(scene["gravity"]) == 2
    names = [item["name"] for key in ("body", "joint", "driver", "force")
             for item in scene.get(key, [])]
    assert len(names) == len(set(names)) and "ground" not in names
    for b in scene["body"]:
        assert b["mass"] > 0 and b["inertia"] > 0
        order = [k for k in BODY_KEYS if k in b]
        assert list(b) == order, f"body {b['name']}: keys out of order"
        if path.stem != "slider_crank":   # the example omits the optional velocities
            assert order == list(BODY_KEYS)
    for jt in scene.get("joint", []):
        keys = COUPLER_KEYS if jt["type"] == "coupler" else JOINT_KEYS
        assert list(jt) == [k for k in keys if k in jt], jt["name"]
        assert jt["type"] in ("revolute", "translational", "slot", "rolling", "coupler")


@pytest.mark.parametrize("path", SCENE_FILES, ids=lambda p: p.stem)
def test_scene_initial_state_closes_every_joint(path):
    scene = ref.load_toml(path)
    res = ref.joint_residuals(scene)
    assert len(res) == len(scene.get("joint", []))
    for name, (pos_res, vel_res) in res.items():
        assert np.abs(pos_res).max() < 1e-12, f"{path.name}: joint {name} position {pos_res}"
        assert np.abs(vel_res).max() < 1e-12, f"{path.name}: joint {name} velocity {vel_res}"


def test_four_bar_scene_matches_freudenstein_and_driver():
    scene = ref.load_toml(ref.SCENES / "four_bar.toml")
    b = {x["name"]: x for x in scene["body"]}
    motion = scene["driver"][0]["motion"]
    th2, w2 = motion["start"], motion["rate"]
    o = ref.freudenstein(th2, w2, **FB)
    assert b["crank"]["angle"] == th2 and b["crank"]["angular_velocity"] == w2
    assert b["coupler"]["angle"] == pytest.approx(float(o["theta3"]), abs=1e-15)
    assert b["rocker"]["angle"] == pytest.approx(float(o["theta4"]), abs=1e-15)
    assert b["coupler"]["angular_velocity"] == pytest.approx(float(o["w3"]), abs=1e-14)
    assert b["rocker"]["angular_velocity"] == pytest.approx(float(o["w4"]), abs=1e-14)
    for name, length in (("crank", 0.1), ("coupler", 0.35), ("rocker", 0.3)):
        assert b[name]["mass"] == pytest.approx(length)              # 1 kg/m
        assert b[name]["inertia"] == pytest.approx(length**3 / 12)   # m L^2 / 12


def test_slider_crank_scene_matches_p4_data():
    scene = ref.load_toml(ref.SCENES / "slider_crank.toml")
    b = {x["name"]: x for x in scene["body"]}
    assert (b["crank"]["mass"], b["rod"]["mass"], b["slider"]["mass"]) == (0.2, 0.2, 0.4)
    assert b["crank"]["inertia"] == pytest.approx(0.2 * 0.1**2 / 12, rel=1e-4)
    assert b["rod"]["inertia"] == pytest.approx(0.2 * 0.3**2 / 12, rel=1e-12)
    assert scene["driver"][0]["motion"] == {"type": "linear", "start": 0.0,
                                            "rate": 314.1592653589793}
    assert scene["force"][0]["value"] == [-10.0, 0.0]


# ------------------------------------------------------------------------------- P8-P11 ---

def test_p8_p9_geared_pair_balances_power_and_newton():
    # input: J_in q_in'' = T - ratio * effort (the reaction on its coordinate); output:
    # inertia_out q_out'' = effort; q_out = ratio q_in
    for ratio in (-0.5, 0.05, 3.0):
        ex = ref.geared_pair(np.array([0.7]), torque=0.1, J_in=0.005, inertia_out=0.04, ratio=ratio)
        assert 0.005 * ex["alpha"] == pytest.approx(0.1 - ratio * ex["effort"], rel=1e-14)
        assert 0.04 * ratio * ex["alpha"] == pytest.approx(ex["effort"], rel=1e-14)
        assert ex["q_out"][0] == pytest.approx(ratio * ex["q_in"][0], rel=1e-14)


def test_p10_rolling_incline_obeys_newton_about_the_centre():
    m, J, r, a = 2.0, 0.01, 0.1, math.pi / 6
    t = np.linspace(0.0, 1.0, 11)
    ex = ref.rolling_incline(t, m=m, J=J, r=r, slope=a, s0=2.0)
    phi_dd = -ex["acc"] / r
    assert m * ex["acc"] == pytest.approx(ex["friction"] - m * ref.G * math.sin(a), rel=1e-14)
    assert J * phi_dd == pytest.approx(r * ex["friction"], rel=1e-14)
    assert ex["normal"] == pytest.approx(m * ref.G * math.cos(a), rel=1e-15)
    # the centre stays r above the line and moves along it
    n = np.array([-math.sin(a), math.cos(a)])
    np.testing.assert_allclose(n[0] * ex["x"] + n[1] * ex["y"], r, atol=1e-15)


def test_p11_slot_rod_conserves_energy_and_keeps_the_pin_on_the_slot():
    t = np.linspace(0.0, 2.0, 41)
    ex = ref.slot_rod(t)
    a, m, J = 0.5, 1.0, 1.0 / 12
    ydot = a * np.sin(ex["theta"]) * ex["theta_dot"]
    energy = 0.5 * m * ydot ** 2 + 0.5 * J * ex["theta_dot"] ** 2 + m * ref.G * ex["y"]
    np.testing.assert_allclose(energy, energy[0], atol=1e-12)
    pin_y = ex["y"] + a * np.cos(ex["theta"])
    np.testing.assert_allclose(pin_y, 0.0, atol=1e-15)


def test_p11_small_oscillations_of_the_slot_rod_have_omega_squared_six_g_over_l():
    # the reduction's period at a tiny amplitude, by quadrature of the energy integral
    from scipy.integrate import quad

    a, m, J, L, th0 = 0.5, 1.0, 1.0 / 12, 1.0, 1e-4

    def integrand(u):
        # dt = dth / th' with th = th0 sin(u); with v = pi/4 - u/2, th0 - th = 2 th0 sin^2 v and
        # cos th - cos th0 = 2 sin((th0 + th) / 2) sin(th0 sin^2 v): the sin v factors cancel
        th, v = th0 * math.sin(u), math.pi / 4 - u / 2
        x = th0 * math.sin(v) ** 2
        sinc = math.sin(x) / x if x else 1.0
        return (th0 * 2 * math.cos(v) * math.sqrt(m * a * a * math.sin(th) ** 2 + J)
                / math.sqrt(4 * m * ref.G * a * math.sin((th0 + th) / 2) * th0 * sinc))

    quarter = quad(integrand, 0.0, math.pi / 2, epsabs=0, epsrel=1e-13)[0]
    assert 4 * quarter == pytest.approx(2 * math.pi / math.sqrt(6 * ref.G / L), rel=1e-8)
