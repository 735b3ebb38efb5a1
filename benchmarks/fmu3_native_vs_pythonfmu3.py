"""FMI 3.0 export: the native wrapper (fmu_build/native/fmi3.c) against pythonfmu3, on the
same toy model, in the hosts that matter.

Both FMUs are the damped mass-spring of tests/fmu_models (x, v outputs, force input);
pythonfmu3's also has an array parameter ``gains`` (FMI 3.0 arrays are its selling point),
and a second pythonfmu3 build of it has scalars only.
For each runtime: fmpy's validation, a run in fmpy against the closed form, a run in
ecospy (in a fresh process), Ecos' command line (C++, no Python inside) from a clean
environment ``--runs`` times (exit statuses), setting the array parameter (pythonfmu3
only), a serialized state restored and stepped again, and the cost per call through fmpy's FMU3Slave (fastest of
``--repeats`` x ``--calls``, the runtimes alternating).

    python benchmarks/fmu3_native_vs_pythonfmu3.py [--runs 20] [--calls 3000] [--repeats 5] [-o DIR]

Prints one table of findings and one of costs, writes fmu3_native_vs_pythonfmu3.csv in DIR.
Needs pythonfmu3 (``pip install pythonfmu3``), ecospy and a C compiler.
"""

from __future__ import annotations

import argparse
import importlib
import csv
import math
import subprocess
import sys
import tempfile
import time
from collections import Counter
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path[:0] = [str(ROOT), str(ROOT / "tests")]

PYTHONFMU3_SOURCE = '''
import math
import numpy as np
from pythonfmu3 import Dimension, Fmi3Causality, Fmi3Initial, Fmi3Slave, Fmi3Variability, Float64


#TRANSITION#


class MassSpringPy3(Fmi3Slave):
    author = "mbdfmu benchmarks"
    description = "The toy mass-spring on pythonfmu3"

    def __init__(self, **kwargs):
        super().__init__(**kwargs)
        self.m, self.k, self.c, self.x0, self.v0, self.F = 2.0, 50.0, 1.0, 0.1, 0.0, 0.5
        self.x, self.v, self.time = self.x0, self.v0, 0.0
        self.gains = np.array([1.0, 1.0])
        self.register_variable(Float64("time", causality=Fmi3Causality.independent,
                                       variability=Fmi3Variability.continuous))
        for name in ("m", "k", "c", "x0", "v0"):
            self.register_variable(Float64(name, causality=Fmi3Causality.parameter,
                                           variability=Fmi3Variability.fixed,
                                           start=getattr(self, name)))
        self.register_variable(Float64("gains", causality=Fmi3Causality.parameter,
                                       variability=Fmi3Variability.tunable, start=[1.0, 1.0],
                                       dimensions=[Dimension(start="2")]))
        self.register_variable(Float64("F", causality=Fmi3Causality.input, start=self.F))
        self.register_variable(Float64("x", causality=Fmi3Causality.output,
                                       initial=Fmi3Initial.exact, start=self.x0))
        self.register_variable(Float64("v", causality=Fmi3Causality.output,
                                       initial=Fmi3Initial.exact, start=self.v0))

    def exit_initialization_mode(self):
        self.state = np.array([self.x0, self.v0])

    def do_step(self, current_time, step_size):
        rest = np.array([self.F / self.k, 0.0])
        self.state = transition(self.m, self.k, self.c, step_size) @ (self.state - rest) + rest
        self.x, self.v = float(self.state[0]), float(self.state[1])
        self.time = current_time + step_size
        return True
'''
# the toy's own exact step, so both runtimes step the same model
PYTHONFMU3_SOURCE = PYTHONFMU3_SOURCE.replace(
    "#TRANSITION#", importlib.import_module("fmu_models.toy").transition_source())

RUN_ECOSPY = '''
import sys
from ecospy.EcosSimulation import EcosSimulation
from ecospy.EcosSimulationStructure import EcosSimulationStructure
structure = EcosSimulationStructure()
structure.add_model("a", sys.argv[1])
simulation = EcosSimulation(structure=structure, step_size=0.01)
simulation.init()
simulation.step(100)
print(simulation.get_real("a::x"))
simulation.terminate()
simulation.free()
'''


# The same pythonfmu3 model without its array parameter.
SCALAR_ONLY = PYTHONFMU3_SOURCE.replace("class MassSpringPy3(", "class MassSpringPy3Scalars(") \
    .replace('''        self.register_variable(Float64("gains", causality=Fmi3Causality.parameter,
                                       variability=Fmi3Variability.tunable, start=[1.0, 1.0],
                                       dimensions=[Dimension(start="2")]))
''', "")


def build_all(folder: Path) -> dict[str, Path]:
    from pythonfmu3.builder import FmuBuilder

    from fmu_models.toy import IDENTIFIER, SOURCE, VARIABLES
    from mbdfmu.fmu_build.package import write_fmu
    built = {}
    for name, text in (("pythonfmu3", PYTHONFMU3_SOURCE), ("pythonfmu3, scalars", SCALAR_ONLY)):
        script = folder / f"mass_spring_py3{len(built)}.py"
        script.write_text(text)
        built[name] = Path(FmuBuilder.build_FMU(script, dest=folder))
    native = write_fmu(folder / f"{IDENTIFIER}3.fmu", IDENTIFIER, VARIABLES, SOURCE.read_text(),
                       cache_dir=folder / "cache", fmi_version=3)
    return {"native fmi3.c": native, **built}


def open_slave(path: Path):
    from fmpy import extract, read_model_description
    from fmpy.fmi3 import FMU3Slave
    md = read_model_description(str(path))
    fmu = FMU3Slave(guid=md.guid, unzipDirectory=extract(str(path)),
                    modelIdentifier=md.coSimulation.modelIdentifier, instanceName="bench")
    fmu.instantiate()
    fmu.enterInitializationMode(startTime=0.0)
    fmu.exitInitializationMode()
    return fmu, {v.name: v.valueReference for v in md.modelVariables}


def closed_form_error(path: Path) -> float:
    from fmu_models.toy import closed_form
    fmu, vr = open_slave(path)
    worst = 0.0
    for k in range(100):
        fmu.doStep(k * 0.01, 0.01)
        x, v = fmu.getFloat64([vr["x"], vr["v"]])
        worst = max(worst, abs(x - closed_form((k + 1) * 0.01)[0]))
    fmu.terminate()
    fmu.freeInstance()
    return worst


def array_parameter(path: Path) -> str:
    """Set the 2-element array parameter (pythonfmu3's FMU only): 'ok' or the failure."""
    fmu, vr = open_slave(path)
    if "gains" not in vr:
        return "no array variables (scalars only)"
    try:
        fmu.setFloat64([vr["gains"]], [2.0, 3.0])
        return "ok"
    except Exception as exc:  # noqa: BLE001 - the finding is the failure
        return f"{type(exc).__name__}: {exc}"


def state_replay(path: Path) -> str:
    """Take the state at t = 0.1 s, run 10 steps, restore (through serialized bytes), run
    them again: does x at 0.2 s repeat?"""
    fmu, vr = open_slave(path)
    for k in range(10):
        fmu.doStep(k * 0.01, 0.01)
    blob = bytes(fmu.serializeFMUState(fmu.getFMUState()))
    ends = []
    for _ in range(2):
        for k in range(10, 20):
            fmu.doStep(k * 0.01, 0.01)
        ends.append(fmu.getFloat64([vr["x"]])[0])
        try:
            fmu.setFMUState(fmu.deserializeFMUState(blob))
        except Exception as exc:  # noqa: BLE001 - the finding is the failure
            return f"{len(blob)} bytes; restoring it: {exc}"
    same = "replays exactly" if ends[0] == ends[1] else f"differs by {abs(ends[0] - ends[1]):.1e}"
    return f"{len(blob)} bytes ({blob[:8]!r}...): {same}"


def ecospy_run(path: Path) -> str:
    run = subprocess.run([sys.executable, "-c", RUN_ECOSPY, str(path)], capture_output=True,
                         text=True, timeout=120)
    return f"exit {run.returncode}" + (f", x(1) = {float(run.stdout.split()[-1]):.6g}"
                                       if run.returncode == 0 and run.stdout.split() else "")


def ecos_cli_runs(path: Path, work: Path, runs: int) -> str:
    from fmu_models import hosts
    work.mkdir(parents=True, exist_ok=True)
    ecos = hosts.ecos_cli(work)
    codes = Counter()
    last = ""
    for _ in range(runs):
        run = hosts.run_ecos_cli(ecos, path, work, 0.1, 0.01)
        codes[run.returncode] += 1
        last = (run.stdout + run.stderr).strip().splitlines()[-1:] or [""]
    return ", ".join(f"exit {c}: {n}" for c, n in sorted(codes.items())) + \
        (f" ({last[0][:80]})" if set(codes) != {0} else "")


def costs(fmus: dict[str, Path], n: int, repeats: int) -> list[dict]:
    opened = {name: open_slave(path) for name, path in fmus.items()}
    clocks = {name: [0.0] for name in fmus}

    def calls(name):
        fmu, vr = opened[name]

        def step():
            fmu.doStep(clocks[name][0], 1e-4)
            clocks[name][0] += 1e-4
        return {"doStep": step, "getFloat64 x": lambda: fmu.getFloat64([vr["x"]]),
                "setFloat64 F": lambda: fmu.setFloat64([vr["F"]], [0.5])}
    timed = {name: calls(name) for name in fmus}
    best = {name: {c: math.inf for c in timed[name]} for name in fmus}
    for _ in range(repeats):
        for call in next(iter(timed.values())):
            for name in fmus:
                start = time.perf_counter()
                for _ in range(n):
                    timed[name][call]()
                best[name][call] = min(best[name][call], (time.perf_counter() - start) / n * 1e6)
    return [{"runtime": name, **figures} for name, figures in best.items()]


def main(argv=None) -> int:
    from fmpy.validation import validate_fmu
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--runs", type=int, default=20)
    parser.add_argument("--calls", type=int, default=3000)
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("-o", "--out", type=Path, default=None)
    args = parser.parse_args(argv)
    out = args.out or Path(tempfile.mkdtemp(prefix="fmu3_"))
    out.mkdir(parents=True, exist_ok=True)
    fmus = build_all(out)
    findings = []
    for name, path in fmus.items():
        findings.append({
            "runtime": name, "fmpy validate": "; ".join(validate_fmu(str(path))) or "no problems",
            "fmpy vs closed form": f"{closed_form_error(path):.1e}",
            "array parameter": array_parameter(path), "state round trip": state_replay(path),
            "ecospy": ecospy_run(path),
            f"Ecos CLI, clean env, {args.runs} runs": ecos_cli_runs(path, out / name.split()[0], args.runs)})
        print(findings[-1], flush=True)
    rows = costs({k: fmus[k] for k in ("native fmi3.c", "pythonfmu3, scalars")}, args.calls,
                 args.repeats)
    with open(out / "fmu3_native_vs_pythonfmu3.csv", "w", newline="") as f:
        writer = csv.DictWriter(f, fieldnames=list(findings[0]) + list(rows[0])[1:])
        writer.writeheader()
        cost = {r["runtime"]: r for r in rows}
        writer.writerows({**a, **cost.get(a["runtime"], {})} for a in findings)
    keys = list(findings[0])
    print("| " + " | ".join(keys) + " |\n|" + "---|" * len(keys))
    for row in findings:
        print("| " + " | ".join(str(row[k]) for k in keys) + " |")
    print(f"\nus per call through fmpy's FMU3Slave, fastest of {args.repeats} x {args.calls}")
    for row in rows:
        print(f"{row['runtime']:<22}" + "".join(f"{k}: {v:.2f}  " for k, v in row.items()
                                                  if k != "runtime"))
    return 0


if __name__ == "__main__":
    sys.exit(main())
