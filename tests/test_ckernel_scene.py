"""The C kernel built for one scene (ckernel/scene_kernel.py): the generic kernel's
doubles, bit for bit, from its constant structure and its straight-line band factor; taken
only by equations of the structure it was built for; shipped in the scene's FMU and run
there, with the generic FMU's values at every step."""

from __future__ import annotations

import functools
import math
import re
import sys
import tomllib
import zipfile
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

sys.path.insert(0, str(Path(__file__).resolve().parent))

import mbdfmu  # noqa: E402
from mbdfmu import cli  # noqa: E402
from mbdfmu.equations import Equations, ckernel  # noqa: E402
from mbdfmu.equations.ckernel import scene_kernel  # noqa: E402
from mbdfmu.equations.ckernel.model import model_arrays  # noqa: E402
from mbdfmu.equations.projection import assemble  # noqa: E402
from mbdfmu.fmu_build import BuildError  # noqa: E402
from mbdfmu.fmu_build.cache import build_fmus  # noqa: E402
from mbdfmu.equations.ckernel.build import KernelBuildError  # noqa: E402
from mbdfmu.fmu_build import scene_fmu  # noqa: E402
from mbdfmu.fmu_build.scene_fmu import SCENE_KERNEL_ENV, build_fmu  # noqa: E402
from mbdfmu.fmu_build.runtime.kernels import SCENE_KERNEL_FILE  # noqa: E402
from mbdfmu.model import scene_from_dict  # noqa: E402
from mbdfmu.scenes.generate_n_four_bar import scene_text  # noqa: E402
from fmu_models import hosts  # noqa: E402
from fmu_models.scenes import generic, lockstep, scene_host  # noqa: E402,F401

pytestmark = pytest.mark.skipif(not ckernel.available(), reason="no C compiler for the kernel")
ROOT = Path(__file__).resolve().parents[1]
CRANE = ROOT / "scenarios" / "hydraulic_crane" / "crane.toml"
CKERNEL = ROOT / "src" / "mbdfmu" / "equations" / "ckernel"
# A ring of four bars, one pinned to the ground: the rows of its four hinges couple in a
# cycle, so S's factor fills in entries S keeps at zero (no shipped scene does).
RING = 'name = "Ring"\n' + "".join(f"""
[[body]]
name = "{name}"
mass = {mass}
inertia = {0.1 * mass}
position = [{x}, {y}]
angle = {angle!r}
""" for name, mass, x, y, angle in (("a", 1.0, 0.5, 0.0, 0.0), ("b", 1.0, 1.0, 0.5, math.pi / 2),
                                    ("c", 2.0, 0.5, 1.0, math.pi), ("d", 1.0, 0.0, 0.5, -math.pi / 2))
) + "".join(f"""
[[joint]]
name = "{i}{j}"
type = "revolute"
body_i = "{i}"
point_i = [{pi}, 0.0]
body_j = "{j}"
point_j = [-0.5, 0.0]
""" for i, j, pi in (("ground", "a", 0.0), ("a", "b", 0.5), ("b", "c", 0.5), ("c", "d", 0.5),
                     ("d", "a", 0.5)))
# a spring with an actuator input (S dense-sized), a slider's line rows and a driver, a
# chain long enough for S in band storage (60 rows and more), and the ring's fill-in
SCENES = {"crane": CRANE, "slider_crank": ROOT / "scenes" / "slider_crank.toml",
          "n_four_bar_10": scene_text(10), "ring": RING,
          # Jacobian terms summed into one entry (the merge's sums, not a copy)
          "gear_pair": ROOT / "scenes" / "gear_pair.toml",
          "rolling_disc": ROOT / "scenes" / "rolling_disc.toml"}


def load(name):
    source = SCENES[name]
    if isinstance(source, str):
        return scene_from_dict(tomllib.loads(source), source=name)
    return mbdfmu.model.reader.load_scene(source)


def test_the_ring_fills_in():
    """S's zero entries the factor fills (what the ring is here for)."""
    a = model_arrays(Equations(load("ring"), kernel="numpy"))
    m, kd = int(a["m"]), int(a["kd"])
    code = "\n".join(scene_kernel._band_code(m, kd, a["band_index"], a["pair_a"], a["pair_b"]))
    written = {int(x) for x in re.findall(r"L\[(\d+)\] -= u", code)}
    assert written - {int(e) for e in a["band_index"]}


@pytest.fixture
def scene_libraries(monkeypatch):
    """The scene kernels offered in this test only (the registry is the process's)."""
    monkeypatch.setattr(ckernel, "_scene_libraries", [])


@functools.lru_cache(maxsize=None)
def generic_and_scene(name):
    """(Equations on the generic kernel, Equations on the scene's own) of one scene."""
    saved, ckernel._scene_libraries = ckernel._scene_libraries, []
    try:
        generic = Equations(load(name), kernel="c")
        assert ckernel.specialize(generic) is not None
        built = Equations(load(name), kernel="c")
    finally:
        ckernel._scene_libraries = saved
    assert built.ckernel.scene_built and not generic.ckernel.scene_built
    return generic, built


@pytest.mark.parametrize("name", list(SCENES))
@settings(max_examples=10, deadline=None)
@given(seed=st.integers(0, 2**31))
def test_the_scene_kernel_gives_the_generic_kernels_doubles(name, seed):
    generic, built = generic_and_scene(name)
    rng = np.random.default_rng(seed)
    q0, _ = assemble(generic)
    q = q0 + rng.normal(scale=0.01, size=q0.size)
    qd = rng.normal(scale=2.0, size=q0.size)
    u = generic.no_inputs
    u = type(u)(u.motions, rng.normal(scale=100.0, size=u.forces.shape))
    (qdd, lam), (qdd_b, lam_b) = (e.accelerations(0.3, q, qd, u) for e in (generic, built))
    assert np.array_equal(qdd, qdd_b) and np.array_equal(lam, lam_b)
    assert np.array_equal(generic.output_values(0.3, q, qd, qdd, lam, u),
                          built.output_values(0.3, q, qd, qdd, lam, u))
    # the singularity indicator (a factor of Psi_q D Psi_q^T of its own)
    motion = generic.motion_values(0.3, u)
    assert generic.ckernel.singularity_indicator(q, motion) == \
        built.ckernel.singularity_indicator(q, motion)


@pytest.mark.parametrize("method", ["dop853p", "rk4p", "genalpha"])
@pytest.mark.parametrize("name", list(SCENES))
def test_a_run_on_the_scene_kernel_is_the_generic_run(name, method, scene_libraries):
    runs = []
    for specialized in (False, True):
        if specialized:
            ckernel.specialize(Equations(load(name), kernel="c"))
        sim = mbdfmu.Simulation(load(name), kernel="c", method=method)
        assert sim.stepped_equations.ckernel.scene_built == specialized
        sim.advance(0.3)
        runs.append((sim.output_vector(), vars(sim.integrator.stats).copy()))
    assert np.array_equal(runs[0][0], runs[1][0]) and runs[0][1] == runs[1][1]


def test_equations_of_another_structure_take_the_generic_kernel(scene_libraries):
    """A scene kernel offered for the crane is refused by a slider-crank and by the crane
    hanging from a second pivot (the same counts, another pattern)."""
    ckernel.specialize(Equations(load("crane"), kernel="c"))
    assert Equations(load("crane"), kernel="c").ckernel.scene_built
    assert not Equations(load("slider_crank"), kernel="c").ckernel.scene_built
    text = CRANE.read_text().replace('body_i = "boom"\npoint_i = [1.0, 0.0]',
                                     'body_i = "ground"\npoint_i = [1.96, 0.4]')
    assert text != CRANE.read_text()
    other = scene_from_dict(tomllib.loads(text), source="moved_hook")
    assert not Equations(other, kernel="c").ckernel.scene_built


def test_a_kernel_offered_again_is_kept_once(scene_libraries, tmp_path):
    """Each instance of an FMU offers its extracted copy: one library per content."""
    path = ckernel.specialize(Equations(load("crane"), kernel="c"))
    copy = tmp_path / "copy.so"
    copy.write_bytes(path.read_bytes())
    ckernel.use_scene_library(copy)
    ckernel.use_scene_library(path)
    assert len(ckernel._scene_libraries) == 1


def test_a_stop_scene_runs_its_modes_on_both_kernels_as_on_the_generic(scene_libraries):
    """crane_stop's free mode on its scene kernel, its held mode (other rows) on the generic
    one: the run is the generic run, bounce for bounce, to the rest on the stop."""
    path = ROOT / "scenes" / "crane_stop.toml"
    runs = []
    for specialized in (False, True):
        if specialized:
            ckernel.specialize(Equations(mbdfmu.model.reader.load_scene(path), kernel="c"))
        sim = mbdfmu.Simulation(path, kernel="c", method="dop853p")
        assert sim.stepped_equations.ckernel.scene_built == specialized
        values = []
        for t in np.arange(1, 41) * 0.025:
            sim.advance(t)
            values.append(sim.output_vector())
        assert not sim.stepped_equations.ckernel.scene_built      # resting: the held mode
        runs.append((np.array(values), vars(sim.integrator.stats).copy()))
    assert np.array_equal(runs[0][0], runs[1][0]) and runs[0][1] == runs[1][1]


def test_every_structure_field_the_c_reads_is_in_every_shipped_scenes_header():
    """What the C sources read through S_() is what scene_kernel.py defines (a missing one
    would fail the scene build, and the FMU would quietly ship the generic kernel only),
    and its index tables are the Model's `const I *` fields."""
    sources = "".join(p.read_text() for p in CKERNEL.glob("*.[ch]"))
    model = sources[sources.index("typedef struct {\n    I nb, n, m, nf;"):]
    model = model[:model.index("} Model;")]
    tables = set(re.findall(r"\*(\w+)", " ".join(re.findall(r"const I ([^;]*);", model))))
    assert tables == set(scene_kernel.INDEX_TABLES)
    uses = "\n".join(line for line in sources.splitlines() if "#define S_" not in line)
    read = set(re.findall(r"S_\(M, (\w+)\)", uses))
    for path in sorted((ROOT / "scenes").glob("*.toml")):
        header = scene_kernel.scene_header(
            Equations(mbdfmu.model.reader.load_scene(path), kernel="numpy"))
        if header is not None:
            assert read <= set(re.findall(r"SC_(\w+)\b", header)), path.name


def test_a_large_mechanism_keeps_the_generic_kernel():
    eq = Equations(scene_from_dict(tomllib.loads(scene_text(40)), source="n40"), kernel="numpy")
    assert scene_kernel.scene_header(eq) is None
    assert scene_kernel.scene_header(Equations(load("crane"), kernel="numpy")).count(
        "sc_factor") == 1


# ------------------------------------------------------------------------------ the FMU

@pytest.fixture(scope="module")
def crane_fmus(tmp_path_factory):
    folder = tmp_path_factory.mktemp("scene_kernel")
    return (build_fmu(CRANE, folder / "scene.fmu", scene_kernel=True),
            build_fmu(CRANE, folder / "generic.fmu", scene_kernel=False))


def test_the_crane_fmu_ships_and_runs_its_scene_kernel_with_the_generic_values(
        crane_fmus, scene_host):
    """Both FMUs stepped at 1 ms with the cylinder's force set before every step (the
    wrapper's own steps): the same doubles at every step; only one carries the kernel."""
    names = {}
    for fmu in crane_fmus:
        with zipfile.ZipFile(fmu) as z:
            names[fmu.stem] = f"resources/{SCENE_KERNEL_FILE}" in z.namelist()
    assert names == {"scene": True, "generic": False}
    force = ("cylinder.actuator", lambda k: 8420.0 * (1 + 0.05 * math.sin(0.02 * k)))
    built = lockstep(crane_fmus, scene_host, 300, 1e-3, force)[0]
    assert not any("does not fit" in m or "cannot be loaded" in m for _, _, m in built.messages)


def test_a_scene_kernel_that_cannot_be_loaded_leaves_the_generic_one_and_says_so(
        crane_fmus, scene_host, tmp_path):
    """The crane's FMU with its scene kernel's file spoilt (another architecture's, say):
    one log line saying so, and the generic build's values at every step."""
    broken = tmp_path / "broken.fmu"
    with zipfile.ZipFile(crane_fmus[0]) as src, zipfile.ZipFile(broken, "w") as dst:
        for item in src.infolist():
            spoilt = item.filename == f"resources/{SCENE_KERNEL_FILE}"
            dst.writestr(item, b"not a library" if spoilt else src.read(item.filename))
    force = ("cylinder.actuator", lambda k: 8420.0 * (1 + 0.05 * math.sin(0.02 * k)))
    # none offered by other tests' FMUs either: the broken one has only the generic library
    host = generic(lambda: lockstep([broken, crane_fmus[1]], scene_host, 50, 1e-3, force))[0]
    said = [m for _, _, m in host.messages if "kernel" in m]
    assert len(said) == 1 and "built for its scene cannot be loaded here" in said[0], said


def test_a_scene_whose_method_cannot_start_still_builds_with_its_kernel(tmp_path):
    """crane_stop under genalpha (which does not locate events: the master sets
    solver.method before it starts) builds as it did without the scene's kernel."""
    path = tmp_path / "stop_genalpha.toml"
    text = (ROOT / "scenes" / "crane_stop.toml").read_text()
    path.write_text(text.replace("[simulation]\n", '[simulation]\nmethod = "genalpha"\n', 1))
    with zipfile.ZipFile(build_fmu(path, tmp_path / "x.fmu", scene_kernel=True)) as z:
        assert f"resources/{SCENE_KERNEL_FILE}" in z.namelist()


@pytest.mark.skipif(not hosts.CHECKER.is_file(), reason=hosts.CHECKER_MISSING)
def test_the_compliance_checker_runs_the_crane_on_its_scene_kernel(crane_fmus, tmp_path):
    run = hosts.run_checker(crane_fmus[0], tmp_path, stop=0.2, h=1e-3)
    report = run.stdout + run.stderr
    assert run.returncode == 0 and "0 Error(s)" in report, report[-3000:]
    data = np.genfromtxt(tmp_path / "out.csv", delimiter=",", names=True, deletechars="")
    expected = mbdfmu.simulate(CRANE, t_end=0.2, output_interval=1e-3, kernel="numpy")
    assert len(data) == len(expected.time)
    for name in ("boom.phi", "load.x", "cylinder.length"):     # the actuator held at 0 N
        np.testing.assert_allclose(data[name], expected[name], rtol=0, atol=1e-9)


def test_fmus_built_once_are_built_again_for_the_other_kernel_setting(tmp_path, monkeypatch):
    """cache.build_fmus (a scenario's FMUs, reused while their sources are unchanged) keys
    them on $MBDFMU_SCENE_KERNEL too."""
    shipped = []
    for setting in ("0", "1", "0"):
        monkeypatch.setenv(SCENE_KERNEL_ENV, setting)
        with zipfile.ZipFile(build_fmus({"crane": CRANE}, tmp_path)["crane"]) as z:
            shipped.append(f"resources/{SCENE_KERNEL_FILE}" in z.namelist())
    assert shipped == [False, True, False]


def test_a_scene_kernel_that_does_not_compile_leaves_the_generic_one_and_says_so(
        tmp_path, monkeypatch, capsys):
    def failing(eq):
        raise KernelBuildError("compiling the C kernel failed: (a compiler error)")
    monkeypatch.setattr(scene_fmu, "compile_scene_kernel", failing)
    with pytest.warns(UserWarning, match="Crane: the C kernel built for the scene was not "
                                         r"compiled \(compiling .*generic C kernel only"):
        fmu = build_fmu(CRANE, tmp_path / "x.fmu", scene_kernel=True)
    with zipfile.ZipFile(fmu) as z:
        names = z.namelist()
    assert f"resources/{SCENE_KERNEL_FILE}" not in names and "resources/mbdfmu_kernel.so" in names
    monkeypatch.delenv(SCENE_KERNEL_ENV)          # the command line's default: with it
    assert cli.main(["build", str(CRANE), "-o", str(tmp_path / "y.fmu")]) == 0
    err = capsys.readouterr().err.strip().splitlines()
    assert err == ["mbdfmu build: warning: Crane: the C kernel built for the scene was not "
                   "compiled (compiling the C kernel failed: (a compiler error)): the FMU "
                   "ships the generic C kernel only"], err


def test_the_command_lines_generic_kernel_leaves_the_scene_kernel_out(tmp_path, monkeypatch):
    monkeypatch.delenv(SCENE_KERNEL_ENV)          # the command line's default: with it
    shipped = []
    for extra in ([], ["--generic-kernel"]):
        fmu = tmp_path / f"crane{len(extra)}.fmu"
        assert cli.main(["build", str(CRANE), "-o", str(fmu), *extra]) == 0
        with zipfile.ZipFile(fmu) as z:
            shipped.append(f"resources/{SCENE_KERNEL_FILE}" in z.namelist())
    assert shipped == [True, False]


def test_the_scene_kernel_setting_is_checked(tmp_path, monkeypatch):
    monkeypatch.setenv(SCENE_KERNEL_ENV, "yes")
    with pytest.raises(BuildError, match=f"{SCENE_KERNEL_ENV}='yes'"):
        build_fmu(CRANE, tmp_path / "x.fmu")
