"""Co-simulation scenarios (scenarios/) in the three masters: fmpy (mbdfmu.cosim.fmpy_master),
fmpy's SSP runner and OSP libcosim.

Each scenario's FMUs are built once per session (``built`` fixture). References are
independent of mbdfmu's equations: the monolithic ODEs and P4's closed form in each
scenario's ``reference.py``. Runs are kept short (a few hundred steps at most).
"""
from __future__ import annotations

import math
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

fmpy = pytest.importorskip("fmpy")

from mbdfmu.cli import main  # noqa: E402
from mbdfmu.cosim import fmpy_master, ssp_runner  # noqa: E402
from mbdfmu.cosim.fmpy_master import run_fmpy  # noqa: E402
from mbdfmu.cosim.libcosim_runner import run_libcosim  # noqa: E402
from mbdfmu.cosim.scenario import (SCENARIOS, ScenarioError, check_variables,  # noqa: E402
                                   reference_function)
from mbdfmu.cosim.scenario_reader import load_scenario  # noqa: E402
from mbdfmu.cosim.settings import CosimError, CosimSettings  # noqa: E402
from mbdfmu.errors import SettingError  # noqa: E402
from mbdfmu.fmu_build.cache import build_fmus as build_sources  # noqa: E402


def build_fmus(scenario, folder):
    return build_sources({i.name: i.source for i in scenario.instances}, folder)

NAMES = ["dc_motor_slider_crank", "hydraulic_crane", "prescribed_motion",
         "prescribed_motion:derivatives", "cart_pendulum_pid", "quarter_car"]
# A short run per scenario for the master-equality tests: (step, t_end).
SHORT = {"dc_motor_slider_crank": (2e-3, 0.04), "hydraulic_crane": (2e-3, 0.06),
         "prescribed_motion": (1e-4, 0.003), "prescribed_motion:derivatives": (1e-4, 0.003),
         "cart_pendulum_pid": (1e-2, 0.3), "quarter_car": (2e-3, 0.04)}


@pytest.fixture(scope="session")
def built(tmp_path_factory):
    """(scenario, {instance: fmu}) of a scenario name; FMUs built once per scenario folder."""
    root = tmp_path_factory.mktemp("cosim_fmus")
    cache: dict[str, tuple] = {}

    def get(name: str):
        if name not in cache:
            scenario = load_scenario(name)
            cache[name] = (scenario, build_fmus(scenario, root / scenario.folder.name))
        return cache[name]
    return get


def _rel(a: np.ndarray, b: np.ndarray) -> float:
    """Largest difference, column by column relative to the column's magnitude."""
    scale = np.maximum(np.abs(a).max(axis=0), np.abs(b).max(axis=0))
    return float((np.abs(a - b).max(axis=0) / np.where(scale > 0, scale, 1.0)).max())


def _error(scenario, result, name, skip: int = 0) -> float:
    ref = reference_function(scenario)(result.time)
    return float(np.abs(result[name][skip:] - ref[name][skip:]).max())


# ----------------------------------------------------------------------------- descriptions

@pytest.mark.parametrize("name", NAMES)
def test_every_scenario_has_its_files_and_fits_its_fmus(name, built):
    scenario, fmus = built(name)
    folder = scenario.folder
    assert (folder / "README.md").is_file()
    assert any(p.suffix == ".toml" for p in (i.source for i in scenario.instances))
    assert any(p.suffix == ".py" for p in (i.source for i in scenario.instances))
    assert scenario.reference is not None and scenario.compare
    descriptions = {i: fmpy.read_model_description(str(p)) for i, p in fmus.items()}
    check_variables(scenario, descriptions)  # raises on any mismatch
    for inst in scenario.instances:
        if inst.source.suffix == ".py":
            assert fmpy.validation.validate_fmu(str(fmus[inst.name])) == [], inst.name
            md = descriptions[inst.name]
            assert md.coSimulation.canGetAndSetFMUstate and md.coSimulation.canSerializeFMUstate
            assert all(v.unit for v in md.modelVariables if v.type == "Real")


def test_a_bad_connections_file_reports_every_problem(tmp_path):
    folder = SCENARIOS / "dc_motor_slider_crank"
    text = (folder / "connections.toml").read_text()
    bad = tmp_path / "connections.toml"
    for f in ("slider_crank.toml", "dc_motor.py", "reference.py"):
        (tmp_path / f).write_text((folder / f).read_text())
    bad.write_text(text.replace('to = "motor.speed"', 'to = "moter.speed"')
                   .replace('algorithm = "gauss-seidel"', 'algorithm = "newton"')
                   .replace("t_end = 0.5", "t_end = -1\nsteps = 3"))
    with pytest.raises(ScenarioError) as err:
        load_scenario(bad)
    text_ = str(err.value)
    assert 'unknown instance "moter"' in text_ and 'did you mean "motor"' in text_
    assert '"newton"' in text_ and "t_end must be a positive number" in text_
    assert 'unknown key "steps"' in text_ and len(err.value.problems) == 4


def test_a_connection_to_an_output_is_refused_with_the_fmus(built, tmp_path):
    scenario, fmus = built("dc_motor_slider_crank")
    swapped = replace(scenario, connections=(
        type(scenario.connections[0])("motor.speed", "mechanism.crank.omega"),))
    with pytest.raises(ScenarioError, match=r'"motor.speed" has causality input, not output'):
        run_fmpy(swapped, fmus)


def test_unknown_scenario_names_suggest_the_known_ones():
    with pytest.raises(ScenarioError, match='did you mean "hydraulic_crane"'):
        load_scenario("hydraulic_cran")


# ----------------------------------------------------------------------------- masters agree

@pytest.mark.parametrize("name", NAMES)
def test_every_master_gives_the_same_jacobi_result(name, built, tmp_path):
    """fmpy master, libcosim (from the description and from the SSP) and fmpy's SSP runner
    all run Jacobi from the exchanged start outputs: equal to rounding (1e-9). Untouched, the
    SSP runner starts its connections at 0.0: equal to the fmpy master's zero start."""
    scenario, fmus = built(name)
    h, t_end = SHORT[name]
    ours = run_fmpy(scenario, fmus, CosimSettings(algorithm="jacobi", step=h, t_end=t_end))
    lc = run_libcosim(scenario, fmus, step=h, t_end=t_end)
    path = tmp_path / "s.ssp"
    runner = ssp_runner.run_ssp(scenario, fmus, path, step=h, t_end=t_end)
    lc_ssp = run_libcosim(scenario, fmus, step=h, t_end=t_end, ssp_path=path)
    n = round(t_end / h)
    assert ours.names == lc.names == runner.names == lc_ssp.names
    assert len(ours.time) == len(lc.time) == n + 1 and len(runner.time) == n
    np.testing.assert_allclose(lc.time, ours.time, rtol=0, atol=1e-12)
    np.testing.assert_allclose(runner.time, ours.time[1:], rtol=0, atol=1e-12)
    assert _rel(ours.values, lc.values) < 1e-9
    assert _rel(ours.values, lc_ssp.values) < 1e-9
    assert _rel(ours.values[1:], runner.values) < 1e-9
    if name != "hydraulic_crane":  # a cylinder of length 0 cannot take the first step
        zero = run_fmpy(scenario, fmus, CosimSettings(algorithm="jacobi", step=h,
                                                         t_end=t_end, start="zero"))
        untouched = ssp_runner.run_ssp(scenario, fmus, path, step=h, t_end=t_end, start="zero")
        assert _rel(zero.values[1:], untouched.values) < 1e-9


@pytest.mark.parametrize("name", NAMES)
def test_ecos_runs_every_scenario_from_the_ssp_like_the_fmpy_master(name, built, tmp_path):
    """Ecos (ecospy) loads the SSP, applies its start values through the one parameter-set
    name and steps Jacobi: equal to the fmpy master to 1e-9 at every point, t = 0 included."""
    pytest.importorskip("ecospy", reason="pip install ecospy (and apt-get install libtbb12)")
    from mbdfmu.cosim.ecos_runner import run_ecos

    scenario, fmus = built(name)
    h, t_end = SHORT[name]
    ours = run_fmpy(scenario, fmus, CosimSettings(algorithm="jacobi", step=h, t_end=t_end))
    ecos = run_ecos(scenario, fmus, tmp_path / "e.ssp", step=h, t_end=t_end)
    assert ecos.names == ours.names and len(ecos.time) == len(ours.time)
    np.testing.assert_allclose(ecos.time, ours.time, rtol=0, atol=1e-12)
    assert _rel(ours.values, ecos.values) < 1e-9


def test_cli_runs_a_scenario_in_ecos(tmp_path, capsys):
    pytest.importorskip("ecospy", reason="pip install ecospy (and apt-get install libtbb12)")
    assert main(["cosim", "dc_motor_slider_crank", "--master", "ecos", "--t-end", "0.01",
                 "-o", str(tmp_path)]) == 0
    assert (tmp_path / "dc_motor_slider_crank_ecos_jacobi.csv").is_file()
    assert "max |error| against the reference" in capsys.readouterr().out


def test_the_untouched_ssp_runner_cannot_start_the_crane(built, tmp_path):
    scenario, fmus = built("hydraulic_crane")
    with pytest.raises(CosimError, match="discard"):
        ssp_runner.run_ssp(scenario, fmus, tmp_path / "c.ssp", step=2e-3, t_end=4e-3, start="zero")


def test_the_other_masters_refuse_gauss_seidel(built, tmp_path):
    scenario, fmus = built("dc_motor_slider_crank")
    with pytest.raises(CosimError, match="Jacobi"):
        run_libcosim(scenario, fmus, algorithm="gauss-seidel")
    with pytest.raises(CosimError, match="Jacobi"):
        ssp_runner.run_ssp(scenario, fmus, tmp_path / "x.ssp", algorithm="gauss-seidel")


def test_the_ssp_file_holds_the_system_and_the_fmus(built, tmp_path):
    import zipfile

    from fmpy.ssp.ssd import read_ssd

    scenario, fmus = built("hydraulic_crane")
    path = ssp_runner.export_ssp(scenario, fmus, tmp_path / "crane.ssp")
    ssd = read_ssd(str(path))  # validates against the SSP 1.0 schema
    assert {c.name for c in ssd.system.elements} == {"command", "hydraulics", "mechanism"}
    assert len(ssd.system.connections) == len(scenario.connections)
    values = {p.name: float(p.value) for p in ssp_runner.start_values(path).parameters}
    assert values == scenario.parameters
    with zipfile.ZipFile(path) as z:
        assert {"resources/crane.fmu", "resources/hydraulic_cylinder.fmu",
                "resources/valve_command.fmu"} <= set(z.namelist())


# ----------------------------------------------------------------------------- convergence

def _orders(errors):
    return [math.log2(a / b) for a, b in zip(errors, errors[1:])]


@pytest.mark.parametrize("algorithm", ["jacobi", "gauss-seidel"])
def test_motor_and_crank_converge_to_the_monolithic_ode_at_first_order(algorithm, built):
    scenario, fmus = built("dc_motor_slider_crank")
    errors = []
    for h in (4e-3, 2e-3, 1e-3):
        r = run_fmpy(scenario, fmus, CosimSettings(algorithm=algorithm, step=h, t_end=0.12))
        errors.append(_error(scenario, r, "mechanism.crank.omega"))
    assert all(0.85 < p < 1.15 for p in _orders(errors)), errors
    assert errors[-1] < 1.0  # rad/s, speeds up to 60 rad/s


@pytest.mark.parametrize("name", ["prescribed_motion", "prescribed_motion:derivatives"])
def test_prescribed_crank_gives_p4s_torque(name, built):
    """Jacobi samples the trajectory at the start of each step, as the driver input expects:
    P4's torque to 1e-9 once the position history has filled (4 samples), from the first
    step with velocity and acceleration. Gauss-Seidel hands the end-of-step position over
    as the start's: a lead of one step, a first-order error."""
    scenario, fmus = built(name)
    jac = run_fmpy(scenario, fmus, CosimSettings(algorithm="jacobi", step=2e-4, t_end=0.02))
    ref = reference_function(scenario)(jac.time)["mechanism.motor.effort"]
    first = 1 if name.endswith("derivatives") else 4
    scale = np.abs(ref).max()
    assert np.abs(jac["mechanism.motor.effort"] - ref)[first:].max() < 1e-9 * scale
    errors = []
    for h in (4e-4, 2e-4):
        gs = run_fmpy(scenario, fmus, CosimSettings(algorithm="gauss-seidel", step=h,
                                                       t_end=0.02))
        errors.append(_error(scenario, gs, "mechanism.motor.effort", skip=round(2e-3 / h)))
    assert 0.9 < _orders(errors)[0] < 1.1, errors


@pytest.mark.parametrize("name, order", [("prescribed_motion", 1.0),
                                         ("prescribed_motion:derivatives", 1.0)])
def test_an_unsteady_crank_rate_converges_at_the_order_of_the_input_derivation(name, order,
                                                                                built):
    """theta = w t + 0.3 sin(2 pi 40 t): from positions the FMU's quadratic through the last
    three samples gives an O(h) acceleration (a second divided difference, held over the
    step); given derivatives are held over the step too (zero-order hold of the
    acceleration): O(h) at the communication points."""
    scenario, fmus = built(name)
    scenario = replace(scenario, parameters={**scenario.parameters, "trajectory.amplitude": 0.3,
                                             "trajectory.frequency": 40.0})
    errors = []
    for h in (4e-4, 2e-4, 1e-4):
        r = run_fmpy(scenario, fmus, CosimSettings(algorithm="jacobi", step=h, t_end=0.012))
        errors.append(_error(scenario, r, "mechanism.motor.effort", skip=round(2e-3 / h)))
    assert all(abs(p - order) < 0.2 for p in _orders(errors)), errors


@pytest.mark.parametrize("algorithm", ["jacobi", "gauss-seidel"])
def test_crane_converges_to_the_monolithic_ode_at_first_order(algorithm, built):
    # (the order approaches 1 from above: 1.3 and 1.2 for Gauss-Seidel, 1.14 and 1.06 for
    # Jacobi over these halvings)
    scenario, fmus = built("hydraulic_crane")
    errors = []
    for h in (2e-3, 1e-3, 5e-4):
        r = run_fmpy(scenario, fmus, CosimSettings(algorithm=algorithm, step=h, t_end=0.3))
        errors.append(_error(scenario, r, "mechanism.boom.phi"))
    orders = _orders(errors)
    assert all(0.9 < p < 1.4 for p in orders) and orders[-1] < 1.25, errors


def test_controlled_cart_converges_to_the_monolithic_closed_loop_at_first_order(built):
    scenario, fmus = built("cart_pendulum_pid")
    errors = []
    for h in (2e-2, 1e-2, 5e-3):
        r = run_fmpy(scenario, fmus, CosimSettings(algorithm="gauss-seidel", step=h,
                                                      t_end=1.5))
        errors.append(_error(scenario, r, "mechanism.pole.phi"))
    assert all(0.9 < p < 1.1 for p in _orders(errors)), errors
    assert np.abs(r["mechanism.pole.phi"] - math.pi / 2).max() < 0.4  # kept upright


# ----------------------------------------------------------------------------- failure

def test_jacobi_loses_the_crane_where_gauss_seidel_and_the_variable_step_keep_it(built):
    """At a 20 ms step the stiff force-displacement coupling blows up under Jacobi (the
    cylinder is driven out of its stroke, the hydraulics discard the step); Gauss-Seidel
    stays close to the reference; the variable-step master (Jacobi inside) cuts the step
    where the coupling error grows and finishes."""
    scenario, fmus = built("hydraulic_crane")
    with pytest.raises(CosimError, match="hydraulics: doStep returned discard"):
        run_fmpy(scenario, fmus, CosimSettings(algorithm="jacobi", step=2e-2, t_end=0.8))
    gs = run_fmpy(scenario, fmus, CosimSettings(algorithm="gauss-seidel", step=2e-2,
                                                   t_end=0.8))
    assert _error(scenario, gs, "mechanism.boom.phi") < 1e-3
    vs = run_fmpy(scenario, fmus, CosimSettings(algorithm="jacobi", step=2e-2, t_end=0.8,
                                                   variable_step=True, rtol=3e-2, h_max=2e-2))
    assert vs.time[-1] == 0.8 and vs.stats["h_max"] <= 2e-2 * (1 + 1e-9)
    assert _error(scenario, vs, "mechanism.boom.phi") < 2e-3


def test_a_variable_step_run_replays_exactly_after_its_rollbacks(built):
    """Rejected steps are undone through fmi2SetFMUstate: stepping the accepted times again
    in a fresh system gives the same outputs bit for bit."""
    scenario, fmus = built("cart_pendulum_pid")
    vs = run_fmpy(scenario, fmus, CosimSettings(algorithm="gauss-seidel", step=1e-2,
                                                   t_end=1.2, variable_step=True, rtol=5e-3))
    assert vs.stats["rollbacks"] > 0
    system = fmpy_master.CoupledSystem(scenario, fmus)
    try:
        system.initialize(0.0, 1.2, "exchange")
        algorithm = fmpy_master.GaussSeidel(scenario)
        rows = [system.sample()]
        for t0, t1 in zip(vs.time[:-1], vs.time[1:]):
            algorithm.step(system, t0, t1 - t0)
            rows.append(system.sample())
    finally:
        system.close()
    assert np.array_equal(np.array(rows), vs.values)


# ----------------------------------------------------------------------------- CLI

def test_cli_runs_a_scenario_and_writes_csv_and_plot(tmp_path, capsys):
    out = tmp_path / "out"
    assert main(["cosim", "prescribed_motion:derivatives", "--master", "ssp", "--t-end", "2e-3",
                 "-o", str(out)]) == 0
    text = capsys.readouterr().out
    assert "mechanism.motor.effort: max |error| against the reference" in text
    csv = out / "prescribed_motion_derivatives_ssp_jacobi.csv"
    assert csv.is_file() and (out / "prescribed_motion_derivatives_ssp_jacobi.png").is_file()
    assert csv.read_text().splitlines()[0].startswith("time,trajectory.position")


def test_cli_errors_are_one_line(tmp_path, capsys):
    assert main(["cosim", "no_such_scenario", "-o", str(tmp_path)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and 'no scenario "no_such_scenario"' in err[0]
    assert main(["cosim", "prescribed_motion", "--master", "libcosim", "--step", "1.5e-10",
                 "-o", str(tmp_path)]) == 2
    assert "nanoseconds" in capsys.readouterr().err


def test_cli_builds_a_companion_source(tmp_path, capsys):
    source = SCENARIOS / "dc_motor_slider_crank" / "dc_motor.py"
    assert main(["build", str(source), "-o", str(tmp_path / "m.fmu")]) == 0
    assert Path(capsys.readouterr().out.strip()).name == "m.fmu"
    assert fmpy.read_model_description(str(tmp_path / "m.fmu")).modelName == "DCMotor"


@pytest.mark.parametrize("settings, words", [
    (dict(master="fmpi"), 'master "fmpi" is not one of'),
    (dict(algorithm="newton"), 'algorithm "newton" is not one of'),
    (dict(step=0.0), "step must be positive and finite"),
    (dict(t_end=float("nan")), "t_end must be positive and finite"),
    (dict(master="ssp", variable_step=True), "variable-step master is the fmpy master's"),
    (dict(master="libcosim", start="zero"), "libcosim always starts"),
])
def test_bad_cosim_settings_are_refused_before_any_work(settings, words):
    with pytest.raises(SettingError, match=words):
        CosimSettings(**settings)


def test_cli_build_writes_the_power_ports_beside_the_fmu(tmp_path, capsys):
    source = SCENARIOS / "hydraulic_crane" / "hydraulic_cylinder.py"
    assert main(["build", str(source), "-o", str(tmp_path / "cyl.fmu")]) == 0
    assert capsys.readouterr().out.strip() == str(tmp_path / "cyl.fmu")
    beside = (tmp_path / "cyl_OspModelDescription.xml").read_text()
    assert '<LinearMechanicalPort name="rod">' in beside and 'ref="rate"' in beside


@pytest.mark.parametrize("name", ["dc_motor_slider_crank", "quarter_car"])
def test_the_fmpy_master_runs_fmi3_fmus_as_their_fmi2_twins(name, built, tmp_path):
    """The same scenario built as FMI 3.0 FMUs (companion and scene) and run by the fmpy
    master: with the inputs held (Gauss-Seidel and Jacobi) bit for bit the FMI 2.0 run; the
    implicit coupling with directional derivatives (fmi3GetDirectionalDerivative) within
    its iteration tolerance of it."""
    scenario, fmus2 = built(name)
    fmus3 = build_sources({i.name: i.source for i in scenario.instances}, tmp_path, fmi_version=3)
    assert all(fmpy.read_model_description(str(f)).fmiVersion == "3.0" for f in fmus3.values())
    h, t_end = SHORT[name]
    for algorithm in ("jacobi", "gauss-seidel"):
        runs = [run_fmpy(scenario, fmus, CosimSettings(algorithm=algorithm, step=h, t_end=t_end,
                                                       fmi_version=v))
                for v, fmus in ((2, fmus2), (3, fmus3))]
        np.testing.assert_array_equal(runs[0].values, runs[1].values)
    settings = dict(algorithm="implicit", jacobian="directional", step=h, t_end=t_end)
    two = run_fmpy(scenario, fmus2, CosimSettings(**settings))
    three = run_fmpy(scenario, fmus3, CosimSettings(**settings, fmi_version=3))
    assert _rel(two.values, three.values) < 1e-8


def test_fmi3_runs_with_the_fmpy_master_only():
    with pytest.raises(SettingError, match="FMI 3.0 FMUs run with the fmpy master"):
        CosimSettings(master="libcosim", fmi_version=3)
    with pytest.raises(SettingError, match="fmi_version must be 2 or 3"):
        CosimSettings(fmi_version=4)
