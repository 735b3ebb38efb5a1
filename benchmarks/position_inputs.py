"""The driver effort's error against the communication step when a master gives a driver's
position samples only, and when it gives position, velocity and acceleration (issue 12).

The slider-crank of ``scenes/slider_crank.toml`` with its motor as an input, driven by
phi = A sin(2 pi F t) (A = 1 rad, F = 1 Hz, from rest), set once per communication step as
an FMU's master sets it: ``Simulation.set_input`` then ``advance(t + h)``. The exact effort
is the same scene with the motion given analytically (a ``harmonic`` driver). Errors are
the largest over one period after the first three steps (the history filling), relative
to the exact effort's largest magnitude; "range" is the effort's range against the exact.

    python benchmarks/position_inputs.py [-o FILE]

Prints a markdown table (and writes it to FILE if given).
"""

from __future__ import annotations

import argparse
import math
import tempfile
from pathlib import Path

import numpy as np

import mbdfmu
from mbdfmu.simulation import input_warnings

ROOT = Path(__file__).resolve().parents[1]
LINEAR_MOTOR = 'motion = { type = "linear", start = 0.0, rate = 314.1592653589793 }'
AMPLITUDE, FREQUENCY = 1.0, 1.0
STEPS = (1e-3, 5e-3, 1e-2, 2e-2, 5e-2)


def scene(motion: str, folder: Path):
    """The slider-crank with another motor motion, starting from rest (assembly sets the
    velocities the motion needs)."""
    text = (ROOT / "scenes" / "slider_crank.toml").read_text()
    text = (text.replace(LINEAR_MOTOR, f"motion = {motion}")
                .replace("angular_velocity = 314.1592653589793", "angular_velocity = 0.0")
                .replace("velocity = [0.0, 15.707963267948966]", "velocity = [0.0, 0.0]"))
    path = folder / f"slider_crank_{abs(hash(motion))}.toml"
    path.write_text(text)
    return mbdfmu.load_scene(path)


def efforts(h: float, full: bool, folder: Path, t_end: float = 1.0 / FREQUENCY):
    """Effort at every communication point: driven by samples, and exact."""
    w = 2 * math.pi * FREQUENCY
    sim = mbdfmu.Simulation(scene('{ type = "input" }', folder))
    ref = mbdfmu.Simulation(scene(f'{{ type = "harmonic", offset = 0.0, amplitude = '
                                  f'{AMPLITUDE}, frequency = {FREQUENCY} }}', folder))
    got, exact, warnings = [], [], []
    for k in range(round(t_end / h)):
        t = k * h
        sim.set_input("motor.position", AMPLITUDE * math.sin(w * t))
        if full:
            sim.set_input("motor.velocity", AMPLITUDE * w * math.cos(w * t))
            sim.set_input("motor.acceleration", -AMPLITUDE * w * w * math.sin(w * t))
        sim.advance((k + 1) * h)
        ref.advance((k + 1) * h)
        warnings += input_warnings(sim)
        got.append(sim.outputs()["motor.effort"])
        exact.append(ref.outputs()["motor.effort"])
    return np.array(got[3:]), np.array(exact[3:]), warnings


def main(argv=None) -> str:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("-o", "--output", type=Path)
    args = parser.parse_args(argv)
    rows = ["| h (ms) | inputs | effort error | effort range (N m) | exact range (N m) | "
            "warnings |", "|---|---|---|---|---|---|"]
    with tempfile.TemporaryDirectory() as tmp:
        for h in STEPS:
            for full in (False, True):
                got, exact, warnings = efforts(h, full, Path(tmp))
                err = np.abs(got - exact).max() / np.abs(exact).max()
                rows.append(f"| {h * 1e3:g} | {'full' if full else 'position'} | {err:.2e} | "
                            f"{got.min():.4f} .. {got.max():.4f} | "
                            f"{exact.min():.4f} .. {exact.max():.4f} | {len(warnings)} |")
    table = "\n".join(rows)
    print(table)
    if args.output:
        args.output.write_text(table + "\n")
    return table


if __name__ == "__main__":
    main()
