"""The command line tells the truth: warnings for changed initial values, fmpy's CSVs,
shipped scene names everywhere, --set with the FMU's checks, sweeps on Dask."""

import csv
import subprocess
import sys
import zipfile

import numpy as np
import pytest

import mbdfmu
from mbdfmu.cli import main

PROJECTED = """
name = "Projected"
[[body]]
name = "rod"
mass = 1.0
inertia = 0.08333333333333333
position = [0.5, 0.0]
angle = 0.0
velocity = [0.0, 0.0]
angular_velocity = 20.0
[[joint]]
name = "pivot"
type = "revolute"
body_i = "ground"
body_j = "rod"
point_j = [-0.5, 0.0]
"""


def test_projected_initial_velocity_warns_in_check_simulate_and_result(tmp_path, capsys):
    # a rod pinned at one end whose given velocities (v_y, w) = (2, 20) disagree with the
    # joint (v_y = 0.5 w)
    path = tmp_path / "p.toml"
    path.write_text(PROJECTED.replace("velocity = [0.0, 0.0]", "velocity = [0.0, 2.0]"))
    result = mbdfmu.simulate(path, t_end=0.01)
    # closest in kinetic energy to (v_y, w) = (2, 20) with v_y = 0.5 w:
    # w = (m 0.5 * 2 + I 20) / (m 0.25 + I)
    w = (0.5 * 2.0 + 20.0 / 12) / (0.25 + 1.0 / 12)
    assert result["rod.omega"][0] == pytest.approx(w, rel=1e-12)
    assert any("angular_velocity = 20" in line and f"{w:.6g}" in line
               for line in result.warnings)
    for command in (["check", str(path)], ["simulate", str(path), "--t-end", "0.01", "--out",
                                            str(tmp_path / "o.csv")]):
        assert main(command) == 0
        err = capsys.readouterr().err
        assert "warning" in err and "angular_velocity = 20 rad/s as given" in err
        assert "velocity[1] = 2 m/s as given" in err


def test_position_beyond_tolerance_warns_and_defaults_do_not(tmp_path):
    path = tmp_path / "p.toml"
    # the angle is left to its default: assembly turns the rod, but only the given
    # position is reported
    path.write_text(PROJECTED.replace("angular_velocity = 20.0", "").replace(
        "angle = 0.0\n", "").replace("position = [0.5, 0.0]", "position = [0.5, 0.01]"))
    sim = mbdfmu.Simulation(mbdfmu.load_scene(path))
    assert sim.q[2] == pytest.approx(0.015, rel=0.01)        # turned: not reported
    assert len(sim.warnings) == 2
    assert "position[0] = 0.5 m as given" in sim.warnings[0]
    assert "position[1] = 0.01 m as given" in sim.warnings[1]


def test_plot_reads_fmpy_csv_with_one_axis_per_unit(tmp_path):
    from fmpy.util import write_csv

    result = mbdfmu.simulate("slider_crank", t_end=0.005, output_interval=5e-4)
    names = ["slider.x", "crank.phi", "B.Fx", "motor.effort"]
    table = np.zeros(len(result.time), dtype=[("time", float)] + [(n, float) for n in names])
    table["time"] = result.time
    for n in names:
        table[n] = result[n]
    path = tmp_path / "fmpy.csv"
    write_csv(str(path), table)
    assert path.read_text().startswith('"time"')          # fmpy quotes its header
    read = mbdfmu.read_csv(path)
    np.testing.assert_allclose(read["slider.x"], result["slider.x"], rtol=1e-5)
    png = tmp_path / "p.png"
    assert main(["plot", str(path), *names, "-o", str(png)]) == 0
    from mbdfmu.plotting import units_from_names
    units = units_from_names(names)
    assert units == {"slider.x": "m", "crank.phi": "rad", "B.Fx": "N"}   # effort: N or N.m
    assert main(["plot", str(path), *names, "-o", str(png), "--scene", "slider_crank"]) == 0
    assert png.stat().st_size > 0


def test_plot_show_without_display_says_so(tmp_path, capsys, monkeypatch):
    monkeypatch.delenv("DISPLAY", raising=False)
    monkeypatch.delenv("WAYLAND_DISPLAY", raising=False)
    monkeypatch.chdir(tmp_path)           # the chart goes to the working directory
    csv_path = mbdfmu.simulate("pendulum", t_end=0.1).to_csv(tmp_path / "r.csv")
    assert main(["plot", str(csv_path), "--show"]) == 0
    assert "no display" in capsys.readouterr().out
    assert (tmp_path / "r.png").is_file()


@pytest.mark.parametrize("command", [
    ["check", "rod_pendulum"],
    ["simulate", "rod_pendulum", "--t-end", "0.05", "--out", "{tmp}/r.csv"],
    ["equilibrium", "rod_pendulum"],
    ["linearize", "rod_pendulum"],
    ["sweep", "rod_pendulum", "--set", "rod.mass=1:2:2", "--t-end", "0.05",
     "--scheduler", "synchronous", "-o", "{tmp}/sw", "--outputs", "rod.phi"],
])
def test_every_command_takes_a_shipped_scene_name(tmp_path, command):
    assert main([c.format(tmp=tmp_path) for c in command]) == 0


def test_animate_takes_a_shipped_scene_name(tmp_path):
    csv_path = mbdfmu.simulate("slider_crank", t_end=0.01).to_csv(tmp_path / "r.csv")
    assert main(["animate", "slider_crank", str(csv_path), "-o", str(tmp_path / "a.gif")]) == 0


@pytest.mark.parametrize("args, message", [
    (["--set", "rod.mas=2"], 'unknown parameter "rod.mas" (did you mean "rod.mass"?)'),
    (["--set", "rod.mass=-1"], '"rod.mass" must be positive, got -1'),
    (["--set", "rod.mass=heavy"], "--set rod.mass: 'heavy' is not a number"),
    (["--set", "rod.mass"], "expected NAME=VALUE"),
    (["--set", "solver.rtol=2"], "solver.rtol must be below 1"),
])
def test_set_errors_are_one_line_exit_2(tmp_path, capsys, args, message):
    for command in (["simulate", "rod_pendulum", "--t-end", "0.01", "--out",
                     str(tmp_path / "o.csv")], ["linearize", "rod_pendulum"]):
        if command[0] == "linearize" and "solver" in args[1]:
            continue
        assert main(command + args) == 2
        err = capsys.readouterr().err.strip()
        assert "\n" not in err and message in err, err


def test_set_on_simulate_changes_the_run(tmp_path):
    out = tmp_path / "o.csv"
    assert main(["simulate", "slider_crank", "--t-end", "0.005", "--set", "load.fx=0",
                 "--set", "rod.mass=0.4", "--out", str(out)]) == 0
    expected = mbdfmu.simulate(mbdfmu.with_parameters(mbdfmu.load_scene("slider_crank"),
                                                      {"load.fx": 0.0, "rod.mass": 0.4}), 0.005)
    np.testing.assert_allclose(mbdfmu.read_csv(out)["motor.effort"], expected["motor.effort"],
                               rtol=1e-9)


def test_build_set_bakes_start_values_into_the_fmu(tmp_path):
    from fmpy import read_model_description

    fmu = tmp_path / "sc.fmu"
    assert main(["build", "slider_crank", "-o", str(fmu), "--set", "load.fx=-50",
                 "--set", "solver.rtol=1e-7"]) == 0
    md = read_model_description(str(fmu))
    start = {v.name: v.start for v in md.modelVariables}
    assert float(start["load.fx"]) == -50.0 and float(start["solver.rtol"]) == 1e-7
    with zipfile.ZipFile(fmu) as z:
        shipped = [n for n in z.namelist() if n.endswith("scene.json")]
        assert '-50.0' in z.read(shipped[0]).decode()


def _rows(path):
    with open(path, newline="") as fh:
        return list(csv.DictReader(fh))


def test_sweep_local_cluster_equals_synchronous_and_failures_are_rows(tmp_path, capsys):
    common = ["sweep", "slider_crank", "--set", "load.fx=-100:0:2", "--set",
              "rod.mass=-0.2:0.4:3", "--t-end", "0.004", "--outputs", "motor.effort",
              "slider.x", "--no-progress"]
    assert main(common + ["-o", str(tmp_path / "sync"), "--scheduler", "synchronous"]) == 0
    assert main(common + ["-o", str(tmp_path / "dask")]) == 0
    assert "LocalCluster" in capsys.readouterr().out
    sync, dask = _rows(tmp_path / "sync/results.csv"), _rows(tmp_path / "dask/results.csv")
    assert sync == dask and len(sync) == 6
    failed = [r for r in sync if r["status"] == "failed"]
    assert len(failed) == 2 and all('"rod.mass" must be positive' in r["reason"]
                                    for r in failed)
    ok = [r for r in sync if r["status"] == "ok"]
    # slider.x at the end of 0.004 s (crank at 1.2566 rad): the same for every load
    phi = 314.1592653589793 * 0.004
    x = 0.1 * np.cos(phi) + np.sqrt(0.3 ** 2 - (0.1 * np.sin(phi)) ** 2)
    for r in ok:
        assert float(r["slider.x.final"]) == pytest.approx(x, rel=1e-9)
        assert float(r["slider.x.peak"]) == pytest.approx(0.4, rel=1e-12)
    assert (tmp_path / "sync/motor.effort.png").stat().st_size > 0


LOG_HOST = """
import sys
from fmpy import simulate_fmu

def logger(env, instance, status, category, message):
    print(status, message.decode() if isinstance(message, bytes) else message)

simulate_fmu(sys.argv[1], stop_time=0.01, output_interval=0.01, logger=logger,
             debug_logging=True)
"""


def test_fmu_log_carries_changed_initial_values(tmp_path):
    # in a process of its own: pythonfmu keeps the first logger callback for the process
    path = tmp_path / "Projected.toml"
    path.write_text(PROJECTED)
    fmu = tmp_path / "Projected.fmu"
    assert main(["build", str(path), "-o", str(fmu)]) == 0
    out = subprocess.run([sys.executable, "-c", LOG_HOST, str(fmu)], capture_output=True,
                         text=True, timeout=120, cwd=tmp_path).stdout.splitlines()
    warnings = [line for line in out if "initial conditions" in line]
    assert any("angular_velocity = 20 rad/s as given, 5 after" in w for w in warnings), out
    assert all(w.startswith("1 ") for w in warnings)      # fmi2Warning
