"""Every solver setting is checked where it enters (Python, CLI, scene file) before any work,
with one line naming the setting; the defaults come from one place."""

from __future__ import annotations

import math
import subprocess
import sys

import pytest

import mbdfmu
from mbdfmu import SettingError, SolverSettings
from mbdfmu.integrators import METHODS

from conftest import SCENES

BAD_FLAGS = [
    (["--step", "0"], "--step must be positive and finite"),
    (["--step", "nan"], "--step must be positive and finite"),
    (["--step", "-1"], "--step must be positive and finite"),
    (["--rtol", "-1"], "--rtol must be positive and finite"),
    (["--rtol", "2"], "--rtol must be below 1"),
    (["--atol", "0"], "--atol must be positive and finite"),
    (["--output-interval", "0"], "--output-interval must be positive and finite"),
    (["--t-end", "-1"], "--t-end must be positive and finite"),
    (["--t-end", "inf"], "--t-end must be positive and finite"),
]


@pytest.mark.parametrize("flags, words", BAD_FLAGS)
def test_cli_rejects_a_bad_setting_with_one_line_and_exit_2(tmp_path, flags, words):
    args = ["simulate", "pendulum", "--out", str(tmp_path / "o.csv")]
    if "--t-end" not in flags:
        args += ["--t-end", "0.01"]
    proc = subprocess.run([sys.executable, "-m", "mbdfmu", *args, *flags], capture_output=True,
                          text=True, timeout=60, cwd=tmp_path)
    assert proc.returncode == 2, proc.stderr
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1 and "Traceback" not in proc.stderr
    assert lines[0].startswith("mbdfmu simulate: ") and words in lines[0]
    assert not (tmp_path / "o.csv").exists()


@pytest.mark.parametrize("kwargs, setting", [
    (dict(rtol=-1.0), "rtol"), (dict(step=0.0), "step"), (dict(step=math.nan), "step"),
    (dict(atol=math.inf), "atol"), (dict(output_interval=-1e-3), "output_interval"),
    (dict(method="rk5"), "method"), (dict(t_end=-1.0), "t_end"),
    (dict(method="genalpha", method_options={"rho_inf": 2.0}), "rho_inf"),
])
def test_python_rejects_a_bad_setting_naming_it(kwargs, setting):
    with pytest.raises(SettingError) as info:
        mbdfmu.simulate(mbdfmu.load_scene("pendulum"), **({"t_end": 0.01} | kwargs))
    assert isinstance(info.value, ValueError) and info.value.setting == setting
    assert setting in str(info.value)


def test_a_bad_method_suggests_the_closest_name():
    with pytest.raises(SettingError, match='"dop835p" is not a method .did you mean "dop853p"'):
        SolverSettings().updated(method="dop835p")


def test_the_scene_file_setting_is_checked_with_the_file_named(tmp_path):
    text = (SCENES / "pendulum.toml").read_text() + '\n[simulation]\nmethod = "rk5"\n'
    path = tmp_path / "p.toml"
    path.write_text(text)
    with pytest.raises(SettingError, match=r'^p.toml: simulation: method "rk5" is not a method'):
        mbdfmu.Simulation(mbdfmu.load_scene(path))
    proc = subprocess.run([sys.executable, "-m", "mbdfmu", "check", str(path)],
                          capture_output=True, text=True, timeout=60)
    assert proc.returncode == 2 and "p.toml: simulation: method" in proc.stderr


def test_defaults_come_from_one_place_and_reach_the_integrator():
    settings = SolverSettings()
    assert (settings.method, settings.rtol, settings.atol) == ("auto", 1e-6, 1e-8)
    for name, cls in METHODS.items():
        sim = mbdfmu.Simulation(mbdfmu.load_scene("pendulum"), method=name)
        # a fixed-step method's step states the accuracy wanted: it keeps a loose one
        expected = (1e-6, 1e-8) if cls.adaptive else (1e-3, 1e-5)
        assert (sim.integrator.rtol, sim.integrator.atol) == expected, name
        if cls.adaptive:
            assert sim.integrator.max_step == math.inf
        else:
            assert sim.integrator.h == cls.default_step
    sim = mbdfmu.Simulation(mbdfmu.load_scene("pendulum"), method="rk4p", step=2e-3)
    assert sim.integrator.h == 2e-3


def test_a_tight_rtol_is_not_capped_by_the_default_atol():
    # atol not given follows rtol down (at most rtol / 100); a given atol is kept
    sim = mbdfmu.Simulation(mbdfmu.load_scene("pendulum"), method="dop853p", rtol=1e-10)
    assert (sim.integrator.rtol, sim.integrator.atol) == (1e-10, 1e-12)
    sim = mbdfmu.Simulation(mbdfmu.load_scene("pendulum"), method="dop853p", rtol=1e-10,
                            atol=1e-9)
    assert sim.integrator.atol == 1e-9
    sim = mbdfmu.Simulation(mbdfmu.load_scene("pendulum"), method="rk4p", rtol=1e-7)
    assert (sim.integrator.rtol, sim.integrator.atol) == (1e-7, 1e-9)
