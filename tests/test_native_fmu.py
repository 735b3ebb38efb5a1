"""The native FMU runtime (fmu_build/native, fmu_build/runtime) in real hosts.

The toy FMU (tests/fmu_models: a damped mass-spring integrated exactly per step) is built
once; every result is compared with the closed-form solution: fmpy, libcosim, Ecos, the
Compliance Checker and a C host without Python, fresh processes that must exit cleanly,
and the one-line messages when Python or numpy cannot be found. The FMI API misuse cases
are in test_native_fmu_api.py.
"""

from __future__ import annotations

import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:       # this checkout's fmu_build, not an installed copy
    sys.path.insert(0, str(ROOT))

pytest.importorskip("fmpy")
from fmpy import extract, read_model_description, simulate_fmu  # noqa: E402
from fmpy.validation import validate_fmu  # noqa: E402

from fmu_models import hosts  # noqa: E402
from fmu_models.harness import ERROR, H, assert_closed_form, toy, unzipped, workdir  # noqa: E402,F401
from fmu_models.toy import IDENTIFIER, build_toy, closed_form  # noqa: E402


# ------------------------------------------------------------------ model description, hosts

def test_model_description_passes_fmpy_validate(toy):
    assert validate_fmu(str(toy)) == []


@pytest.mark.skipif(not hosts.CHECKER.exists(), reason=hosts.CHECKER_MISSING)
def test_compliance_checker_from_a_clean_environment_matches_the_closed_form(toy, tmp_path):
    run = hosts.run_checker(toy, tmp_path, stop=1.0, h=H)
    assert run.returncode == 0, run.stdout + run.stderr
    report = run.stdout + run.stderr
    assert "0 Warning(s)" in report and "0 Error(s)" in report, report
    data = np.genfromtxt(tmp_path / "out.csv", delimiter=",", names=True)
    assert len(data) == 101 and data["time"][-1] == pytest.approx(1.0)
    assert_closed_form(data["time"], data["x"], data["v"])


def test_fmpy_simulate_matches_the_closed_form(toy):
    result = simulate_fmu(toy, stop_time=1.0, output_interval=H)
    assert len(result) == 101
    assert_closed_form(result["time"], result["x"], result["v"])


def test_libcosim_matches_the_closed_form(toy):
    pytest.importorskip("libcosimpy")
    run = hosts.run_python(hosts.LIBCOSIM_RUN, toy, 100, H)
    assert run.returncode == 0, run.stderr[-2000:]
    assert abs(hosts.result(run.stdout) - closed_form(1.0)[0]) <= 1e-9


@pytest.mark.parametrize("kind", ["fmpy", "libcosim", "libcosim then fmpy", "checker"])
def test_fresh_processes_load_step_free_and_exit_cleanly(toy, tmp_path, kind):
    """The exit crash of pythonfmu FMUs (SIGSEGV / abort after numpy) must not happen."""
    runs = 10
    for i in range(runs):
        if kind == "checker":
            if not hosts.CHECKER.exists():
                pytest.skip(hosts.CHECKER_MISSING)
            (tmp_path / str(i)).mkdir()
            run = hosts.run_checker(toy, tmp_path / str(i), stop=0.1, h=H)
        else:
            if kind != "fmpy":
                pytest.importorskip("libcosimpy")
            script = {"fmpy": hosts.FMPY_RUN, "libcosim": hosts.LIBCOSIM_RUN,
                      "libcosim then fmpy": hosts.LIBCOSIM_THEN_FMPY}[kind]
            run = hosts.run_python(script, toy, 10, H)
            assert abs(hosts.result(run.stdout) - closed_form(10 * H)[0]) <= 1e-9, run.stdout
        assert run.returncode == 0, (i, run.returncode, run.stderr[-2000:])


# ------------------------------------------------------------------ hosts without Python

@pytest.fixture(scope="module")
def c_host(workdir) -> Path:
    if not shutil.which("gcc"):
        pytest.skip("gcc is needed to build the C host")
    return hosts.compile_host(workdir)


def run_c_host(c_host, fmus, env_extra=None, steps=100):
    args = [str(c_host), str(steps), repr(H)]
    for directory, md in fmus:
        args += [directory, md.coSimulation.modelIdentifier, md.guid]
    return subprocess.run(args, capture_output=True, text=True, timeout=120,
                          env=hosts.clean_env(Path(fmus[0][0]), **(env_extra or {})))


def test_a_c_host_without_libpython_runs_two_instances(c_host, unzipped):
    run = run_c_host(c_host, [unzipped])
    assert run.returncode == 0, run.stdout + run.stderr
    xs = [float(line.split()[1]) for line in run.stdout.splitlines() if line.startswith("x ")]
    assert len(xs) == 2 and all(abs(x - closed_form(1.0)[0]) <= 1e-9 for x in xs)


def test_two_different_fmus_run_side_by_side_in_a_c_host(c_host, unzipped, workdir):
    """Different model modules and GUIDs in one interpreter do not clash."""
    source = (Path(__file__).parent / "fmu_models" / "mass_spring.py").read_text()
    variant = source.replace('"""Damped mass-spring (SI', '"""A second FMU: damped mass-spring (SI')
    other = build_toy(workdir / "Variant.fmu", cache_dir=workdir / "cache", source=variant)
    other_unzipped = (extract(other), read_model_description(other))
    assert other_unzipped[1].guid != unzipped[1].guid
    run = run_c_host(c_host, [unzipped, other_unzipped])
    assert run.returncode == 0, run.stdout + run.stderr
    xs = [float(line.split()[1]) for line in run.stdout.splitlines() if line.startswith("x ")]
    assert len(xs) == 4 and all(abs(x - closed_form(1.0)[0]) <= 1e-9 for x in xs)


def test_a_missing_python_library_fails_instantiate_with_one_clear_line(c_host, unzipped):
    run = run_c_host(c_host, [unzipped], {"MBDFMU_PYTHON_LIBRARY": "/nonexistent/libpython3.so"})
    assert run.returncode == 3, run.stdout + run.stderr
    lines = [line for line in run.stdout.splitlines() if line.startswith("LOG")]
    assert len(lines) == 1, lines
    assert lines[0].startswith(f"LOG {ERROR} logStatusError")
    assert "/nonexistent/libpython3.so" in lines[0] and "MBDFMU_PYTHON_LIBRARY" in lines[0]


def test_a_python_without_numpy_fails_instantiate_with_one_clear_line(c_host, unzipped, tmp_path):
    """Simulated: a folder first on MBDFMU_PYTHONPATH whose numpy cannot be imported."""
    (tmp_path / "numpy").mkdir()
    (tmp_path / "numpy" / "__init__.py").write_text(
        "raise ModuleNotFoundError(\"No module named 'numpy'\", name='numpy')\n")
    run = run_c_host(c_host, [unzipped], {"MBDFMU_PYTHONPATH": str(tmp_path)})
    assert run.returncode == 3, run.stdout + run.stderr
    lines = [line for line in run.stdout.splitlines() if line.startswith("LOG")]
    assert len(lines) == 1, lines
    assert "'numpy'" in lines[0] and "pip install numpy" in lines[0] and "MBDFMU_PYTHONPATH" in lines[0]


# ------------------------------------------------------------------ build

def test_no_compiler_fails_the_build_with_one_line(monkeypatch, tmp_path, workdir):
    from mbdfmu.fmu_build.native import CompileError, compile_wrapper
    monkeypatch.setenv("CC", "no-such-cc")
    with pytest.raises(CompileError) as info:
        compile_wrapper(tmp_path)
    message = str(info.value)
    assert "\n" not in message and "no C compiler found" in message and "apt-get install gcc" in message


def test_the_wrapper_is_compiled_once_per_source_and_compiler(workdir):
    from mbdfmu.fmu_build.native import compile_wrapper
    first = compile_wrapper(workdir / "cache")
    stamp = first.stat().st_mtime_ns
    assert compile_wrapper(workdir / "cache") == first and first.stat().st_mtime_ns == stamp


def test_same_inputs_give_the_same_fmu_bytes(workdir, toy):
    again = build_toy(workdir / "again.fmu", cache_dir=workdir / "cache")
    assert again.read_bytes() == toy.read_bytes()


# ------------------------------------------------------------------ Ecos (pip install ecospy; apt-get install libtbb12)

def test_ecos_command_line_host_runs_the_fmu_from_a_clean_environment(toy, tmp_path):
    """Ecos' C++ command line has no Python inside; its CSV has 6 decimals."""
    ecospy = pytest.importorskip("ecospy", reason="pip install ecospy (and apt-get install libtbb12)")
    shipped = Path(ecospy.__file__).parent / "binaries" / "ecos"
    ecos = tmp_path / "ecos"
    shutil.copy(shipped, ecos)
    ecos.chmod(0o755)
    run = subprocess.run([str(ecos), "simulate", "--path", str(toy), "--stopTime", "1",
                          "--stepSize", repr(H)], capture_output=True, text=True, timeout=120,
                         cwd=tmp_path, env=hosts.clean_env(tmp_path))
    assert run.returncode == 0, run.stdout[-2000:] + run.stderr[-2000:]
    rows = (tmp_path / f"{IDENTIFIER}.csv").read_text().splitlines()
    header = [name.strip() for name in rows[0].split(",")]
    columns = list(zip(*(map(str.strip, row.split(",")) for row in rows[1:])))
    times = [float(t) for t in columns[header.index("time")]]
    xs = [float(x) for x in columns[header.index("instance::x[REAL]")]]
    assert len(times) >= 100
    for t, x in zip(times, xs):
        assert abs(x - closed_form(t)[0]) <= 5e-7, (t, x)


def test_ecospy_runs_the_fmu_like_the_closed_form(toy):
    pytest.importorskip("ecospy", reason="pip install ecospy (and apt-get install libtbb12)")
    from ecospy.EcosSimulation import EcosSimulation
    from ecospy.EcosSimulationStructure import EcosSimulationStructure
    structure = EcosSimulationStructure()
    structure.add_model("toy", str(toy))
    simulation = EcosSimulation(structure=structure, step_size=H)
    simulation.init()
    simulation.step(100)
    t, x = simulation.get_time(), simulation.get_real("toy::x")
    simulation.terminate()
    simulation.free()
    assert t == pytest.approx(1.0, abs=1e-12) and abs(x - closed_form(t)[0]) <= 1e-9
