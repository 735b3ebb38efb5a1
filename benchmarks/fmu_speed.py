"""What users run, in one run: the scene FMUs at their default settings stepped by fmpy and
by libcosimpy at 1 ms and 10 ms communication steps, cold and warm, against the solver
called directly and Exudyn's generalized-alpha on the same mechanism.

Cases: the slider-crank (P4), P2 N = 2 (scenes/n_four_bar_2.toml), the hydraulic crane's
mechanism (scenarios/hydraulic_crane/crane.toml, its actuator force set by the master at
every step as a connected input would: a hold force plus a swing), the same with ``auto``
and with rk4p in place of its scene's dop853p (``VARIANTS``), and P1 (the pendulum). Each
FMU is built as ``mbdfmu build`` builds it: with the C kernel built for its scene.

- cold: a fresh Python process extracts the FMU to a new folder (not timed), then
  ``FMU2Slave`` (the binary loaded), instantiate, setup, initialization and the first
  doStep are timed (wall clock); for libcosimpy, ``add_local_slave`` (it loads and
  instantiates) and the first step.
- warm, fmpy: ``FMU2Slave`` in this process, after 20 steps, a loop of doStep + getReal of
  every output (+ setReal of the input where there is one): wall and CPU time per
  communication step, and the real-time factor (simulated s per wall s); then doStep
  alone and getReal alone, to show each call's cost.
- warm, libcosimpy: ``execution.step(n)`` with a time-series observer on every output;
  then the same with the thread held to one core while the execution is made (its
  worker threads inherit that; ``mbdfmu.cosim.threads.one_core``): libcosim's fixed-step
  algorithm hands every step to a worker thread, and on an idle machine with a free core
  each handoff waits for that core's thread to wake, a cost of libcosim's own that one
  core does not have.
- direct: ``Simulation.advance`` + ``output_vector`` per communication step, kernel "c"
  (the FMU's) and "numpy" (what FMUs ran before).
- Exudyn (every case, ``exudyn_compare.exudyn_model``): CPU time per 1 ms step of
  ``SolveDynamic`` at h = 1 ms, best of ``--repeat``, against the FMU's CPU time per 1 ms
  step in fmpy (doStep + getReal + setReal), best of ``--repeat``, and by a minimal master
  calling the same FMI functions through ctypes (``ctypes_run``), and by a master written in
  C with no Python in its loop (``c_master.py``: what the FMU costs a C/C++ master such as
  libcosim's or an engine's; fmpy's Python around each call is fmpy's own cost). The crane's cylinder
  force in Exudyn: held constant (its favourable case), and set before every step by a
  pre-step user function (Python), as the master sets the FMU's input.

Each other warm figure is the median of ``--repeat`` runs, the runs interleaved.

    python benchmarks/fmu_speed.py [--t-end 1.0] [--repeat 3] [--quick] [-o DIR]

Writes ``fmu_speed.md``, ``fmu_speed.csv`` and ``fmu_speed.png`` into DIR (default
docs/figures/performance).
"""

from __future__ import annotations

import os

for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import argparse  # noqa: E402
import contextlib  # noqa: E402
import csv  # noqa: E402
import ctypes  # noqa: E402
import json  # noqa: E402
import math  # noqa: E402
import statistics  # noqa: E402
import subprocess  # noqa: E402
import sys  # noqa: E402
import tempfile  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402
from fmpy import extract, read_model_description  # noqa: E402
from fmpy.fmi2 import FMU2Slave  # noqa: E402

import mbdfmu  # noqa: E402
from mbdfmu.fmu_build.scene_fmu import build_fmu  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "benchmarks"))
from c_master import c_master_cpu, compile_master  # noqa: E402
CASES = {"slider-crank (P4)": ROOT / "scenes" / "slider_crank.toml",
         "P2 N = 2": ROOT / "scenes" / "n_four_bar_2.toml",
         "crane mechanism": ROOT / "scenarios" / "hydraulic_crane" / "crane.toml",
         "P1 pendulum": ROOT / "scenes" / "pendulum.toml"}
# Cases run on a variant of another's scene: the crane's mechanism with auto in place of
# its scene's dop853p (the FMU's default settings choosing, the master setting the force),
# and with rk4p (the wrapper's rk4p steps after each fmi2SetReal).
VARIANTS = {"crane mechanism, auto": ("crane mechanism", 'method = "dop853p"', 'method = "auto"'),
            "crane mechanism, rk4p": ("crane mechanism", 'method = "dop853p"', 'method = "rk4p"')}
STEPS = (1e-3, 1e-2)
HOLD = 8420.0                  # N: the cylinder force that about holds the crane's boom
SWING = 0.05                   # its relative swing, at 1 Hz


def actuator(t: float) -> float:
    """The crane's actuator force as the master sets it (N)."""
    return HOLD * (1.0 + SWING * math.sin(2.0 * math.pi * t))


def input_of(case: str) -> str | None:
    return "cylinder.actuator" if case.startswith("crane mechanism") else None


def scene_paths(folder: Path) -> dict:
    """Every case's scene file, in the order of the tables; the variants written into
    ``folder``."""
    paths = {}
    for case, path in CASES.items():
        paths[case] = path
        for variant, (base, old, new) in VARIANTS.items():
            if base == case:
                text = path.read_text()
                if old not in text:
                    raise SystemExit(f"{path}: no line {old!r} to vary for {variant!r}")
                paths[variant] = folder / f"variant{len(paths)}.toml"
                paths[variant].write_text(text.replace(old, new))
    return paths


# ------------------------------------------------------------------------------ cold

COLD_FMPY = """
import json, sys, time
from fmpy import extract, read_model_description
from fmpy.fmi2 import FMU2Slave
path, h = sys.argv[1], float(sys.argv[2])
md = read_model_description(path)
folder = extract(path)
t0 = time.perf_counter()
s = FMU2Slave(guid=md.guid, unzipDirectory=folder, instanceName="cold",
              modelIdentifier=md.coSimulation.modelIdentifier)
s.instantiate()
s.setupExperiment(startTime=0.0)
s.enterInitializationMode()
s.exitInitializationMode()
t1 = time.perf_counter()
s.doStep(0.0, h)
t2 = time.perf_counter()
print("RESULT", json.dumps({"instantiate_s": t1 - t0, "first_step_s": t2 - t1}))
"""

COLD_COSIM = """
import json, sys, time
from libcosimpy.CosimExecution import CosimExecution
from libcosimpy.CosimLogging import CosimLogLevel, log_output_level
from libcosimpy.CosimSlave import CosimLocalSlave
log_output_level(CosimLogLevel.ERROR)
path, h = sys.argv[1], float(sys.argv[2])
execution = CosimExecution.from_step_size(step_size=round(h * 1e9))
t0 = time.perf_counter()
index = execution.add_local_slave(CosimLocalSlave(fmu_path=path, instance_name="cold"))
t1 = time.perf_counter()
assert index >= 0 and execution.step(1)
t2 = time.perf_counter()
print("RESULT", json.dumps({"instantiate_s": t1 - t0, "first_step_s": t2 - t1}))
"""


def cold(script: str, fmu: Path, h: float) -> dict:
    """Instantiation and first step in a fresh process on a freshly extracted FMU."""
    run = subprocess.run([sys.executable, "-c", script, str(fmu), repr(h)],
                         capture_output=True, text=True, timeout=300)
    if run.returncode != 0:
        return {"error": (run.stderr.strip().splitlines() or ["failed"])[-1]}
    line = [x for x in run.stdout.splitlines() if x.startswith("RESULT ")][-1]
    return json.loads(line[len("RESULT "):])


# ------------------------------------------------------------------------------ warm

class FmpyRun:
    """One instance in fmpy, initialized and stepped a little (imports, caches)."""

    def __init__(self, fmu: Path, case: str, h: float):
        md = read_model_description(fmu)
        self.slave = FMU2Slave(guid=md.guid, unzipDirectory=extract(fmu), instanceName="warm",
                               modelIdentifier=md.coSimulation.modelIdentifier)
        self.outputs = [v.valueReference for v in md.modelVariables if v.causality == "output"]
        names = {v.name: v.valueReference for v in md.modelVariables}
        self.input = names.get(input_of(case)) if input_of(case) else None
        self.h, self.t = h, 0.0
        s = self.slave
        s.instantiate()
        s.setupExperiment(startTime=0.0)
        s.enterInitializationMode()
        s.exitInitializationMode()
        self.steps(20)

    def steps(self, n: int, get: bool = True, step: bool = True) -> None:
        s, h, outputs, vr = self.slave, self.h, self.outputs, self.input
        for _ in range(n):
            if vr is not None:
                s.setReal([vr], [actuator(self.t)])
            if step:
                s.doStep(self.t, h)
                self.t += h
            if get:
                s.getReal(outputs)

    def timed(self, n: int, **kwargs) -> tuple[float, float]:
        """(wall s, CPU s) per iteration of ``steps``."""
        w, c = time.perf_counter(), time.process_time()
        self.steps(n, **kwargs)
        return (time.perf_counter() - w) / n, (time.process_time() - c) / n

    def free(self):
        self.slave.terminate()
        self.slave.freeInstance()


def ctypes_run(fmu: Path, case: str, h: float, n: int) -> float:
    """CPU s per communication step of a minimal master: the same setReal (where the case
    has an input), doStep and getReal of every output as ``FmpyRun.steps``, called through
    ctypes with their arguments made once, so that what remains is the FMU's own cost plus
    about a microsecond per call (fmpy's Python around each call left out)."""
    run = FmpyRun(fmu, case, h)
    dll, component = run.slave.dll, ctypes.c_void_p(run.slave.component)
    count = len(run.outputs)
    vrs, values = (ctypes.c_uint * count)(*run.outputs), (ctypes.c_double * count)()
    vin, new = (ctypes.c_uint * 1)(run.input or 0), (ctypes.c_double * 1)()
    set_real, do_step, get_real = dll.fmi2SetReal, dll.fmi2DoStep, dll.fmi2GetReal
    do_step.argtypes = [ctypes.c_void_p, ctypes.c_double, ctypes.c_double, ctypes.c_int]
    t, failed, one, size = run.t, 0, ctypes.c_size_t(1), ctypes.c_size_t(count)
    start = time.process_time()
    for _ in range(n):
        if run.input is not None:
            new[0] = actuator(t)
            failed |= set_real(component, vin, one, new)
        failed |= do_step(component, t, h, 1)
        t += h
        failed |= get_real(component, vrs, size, values)
    cpu = (time.process_time() - start) / n
    run.free()
    if failed:
        raise RuntimeError(f"{case}: an FMI call failed in the ctypes master")
    return cpu


def c_master_run(binary: Path, fmu: Path, case: str, h: float, n: int) -> float:
    """CPU s per communication step of the C master (``c_master.py``): the same setReal
    (where the case has an input, ``actuator``'s force computed in C), doStep and getReal of
    every output as ``FmpyRun.steps``, with no Python in the loop: the FMU's own cost."""
    md = read_model_description(fmu)
    names = {v.name: v.valueReference for v in md.modelVariables}
    outputs = [v.valueReference for v in md.modelVariables if v.causality == "output"]
    return c_master_cpu(binary, fmu, h=h, n=n, outputs=outputs, hold=HOLD, swing=SWING,
                        input_vr=names[input_of(case)] if input_of(case) else None)


def cosim_run(fmu: Path, case: str, h: float, n: int, *,
              one_core: bool = False) -> tuple[float, float]:
    """(wall s, CPU s) per communication step of libcosim's ``execution.step``;
    ``one_core``: this thread held to one core while the execution (and its worker
    threads) is made and run, as ``mbdfmu cosim --master libcosim`` runs it."""
    from mbdfmu.cosim.threads import one_core as held_to_one_core
    with held_to_one_core() if one_core else contextlib.nullcontext():
        return _cosim_steps(fmu, case, h, n)


def _cosim_steps(fmu: Path, case: str, h: float, n: int) -> tuple[float, float]:
    from libcosimpy.CosimEnums import CosimVariableType
    from libcosimpy.CosimExecution import CosimExecution
    from libcosimpy.CosimLogging import CosimLogLevel, log_output_level
    from libcosimpy.CosimObserver import CosimObserver
    from libcosimpy.CosimSlave import CosimLocalSlave

    log_output_level(CosimLogLevel.ERROR)
    md = read_model_description(fmu)
    execution = CosimExecution.from_step_size(step_size=round(h * 1e9))
    index = execution.add_local_slave(CosimLocalSlave(fmu_path=str(fmu), instance_name="warm"))
    names = {v.name: v.valueReference for v in md.modelVariables}
    if input_of(case):
        execution.real_initial_value(index, names[input_of(case)], HOLD)
    series = CosimObserver.create_time_series(buffer_size=n + 64)
    execution.add_observer(series)
    for v in md.modelVariables:
        if v.causality == "output":
            series.start_time_series(index, value_reference=v.valueReference,
                                     variable_type=CosimVariableType.REAL)
    execution.step(20)
    w, c = time.perf_counter(), time.process_time()
    assert execution.step(n)
    return (time.perf_counter() - w) / n, (time.process_time() - c) / n


def stepper(sim, case: str, h: float):
    """``steps(count)``: ``count`` communication steps of ``h`` on ``sim`` as an FMU's master
    drives it (the case's actuator input set before each step, every output read after)."""
    name, t = input_of(case), [0.0]

    def steps(count):
        for _ in range(count):
            if name:
                sim.set_input(name, actuator(t[0]))
            t[0] += h
            sim.advance(t[0])
            sim.output_vector()
    return steps


def direct_run(scene_path: Path, case: str, h: float, n: int, kernel: str) -> tuple[float, float]:
    """(wall s, CPU s) per communication step of the solver called directly."""
    steps = stepper(mbdfmu.Simulation(mbdfmu.load_scene(scene_path), kernel=kernel), case, h)
    steps(20)
    w, c = time.perf_counter(), time.process_time()
    steps(n)
    return (time.perf_counter() - w) / n, (time.process_time() - c) / n


def exudyn_run(case: str, scene_path: Path, t_end: float, *, per_step: bool = False) -> float:
    """CPU s per 1 ms step of Exudyn's generalized-alpha (model building, assembly and the
    solve, as ``exudyn_compare.run_exudyn``) on the case's mechanism. The crane's cylinder
    force: held at ``HOLD`` over the run (Exudyn's favourable case), or with ``per_step`` set
    to ``actuator(t)`` before every step by a pre-step user function, as our master sets the
    FMU's input."""
    import exudyn_compare as ex
    scene = mbdfmu.load_scene(scene_path)
    name = input_of(case)
    start = time.process_time()
    model = ex.exudyn_model(scene, actuators={name.split(".")[0]: HOLD} if name else None)
    if per_step:
        ex.set_before_each_step(model, name.split(".")[0], actuator)
    info = ex.solve_exudyn(model, step=1e-3, t_end=t_end)
    cpu = time.process_time() - start
    if info["status"] != "ok":
        raise RuntimeError(f"{case}: {info['reason']}")
    return cpu / max(1, info["nsteps"])


def exudyn_per_step(case: str, scene_path: Path, t_end: float, repeat: int) -> dict:
    """Exudyn's CPU µs per 1 ms step, best of ``repeat`` (after a warm-up): ``exudyn_cpu_us``
    and, for the crane, ``exudyn_set_cpu_us`` (its force set before every step)."""
    try:
        import exudyn_compare as ex
    except ImportError:
        return {}
    if ex.exu is None:
        return {}
    modes = {"exudyn_cpu_us": False} | ({"exudyn_set_cpu_us": True} if input_of(case) else {})
    out = {}
    for key, per_step in modes.items():
        exudyn_run(case, scene_path, 0.01, per_step=per_step)            # warm-up
        out[key] = min(exudyn_run(case, scene_path, t_end, per_step=per_step)
                       for _ in range(repeat)) * 1e6
    return out


# ------------------------------------------------------------------------------ the run

def measure(case: str, scene_path: Path, fmu: Path, h: float, args) -> dict:
    n = max(1, int(round(args.t_end / h)))
    row = {"case": case, "step_ms": h * 1e3, "method": "", "outputs": 0}
    row.update({f"cold_fmpy_{k}": v for k, v in cold(COLD_FMPY, fmu, h).items()})
    row.update({f"cold_cosim_{k}": v for k, v in cold(COLD_COSIM, fmu, h).items()})
    samples: dict[str, list] = {}
    for _ in range(args.repeat):
        run = FmpyRun(fmu, case, h)
        row["outputs"] = len(run.outputs)
        samples.setdefault("fmpy", []).append(run.timed(n))
        samples.setdefault("doStep", []).append(run.timed(n, get=False))
        samples.setdefault("getReal", []).append(run.timed(n, step=False))
        run.free()
        samples.setdefault("ctypes", []).append(ctypes_run(fmu, case, h, n))
        if h == 1e-3:
            samples.setdefault("c_master", []).append(c_master_run(args.c_master, fmu, case, h, n))
        samples.setdefault("cosim", []).append(cosim_run(fmu, case, h, n))
        samples.setdefault("cosim_one_core", []).append(cosim_run(fmu, case, h, n, one_core=True))
        for kernel in ("c", "numpy"):
            samples.setdefault(f"direct_{kernel}", []).append(
                direct_run(scene_path, case, h, n if kernel == "c" else max(1, n // 5), kernel))
    for key, values in samples.items():
        if key in ("ctypes", "c_master"):
            continue
        row[f"{key}_wall_us"] = statistics.median(v[0] for v in values) * 1e6
        row[f"{key}_cpu_us"] = statistics.median(v[1] for v in values) * 1e6
    row["fmpy_cpu_best_us"] = min(v[1] for v in samples["fmpy"]) * 1e6
    row["ctypes_cpu_best_us"] = min(samples["ctypes"]) * 1e6
    if "c_master" in samples:
        row["c_master_cpu_best_us"] = min(samples["c_master"]) * 1e6
    row["rtf_fmpy"] = h / (row["fmpy_wall_us"] * 1e-6)
    row["rtf_cosim"] = h / (row["cosim_wall_us"] * 1e-6)
    row["rtf_cosim_one_core"] = h / (row["cosim_one_core_wall_us"] * 1e-6)
    sim = mbdfmu.Simulation(mbdfmu.load_scene(scene_path))
    row["method"] = sim.method_name
    if h == 1e-3:
        row.update(exudyn_per_step(case, scene_path, args.t_end, args.repeat))
    return row


def markdown(rows: list[dict], header: str) -> str:
    lines = [header, "",
             "| case | method | h (ms) | cold fmpy: instantiate + 1st doStep (s) | cold libcosim (s) "
             "| fmpy µs/step (RTF) | doStep µs | getReal µs (outputs) | libcosim µs/step (RTF) "
             "| libcosim on one core µs/step (RTF) "
             "| direct, kernel c µs | direct, numpy µs | fmpy CPU µs per 1 ms, best "
             "| ctypes master CPU µs per 1 ms, best | C master CPU µs per 1 ms, best "
             "| Exudyn CPU µs per 1 ms, best |",
             "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|"]

    def cold_text(prefix, r):
        if f"{prefix}_error" in r:
            return "failed: " + r[f"{prefix}_error"]
        return f"{r[prefix + '_instantiate_s'] + r[prefix + '_first_step_s']:.3f}"
    for r in rows:
        exu = f"{r['exudyn_cpu_us']:.1f}" if r.get("exudyn_cpu_us", "") != "" else ""
        if r.get("exudyn_set_cpu_us", "") != "":
            exu += f" (force set per step: {r['exudyn_set_cpu_us']:.1f})"
        best = f"{r['fmpy_cpu_best_us']:.1f}" if r["step_ms"] == 1.0 else ""
        bare = f"{r['ctypes_cpu_best_us']:.1f}" if r["step_ms"] == 1.0 else ""
        in_c = f"{r['c_master_cpu_best_us']:.1f}" if r.get("c_master_cpu_best_us") else ""
        lines.append(
            f"| {r['case']} | {r['method']} | {r['step_ms']:g} | {cold_text('cold_fmpy', r)} | "
            f"{cold_text('cold_cosim', r)} | {r['fmpy_wall_us']:.1f} ({r['rtf_fmpy']:.1f}) | "
            f"{r['doStep_wall_us']:.1f} | {r['getReal_wall_us']:.1f} ({r['outputs']}) | "
            f"{r['cosim_wall_us']:.1f} ({r['rtf_cosim']:.1f}) | "
            f"{r['cosim_one_core_wall_us']:.1f} ({r['rtf_cosim_one_core']:.1f}) | "
            f"{r['direct_c_wall_us']:.1f} | "
            f"{r['direct_numpy_wall_us']:.1f} | {best} | {bare} | {in_c} | {exu} |")
    return "\n".join(lines) + "\n"


def chart(rows: list[dict], path: Path) -> None:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    ms = [r for r in rows if r["step_ms"] == 1.0]
    keys = [("fmpy_wall_us", "FMU in fmpy"), ("cosim_wall_us", "FMU in libcosim"),
            ("cosim_one_core_wall_us", "FMU in libcosim, one core"),
            ("direct_c_wall_us", "solver directly (kernel c)"), ("exudyn_cpu_us", "Exudyn")]
    fig, ax = plt.subplots(figsize=(8, 3.8))
    width = 0.16
    for k, (key, label) in enumerate(keys):
        values = [r.get(key) if r.get(key) not in ("", None) else np.nan for r in ms]
        ax.bar(np.arange(len(ms)) + (k - 2) * width, values, width, label=label)
    ax.axhline(50.0, color="k", lw=0.8, ls="--", label="real-time factor 20 (50 µs)")
    ax.set_xticks(np.arange(len(ms)), [r["case"] for r in ms])
    ax.set_ylabel("µs per 1 ms communication step")
    ax.set_yscale("log")
    ax.legend(fontsize=8)
    ax.set_title("What a 1 ms step costs: the FMU at its default settings")
    fig.tight_layout()
    fig.savefig(path, dpi=110)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--t-end", type=float, default=1.0, help="simulated s per warm run")
    parser.add_argument("--repeat", type=int, default=3)
    parser.add_argument("--quick", action="store_true", help="1 ms only, 0.2 s, one repeat")
    parser.add_argument("-o", "--output", default=str(ROOT / "docs" / "figures" / "performance"))
    args = parser.parse_args(argv)
    if args.quick:
        args.t_end, args.repeat = 0.2, 1
    steps = STEPS[:1] if args.quick else STEPS
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        paths = scene_paths(Path(tmp))
        args.c_master = compile_master(Path(tmp))
        fmus = {case: build_fmu(path, output=Path(tmp) / f"case{k}.fmu")
                for k, (case, path) in enumerate(paths.items())}
        for case, fmu in fmus.items():
            for h in steps:
                rows.append(measure(case, paths[case], fmu, h, args))
                print(json.dumps(rows[-1]), flush=True)
    header = (f"`python benchmarks/fmu_speed.py --t-end {args.t_end:g} --repeat {args.repeat}`: "
              f"median of {args.repeat}, wall clock per communication step (µs), the real-time "
              "factor in brackets; fmpy CPU and Exudyn: CPU time per 1 ms step, best of "
              f"{args.repeat}; cold: wall s in a fresh "
              "process.")
    out = Path(args.output)
    out.mkdir(parents=True, exist_ok=True)
    text = markdown(rows, header)
    print(text)
    (out / "fmu_speed.md").write_text(text)
    with open(out / "fmu_speed.csv", "w", newline="") as f:
        fields = sorted({k for r in rows for k in r})
        writer = csv.DictWriter(f, fieldnames=fields)
        writer.writeheader()
        writer.writerows(rows)
    chart(rows, out / "fmu_speed.png")
    return 0


if __name__ == "__main__":
    sys.exit(main())
