"""Scene FMUs for the host and misuse tests: built once per test module, driven through
the harness's ``Host`` (fmpy's FMU2Slave, logging on), and compared with mbdfmu itself."""

from __future__ import annotations

import ctypes
import sys
from pathlib import Path

import numpy as np
import pytest
from fmpy import extract, read_model_description

import mbdfmu
from mbdfmu.fmu_build.scene_fmu import build_fmu
from fmu_models.harness import OK, Host

SCENES = Path(__file__).resolve().parents[2] / "scenes"


@pytest.fixture(scope="module")
def scene_fmu(tmp_path_factory):
    """Path of a shipped scene's FMU, built once per module."""
    folder = tmp_path_factory.mktemp("scene_fmus")
    built: dict[str, Path] = {}

    def get(stem: str) -> Path:
        if stem not in built:
            built[stem] = build_fmu(SCENES / f"{stem}.toml", folder / f"{stem}.fmu")
        return built[stem]
    return get


class SceneHost(Host):
    """A ``Host`` of a scene FMU that knows its variables by name."""

    def __init__(self, path: Path, name: str = "a", logging_on: bool = True):
        md = read_model_description(path)
        super().__init__((extract(path), md), name, logging_on)
        self.vr = {v.name: v.valueReference for v in md.modelVariables}
        self.outputs = [v.name for v in md.modelVariables if v.causality == "output"]

    def real(self, *names) -> list[float]:
        code, values = self.get_real(*(self.vr[n] for n in names))
        assert code == OK, self.messages[-3:]
        return values

    def set_int(self, name: str, value: int) -> int:
        return self.status("fmi2SetInteger", (ctypes.c_uint * 1)(self.vr[name]), 1,
                           (ctypes.c_int * 1)(value))


@pytest.fixture
def scene_host():
    made: list[SceneHost] = []

    def make(path, name="a", logging_on=True):
        made.append(SceneHost(path, name, logging_on))
        return made[-1]
    yield make
    for h in made:
        h.free()


def simulate_numpy(stem: str, t_end: float, h: float, **kwargs):
    """``mbdfmu simulate`` of a shipped scene with the FMU's kernel (numpy)."""
    return mbdfmu.simulate(SCENES / f"{stem}.toml", t_end=t_end, output_interval=h,
                           kernel="numpy", **kwargs)


def max_error(got: dict[str, np.ndarray], expected, names) -> float:
    """Largest difference, each variable relative to its magnitude (at least 1)."""
    return max(float(np.max(np.abs(np.asarray(got[n]) - expected[n]))
                     / max(1.0, float(np.max(np.abs(expected[n]))))) for n in names)


def offered_kernels() -> list | None:
    """The scene kernels offered in the FMUs' core (``ckernel._scene_libraries``). Two FMUs
    built from one checkout import one copy of mbdfmu (``_mbdfmu_<hash>``), so a kernel
    one FMU offers, the other's Kernels would take too. None before an FMU is loaded."""
    found = [m._scene_libraries for name, m in sys.modules.items()
             if name.startswith("_mbdfmu_") and name.endswith(".equations.ckernel")]
    assert len(found) <= 1, "one core copy expected"
    return found[0] if found else None


def generic(call):
    """``call()`` with no scene kernel offered: the Kernels it makes take the generic
    library (those of the contact modes a step reaches too)."""
    offered = offered_kernels()
    saved = list(offered or ())
    if offered is not None:
        offered.clear()
    try:
        return call()
    finally:
        after = offered_kernels()
        if after is not None:
            after[:] = saved


def lockstep(fmus, scene_host, steps, h, force=None):
    """The FMUs (one with its scene kernels, then one without) stepped side by side at
    ``h`` (``force``: the input set before every step, (name, value of step k)); their
    outputs equal at every step, to the bit. The second is made and stepped with no scene
    kernel offered (``generic``), so that it runs the generic library throughout."""
    hosts_ = [scene_host(fmus[0], fmus[0].stem).init(),
              generic(lambda: scene_host(fmus[1], fmus[1].stem).init())]
    for k in range(steps):
        values = []
        for i, h_ in enumerate(hosts_):
            def step(h_=h_):
                if force is not None:
                    assert h_.set_real([h_.vr[force[0]]], [force[1](k)]) == OK
                assert h_.step(h) == OK, h_.messages[-3:]
                return h_.real(*h_.outputs)
            values.append(generic(step) if i else step())
        assert values[0] == values[1], k
    return hosts_
