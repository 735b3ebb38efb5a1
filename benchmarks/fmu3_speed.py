"""FMI 2.0 and FMI 3.0 FMUs of the same mechanisms in fmpy, in one run: the real-time
factor at a 1 ms communication step, default settings (benchmarks/fmu_speed.py's warm
fmpy loop: doStep + get of every output, + set of the input where there is one).

Cases: fmu_speed.py's slider-crank (P4), P2 N = 2 and the crane's mechanism (its actuator
force set by the master before every step). Each FMU is built once in each version; each
measurement is ``FMU2Slave`` or ``FMU3Slave`` in this process, initialized, 20 steps, then
``--t-end`` simulated seconds timed; the versions interleaved, best of ``--repeat``.

    python benchmarks/fmu3_speed.py [--t-end 1.0] [--repeat 3] [-o DIR]

Writes ``fmu3_speed.md`` into DIR (default docs/figures/performance).
"""

from __future__ import annotations

import os

for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import argparse  # noqa: E402
import sys  # noqa: E402
import tempfile  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

from fmpy import extract, read_model_description  # noqa: E402
from fmpy.fmi2 import FMU2Slave  # noqa: E402
from fmpy.fmi3 import FMU3Slave  # noqa: E402

from mbdfmu.fmu_build.scene_fmu import build_fmu  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "benchmarks"))
from fmu_speed import CASES, actuator, input_of  # noqa: E402

H = 1e-3


class Run:
    """One warm instance of an FMI 2.0 or 3.0 FMU in fmpy."""

    def __init__(self, fmu: Path, case: str, version: int):
        md = read_model_description(fmu)
        cls = FMU3Slave if version == 3 else FMU2Slave
        self.slave = s = cls(guid=md.guid, unzipDirectory=extract(fmu), instanceName="warm",
                             modelIdentifier=md.coSimulation.modelIdentifier)
        self.outputs = [v.valueReference for v in md.modelVariables if v.causality == "output"]
        names = {v.name: v.valueReference for v in md.modelVariables}
        self.input = names[input_of(case)] if input_of(case) else None
        self.get, self.set = (s.getFloat64, s.setFloat64) if version == 3 else \
            (s.getReal, s.setReal)
        self.t = 0.0
        s.instantiate()
        if version == 3:
            s.enterInitializationMode(startTime=0.0)
        else:
            s.setupExperiment(startTime=0.0)
            s.enterInitializationMode()
        s.exitInitializationMode()
        self.steps(20)

    def steps(self, n: int) -> None:
        s, get, set_, outputs, vr = self.slave, self.get, self.set, self.outputs, self.input
        for _ in range(n):
            if vr is not None:
                set_([vr], [actuator(self.t)])
            s.doStep(self.t, H)
            self.t += H
            get(outputs)

    def timed(self, n: int) -> float:
        """Wall s per communication step."""
        w = time.perf_counter()
        self.steps(n)
        return (time.perf_counter() - w) / n

    def free(self) -> None:
        self.slave.terminate()
        self.slave.freeInstance()


def measure(fmus: dict, t_end: float, repeat: int) -> dict:
    """(case, version) -> best wall s per 1 ms step."""
    n, best = max(1, round(t_end / H)), {}
    for _ in range(repeat):
        for key, fmu in fmus.items():
            run = Run(fmu, key[0], key[1])
            best[key] = min(best.get(key, float("inf")), run.timed(n))
            run.free()
    return best


def markdown(best: dict, args) -> str:
    lines = [f"`python benchmarks/fmu3_speed.py --t-end {args.t_end:g} --repeat {args.repeat}`"
             f": fmpy, 1 ms communication step, default settings, best of {args.repeat}; "
             "wall µs per step (doStep + get of the outputs, + set of the input), the "
             "real-time factor in brackets.", "",
             "| case | FMI 2.0 µs/step (RTF) | FMI 3.0 µs/step (RTF) | FMI 3.0 / FMI 2.0 |",
             "|---|---|---|---|"]
    for case in CASES:
        if (case, 2) not in best:
            continue
        two, three = best[(case, 2)], best[(case, 3)]
        lines.append(f"| {case} | {two * 1e6:.1f} ({H / two:.1f}) | {three * 1e6:.1f} "
                     f"({H / three:.1f}) | {three / two:.2f} |")
    return "\n".join(lines) + "\n"


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--t-end", type=float, default=1.0, help="simulated s per run")
    parser.add_argument("--repeat", type=int, default=3)
    parser.add_argument("-o", "--output", default=str(ROOT / "docs" / "figures" / "performance"))
    args = parser.parse_args(argv)
    cases = [c for c in CASES if c != "P1 pendulum"]
    with tempfile.TemporaryDirectory() as tmp:
        fmus = {(case, v): build_fmu(CASES[case], output=Path(tmp) / f"case{k}_{v}.fmu",
                                     fmi_version=v)
                for k, case in enumerate(cases) for v in (2, 3)}
        best = measure(fmus, args.t_end, args.repeat)
    text = markdown(best, args)
    print(text)
    out = Path(args.output)
    out.mkdir(parents=True, exist_ok=True)
    (out / "fmu3_speed.md").write_text(text)
    return 0


if __name__ == "__main__":
    sys.exit(main())
