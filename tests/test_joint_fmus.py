"""The P8-P11 scenes through their FMUs in fmpy, against the same closed forms as
``simulate()`` (``joint_checks.py``): positions to 1e-8, reactions and efforts to 1e-6
relative, at the FMU's default solver settings and at solver.rtol = 1e-10."""

from __future__ import annotations

import numpy as np
import pytest

fmpy = pytest.importorskip("fmpy")

from mbdfmu.fmu_build import build  # noqa: E402
from mbdfmu.model import load_scene  # noqa: E402

import exact_solutions as ref  # noqa: E402
from joint_checks import CHECKS  # noqa: E402

START = {"default": {}, "rtol 1e-10": {"solver.rtol": 1e-10, "solver.atol": 1e-10}}


@pytest.fixture(scope="module")
def fmus(tmp_path_factory):
    folder = tmp_path_factory.mktemp("joint_fmus")
    return {name: build(ref.SCENES / f"{name}.toml", folder / f"{name}.fmu") for name in CHECKS}


@pytest.mark.parametrize("start", START)
@pytest.mark.parametrize("name", CHECKS)
def test_fmu_matches_the_closed_form(fmus, name, start):
    t_end = load_scene(ref.SCENES / f"{name}.toml").simulation.t_end
    table = fmpy.simulate_fmu(str(fmus[name]), stop_time=t_end, output_interval=t_end / 50,
                              start_values=START[start])
    time = np.asarray(table["time"], dtype=float)
    assert time[-1] == pytest.approx(t_end)
    CHECKS[name](time, {n: np.asarray(table[n], dtype=float) for n in table.dtype.names})


def test_fmu_coupler_ratio_is_a_parameter(fmus):
    table = fmpy.simulate_fmu(str(fmus["gear_pair"]), stop_time=0.5, output_interval=0.05,
                              start_values={"mesh.ratio": 3.0})
    time = np.asarray(table["time"], dtype=float)
    ex = ref.geared_pair(time, torque=0.1, J_in=0.005, inertia_out=0.04, ratio=3.0)
    np.testing.assert_allclose(table["wheel.phi"], ex["q_out"], rtol=0, atol=1e-8)
    np.testing.assert_allclose(table["mesh.effort"], ex["effort"], rtol=1e-6)
