"""Scene FMUs for the host and misuse tests: built once per test module, driven through
the harness's ``Host`` (fmpy's FMU2Slave, logging on), and compared with mbdfmu itself."""

from __future__ import annotations

import ctypes
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
