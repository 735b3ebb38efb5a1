"""The command line end to end: demo, check, simulate with an input table, plot, animate."""

import subprocess
import sys

import numpy as np
import pytest

import mbdfmu
from mbdfmu.cli import main

from conftest import SCENES


def test_demo_builds_runs_and_writes_csv_plot_and_animation(tmp_path, capsys):
    assert main(["demo", "-o", str(tmp_path)]) == 0
    printed = capsys.readouterr().out
    for name in ("SliderCrank.fmu", "slider_crank.csv", "slider_crank.png", "slider_crank.gif"):
        assert (tmp_path / name).stat().st_size > 0 and name in printed
    result = mbdfmu.read_csv(tmp_path / "slider_crank.csv")
    # P4: the slider runs between l - r and l + r (0.2 .. 0.4 m).
    assert result["slider.x"].max() == pytest.approx(0.4, abs=1e-6)
    assert result["slider.x"].min() == pytest.approx(0.2, abs=2e-4)


def test_check_prints_structure_dof_and_redundancy(capsys):
    assert main(["check", str(SCENES / "parallelogram.toml")]) == 0
    out = capsys.readouterr().out
    assert "degrees of freedom 1" in out and "redundant constraints: joint" in out
    assert main(["check", str(SCENES / "slider_crank.toml")]) == 0
    out = capsys.readouterr().out
    assert "degrees of freedom 0" in out and "redundant constraints: none" in out


def test_simulate_with_a_driver_input_table_reproduces_the_prescribed_motion(tmp_path):
    # The slider-crank with its motor position read from a CSV: theta = 50 t^2 (smooth).
    text = (SCENES / "slider_crank.toml").read_text().replace(
        'motion = { type = "linear", start = 0.0, rate = 314.1592653589793 }',
        'motion = { type = "input" }')
    scene = tmp_path / "sc.toml"
    scene.write_text(text)
    t = np.linspace(0, 0.2, 201)
    table = tmp_path / "in.csv"
    np.savetxt(table, np.column_stack((t, 50 * t**2)), delimiter=",",
               header="time,motor.position", comments="")
    out = tmp_path / "out.csv"
    assert main(["simulate", str(scene), "--t-end", "0.2", "--input", str(table),
                 "--output-interval", "0.01", "--out", str(out)]) == 0
    result = mbdfmu.read_csv(out)
    np.testing.assert_allclose(result["crank.phi"], 50 * result.time**2, atol=1e-9)
    np.testing.assert_allclose(result["crank.omega"], 100 * result.time, atol=1e-6)


def test_unknown_input_column_is_an_error(tmp_path, capsys):
    table = tmp_path / "in.csv"
    table.write_text("time,motor.positon\n0,0\n1,1\n")
    code = main(["simulate", str(SCENES / "pendulum_torque.toml"), "--t-end", "0.1",
                 "--input", str(table), "--out", str(tmp_path / "o.csv")])
    assert code == 2
    assert 'unknown input "motor.positon"' in capsys.readouterr().err


def test_plot_and_animate(tmp_path):
    result = mbdfmu.simulate(mbdfmu.load_scene(SCENES / "double_pendulum.toml"), 1.0)
    csv = result.to_csv(tmp_path / "r.csv")
    assert main(["plot", str(csv), "bob*.x", "-o", str(tmp_path / "p.png")]) == 0
    assert main(["animate", str(SCENES / "double_pendulum.toml"), str(csv),
                 "-o", str(tmp_path / "a.gif")]) == 0
    from PIL import Image
    with Image.open(tmp_path / "a.gif") as gif:
        assert gif.n_frames > 50


def test_version_and_help_list_the_methods():
    proc = subprocess.run([sys.executable, "-m", "mbdfmu.cli", "simulate", "--help"],
                          capture_output=True, text=True)
    assert proc.returncode == 0
    for name in mbdfmu.METHODS:
        assert name in proc.stdout
