"""Cost of a doStep of the slider-crank FMU in fmpy against the solver called directly, and
the FMU's real-time factor.

Both run the same communication steps (1 ms by default) with the same method (the scene's
default, ``auto``, at its default tolerance) and the same constraint kernel; the FMU run also
reads every output after each step, as a master does. Times are process CPU time, the
fastest of several interleaved repetitions (alternating which goes first) in one run; the
ratio is what to compare across machines.
The real-time factor is simulated time over wall-clock time of ``fmpy.simulate_fmu`` (the
whole fmpy loop, output recording included) at the same communication step.

Kernels: FMUs run the numpy kernel unless ``MBDFMU_KERNEL`` says otherwise (numba would
recompile in every fresh extraction), so ``--kernel numpy`` (default) is what users get;
``--kernel numba`` sets ``MBDFMU_KERNEL=numba`` for the FMU and the direct run alike.

    python benchmarks/fmu_overhead.py [--kernel numpy|numba] [--step 1e-3] [--t-end 0.5]
                                      [--repeat 15] [-o DIR]

Writes ``fmu_overhead_<kernel>.md`` and ``.png`` into DIR (default docs/figures/performance).
"""

from __future__ import annotations

import os

for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import argparse  # noqa: E402
import tempfile  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

import matplotlib  # noqa: E402

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
from fmpy import extract, read_model_description, simulate_fmu  # noqa: E402
from fmpy.fmi2 import FMU2Slave  # noqa: E402

import mbdfmu  # noqa: E402
from mbdfmu.fmu_build.scene_fmu import build_fmu  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]


def run_direct(scene, times, kernel):
    sim = mbdfmu.Simulation(scene, kernel=kernel)
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


def real_time_factor(fmu_path, t_end, step):
    """Simulated seconds per wall-clock second of fmpy's own simulation loop."""
    t0 = time.perf_counter()
    simulate_fmu(fmu_path, stop_time=t_end, output_interval=step)
    return t_end / (time.perf_counter() - t0)


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--kernel", choices=("numpy", "numba"), default="numpy")
    parser.add_argument("--step", type=float, default=1e-3)
    parser.add_argument("--t-end", type=float, default=0.5)
    parser.add_argument("--repeat", type=int, default=15)
    parser.add_argument("-o", "--output", default=str(ROOT / "docs" / "figures" / "performance"))
    args = parser.parse_args(argv)
    os.environ["MBDFMU_KERNEL"] = args.kernel      # read by the FMU at instantiation
    scene_path = ROOT / "scenes" / "slider_crank.toml"
    scene = mbdfmu.load_scene(scene_path)
    n = int(round(args.t_end / args.step))
    times = np.arange(n + 1) * args.step
    with tempfile.TemporaryDirectory() as tmp:
        fmu_path = str(build_fmu(scene_path, output=Path(tmp) / "SliderCrank.fmu"))
        run_fmu(fmu_path, times[:3])                # warm-up: imports, numba cache
        direct, fmu, rtf = [], [], []
        for k in range(args.repeat):  # interleaved, in alternating order: load hits both alike
            if k % 2:
                f, last_fmu = run_fmu(fmu_path, times)
                d, last_direct = run_direct(scene, times, args.kernel)
            else:
                d, last_direct = run_direct(scene, times, args.kernel)
                f, last_fmu = run_fmu(fmu_path, times)
            direct.append(d)
            fmu.append(f)
            rtf.append(real_time_factor(fmu_path, args.t_end, args.step))
    sim = mbdfmu.Simulation(scene, kernel=args.kernel)
    names = sim.output_names
    selected = [names.index(v) for v in sim.output_names
                if v.split(".")[0] in {b.name for b in scene.bodies}
                | {j.name for j in scene.joints} | {d.name for d in scene.drivers}]
    agree = np.max(np.abs(last_direct[selected] - last_fmu)) if len(selected) == len(last_fmu) else float("nan")
    # the fastest repetition of each: load on a shared machine only ever adds time
    d_step = min(direct) / n * 1e3
    f_step = min(fmu) / n * 1e3
    overhead = 100 * (f_step / d_step - 1)
    lines = [f"slider-crank, {n} communication steps of {args.step * 1e3:g} ms, method "
             f"{sim.method_name}, kernel {args.kernel}, fastest of {args.repeat} (CPU time; "
             f"`python benchmarks/fmu_overhead.py --kernel {args.kernel} --repeat {args.repeat}`)",
             "",
             "| run | ms per step | ratio |", "|---|---|---|",
             f"| solver directly (Simulation.advance + outputs) | {d_step:.3f} | 1.00 |",
             f"| FMU in fmpy (doStep + getReal of {len(last_fmu)} outputs) | {f_step:.3f} | "
             f"{f_step / d_step:.3f} |", "",
             f"FMU overhead: {overhead:+.1f} % (target: under 10 %); largest difference of "
             f"final outputs: {agree:.2g}; per step the FMU adds "
             f"{(f_step - d_step) * 1e3:.0f} µs.",
             f"Real-time factor in fmpy.simulate_fmu: {max(rtf):.2f} (best of {len(rtf)}) "
             f"(simulated s per wall-clock s; above 1 is faster than real time).", ""]
    print("\n".join(lines))
    out = Path(args.output)
    out.mkdir(parents=True, exist_ok=True)
    (out / f"fmu_overhead_{args.kernel}.md").write_text("\n".join(lines))
    fig, ax = plt.subplots(figsize=(6, 3))
    ax.barh(["solver directly", "FMU in fmpy"], [d_step, f_step], color=["C0", "C1"])
    ax.set_xlabel(f"CPU time per {args.step * 1e3:g} ms communication step (ms)")
    ax.set_title(f"FMU overhead, slider-crank, {args.kernel} kernel: {overhead:+.1f} %")
    fig.tight_layout()
    fig.savefig(out / f"fmu_overhead_{args.kernel}.png", dpi=110)
    print(out / f"fmu_overhead_{args.kernel}.png")


if __name__ == "__main__":
    main()
