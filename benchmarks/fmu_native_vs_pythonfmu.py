"""Cost per FMI call of the native wrapper against pythonfmu 0.7, on the same toy model.

Both FMUs are the damped mass-spring of tests/fmu_models (the same numpy step: a 2x2
transition matrix per step); only the FMU runtime differs. Each figure is the fastest of
``--repeats`` timings of ``--calls`` calls through fmpy's FMU2Slave in this one process
(the fastest is the least disturbed by the other work on a shared machine); the two
runtimes alternate within each repeat.

    python benchmarks/fmu_native_vs_pythonfmu.py [--calls 5000] [--repeats 7] [-o DIR]

Prints a table and writes fmu_native_vs_pythonfmu.csv in DIR (default: a temp folder).
Needs pythonfmu 0.7 (``pip install pythonfmu``) and a C compiler.
"""

from __future__ import annotations

import argparse
import importlib
import csv
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path[:0] = [str(ROOT), str(ROOT / "tests")]

from fmpy import extract, read_model_description  # noqa: E402
from fmpy.fmi2 import FMU2Slave  # noqa: E402

PYTHONFMU_SOURCE = '''
import math
import numpy as np
from pythonfmu import Fmi2Causality, Fmi2Initial, Fmi2Slave, Fmi2Variability, Real


#TRANSITION#


class MassSpringPy(Fmi2Slave):
    author = "mbdfmu benchmarks"
    description = "The toy mass-spring on pythonfmu"

    def __init__(self, **kwargs):
        super().__init__(**kwargs)
        self.m, self.k, self.c, self.x0, self.v0, self.F = 2.0, 50.0, 1.0, 0.1, 0.0, 0.5
        self.x, self.v = self.x0, self.v0
        for name in ("m", "k", "c", "x0", "v0"):
            self.register_variable(Real(name, causality=Fmi2Causality.parameter,
                                        variability=Fmi2Variability.fixed))
        self.register_variable(Real("F", causality=Fmi2Causality.input))
        self.register_variable(Real("x", causality=Fmi2Causality.output, initial=Fmi2Initial.exact))
        self.register_variable(Real("v", causality=Fmi2Causality.output, initial=Fmi2Initial.exact))

    def exit_initialization_mode(self):
        self.state = np.array([self.x0, self.v0])

    def do_step(self, current_time, step_size):
        rest = np.array([self.F / self.k, 0.0])
        self.state = transition(self.m, self.k, self.c, step_size) @ (self.state - rest) + rest
        self.x, self.v = float(self.state[0]), float(self.state[1])
        return True
'''
# the toy's own exact step, so both runtimes step the same model
PYTHONFMU_SOURCE = PYTHONFMU_SOURCE.replace(
    "#TRANSITION#", importlib.import_module("fmu_models.toy").transition_source())


def build_both(folder: Path) -> dict[str, Path]:
    """The toy FMU on each runtime."""
    from pythonfmu.builder import FmuBuilder

    from fmu_models.toy import build_toy
    script = folder / "mass_spring_py.py"
    script.write_text(PYTHONFMU_SOURCE)
    pythonfmu = Path(FmuBuilder.build_FMU(script, dest=folder))
    return {"native": build_toy(folder / "MassSpring.fmu", cache_dir=folder / "cache"),
            "pythonfmu": pythonfmu}


def open_slave(path: Path) -> tuple[FMU2Slave, dict[str, int]]:
    """An initialized instance of the FMU at ``path`` and its value references."""
    md = read_model_description(path)
    fmu = FMU2Slave(guid=md.guid, unzipDirectory=extract(path),
                    modelIdentifier=md.coSimulation.modelIdentifier, instanceName="bench")
    fmu.instantiate()
    fmu.setupExperiment(startTime=0.0)
    fmu.enterInitializationMode()
    fmu.exitInitializationMode()
    return fmu, {v.name: v.valueReference for v in md.modelVariables}


def calls(fmu: FMU2Slave, vr: dict[str, int]) -> dict:
    """The calls timed: name -> function doing one call."""
    clock = {"t": 0.0}

    def step():
        fmu.doStep(clock["t"], 1e-4)
        clock["t"] += 1e-4
    return {"doStep": step, "getReal x": lambda: fmu.getReal([vr["x"]]),
            "getReal x, v": lambda: fmu.getReal([vr["x"], vr["v"]]),
            "setReal F": lambda: fmu.setReal([vr["F"]], [0.5])}


def measure(fmus: dict[str, Path], n: int, repeats: int) -> list[dict]:
    """Microseconds per call, fastest of ``repeats``; the runtimes alternate within each
    repeat, so both see the same load of a shared machine."""
    opened = {name: open_slave(path) for name, path in fmus.items()}
    timed = {name: calls(*pair) for name, pair in opened.items()}
    best = {name: {call: float("inf") for call in timed[name]} for name in timed}
    for _ in range(repeats):
        for call in next(iter(timed.values())):
            for name in timed:
                function = timed[name][call]
                start = time.perf_counter()
                for _ in range(n):
                    function()
                best[name][call] = min(best[name][call], (time.perf_counter() - start) / n * 1e6)
    for fmu, _ in opened.values():
        fmu.terminate()
        fmu.freeInstance()
    return [{"runtime": name, **figures} for name, figures in best.items()]


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--calls", type=int, default=5000)
    parser.add_argument("--repeats", type=int, default=7)
    parser.add_argument("-o", "--out", type=Path, default=None)
    args = parser.parse_args(argv)
    out = args.out or Path(tempfile.mkdtemp(prefix="fmu_cost_"))
    out.mkdir(parents=True, exist_ok=True)
    fmus = build_both(out)
    rows = measure(fmus, args.calls, args.repeats)
    with open(out / "fmu_native_vs_pythonfmu.csv", "w", newline="") as f:
        writer = csv.DictWriter(f, fieldnames=list(rows[0]))
        writer.writeheader()
        writer.writerows(rows)
    print(f"us per call through fmpy, fastest of {args.repeats} x {args.calls} calls")
    print(f"{'runtime':<10}" + "".join(f"{k:>14}" for k in rows[0] if k != "runtime"))
    for row in rows:
        print(f"{row['runtime']:<10}" + "".join(f"{v:>14.2f}" for k, v in row.items() if k != "runtime"))
    print(f"written: {out / 'fmu_native_vs_pythonfmu.csv'}; FMUs: {', '.join(map(str, fmus.values()))}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
