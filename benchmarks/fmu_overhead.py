"""Cost of a doStep of the slider-crank FMU in fmpy against the solver called directly.

Both run the same communication steps (1 ms by default) with the same method; the FMU run
also reads every output after each step, as a master does. Times are process CPU time, the
median of several repetitions, measured in one run; the ratio is what to compare across
machines.

    python benchmarks/fmu_overhead.py [--step 1e-3] [--t-end 0.2] [--repeat 5] [-o DIR]
"""

from __future__ import annotations

import argparse
import statistics
import tempfile
import time
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
from fmpy import extract, read_model_description  # noqa: E402
from fmpy.fmi2 import FMU2Slave  # noqa: E402

import mbdfmu  # noqa: E402
from fmu_build.build import build_fmu  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]


def run_direct(scene, times):
    sim = mbdfmu.Simulation(scene)
    t0 = time.process_time()
    for t in times[1:]:
        sim.advance(t)
        sim.output_vector()
    return time.process_time() - t0, sim.output_vector()


def run_fmu(fmu_path, times):
    md = read_model_description(fmu_path)
    unzipped = extract(fmu_path)
    slave = FMU2Slave(guid=md.guid, unzipDirectory=unzipped,
                      modelIdentifier=md.coSimulation.modelIdentifier, instanceName="bench")
    outputs = [v.valueReference for v in md.modelVariables if v.causality == "output"]
    slave.instantiate()
    slave.setupExperiment(startTime=0.0)
    slave.enterInitializationMode()
    slave.exitInitializationMode()
    t0 = time.process_time()
    for t, h in zip(times[:-1], np.diff(times)):
        slave.doStep(currentCommunicationPoint=t, communicationStepSize=h)
        values = slave.getReal(outputs)
    elapsed = time.process_time() - t0
    slave.terminate()
    slave.freeInstance()
    return elapsed, np.array(values)


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--step", type=float, default=1e-3)
    parser.add_argument("--t-end", type=float, default=0.2)
    parser.add_argument("--repeat", type=int, default=5)
    parser.add_argument("-o", "--output", default=str(ROOT / "docs" / "figures"))
    args = parser.parse_args(argv)
    scene_path = ROOT / "scenes" / "slider_crank.toml"
    scene = mbdfmu.load_scene(scene_path)
    n = int(round(args.t_end / args.step))
    times = np.arange(n + 1) * args.step
    with tempfile.TemporaryDirectory() as tmp:
        fmu_path = str(build_fmu(scene_path, output=Path(tmp) / "SliderCrank.fmu"))
        direct, fmu = [], []
        for _ in range(args.repeat):  # interleaved, so load changes hit both alike
            d, last_direct = run_direct(scene, times)
            f, last_fmu = run_fmu(fmu_path, times)
            direct.append(d)
            fmu.append(f)
    sim = mbdfmu.Simulation(scene)
    names = [v.name for v in sim.system.outputs]
    selected = [names.index(v.name) for v in sim.system.outputs
                if v.name.split(".")[0] in {b.name for b in scene.bodies}
                | {j.name for j in scene.joints} | {d.name for d in scene.drivers}]
    agree = np.max(np.abs(last_direct[selected] - last_fmu)) if len(selected) == len(last_fmu) else float("nan")
    d_step = statistics.median(direct) / n * 1e3
    f_step = statistics.median(fmu) / n * 1e3
    print(f"slider-crank, {n} communication steps of {args.step * 1e3:g} ms, method "
          f"{sim.method.name}, median of {args.repeat} (CPU time)")
    print(f"| run | ms per step | ratio |\n|---|---|---|")
    print(f"| solver directly (Simulation.advance + outputs) | {d_step:.3f} | 1.00 |")
    print(f"| FMU in fmpy (doStep + getReal of {len(last_fmu)} outputs) | {f_step:.3f} | "
          f"{f_step / d_step:.3f} |")
    print(f"FMU overhead: {100 * (f_step / d_step - 1):+.1f} %; "
          f"largest difference of final outputs: {agree:.2g}")
    out = Path(args.output)
    out.mkdir(parents=True, exist_ok=True)
    fig, ax = plt.subplots(figsize=(6, 3))
    ax.barh(["solver directly", "FMU in fmpy"], [d_step, f_step], color=["C0", "C1"])
    ax.set_xlabel("CPU time per 1 ms communication step (ms)")
    ax.set_title(f"FMU overhead on the slider-crank: {100 * (f_step / d_step - 1):+.1f} %")
    fig.tight_layout()
    fig.savefig(out / "fmu_overhead.png", dpi=110)
    print(out / "fmu_overhead.png")


if __name__ == "__main__":
    main()
