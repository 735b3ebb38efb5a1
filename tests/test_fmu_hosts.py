"""Real scene FMUs in hosts that did not come with mbdfmu: the FMI Compliance Checker and
Ecos' command line (C and C++, no Python inside, clean environment), fmpy, libcosim and
ecospy in fresh processes; each result against ``mbdfmu simulate`` at the same steps.

The checker is $MBDFMU_FMU_CHECKER or fmuCheck.linux64 on PATH (skipped when absent);
Ecos from the ecospy wheel (its ``ecos`` binary copied with an execute bit).
benchmarks/fmu_hosts_matrix.py runs every shipped scene in every host, and 200 processes.
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT / "tests") not in sys.path:
    sys.path.insert(0, str(ROOT / "tests"))

pytest.importorskip("fmpy")
from fmu_models import hosts  # noqa: E402
from fmu_models.scenes import max_error, scene_fmu, simulate_numpy  # noqa: E402,F401

needs_checker = pytest.mark.skipif(not hosts.CHECKER.exists(),
                                   reason=hosts.CHECKER_MISSING)
# (scene, communication step, stop time) of the checker runs: a fixed-step and two adaptive
# methods, a scene with inputs (held at their start values by the checker)
CHECKED = [("slider_crank", 1e-3, 0.05), ("pendulum_torque", 1e-2, 0.3),
           ("slider_force", 1e-2, 0.3), ("four_bar", 1e-2, 0.2)]


@needs_checker
@pytest.mark.parametrize("stem, h, stop", CHECKED, ids=[c[0] for c in CHECKED])
def test_the_compliance_checker_runs_scene_fmus_from_a_clean_environment(scene_fmu, tmp_path,
                                                                        stem, h, stop):
    run = hosts.run_checker(scene_fmu(stem), tmp_path, stop=stop, h=h)
    report = run.stdout + run.stderr
    assert run.returncode == 0, report[-3000:]
    assert "0 Warning(s)" in report and "0 Error(s)" in report, report[-3000:]
    data = np.genfromtxt(tmp_path / "out.csv", delimiter=",", names=True, deletechars="")
    expected = simulate_numpy(stem, stop, h)
    assert len(data) == len(expected.time)
    np.testing.assert_allclose(data["time"], expected.time, rtol=0, atol=1e-12)
    names = [n for n in data.dtype.names if n != "time"]
    assert names and max_error(data, expected, names) < 1e-9


@needs_checker
def test_a_missing_python_library_fails_instantiate_in_the_checker(scene_fmu, tmp_path):
    run = hosts.run_checker(scene_fmu("slider_crank"), tmp_path, stop=0.01, h=1e-3,
                            MBDFMU_PYTHON_LIBRARY="/nonexistent/libpython3.so")
    report = run.stdout + run.stderr
    assert run.returncode != 0
    assert "cannot load the Python library /nonexistent/libpython3.so" in report, report[-2000:]
    assert "MBDFMU_PYTHON_LIBRARY" in report


@pytest.mark.parametrize("kind", ["fmpy", "libcosim", "libcosim then fmpy", "checker"])
def test_fresh_processes_load_step_free_and_exit_cleanly(scene_fmu, tmp_path, kind):
    """Three processes per host (the benchmark runs 200): exit status 0, the right result."""
    path, h, steps = scene_fmu("slider_crank"), 1e-3, 10
    expected = simulate_numpy("slider_crank", steps * h, h)["slider.x"][-1]
    for i in range(3):
        if kind == "checker":
            if not hosts.CHECKER.exists():
                pytest.skip(hosts.CHECKER_MISSING)
            (tmp_path / str(i)).mkdir()
            run = hosts.run_checker(path, tmp_path / str(i), stop=steps * h, h=h)
        else:
            if kind != "fmpy":
                pytest.importorskip("libcosimpy")
            script = {"fmpy": hosts.FMPY_RUN, "libcosim": hosts.LIBCOSIM_RUN,
                      "libcosim then fmpy": hosts.LIBCOSIM_THEN_FMPY}[kind]
            run = hosts.run_python(script, path, steps, h, variable="slider.x")
            assert abs(hosts.result(run.stdout) - expected) <= 1e-9, run.stdout + run.stderr
        assert run.returncode == 0, (i, run.returncode, run.stderr[-2000:])


def test_ecos_command_line_runs_a_scene_fmu_from_a_clean_environment(scene_fmu, tmp_path):
    """Ecos' C++ command line (no Python inside); its CSV keeps 6 significant digits."""
    pytest.importorskip("ecospy", reason="pip install ecospy (and apt-get install libtbb12)")
    ecos = hosts.ecos_cli(tmp_path)
    h, stop = 1e-2, 0.3
    run = hosts.run_ecos_cli(ecos, scene_fmu("pendulum_torque"), tmp_path, stop, h)
    assert run.returncode == 0, run.stdout[-2000:] + run.stderr[-2000:]
    data = hosts.read_ecos_csv(tmp_path / "pendulum_torque.csv")     # named after the file
    expected = simulate_numpy("pendulum_torque", stop, h)
    assert len(data["time"]) >= len(expected.time) - 1
    for name in ("rod.phi", "rod.omega", "pivot.Fy"):
        got = np.interp(expected.time, data["time"], data[name])
        scale = max(1.0, float(np.max(np.abs(expected[name]))))
        assert float(np.max(np.abs(got - expected[name]))) / scale < 1e-5, name


def test_ecospy_runs_a_scene_fmu_like_mbdfmu_simulate(scene_fmu):
    pytest.importorskip("ecospy", reason="pip install ecospy (and apt-get install libtbb12)")
    from ecospy.EcosSimulation import EcosSimulation
    from ecospy.EcosSimulationStructure import EcosSimulationStructure
    h, n = 1e-3, 20
    structure = EcosSimulationStructure()
    structure.add_model("sc", str(scene_fmu("slider_crank")))
    simulation = EcosSimulation(structure=structure, step_size=h)
    simulation.init()
    rows = []
    for _ in range(n):
        simulation.step(1)
        rows.append([simulation.get_real("sc::slider.x"), simulation.get_real("sc::O.Fx")])
    simulation.terminate()
    simulation.free()
    expected = simulate_numpy("slider_crank", n * h, h)
    got = {"slider.x": np.array(rows)[:, 0], "O.Fx": np.array(rows)[:, 1]}
    assert max_error(got, {k: expected[k][1:] for k in got}, list(got)) < 1e-9
