"""The integrator family against outside references (tests/exact_solutions.py), method by method.

Every method (taylor, baumgarte, rk4p, rk45p, dop853p, genalpha, ali3p, and auto's choices) is
run on the benchmark problems of docs/problems.md and checked against the exact
answers, and every failure mode is pinned: a method that cannot do a scene must say so with a
``SolverError`` naming the time and the reason, never return a wrong answer. Error thresholds
are a few times the errors measured when the tests were written (quoted in comments), so a
regression in accuracy shows, not only a crash.

Long runs are skipped unless MBDFMU_SLOW=1 (as in test_physics.py); each has a fast variant.
"""
import dataclasses
import math
import os

import numpy as np
import pytest

import exact_solutions as ref

mbdfmu = pytest.importorskip("mbdfmu")
from mbdfmu.integrators import (DEFAULT_METHOD, METHOD_NAMES, METHODS, SUMMARIES,  # noqa: E402
                                make_integrator)
from mbdfmu.integrators import choose_method  # noqa: E402
from mbdfmu.equations.projection import assemble  # noqa: E402
from mbdfmu.equations import Equations  # noqa: E402

SLOW = [pytest.mark.slow,
        pytest.mark.skipif(not os.environ.get("MBDFMU_SLOW"), reason="long run; set MBDFMU_SLOW=1")]
FIXED = ("taylor", "baumgarte", "rk4p", "genalpha", "ali3p")
ADAPTIVE = ("rk45p", "dop853p")


def scene(name):
    return mbdfmu.load_scene(ref.SCENES / f"{name}.toml")


def run(name, t_end, **kw):
    return mbdfmu.simulate(scene(name) if isinstance(name, str) else name, t_end, **kw)


def wrap(angle):
    return np.angle(np.exp(1j * np.asarray(angle)))


def b0(res):
    """Top of crank0 (B0 of P2): crank0's centre plus half its length along its axis."""
    phi = res["crank0.phi"]
    return res["crank0.x"] + 0.5 * np.cos(phi), res["crank0.y"] + 0.5 * np.sin(phi)


def horizontal_passes(angle):
    """How many times a crank angle (rad, unwrapped) passed the horizontal (a multiple of pi)."""
    return int(np.sum(np.abs(np.diff(np.floor(np.asarray(angle) / math.pi))) > 0))


def cart_pole_errors(res):
    """P6's error criterion from the exact quadratures: cart x (m) and theta'^2 relative to its
    largest value, at every output point."""
    theta = res["bob.phi"] + math.pi / 2   # the bob's frame x runs from the hinge to the bob
    inv = ref.cart_pole_invariants(theta, M=1e-6, m=1.0, l=1.0, J=1e-6)
    x_err = np.max(np.abs(res["cart.x"] - inv["x"]))
    w_err = np.max(np.abs(res["bob.omega"] ** 2 - inv["theta_dot_sq"])) / inv["theta_dot_sq"].max()
    return x_err, w_err


P6_CRITERION = 1e-6


# ------------------------------------------------------------------------------ registry ---

def test_every_method_is_registered_with_a_one_line_summary():
    assert {"taylor", "baumgarte", "rk4p", "rk45p", "dop853p", "genalpha", "ali3p"} <= set(METHODS)
    assert DEFAULT_METHOD == "auto" and METHOD_NAMES == ("auto", *METHODS)
    for name, cls in METHODS.items():
        assert cls.name == name
        assert cls.summary and "\n" not in cls.summary
    assert set(SUMMARIES) == set(METHOD_NAMES) and "\n" not in SUMMARIES["auto"]
    assert METHODS["baumgarte"].option_names == ("alpha", "beta")
    assert METHODS["genalpha"].option_names == ("rho_inf", "jacobian", "step_control")
    assert METHODS["ali3p"].option_names == ("alpha", "step_control")


@pytest.mark.parametrize("method, options, words", [
    ("genalpha", {"rho_inf": 1.5}, "rho_inf"),
    ("genalpha", {"jacobian": "exact"}, "jacobian"),
    ("ali3p", {"alpha": -1.0}, "alpha"),
    ("rk4p", {"alpha": 1.0}, "no option alpha"),
    ("auto", {"rho_inf": 0.5}, "no option rho_inf"),
])
def test_bad_method_options_are_rejected_by_name(method, options, words):
    with pytest.raises(mbdfmu.SettingError, match=words) as info:
        run("pendulum", 0.01, method=method, method_options=options)
    assert isinstance(info.value, ValueError)


# -------------------------------------------------------------------------------- auto ---

HORIZONTAL_FOUR_BAR = """
name = "HorizontalFourBar"
gravity = [0.0, -9.81]

[[body]]
name = "crank0"
mass = 1.0
inertia = 0.08333333333333333
position = [0.5, 0.0]
velocity = [0.0, 0.5]
angular_velocity = 1.0

[[body]]
name = "crank1"
mass = 1.0
inertia = 0.08333333333333333
position = [1.5, 0.0]
velocity = [0.0, 0.5]
angular_velocity = 1.0

[[body]]
name = "coupler"
mass = 1.0
inertia = 0.08333333333333333
position = [1.5, 0.0]
velocity = [0.0, 1.0]

[[joint]]
name = "A0"
type = "revolute"
body_i = "ground"
point_i = [0.0, 0.0]
body_j = "crank0"
point_j = [-0.5, 0.0]

[[joint]]
name = "A1"
type = "revolute"
body_i = "ground"
point_i = [1.0, 0.0]
body_j = "crank1"
point_j = [-0.5, 0.0]

[[joint]]
name = "B0"
type = "revolute"
body_i = "crank0"
point_i = [0.5, 0.0]
body_j = "coupler"
point_j = [-0.5, 0.0]

[[joint]]
name = "B1"
type = "revolute"
body_i = "crank1"
point_i = [0.5, 0.0]
body_j = "coupler"
point_j = [0.5, 0.0]
"""

STIFF_SPRING_PENDULUM = ((ref.SCENES / "stiff_spring.toml").read_text()
                         + "\n[simulation]\nt_end = 2.0\noutput_interval = 0.05\n")


def scene_from_text(tmp_path, text, name="scene"):
    path = tmp_path / f"{name}.toml"
    path.write_text(text)
    return mbdfmu.load_scene(path)


@pytest.mark.parametrize("name, picked, words", [
    ("pendulum", "dop853p", "smooth"),
    ("andrews", "dop853p", "smooth"),
    ("n_four_bar_40", "dop853p", "smooth"),     # singular only later: auto looks at t0
    ("parallelogram", "dop853p", "redundant"),  # consistent: minimum-norm multipliers
    ("light_cart_pole", "dop853p", "1e+06x"),
    ("slider_crank", "rk4p", "no degrees of freedom"),   # the projections give the motion
])
def test_auto_picks_per_scene_and_says_why(name, picked, words):
    sim = mbdfmu.Simulation(scene(name))
    assert sim.method_name == f"auto->{picked}"
    assert words in sim.method_reason


def test_auto_takes_ali3p_at_a_singular_start_and_passes_it(tmp_path):
    sc = scene_from_text(tmp_path, HORIZONTAL_FOUR_BAR)
    sim = mbdfmu.Simulation(sc)
    assert sim.method_name == "auto->ali3p"
    assert "singular configuration" in sim.method_reason
    res = mbdfmu.simulate(sc, 2.0, output_interval=0.01)
    # ali3p across the singular start, dop853p once it is passed (auto_watch.py)
    assert res.method == "auto->ali3p->dop853p"
    assert [s[1:3] for s in res.switches] == [("ali3p", "dop853p")]
    # the cranks stay parallel (the coupler translates) through the singular start
    np.testing.assert_allclose(wrap(res["crank1.phi"] - res["crank0.phi"]), 0.0, atol=1e-8)
    np.testing.assert_allclose(res["coupler.phi"], 0.0, atol=1e-8)
    ex = ref.parallel_cranks(res.time, n_cranks=2, crank_mass=1.0, L=1.0, coupler_mass=1.0,
                             theta0=0.0, theta_dot0=1.0)
    # trapezoidal rule at h = 1 ms: second order (measured 3e-5 rad)
    np.testing.assert_allclose(wrap(res["crank0.phi"] - ex["theta"]), 0.0, atol=3e-4)


def test_auto_takes_genalpha_for_a_stiff_spring_and_damps_it(tmp_path):
    sc = scene_from_text(tmp_path, STIFF_SPRING_PENDULUM)
    sim = mbdfmu.Simulation(sc)
    assert sim.method_name == "auto->genalpha"
    assert 'force "rod"' in sim.method_reason and "stiff" in sim.method_reason
    res = mbdfmu.simulate(sc)
    assert res.method == "auto->genalpha"
    # a spring of 1e10 N/m is a rigid link to 3e-9 m: the rigid pendulum of P1
    ex = ref.simple_pendulum(res.time, J=1e-6)
    np.testing.assert_allclose(res["bob.x"], ex["x"], atol=2e-4)   # 4e-5 at auto's old fixed 1 ms
    np.testing.assert_allclose(res["bob.y"], ex["y"], atol=2e-4)


def test_auto_sends_a_stiff_spring_to_genalpha_at_an_fmu_step_within_tolerance(tmp_path):
    # at a 1 ms output interval the spring's period (63 µs) is not 1 % of it: the rule that
    # catches it compares dop853p's stable step with the step rtol needs on the motion
    sc = scene_from_text(tmp_path, STIFF_SPRING_PENDULUM)
    sim = mbdfmu.Simulation(sc, output_interval=1e-3)
    assert sim.method_name == "auto->genalpha"
    assert "stability" in sim.method_reason and 'force "rod"' in sim.method_reason
    res = mbdfmu.simulate(sc, 0.02, output_interval=1e-3)
    # the spring stretches at most m g / k = 1e-9 m: the rigid pendulum, to the tolerance
    ex = ref.simple_pendulum(res.time, J=1e-6)
    tol = 1e-6 * 1.0 + 1e-8     # default rtol x 1 m + atol
    assert np.max(np.hypot(res["bob.x"] - ex["x"], res["bob.y"] - ex["y"])) < tol


def test_auto_resolves_a_stretched_stiff_spring_whose_oscillation_shows(tmp_path):
    # stretched by 1 mm at t0 without gravity: x = 1 + 1e-3 cos(w t), w = sqrt(k / m), an
    # oscillation far above the tolerance, so damping it would be a wrong result
    text = (STIFF_SPRING_PENDULUM.replace("[0.0, -9.81]", "[0.0, 0.0]")
            .replace("position = [1.0, 0.0]", "position = [1.001, 0.0]")
            .replace("stiffness = 1.0e10", "stiffness = 1.0e6"))
    sc = scene_from_text(tmp_path, text)
    sim = mbdfmu.Simulation(sc, output_interval=1e-3)
    assert sim.method_name == "auto->dop853p"
    res = mbdfmu.simulate(sc, 0.02, output_interval=1e-3)
    expected = 1.0 + 1e-3 * np.cos(1e3 * res.time)
    np.testing.assert_allclose(res["bob.x"], expected, atol=2e-6)
    np.testing.assert_allclose(res["bob.y"], 0.0, atol=1e-12)


def test_choose_method_is_the_rule_set_without_running():
    system = Equations(scene("n_four_bar_2"))
    q, _ = assemble(system)
    cls, reason = choose_method(system, 0.0, q, output_interval=0.02)
    assert cls.name == "dop853p" and reason


# ------------------------------------------------------------------------- P1 pendulum ---

def test_p1_within_ten_rtol_at_ten_seconds_with_the_best_method():
    # rtol 1e-10 (the step control aims at rtol / 100 per step): issue 12 asks 10 rtol
    res = run("pendulum", 10.0, method="dop853p", rtol=1e-10, atol=1e-10, output_interval=0.5)
    ex = ref.simple_pendulum(res.time, J=1e-6)
    # measured 4.7e-10 (numpy kernel)
    assert abs(res["bob.x"][-1] - ex["x"][-1]) < 1e-9
    assert abs(res["bob.y"][-1] - ex["y"][-1]) < 1e-9


@pytest.mark.parametrize("method, kw, tol", [   # errors measured over 10 s; the test runs 3 s
    ("rk45p", {"rtol": 1e-10, "atol": 1e-10}, 1e-7),      # measured 2.6e-8
    ("rk4p", {"step": 1e-3}, 1e-10),                      # 3.0e-12
    ("baumgarte", {"step": 1e-3}, 5e-7),                  # 7.0e-8
    ("genalpha", {"step": 1e-3}, 1e-3),                   # 2.0e-4 (second order, damped)
    ("ali3p", {"step": 1e-3}, 3e-4),                      # 7.5e-5 (second order)
])
def test_p1_each_method_against_the_elliptic_solution(method, kw, tol):
    res = run("pendulum", 3.0, method=method, output_interval=0.05, **kw)
    ex = ref.simple_pendulum(res.time, J=1e-6)
    np.testing.assert_allclose(res["bob.x"], ex["x"], atol=tol)
    np.testing.assert_allclose(res["bob.y"], ex["y"], atol=tol)
    assert np.max(res["constraint.position_error"]) < (1e-6 if method == "baumgarte" else 1e-9)


def test_second_order_methods_converge_at_second_order_on_p1():
    def error(method, h):
        res = run("pendulum", 2.0, method=method, step=h, output_interval=0.1)
        ex = ref.simple_pendulum(res.time, J=1e-6)
        return np.max(np.abs(res["bob.x"] - ex["x"]))
    for method in ("genalpha", "ali3p"):
        ratio = error(method, 4e-3) / error(method, 2e-3)
        assert 3.0 < ratio < 5.0, (method, ratio)


# ------------------------------------------------------------------ Taylor and Baumgarte ---

def test_taylor_keeps_its_stated_accuracy_or_stops():
    # h = 1 ms at the stated accuracy a fixed step has by default (rtol 1e-3, atol 1e-5):
    # the error estimate (step doubling, velocity errors carried to t) passes
    # 10 (atol + rtol L) = 0.0101 m before t = 0.9 s (the bob is 3.6e-3 m off then), and the
    # run stops at the end of that output interval with the reason
    with pytest.raises(mbdfmu.SolverError, match=r"t = 0\.[89] s: taylor: estimated error "
                       r".*stated accuracy rtol = 0\.001"):
        run("pendulum", 10.0, method="taylor", step=1e-3, output_interval=0.1)
    # stated loosely (rtol 0.1: allows 1 m), the same run goes on, drifting steadily
    res = run("pendulum", 5.0, method="taylor", step=1e-3, rtol=0.1, output_interval=0.1)
    drift = res["constraint.position_error"]
    assert 1e-2 < drift[-1] < 1e-1                      # measured 2.7e-2 m on a 1 m link
    assert drift[-1] > 2 * drift[np.searchsorted(res.time, 2.0)]   # 2.7e-2 against 1.2e-2
    bob = scene("pendulum").bodies[0]
    ex = ref.simple_pendulum(res.time, m=bob.mass, J=bob.inertia)
    error = np.max(np.hypot(res["bob.x"] - ex["x"], res["bob.y"] - ex["y"]))
    assert error <= res.stats["error_estimate"]         # measured 0.034 m against 0.44 m
    # h = 50 ms: it stops early, with the time
    with pytest.raises(mbdfmu.SolverError, match=r"t = 0\.\d+ s: taylor: "):
        run("pendulum", 10.0, method="taylor", step=0.05, output_interval=0.05)


def test_baumgarte_bounds_the_drift_that_the_unstabilised_form_lets_grow():
    kw = dict(method="baumgarte", step=1e-2, output_interval=0.01)
    free = run("pendulum", 10.0, method_options={"alpha": 0.0, "beta": 0.0}, **kw)
    stabilised = run("pendulum", 10.0, **kw)                 # alpha = beta = 0.1 / h
    drift_free = free["constraint.position_error"]
    drift_stab = stabilised["constraint.position_error"]
    assert drift_free[-1] > 1e-6                          # measured 3.8e-6, growing
    assert drift_free[-1] > 3 * drift_free[np.searchsorted(free.time, 2.0)]
    assert np.max(drift_stab) < 0.2 * drift_free[-1]      # measured 3.1e-7, bounded
    assert np.max(drift_stab) > 1e-9                      # damped, not removed


def test_baumgarte_diverges_when_alpha_h_is_large():
    # alpha h = beta h = 10: the stabilisation itself is outside RK4's stability region
    with pytest.raises(mbdfmu.SolverError,
                       match=r"t = .* baumgarte: .*(diverged|energy balance broken)"):
        run("pendulum", 1.0, method="baumgarte", step=1e-3,
            method_options={"alpha": 1e4, "beta": 1e4})


# -------------------------------------------------------------------------- P2 N-four-bar ---

def test_p2_double_four_bar_b0_to_5e_8_through_all_crossings():
    """dop853p with the minimum-norm multipliers of eq. 14 passes the 20 singular crossings
    at tight tolerances. Measured at rtol = atol = 1e-11: 1.4e-8 (numpy kernel), 2.3e-8
    (numba kernel), 4.9e-9 with the first dense kernel: each crossing amplifies round-off,
    so the order of summation shows at this level."""
    res = run("n_four_bar_2", 20.0, method="dop853p", rtol=1e-11, atol=1e-11,
              output_interval=0.05)
    assert horizontal_passes(res["crank0.phi"]) == 20
    ex = ref.n_four_bar(res.time, 2)
    bx, by = b0(res)
    assert np.max(np.hypot(bx - ex["B0_x"], by - ex["B0_y"])) < 5e-8


def test_p2_default_settings_pass_every_crossing_at_any_output_interval():
    """Issue 12's target at default settings: B0 within 1e-6 of the exact reduction at
    t = 10 and 20 s, with the same steps whatever the output interval (dense output)."""
    runs = [run("n_four_bar_2", 20.0, output_interval=h) for h in (0.1, 0.01)]
    for res in runs:
        assert res.method == "auto->dop853p"
        assert horizontal_passes(res["crank0.phi"]) == 20
        ex = ref.n_four_bar(res.time, 2)
        bx, by = b0(res)
        error = np.hypot(bx - ex["B0_x"], by - ex["B0_y"])
        for t in (10.0, 20.0):
            assert error[np.searchsorted(res.time, t - 1e-9)] < 1e-6   # measured 8.6e-8, 7.1e-7
    assert runs[0].stats["nsteps"] == runs[1].stats["nsteps"]


def test_p2_ali3p_passes_all_twenty_crossings():
    res = run("n_four_bar_2", 20.0, method="ali3p", step=2e-3, output_interval=0.05)
    assert horizontal_passes(res["crank0.phi"]) == 20
    for k in (1, 2):
        np.testing.assert_allclose(wrap(res[f"crank{k}.phi"] - res["crank0.phi"]), 0, atol=1e-8)
    ex = ref.n_four_bar(res.time, 2)
    bx, by = b0(res)
    # measured 2.3e-3 at h = 2 ms, 5.0e-4 at 1 ms, 1.7e-4 at 0.5 ms
    assert np.max(np.hypot(bx - ex["B0_x"], by - ex["B0_y"])) < 1e-2
    assert res.stats["nrejected"] == 0


def test_p2_ali3p_converges_at_second_order():
    def error(h):
        res = run("n_four_bar_2", 2.0, method="ali3p", step=h, output_interval=0.05)
        ex = ref.n_four_bar(res.time, 2)
        bx, by = b0(res)
        return np.max(np.hypot(bx - ex["B0_x"], by - ex["B0_y"]))
    assert 3.0 < error(4e-3) / error(2e-3) < 6.0


def test_p2_forty_windows_first_crossings_fast():
    res = run("n_four_bar_40", 1.5, method="ali3p", step=2e-3, output_interval=0.05)
    assert horizontal_passes(res["crank0.phi"]) == 2
    ex = ref.n_four_bar(res.time, 40)
    bx, by = b0(res)
    assert np.max(np.hypot(bx - ex["B0_x"], by - ex["B0_y"])) < 1e-3
    np.testing.assert_allclose(wrap(res["crank40.phi"] - res["crank0.phi"]), 0, atol=1e-8)


def test_p2_forty_windows_all_crossings_with_ali3p():
    res = run("n_four_bar_40", 20.0, method="ali3p", step=2e-3, output_interval=0.05)
    assert horizontal_passes(res["crank0.phi"]) == 20
    ex = ref.n_four_bar(res.time, 40)
    bx, by = b0(res)
    assert np.max(np.hypot(bx - ex["B0_x"], by - ex["B0_y"])) < 1e-2    # measured 2.2e-3, 70 s


def test_p2_forty_windows_dop853p_passes_or_says_which_crossing_stopped_it():
    """The minimum-norm multipliers carry dop853p through P2 with N = 2, not with N = 40:
    at rtol = atol = 1e-11 it stops at the second crossing (t = 1.24 s) with the energy
    balance broken by 4e-6 and names the singular configuration."""
    try:
        res = run("n_four_bar_40", 20.0, method="dop853p", rtol=1e-11, atol=1e-11,
                  output_interval=0.05)
    except mbdfmu.SolverError as exc:
        assert "singular configuration" in str(exc) and "ali3p" in str(exc)
        return
    ex = ref.n_four_bar(res.time, 40)
    bx, by = b0(res)
    assert np.max(np.hypot(bx - ex["B0_x"], by - ex["B0_y"])) < 1e-6


for _mark in SLOW:
    test_p2_forty_windows_all_crossings_with_ali3p = _mark(
        test_p2_forty_windows_all_crossings_with_ali3p)
    test_p2_forty_windows_dop853p_passes_or_says_which_crossing_stopped_it = _mark(
        test_p2_forty_windows_dop853p_passes_or_says_which_crossing_stopped_it)


def test_genalpha_stops_at_redundant_constraints_with_the_reason():
    with pytest.raises(mbdfmu.SolverError, match=r"t = .*genalpha: .*halved.*singular"):
        run("parallelogram", 1.0, method="genalpha", step=1e-3)


def test_parallelogram_redundant_crank_runs_with_ali3p_and_dop853p():
    ex_kw = dict(n_cranks=3, crank_mass=1.0, L=1.0, coupler_mass=2.0, theta0=-math.pi / 3,
                 theta_dot0=1.0)
    for method, kw, tol in (("ali3p", {"step": 1e-3}, 1e-4),     # measured 2.5e-5
                            ("dop853p", {}, 1e-6)):
        res = run("parallelogram", 2.5, method=method, output_interval=0.05, **kw)
        ex = ref.parallel_cranks(res.time, **ex_kw)
        for k in range(3):
            np.testing.assert_allclose(wrap(res[f"crank{k}.phi"] - ex["theta"]), 0, atol=tol)
        assert np.max(res["constraint.position_error"]) < 1e-9


# --------------------------------------------------------------------------------- P3 ---

ANDREWS_METHODS = [  # (method, settings, coarse step, beta error bound at the fine setting)
    ("dop853p", {"rtol": 1e-9, "atol": 1e-11}, None, 1e-8),
    ("rk45p", {"rtol": 1e-9, "atol": 1e-11}, None, 1e-7),
    ("rk4p", {"step": 2e-5}, 4e-5, 1e-7),
    ("baumgarte", {"step": 2e-5}, 4e-5, 2e-6),
    ("genalpha", {"step": 2e-5}, 4e-5, 1e-3),      # measured 9.4e-5 at h = 1e-5
    ("ali3p", {"step": 2e-5}, 4e-5, 1e-3),         # 6.8e-5 at h = 1e-5
    # taylor states a loose accuracy: at the default one its estimate stops it (0.14 rad off)
    ("taylor", {"step": 1e-5, "rtol": 0.5}, 2e-5, 0.3),
]


@pytest.mark.parametrize("method, kw, coarse, tol", ANDREWS_METHODS)
def test_p3_andrews_every_method_converges_to_the_published_answer(method, kw, coarse, tol):
    res = run("andrews", 0.03, method=method, output_interval=1e-3, **kw)
    beta_err = abs(res["crank.phi"][-1] - ref.ANDREWS_AT_T_END["beta"])
    assert beta_err < tol
    # constraints held (index 3 and projected methods to round-off; the others drift)
    limit = {"taylor": 2e-3, "baumgarte": 1e-8}.get(method, 1e-10)
    assert np.max(res["constraint.position_error"]) < limit
    # energy balance: kinetic + spring - torque work is constant
    work = 0.033 * (res["crank.phi"] - res["crank.phi"][0])
    total = res["energy.kinetic"] + res["energy.potential"] - work
    assert np.ptp(total) < max(10 * tol, 1e-7) * np.abs(work).max()
    if coarse is not None:
        coarse_res = run("andrews", 0.03, method=method, output_interval=1e-3,
                         **{**kw, "step": coarse})
        coarse_err = abs(coarse_res["crank.phi"][-1] - ref.ANDREWS_AT_T_END["beta"])
        assert coarse_err > 1.5 * beta_err, "halving the step must reduce the error"


# ----------------------------------------------------------------------------- P4 and P5 ---

SC = dict(r=0.1, l=0.3, crank_mass=0.2, crank_inertia=1.6667e-4, rod_mass=0.2,
          rod_inertia=1.5e-3, slider_mass=0.4, load=(-10.0, 0.0))
W = 314.1592653589793


@pytest.mark.parametrize("method, kw, tol", [
    ("dop853p", {"rtol": 1e-8, "atol": 1e-10}, 1e-10),
    ("rk45p", {"rtol": 1e-8, "atol": 1e-10}, 1e-9),
    ("rk4p", {"step": 2e-5}, 1e-9),
    ("baumgarte", {"step": 2e-5}, 1e-6),
    ("genalpha", {"step": 2e-5}, 1e-9),
    ("ali3p", {"step": 2e-5}, 1e-9),
    ("taylor", {"step": 1e-5}, 1e-2),
])
def test_p4_slider_crank_closed_form_with_each_method(method, kw, tol):
    res = run("slider_crank", 0.02, method=method, output_interval=5e-4, **kw)
    ex = ref.slider_crank(W * res.time, W, **SC)
    np.testing.assert_allclose(wrap(res["rod.phi"] - ex["phi"]), 0, atol=tol)
    np.testing.assert_allclose(res["slider.x"], ex["xB"], atol=tol * 0.4)
    np.testing.assert_allclose(res["slider.vx"], ex["xB_d"], atol=tol * np.abs(ex["xB_d"]).max())
    np.testing.assert_allclose(res["motor.effort"], ex["torque"],
                               atol=tol * np.abs(ex["torque"]).max())


@pytest.mark.parametrize("method, kw, tol", [
    ("dop853p", {}, 1e-9),
    ("rk45p", {}, 1e-8),
    ("rk4p", {"step": 1e-3}, 1e-10),
    ("baumgarte", {"step": 1e-3}, 1e-8),
    ("genalpha", {"step": 1e-3}, 1e-9),
    ("ali3p", {"step": 1e-3}, 1e-9),
    ("taylor", {"step": 1e-3, "rtol": 0.1}, 0.05),   # default rtol: its estimate stops it
])
def test_p5_four_bar_freudenstein_with_each_method(method, kw, tol):
    res = run("four_bar", 1.0, method=method, output_interval=0.01, **kw)
    ex = ref.freudenstein(res["crank.phi"], 2 * math.pi, a=0.1, b=0.35, c=0.3, d=0.4)
    np.testing.assert_allclose(wrap(res["coupler.phi"] - ex["theta3"]), 0, atol=tol)
    np.testing.assert_allclose(wrap(res["rocker.phi"] - ex["theta4"]), 0, atol=tol)


# --------------------------------------------------------------------------------- P6 ---

def test_p6_default_is_within_the_criterion_or_says_so():
    try:
        res = run("light_cart_pole", 10.0, output_interval=0.01)
    except mbdfmu.SolverError as exc:
        assert "t = " in str(exc)
        return
    x_err, w_err = cart_pole_errors(res)
    assert x_err < P6_CRITERION and w_err < P6_CRITERION     # measured 3e-11, 2.3e-7
    assert res.method == "auto->dop853p"


@pytest.mark.parametrize("t_end", [3.0, pytest.param(10.0, marks=SLOW)])
def test_p6_rk45p_at_its_default_tolerance_is_within_the_criterion_or_says_so(t_end):
    try:
        res = run("light_cart_pole", t_end, method="rk45p", output_interval=0.01)
    except mbdfmu.SolverError:
        return
    x_err, w_err = cart_pole_errors(res)
    assert x_err < P6_CRITERION and w_err < P6_CRITERION     # measured 2.3e-7


@pytest.mark.parametrize("method", FIXED)
def test_p6_fixed_step_methods_stop_at_the_first_spike(method):
    with pytest.raises(mbdfmu.SolverError, match=rf"t = 0\.45\d* s: {method}"):
        run("light_cart_pole", 10.0, method=method, output_interval=0.01)


def test_step_control_at_rtol_over_100_resolves_p6_with_or_without_the_energy_estimate(
        monkeypatch):
    """At rtol as a per-step tolerance dop853p missed P6's criterion by 15x without the
    energy error estimate; aiming each step at rtol / 100 (``local_tolerance``) it meets
    it by itself (measured 7.5e-9 at 3 s either way)."""
    import mbdfmu.integrators.energy_audit as audit
    for factor in (1e12, audit.ENERGY_STEP_FACTOR):
        monkeypatch.setattr(audit, "ENERGY_STEP_FACTOR", factor)
        res = run("light_cart_pole", 3.0, method="dop853p", output_interval=0.01)
        _, w_err = cart_pole_errors(res)
        assert w_err < 0.05 * P6_CRITERION


# --------------------------------------------------------------------------------- P7 ---

def _reversed(sc, q, qd):
    bodies = tuple(dataclasses.replace(b, position=(q[3 * k], q[3 * k + 1]), angle=q[3 * k + 2],
                                       velocity=(-qd[3 * k], -qd[3 * k + 1]),
                                       angular_velocity=-qd[3 * k + 2])
                   for k, b in enumerate(sc.bodies))
    return dataclasses.replace(sc, bodies=bodies)


@pytest.mark.parametrize("method, kw, tol", [
    # rtol 1e-10: the step control aims at rtol / 100 per step, 1e-12 as before
    ("dop853p", {"rtol": 1e-10, "atol": 1e-10}, 1e-9),
    ("rk4p", {"step": 1e-3}, 1e-9),                         # 1.5e-11
    ("ali3p", {"step": 1e-3}, 1e-5),                        # 6.8e-7 (symmetric rule)
    ("genalpha", {"step": 1e-3, "method_options": {"rho_inf": 1.0}}, 1e-5),   # 4.8e-7
])
def test_p7_double_pendulum_time_reversal(method, kw, tol):
    sc = scene("double_pendulum")
    forward = mbdfmu.Simulation(sc, method=method, **kw)
    forward.advance(1.5)
    back = mbdfmu.Simulation(_reversed(sc, forward.q, forward.qd), method=method, **kw)
    back.advance(1.5)
    q0 = np.array([[*b.position, b.angle] for b in sc.bodies]).ravel()
    assert np.max(np.abs(back.q - q0)) < tol
    assert np.max(np.abs(back.qd)) < 10 * tol


def test_p7_double_pendulum_energy_and_early_trajectory():
    res = run("double_pendulum", 5.0, method="dop853p", rtol=1e-10, atol=1e-10,
              output_interval=0.05)
    total = res["energy.kinetic"] + res["energy.potential"]
    assert np.ptp(total) < 1e-8
    early = res.time <= 2.0
    ex = ref.double_pendulum(res.time[early], J1=1e-6, J2=1e-6)
    np.testing.assert_allclose(res["bob2.x"][early], ex["x2"], atol=1e-7)
    # a dissipative method loses energy, a symmetric one keeps it bounded
    damped = run("double_pendulum", 2.0, method="genalpha", step=1e-3, output_interval=0.05)
    e = damped["energy.kinetic"] + damped["energy.potential"]
    assert e[-1] < e[0] - 1e-6


# -------------------------------------------------------------------- energy audit ---

@pytest.mark.parametrize("name, t_end", [("pendulum", 10.0), ("double_pendulum", 10.0),
                                         ("parallelogram", 10.0), ("andrews", 0.03)])
@pytest.mark.parametrize("method", ADAPTIVE)
@pytest.mark.parametrize("rtol", [1e-4, 1e-8])
def test_energy_audit_does_not_stop_smooth_scenes(name, t_end, method, rtol):
    sim = mbdfmu.Simulation(scene(name), method=method, rtol=rtol)
    sim.advance(t_end)
    # the largest drift seen, as a fraction of the allowance (1 would stop the run);
    # measured at most 0.27 of it (parallelogram, rk45p, rtol 1e-8)
    assert sim.integrator.audit.worst < 0.5


def test_a_loose_rtol_on_p2_is_never_silently_wrong():
    # dop853p at rtol 1e-4 used to end P2 with half the energy gone, reported as success;
    # now it passes every crossing within 100 rtol of the exact reduction, or stops
    # naming the singular configuration
    try:
        res = run("n_four_bar_2", 20.0, method="dop853p", rtol=1e-4, output_interval=0.05)
    except mbdfmu.SolverError as exc:
        assert "singular configuration" in str(exc)
        return
    assert horizontal_passes(res["crank0.phi"]) == 20
    ex = ref.n_four_bar(res.time, 2)
    bx, by = b0(res)
    assert np.max(np.hypot(bx - ex["B0_x"], by - ex["B0_y"])) < 100 * 1e-4


def test_energy_audit_is_off_where_energy_is_not_conserved():
    sim = mbdfmu.Simulation(scene("slider_crank"))
    assert sim.integrator.audit is None
    assert sim.equations.nonconservative_reason() == 'driver "motor" does work'


# ------------------------------------------------------------- equations and state ---

@pytest.mark.parametrize("name", ["andrews", "light_cart_pole", "slider_crank", "n_four_bar_2"])
def test_constraint_hessian_is_the_derivative_of_the_constraint_forces(name):
    system = Equations(scene(name))
    rng = np.random.default_rng(7)
    q, mu = rng.normal(size=system.n), rng.normal(size=system.m)
    H = system.constraint_hessian(q, mu)
    eps = 1e-6
    for k in range(system.n):
        dq = np.zeros(system.n)
        dq[k] = eps
        col = (system.constraints(0.3, q + dq)[1].T @ mu
               - system.constraints(0.3, q - dq)[1].T @ mu) / (2 * eps)
        np.testing.assert_allclose(H[:, k], col, atol=1e-8)
    np.testing.assert_array_equal(H, H.T)


@pytest.mark.parametrize("method", ["genalpha", "ali3p", "rk4p", "baumgarte", "dop853p"])
def test_state_replays_bit_for_bit(method):
    sim = mbdfmu.Simulation(scene("andrews"), method=method, step=2e-5)
    sim.advance(0.002)
    state = sim.get_state()
    sim.advance(0.004)
    first = sim.q.copy()
    sim.set_state(state)
    sim.advance(0.004)
    np.testing.assert_array_equal(sim.q, first)


def test_result_names_the_method_auto_picked():
    res = run("pendulum", 0.1)
    assert res.method == "auto->dop853p"
    assert run("pendulum", 0.1, method="ali3p").method == "ali3p"


def test_implicit_methods_count_their_work():
    res = run("pendulum", 1.0, method="ali3p", step=1e-3)
    assert res.stats["nnewton"] >= res.stats["nsteps"] > 0
    assert 0 < res.stats["nlu"] == res.stats["njev"] < res.stats["nsteps"]


def test_make_integrator_accepts_a_class():
    system = Equations(scene("pendulum"))
    q, qd = assemble(system)
    integ = make_integrator(METHODS["rk4p"], system, 0.0, q, qd, step=1e-3)
    integ.advance(0.01)
    assert integ.t == 0.01
