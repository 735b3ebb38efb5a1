"""The kernels an event scene's FMU ships for its contact modes (scene_fmu.kernel_equations):
one per structure, each taken by the modes of its structure, each the generic kernel's
doubles, in the FMU's wrapper and in Python; a mode kernel that cannot be loaded is said
once and leaves that mode on the generic kernel."""

from __future__ import annotations

import sys
import zipfile
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parent))

import mbdfmu  # noqa: E402
from mbdfmu.equations import ckernel  # noqa: E402
from mbdfmu.equations.ckernel import scene_kernel  # noqa: E402
from mbdfmu.fmu_build import scene_fmu  # noqa: E402
from mbdfmu.fmu_build.scene_fmu import build_fmu  # noqa: E402
from mbdfmu.fmu_build.runtime.kernels import MODE_KERNEL_FILE, SCENE_KERNEL_FILE  # noqa: E402
from fmu_models.scenes import generic, lockstep, scene_host  # noqa: E402,F401

pytestmark = pytest.mark.skipif(not ckernel.available(), reason="no C compiler for the kernel")
ROOT = Path(__file__).resolve().parents[1]


@pytest.mark.parametrize("stem", ["crane_stop", "incline_stick"])
def test_an_event_scenes_fmu_on_its_scene_kernels_steps_as_the_generic_one(stem, tmp_path,
                                                                          scene_host):
    """crane_stop through its bounces to rest on its stop, incline_stick sliding, then
    sticking, at 1 ms: kernels are built for the contact mode each starts in and for its
    other mode's structure (the crane held on its stop, the block held sticking), in the
    wrapper and in Python; with its mode kernel's file spoilt, crane_stop says so once and
    runs that mode on the generic kernel, the same doubles."""
    path = ROOT / "scenes" / f"{stem}.toml"
    fmus = [build_fmu(path, tmp_path / f"{k}.fmu", scene_kernel=k == "scene")
            for k in ("scene", "generic")]
    with zipfile.ZipFile(fmus[0]) as z:
        assert {SCENE_KERNEL_FILE, MODE_KERNEL_FILE.format(1)} <= {
            Path(name).name for name in z.namelist()}
    built = lockstep(fmus, scene_host, 800, 1e-3)[0]
    assert not any("does not fit" in m or "cannot be loaded" in m for _, _, m in built.messages)
    if stem == "crane_stop":
        broken = tmp_path / "broken.fmu"
        with zipfile.ZipFile(fmus[0]) as src, zipfile.ZipFile(broken, "w") as dst:
            for item in src.infolist():
                spoilt = item.filename == f"resources/{MODE_KERNEL_FILE.format(1)}"
                dst.writestr(item, b"not a library" if spoilt else src.read(item.filename))
        host = generic(lambda: lockstep([broken, fmus[1]], scene_host, 800, 1e-3))[0]
        said = [m for _, _, m in host.messages if "kernel built for" in m]
        assert len(said) == 1 and "one of its contact modes" in said[0], said


@pytest.mark.parametrize("stem", ["crane_stop", "incline_stick"])
def test_every_contact_mode_runs_a_kernel_built_for_its_structure(stem, monkeypatch):
    """The build's kernels for an event scene (scene_fmu.kernel_equations): one per
    structure of its contact modes, starting mode first. Offered in Python, every mode a
    run reaches (the crane free and held on its stop, the block sliding and sticking) takes
    one, and the run is the generic kernel's to the bit."""
    scene = mbdfmu.load_scene(ROOT / "scenes" / f"{stem}.toml")
    equations = scene_fmu.kernel_equations(scene)
    headers = [scene_kernel.scene_header(eq) for eq in equations]
    assert len(equations) == 2 and len(set(headers)) == 2 and None not in headers

    def run():
        sim, visited = mbdfmu.Simulation(scene, kernel="c"), set()
        for k in range(1, 2001):
            sim.advance(k * 1e-3)
            eq = sim.stepped_equations
            visited.add((tuple(eq.held_rows), eq.ckernel.scene_built))
        return sim.output_vector(), visited
    with monkeypatch.context() as m:
        m.setattr(ckernel, "_scene_libraries", [])
        plain, visited = run()
        assert {built for _, built in visited} == {False}
        for eq in equations:
            ckernel.specialize(eq)
        fast, visited = run()
    assert len(visited) == 2 and {built for _, built in visited} == {True}, visited
    assert np.array_equal(fast, plain)
