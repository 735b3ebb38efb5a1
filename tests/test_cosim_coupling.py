"""Coupling beyond zero-order hold: input and output derivatives of the FMUs, the fmpy
master's extrapolation (orders 1 and 2), the implicit coupling, the two-mass oscillator's
stability against its closed-form analysis, and ECCO in libcosim.

References: closed forms (a slider pushed by a polynomial force), the scenarios'
monolithic references, finite differences of the FMUs' own outputs in time, and the
two-mass oscillator's amplification matrix (scenarios/two_mass_oscillator/stability.py,
numpy and scipy only).
"""
from __future__ import annotations

import importlib.util
import math

import numpy as np
import pytest

fmpy = pytest.importorskip("fmpy")

from mbdfmu.cosim.fmpy_master import run_fmpy  # noqa: E402
from mbdfmu.cosim.scenario import SCENARIOS, ScenarioError, reference_function  # noqa: E402
from mbdfmu.cosim.scenario_reader import load_scenario  # noqa: E402
from mbdfmu.cosim.settings import CosimError, CosimSettings  # noqa: E402
from mbdfmu.errors import SettingError  # noqa: E402
from mbdfmu.fmu_build.cache import build_fmus as build_sources  # noqa: E402
from mbdfmu.fmu_build.scene_fmu import build_fmu  # noqa: E402


@pytest.fixture(scope="module")
def built(tmp_path_factory):
    root = tmp_path_factory.mktemp("coupling_fmus")
    cache: dict[str, tuple] = {}

    def get(name: str):
        if name not in cache:
            scenario = load_scenario(name)
            fmus = build_sources({i.name: i.source for i in scenario.instances},
                                 root / scenario.folder.name)
            cache[name] = (scenario, fmus)
        return cache[name]
    return get


def _slave(path, name="a"):
    from fmpy import extract, read_model_description
    from fmpy.fmi2 import FMU2Slave

    md = read_model_description(str(path))
    fmu = FMU2Slave(guid=md.guid, unzipDirectory=extract(str(path)),
                    modelIdentifier=md.coSimulation.modelIdentifier, instanceName=name)
    fmu.instantiate()
    fmu.setupExperiment(startTime=0.0)
    fmu.enterInitializationMode()
    fmu.exitInitializationMode()
    return fmu, {v.name: v.valueReference for v in md.modelVariables}, md


def _error(scenario, result, names=None) -> float:
    ref = reference_function(scenario)(result.time)
    return max(float(np.abs(result[n] - ref[n]).max() / np.ptp(ref[n]))
               for n in (names or scenario.compare))


def _orders(errors):
    return [math.log2(a / b) for a, b in zip(errors, errors[1:])]


# ----------------------------------------------------------------------------- the FMUs

def test_a_force_with_derivatives_follows_its_polynomial_to_the_closed_form(tmp_path):
    """slider_force: a 2 kg slider on a frictionless guide. With F = 1 + 20 t + 100 t^2
    given at t = 0 as a value and two derivatives, one step of 0.1 s lands on the closed
    form x = (t^2/2 + 20 t^3/6 + 200 t^4/24) / m; held, it would be t^2 / (2 m)."""
    path = build_fmu("slider_force", tmp_path / "S.fmu")
    fmu, vr, md = _slave(path)
    assert md.coSimulation.canInterpolateInputs
    assert md.coSimulation.maxOutputDerivativeOrder == 2
    fmu.setReal([vr["push.fx"]], [1.0])
    fmu.setRealInputDerivatives([vr["push.fx"]] * 2, [1, 2], [20.0, 200.0])
    fmu.doStep(0.0, 0.1)
    t, m = 0.1, 2.0
    x = (t * t / 2 + 20 * t ** 3 / 6 + 200 * t ** 4 / 24) / m
    assert fmu.getReal([vr["slider.x"]])[0] == pytest.approx(x, rel=1e-9)
    # the input keeps following its polynomial until set again: v' = F(t) / m
    assert fmu.getRealOutputDerivatives([vr["slider.vx"]], [1])[0] == \
        pytest.approx((1 + 20 * t + 100 * t * t) / m, rel=1e-8)
    fmu.terminate()
    fmu.freeInstance()


def test_output_derivatives_match_finite_differences_of_the_fmu_in_time(tmp_path):
    """pendulum_torque with a ramped torque: every output's first and second derivatives
    at the communication point against one-sided differences of the FMU's own outputs
    after steps of k * 1 ms from a saved state (errors O(h^4) and O(h^3))."""
    path = build_fmu("pendulum_torque", tmp_path / "P.fmu")
    fmu, vr, md = _slave(path)
    outs = [v.name for v in md.modelVariables if v.causality == "output"]
    refs = [vr[n] for n in outs]
    fmu.setReal([vr["drive.torque"]], [1.0])
    fmu.setRealInputDerivatives([vr["drive.torque"]] * 2, [1, 2], [20.0, 200.0])
    fmu.doStep(0.0, 0.1)
    d1 = np.array(fmu.getRealOutputDerivatives(refs, [1] * len(refs)))
    d2 = np.array(fmu.getRealOutputDerivatives(refs, [2] * len(refs)))
    h, state = 1e-3, fmu.getFMUstate()
    y = [np.array(fmu.getReal(refs))]
    for k in range(1, 5):
        fmu.setFMUstate(state)
        fmu.doStep(0.1, k * h)
        y.append(np.array(fmu.getReal(refs)))
    fd1 = (-25 * y[0] + 48 * y[1] - 36 * y[2] + 16 * y[3] - 3 * y[4]) / (12 * h)
    fd2 = (35 * y[0] - 104 * y[1] + 114 * y[2] - 56 * y[3] + 11 * y[4]) / (12 * h * h)
    assert np.abs(d1 - fd1).max() < 1e-6 * np.abs(fd1).max()
    assert np.abs(d2 - fd2).max() < 1e-4 * np.abs(fd2).max()
    with pytest.raises(fmpy.fmi1.FMICallException):   # orders 1 and 2 only
        fmu.getRealOutputDerivatives(refs[:1], [3])
    fmu.freeFMUstate(state)
    fmu.freeInstance()


# ----------------------------------------------------------------------------- extrapolation

def test_extrapolation_raises_the_coupling_order_to_two_and_three(built):
    """DC motor + slider-crank, Jacobi: zero-order hold is first order; inputs that follow
    the sources' first (second) output derivatives over the step give order 2 (3)."""
    scenario, fmus = built("dc_motor_slider_crank")
    measured = {}
    for p in (0, 1, 2):
        errors = [_error(scenario, run_fmpy(scenario, fmus, CosimSettings(
            algorithm="jacobi", step=h, t_end=0.12, extrapolation=p)),
            ["mechanism.crank.omega"]) for h in (4e-3, 2e-3, 1e-3)]
        measured[p] = _orders(errors)
    assert all(0.9 < q < 1.25 for q in measured[0]), measured
    assert all(1.85 < q < 2.3 for q in measured[1]), measured
    assert all(2.7 < q < 3.3 for q in measured[2]), measured


def test_a_bad_extrapolation_setting_is_refused():
    with pytest.raises(SettingError, match="extrapolation must be 0"):
        CosimSettings(extrapolation=3)
    with pytest.raises(SettingError, match="fmpy master"):
        CosimSettings(master="libcosim", extrapolation=1)
    with pytest.raises(SettingError, match="libcosim"):
        CosimSettings(algorithm="ecco")


# ----------------------------------------------------------------------------- implicit

def test_the_implicit_coupling_keeps_the_crane_at_50_ms_where_jacobi_fails(built):
    """With either interface Jacobian: from finite differences of whole steps, and from
    the FMUs' directional derivatives, which gives the same converged steps (both iterate
    to 1e-8 of each output's scale) without the extra steps."""
    scenario, fmus = built("hydraulic_crane")
    with pytest.raises(CosimError, match="doStep returned discard"):
        run_fmpy(scenario, fmus, CosimSettings(algorithm="jacobi", step=5e-2, t_end=1.0))
    settings = dict(algorithm="implicit", step=5e-2, t_end=1.0)
    fd = run_fmpy(scenario, fmus, CosimSettings(**settings))
    assert fd.time[-1] == pytest.approx(1.0)
    assert _error(scenario, fd, ["mechanism.boom.phi", "mechanism.load.phi"]) < 0.03
    assert fd.stats["iterations"] >= fd.stats["steps"]
    dd = run_fmpy(scenario, fmus, CosimSettings(**settings, jacobian="directional"))
    assert dd.time[-1] == pytest.approx(1.0)
    assert _error(scenario, dd, ["mechanism.boom.phi", "mechanism.load.phi"]) < 0.03
    for name in ("mechanism.boom.phi", "mechanism.load.phi", "hydraulics.p_A"):
        assert np.abs(dd[name] - fd[name]).max() < 1e-6 * np.abs(fd[name]).max(), name
    assert dd.stats["jacobians"] == dd.stats["steps"] and "fallbacks" not in dd.stats


def test_the_implicit_coupling_converges_on_the_motor_and_crank_at_50_ms(built):
    """The crank's inertia changes along its turn, so over 50 ms the step is far from the
    linearization at t: held fixed, that Jacobian contracts the residual by only 0.43 per
    iteration at t = 0.4 s and the step is refused after 12; Broyden's update after each
    iteration converges in a few. The result stays within the monolithic reference's range
    of its crank speed (9 steps over 0.45 s: half the range)."""
    scenario, fmus = built("dc_motor_slider_crank")
    r = run_fmpy(scenario, fmus, CosimSettings(algorithm="implicit", jacobian="directional",
                                               step=5e-2, t_end=0.45))
    assert r.time[-1] == pytest.approx(0.45)
    assert r.stats["iterations"] <= 6 * r.stats["steps"], r.stats
    assert _error(scenario, r) < 0.6


@pytest.mark.parametrize("name", ["two_mass_oscillator", "two_mass_oscillator:dd"])
def test_the_directional_jacobian_is_exact_for_linear_fmus(name, built):
    """The oscillator FMUs are linear and integrate exactly: the Jacobian of the linearized
    step is the step's own, so Newton's first update lands on the solution (two
    evaluations per step: the guess and the converged one)."""
    scenario, fmus = built(name)
    r = run_fmpy(scenario, fmus, CosimSettings(algorithm="implicit", step=0.02, t_end=0.4,
                                               jacobian="directional"))
    assert r.stats["iterations"] == 2 * r.stats["steps"] == 40


def test_step_sensitivity_is_the_closed_form_of_a_scalar_linear_system():
    from mbdfmu.cosim.interface_jacobian import step_sensitivity

    a, b, h = -30.0, 2.5, 0.05
    ramp = b / (a * a * h) * (math.exp(a * h) - 1 - a * h)   # int e^{a(h-s)} b s/h ds
    hold = b / a * (math.exp(a * h) - 1)
    got_ramp = step_sensitivity(np.array([[a]]), np.array([[b]]), h, ramp=True)
    got_hold = step_sensitivity(np.array([[a]]), np.array([[b]]), h, ramp=False)
    assert got_ramp[0, 0] == pytest.approx(ramp, rel=1e-12)
    assert got_hold[0, 0] == pytest.approx(hold, rel=1e-12)


def test_the_directional_jacobian_is_an_option_of_the_implicit_coupling_only():
    with pytest.raises(SettingError, match="interface Jacobian is the implicit"):
        CosimSettings(algorithm="jacobi", jacobian="directional")
    with pytest.raises(SettingError, match="jacobian"):
        CosimSettings(algorithm="implicit", jacobian="exact")


# ----------------------------------------------------------------------------- two masses

def _stability():
    spec = importlib.util.spec_from_file_location(
        "two_mass_stability", SCENARIOS / "two_mass_oscillator" / "stability.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


@pytest.mark.parametrize("name, algorithm, p", [("two_mass_oscillator", "jacobi", 0),
                                                ("two_mass_oscillator:dd", "gauss-seidel", 1)])
def test_two_mass_stability_limits_agree_with_the_closed_form(name, algorithm, p, built):
    """Runs at 0.9 and 1.1 times the closed-form limit: the amplitude's growth per step,
    measured over 300 steps, matches the amplification matrix's spectral radius, below 1
    and above 1."""
    st = _stability()
    scenario, fmus = built(name)
    masses, connections = st.from_scenario(scenario)
    limit = st.largest_stable_step(masses, connections, algorithm, p, points=60)
    for factor in (0.9, 1.1):
        h, n = factor * limit, 450
        r = run_fmpy(scenario, fmus, CosimSettings(algorithm=algorithm, step=h, t_end=n * h,
                                                   extrapolation=p))
        amplitude = np.abs(np.column_stack([r["mass1.x"], r["mass2.x"]])).max(axis=1)
        w = n // 6
        measured = (amplitude[-w:].max() / amplitude[w:2 * w].max()) ** (1.0 / (n - 2 * w))
        rho = st.spectral_radius(masses, connections, h, algorithm, p)
        assert (measured - 1) * (rho - 1) > 0, (factor, measured, rho)
        # (the growth measured over 300 steps is still approaching the dominant mode's)
        assert abs(measured - rho) < 1.5e-3, (factor, measured, rho)


@pytest.mark.parametrize("name, p, order", [("two_mass_oscillator", 1, 2.0),
                                            ("two_mass_oscillator:dd", 2, 3.0)])
def test_the_two_mass_scenarios_converge_to_their_monolithic_reference(name, p, order, built):
    scenario, fmus = built(name)
    errors = [_error(scenario, run_fmpy(scenario, fmus, CosimSettings(
        algorithm="jacobi", step=h, t_end=1.0, extrapolation=p))) for h in (2e-3, 1e-3)]
    assert abs(_orders(errors)[0] - order) < 0.25, errors


def test_force_displacement_with_second_order_extrapolation_is_third_order(built):
    """The coupling force reads the other mass's position and velocity (direct
    feedthrough), so its derivatives at t0 need the inputs' derivatives, which the master
    settles at the start. The runs follow the closed-form co-simulation (stability.py's
    macro steps from a consistent start) to rounding, and converge at order 3 against the
    monolithic solution (an inconsistent start gives 2.0 between 2 and 1 ms)."""
    st = _stability()
    scenario, fmus = built("two_mass_oscillator")
    masses, connections = st.from_scenario(scenario)
    q = scenario.parameters
    start = st.start_state(masses, connections, [[q["mass1.x0"], 0.0], [0.0, 0.0]], 2)
    errors = []
    for h in (2e-3, 1e-3):
        r = run_fmpy(scenario, fmus, CosimSettings(algorithm="jacobi", step=h, t_end=0.25,
                                                   extrapolation=2))
        closed = st.positions(masses, connections, start, h, round(0.25 / h), "jacobi", 2)
        run = np.column_stack([r["mass1.x"], r["mass2.x"]])
        assert np.abs(run - closed).max() < 1e-9 * np.ptp(closed), h
        errors.append(_error(scenario, r))
    assert 2.8 < _orders(errors)[0] < 3.2, errors


def test_output_derivatives_of_direct_feedthrough_follow_the_input_derivatives(built):
    """The oscillator's coupling force reads its position inputs: after input values and
    derivatives are set (before the step), its output derivatives at that point are the
    one-sided differences in time of the force along steps of k * 1 ms (the inputs
    following their polynomials), dy/du du/dt included."""
    from fmpy import extract, read_model_description
    from fmpy.fmi2 import FMU2Slave

    _, fmus = built("two_mass_oscillator")
    md = read_model_description(str(fmus["mass1"]))
    vr = {v.name: v.valueReference for v in md.modelVariables}
    fmu = FMU2Slave(guid=md.guid, unzipDirectory=extract(str(fmus["mass1"])),
                    modelIdentifier=md.coSimulation.modelIdentifier, instanceName="m1")
    fmu.instantiate()
    fmu.setupExperiment(startTime=0.0)
    fmu.enterInitializationMode()
    fmu.setReal([vr["cc"], vr["dc"], vr["x0"]], [1000.0, 2.0, 0.1])
    fmu.exitInitializationMode()
    ins = [vr["x_other"], vr["v_other"]]
    fmu.setReal(ins, [0.02, 0.5])
    fmu.setRealInputDerivatives(ins + ins, [1, 1, 2, 2], [0.5, 30.0, 30.0, -400.0])
    force = [vr["coupling_force"]]
    d1, d2 = (fmu.getRealOutputDerivatives(force, [k])[0] for k in (1, 2))
    h, state = 1e-3, fmu.getFMUstate()
    y = [fmu.getReal(force)[0]]
    for k in range(1, 5):
        fmu.setFMUstate(state)
        fmu.doStep(0.0, k * h)
        y.append(fmu.getReal(force)[0])
    fd1 = (-25 * y[0] + 48 * y[1] - 36 * y[2] + 16 * y[3] - 3 * y[4]) / (12 * h)
    fd2 = (35 * y[0] - 104 * y[1] + 114 * y[2] - 56 * y[3] + 11 * y[4]) / (12 * h * h)
    assert d1 == pytest.approx(fd1, rel=1e-5)
    assert d2 == pytest.approx(fd2, rel=1e-3)
    fmu.freeFMUstate(state)
    fmu.freeInstance()


# ----------------------------------------------------------------------------- ECCO

def test_ecco_runs_the_quarter_car_in_libcosim(built):
    pytest.importorskip("libcosimpy")
    from mbdfmu.cosim.ecco_runner import RESIDUAL, run_ecco

    scenario, fmus = built("quarter_car")
    r = run_ecco(scenario, fmus, step=2e-3, t_end=0.3, rtol=1e-2, atol=1e-2)
    assert r.time[-1] == pytest.approx(0.3, abs=3e-3)
    assert len(set(np.round(np.diff(r.time), 9))) > 3          # the step varies
    assert _error(scenario, r) < 0.05
    assert np.all(np.isfinite(r[RESIDUAL]))


def test_ecco_starts_at_the_start_step_and_grows_by_its_change_bound(built):
    """libcosim's controller takes its first two steps at the configured step (it needs two
    error estimates) and changes a step by at most MAX_CHANGE after that: a start step of
    1 % of h reaches h only after about a dozen steps (docs/cosimulation.md, ECCO)."""
    pytest.importorskip("libcosimpy")
    from mbdfmu.cosim.ecco_runner import MAX_CHANGE, run_ecco

    scenario, fmus = built("quarter_car")
    r = run_ecco(scenario, fmus, step=2e-3, t_end=0.01, rtol=1e-2, atol=1e-2,
                 start_step=2e-5)
    steps = np.diff(r.time)
    assert steps[:2] == pytest.approx([2e-5, 2e-5], abs=2e-9)
    assert np.all(steps[1:] <= MAX_CHANGE * steps[:-1] * (1 + 1e-6) + 2e-9)


@pytest.mark.parametrize("name", ["quarter_car", "hydraulic_crane"])
def test_the_ecco_configuration_comes_from_the_fmus_power_ports(name, built, tmp_path):
    """The bond found from the ports the FMUs declare (extra/OspModelDescription.xml) is the
    one the scenario names by hand in [power_bonds]; the OspSystemStructure.xml written
    for it marks those two connections, and libcosim runs ECCO from it."""
    pytest.importorskip("libcosimpy")
    import xml.etree.ElementTree as ET

    from mbdfmu.cosim.ecco_config import NAMESPACE, find_bond
    from mbdfmu.cosim.ecco_runner import RESIDUAL, run_ecco

    scenario, fmus = built(name)
    bond = find_bond(scenario, fmus)
    assert bond.as_table() == {k: tuple(v) for k, v in scenario.power_bonds.items()}
    path = tmp_path / "OspSystemStructure.xml"
    r = run_ecco(scenario, fmus, step=2e-3, t_end=0.1, rtol=1e-2, atol=1e-2, structure=path)
    marked = [c for c in ET.parse(path).getroot().iter(f"{{{NAMESPACE}}}VariableConnection")
              if c.get("powerBond")]
    ends = [tuple(f'{v.get("simulator")}.{v.get("name")}' for v in c) for c in marked]
    assert ends == bond.connections()
    assert r.time[-1] == pytest.approx(0.1, abs=2e-2)    # within its largest step (10 h)
    assert np.all(np.isfinite(r[RESIDUAL]))


def test_ecco_needs_one_bond_of_the_fmus_ports(built):
    """Displacement-displacement coupling connects no force to a velocity: no bond; a
    scenario table that names another bond than the FMUs' is refused."""
    from dataclasses import replace

    from mbdfmu.cosim.ecco_config import check_scenario_table, find_bond

    scenario, fmus = built("two_mass_oscillator:dd")
    with pytest.raises(CosimError, match="needs exactly one power bond .* found 0; the FMUs' "
                                         "ports: mass1: mass, coupling"):
        find_bond(scenario, fmus)
    scenario, fmus = built("two_mass_oscillator")
    bond = find_bond(scenario, fmus)
    assert bond.as_table() == {"mass2": ("force", "v"), "mass1": ("v_other", "coupling_force")}
    wrong = replace(scenario, power_bonds={"mass2": ["force", "x"],
                                           "mass1": ["v_other", "coupling_force"]})
    with pytest.raises(CosimError, match="is not the bond the FMUs declare"):
        check_scenario_table(wrong, bond)


def test_the_fmus_declare_their_power_ports(built):
    from mbdfmu.fmu_build.osp import Port, read_ports

    _, fmus = built("hydraulic_crane")
    assert read_ports(fmus["mechanism"]) == [Port("cylinder", "cylinder.actuator",
                                                  "cylinder.velocity", "N")]
    assert read_ports(fmus["hydraulics"]) == [Port("rod", "force", "rate", "N")]
    assert read_ports(fmus["command"]) == []
    _, fmus = built("dc_motor_slider_crank")
    assert Port("shaft", "torque", "speed", "N.m") in read_ports(fmus["motor"])


def test_a_power_port_must_pair_an_effort_with_its_flow(tmp_path):
    from mbdfmu.fmu_build.common import BuildError
    from mbdfmu.fmu_build.companion import build_companion

    source = (SCENARIOS / "hydraulic_crane" / "hydraulic_cylinder.py").read_text()
    bad = tmp_path / "bad_cylinder.py"
    bad.write_text(source.replace('POWER_PORTS = {"rod": ("force", "rate")}',
                                  'POWER_PORTS = {"rod": ("force", "p_A")}'))
    with pytest.raises(BuildError, match='power port "rod": "force" \\(N\\) and "p_A"'):
        build_companion(bad, tmp_path / "bad.fmu")


def test_a_power_bond_must_follow_the_connections(tmp_path):
    import shutil

    folder = shutil.copytree(SCENARIOS / "quarter_car", tmp_path / "quarter_car")
    file = folder / "connections.toml"
    file.write_text(file.read_text().replace('wheel = ["v_other", "coupling_force"]',
                                             'wheel = ["x_other", "coupling_force"]'))
    with pytest.raises(ScenarioError, match='"chassis.chassis.vy" -> "wheel.x_other" is not'):
        load_scenario(file)
