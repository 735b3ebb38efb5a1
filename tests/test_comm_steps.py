"""Issue 12: accuracy that does not depend on where the communication points fall.

P2 (the N-four-bar, scenes as shipped, default settings) stepped as a co-simulation master
steps an FMU: every communication point ends an ``advance`` call. The reference is the exact
one-degree-of-freedom reduction (``tests/exact_solutions.py``). The full sweep (0.1 ms to
0.1 s, rtol 1e-10, N = 40 in the FMU) is ``benchmarks/comm_steps.py`` and
``benchmarks/fmu_comm_steps.py``.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

import exact_solutions as ref

mbdfmu = pytest.importorskip("mbdfmu")

SCENES = Path(__file__).resolve().parents[1] / "scenes"


def b0(values: dict) -> np.ndarray:
    """Top of crank0 (B0 of P2) from outputs by name."""
    phi = values["crank0.phi"]
    return np.array([values["crank0.x"] + 0.5 * math.cos(phi),
                     values["crank0.y"] + 0.5 * math.sin(phi)])


def exact_b0(t: float, n: int) -> np.ndarray:
    ex = ref.n_four_bar(np.array([0.0, t]), n)
    return np.array([ex["B0_x"][-1], ex["B0_y"][-1]])


def stepped(n: int, h: float, t_end: float, **kw):
    """The FMU's pattern in Python: advance by h to t_end; (B0 error at t_end, steps)."""
    sim = mbdfmu.Simulation(mbdfmu.load_scene(SCENES / f"n_four_bar_{n}.toml"), **kw)
    for k in range(1, round(t_end / h) + 1):
        sim.advance(k * h)
    return float(np.hypot(*(b0(sim.outputs()) - exact_b0(t_end, n)))), sim.integrator.stats


@pytest.mark.parametrize("n, target", [(2, 1e-6), (40, 1e-5)])
def test_default_settings_meet_the_target_at_any_communication_step(n, target):
    """The C kernel (what FMUs run), 0.1 s and 10 ms communication steps to t = 10 s:
    measured 8.6e-8 (N = 2) and 3.9e-9 (N = 40) at both, with the same steps."""
    runs = [stepped(n, h, 10.0, kernel="c") for h in (0.1, 0.01)]
    for error, _ in runs:
        assert error < target
    assert runs[0][1].nsteps == runs[1][1].nsteps    # the points do not change the steps


def test_rtol_1e_10_meets_its_target_at_a_10_ms_communication_step():
    error, _ = stepped(2, 0.01, 10.0, kernel="c", rtol=1e-10)
    assert error < 1e-9                                # measured 4.5e-12


def test_the_fmu_in_fmpy_meets_the_target_at_10_ms(tmp_path):
    fmpy = pytest.importorskip("fmpy")
    from mbdfmu.fmu_build.scene_fmu import build_fmu
    fmu = build_fmu(SCENES / "n_four_bar_2.toml", tmp_path / "p2.fmu")
    res = fmpy.simulate_fmu(str(fmu), stop_time=10.0, step_size=0.01, output_interval=0.01,
                            output=["crank0.x", "crank0.y", "crank0.phi"])
    last = {name: float(res[name][-1]) for name in ("crank0.x", "crank0.y", "crank0.phi")}
    assert res["time"][-1] == pytest.approx(10.0)
    assert np.hypot(*(b0(last) - exact_b0(10.0, 2))) < 1e-6    # measured 8.6e-8
