"""The time each communication step takes: the scene FMUs stepped by fmpy at 1 ms, every
doStep (with fmi2SetReal of the crane's cylinder force before it, and fmi2GetReal of every
output after it) timed on its own, for the distribution a real-time master sees: median,
mean, the 99th and 99.9th percentiles, the largest, and how many steps took over 100 µs
(where Python took the step instead of the FMU's C wrapper, the slow tail).

CPU time of the stepping thread (``time.thread_time``), so that another process's load on
this shared machine does not count. ``--python`` builds the FMUs with another checkout's
interpreter too (label=path), for a before/after in one run: each build's rows are
measured alternately, ``--repeat`` rounds, and the round with the lowest mean kept.

    python benchmarks/fmu_step_times.py [--set targets|events|drivers|stiff|shipped]
        [--method rk4p]
        [--t-end 10] [--repeat 3] [--python base=/path/python]

``--set events`` times the shipped scenes with end stops and friction instead (and
crane_stop with its cylinder's force set before every doStep); ``--set drivers`` the
prescribed-motion slider-crank with its crank angle set before every doStep; ``--set
stiff`` a 1e10 N/m spring under auto (genalpha's controlled steps), alone, with a push set
before every doStep, and hung from a pinned body; ``--set shipped`` every other shipped
scene (those without end stops or friction) with its inputs held; ``--method``
sets every FMU's ``solver.method`` (its scene's by default). Writes ``fmu_step_times.md``
(``fmu_step_times_events.md``; with ``--method M``, ``..._M.md``), ``.csv`` and ``.png``
into ``-o`` (default docs/figures/performance).
"""

from __future__ import annotations

import os

for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import argparse  # noqa: E402
import csv  # noqa: E402
import math  # noqa: E402
import subprocess  # noqa: E402
import sys  # noqa: E402
import tempfile  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402
from mbdfmu.scenes import variants  # noqa: E402
from fmpy import extract, read_model_description  # noqa: E402
from fmpy.fmi1 import FMICallException  # noqa: E402
from fmpy.fmi2 import FMU2Slave  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
H = 1e-3
SLOW_US = 100.0
HOLD, SWING = 8420.0, 0.05     # the crane's cylinder force (N) as fmu_speed.py sets it
# crane_stop with an actuator force between its cylinder's barrel and rod (a hydraulic
# cylinder with end stops), swinging about the 2309 N that hold the boom on its lower stop:
# it leaves the stop, rests on the upper one, falls back onto the lower one, bounces, rests
CYLINDER = variants.CYLINDER


def crane_force(t: float) -> float:
    return HOLD * (1.0 + SWING * math.sin(2.0 * math.pi * t))


def cylinder_force(t: float) -> float:
    return 2300.0 + 4000.0 * math.sin(math.pi * t)


# case: (scene, TOML appended to it, the input set before every doStep, its value at t)
CASES = {"slider-crank (P4)": (ROOT / "scenes" / "slider_crank.toml", "", None, None),
         "P2 N = 2": (ROOT / "scenes" / "n_four_bar_2.toml", "", None, None),
         "crane mechanism": (ROOT / "scenarios" / "hydraulic_crane" / "crane.toml", "",
                             "cylinder.actuator", crane_force)}
# --set events: the shipped scenes with end stops and friction (impacts, rest on a stop,
# sticking, sliding), default settings; and crane_stop with its cylinder's force set
EVENT_CASES = {stem: (ROOT / "scenes" / f"{stem}.toml", "", None, None)
               for stem in ("slider_stop", "crane_stop", "incline_stick", "incline_slide")}
EVENT_CASES["crane_stop, force set"] = (ROOT / "scenes" / "crane_stop.toml", CYLINDER,
                                        "cylinder.actuator", cylinder_force)
# --set drivers: the prescribed-motion scenario's slider-crank, its crank angle set by the
# master before every doStep (positions only), at P4's rate with a 0.1 rad, 5 Hz wobble
DRIVER_CASES = {"prescribed slider-crank, position set": (
    ROOT / "scenarios" / "prescribed_motion" / "slider_crank.toml", "", "motor.position",
    lambda t: 314.1592653589793 * t + 0.1 * math.sin(2.0 * math.pi * 5.0 * t))}
# --set stiff: P1 with its rod a 1e10 N/m spring (scenes/stiff_spring.toml), auto's stiff
# case (genalpha under step control), alone and with a push across it set before every
# doStep, and hung from a second body pinned off its centre (constraints, a force Jacobian
# coupling two bodies)
STIFF_SCENE = ROOT / "scenes" / "stiff_spring.toml"
STIFF_CASES = {
    "stiff spring, auto": (STIFF_SCENE, "", None, None),
    "stiff spring, push set": (STIFF_SCENE, variants.PUSH, "push.fy",
                               lambda t: -2.0 + math.sin(2.0 * math.pi * t)),
    "stiff spring on a pinned hook, push set": (None, variants.hooked(STIFF_SCENE.read_text()),
                                                "push.fy",
                                                lambda t: -2.0 + math.sin(2.0 * math.pi * t))}
# --set shipped: every other shipped scene (none with end stops or friction), inputs held
SHIPPED_CASES = {path.stem: (path, "", None, None)
                 for path in sorted((ROOT / "scenes").glob("*.toml"))
                 if path.stem not in EVENT_CASES}
SETS = {"targets": (CASES, "fmu_step_times"), "events": (EVENT_CASES, "fmu_step_times_events"),
        "drivers": (DRIVER_CASES, "fmu_step_times_drivers"),
        "stiff": (STIFF_CASES, "fmu_step_times_stiff"),
        "shipped": (SHIPPED_CASES, "fmu_step_times_shipped")}


def build(python: str, scene: Path, target: Path) -> Path:
    run = subprocess.run([python, "-m", "mbdfmu", "build", str(scene), "-o", str(target)],
                         capture_output=True, text=True)
    if run.returncode != 0:
        raise SystemExit(f"building {scene.name} with {python}: {run.stderr.strip()[-300:]}")
    return target


def step_times(fmu: Path, input_name: str | None, value, t_end: float,
               method: str | None = None) -> np.ndarray:
    """CPU µs of each doStep (with its set of ``input_name`` to ``value(t)`` and its get)
    over t_end at H; ``method``: the FMU's solver.method, set before initialization (None:
    its scene's)."""
    md = read_model_description(fmu)
    slave = FMU2Slave(guid=md.guid, unzipDirectory=extract(fmu), instanceName="times",
                      modelIdentifier=md.coSimulation.modelIdentifier)
    outputs = [v.valueReference for v in md.modelVariables if v.causality == "output"]
    vr = {v.name: v.valueReference for v in md.modelVariables}.get(input_name)
    slave.instantiate()
    if method is not None:
        slave.setString([{v.name: v.valueReference for v in md.modelVariables}["solver.method"]],
                        [method])
    slave.setupExperiment(startTime=0.0)
    slave.enterInitializationMode()
    slave.exitInitializationMode()
    n = int(round(t_end / H))
    times, t = np.empty(n), 0.0
    for k in range(n):
        start = time.thread_time()
        if vr is not None:
            slave.setReal([vr], [value(t)])
        slave.doStep(t, H)
        slave.getReal(outputs)
        times[k] = time.thread_time() - start
        t += H
    slave.terminate()
    slave.freeInstance()
    return times * 1e6


def summary(case: str, build_label: str, times: np.ndarray) -> dict:
    slow = times > SLOW_US
    return {"case": case, "build": build_label, "steps": times.size,
            "median_us": float(np.median(times)), "mean_us": float(times.mean()),
            "real_time_factor": float(H * 1e6 / times.mean()),
            "p99_us": float(np.quantile(times, 0.99)),
            "p999_us": float(np.quantile(times, 0.999)), "max_us": float(times.max()),
            "slow_steps": int(slow.sum()), "slow_share": float(times[slow].sum() / times.sum())}


def markdown(rows: list[dict], header: str) -> str:
    lines = [header, "", "| case | build | median µs | mean µs | real-time factor | p99 µs "
             f"| p99.9 µs | largest µs | steps over {SLOW_US:g} µs | their share of the time |",
             "|---|---|---|---|---|---|---|---|---|---|"]
    for r in rows:
        lines.append(f"| {r['case']} | {r['build']} | {r['median_us']:.1f} | {r['mean_us']:.1f} "
                     f"| {r['real_time_factor']:.1f} "
                     f"| {r['p99_us']:.1f} | {r['p999_us']:.1f} | {r['max_us']:.0f} "
                     f"| {r['slow_steps']} of {r['steps']} | {100 * r['slow_share']:.0f} % |")
    return "\n".join(lines) + "\n"


def chart(samples: dict, path: Path) -> None:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    fig, ax = plt.subplots(figsize=(7.5, 4.5))
    for (case, label), times in samples.items():
        x = np.sort(times)
        ax.semilogx(x, 1.0 - np.arange(x.size) / x.size, label=f"{case}, {label}")
    ax.set_yscale("log")
    ax.set_xlabel("CPU time of one 1 ms doStep in fmpy (µs)")
    ax.set_ylabel("share of doSteps taking longer")
    ax.set_title("Communication step times: the slow tail is Python's steps")
    ax.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=110)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--t-end", type=float, default=10.0)
    parser.add_argument("--repeat", type=int, default=3)
    parser.add_argument("--set", choices=SETS, default="targets",
                        help="targets: issue 13's three mechanisms; events: the scenes with "
                             "end stops and friction (writes fmu_step_times_events.*); "
                             "drivers: a crank angle set by the master; stiff: a 1e10 N/m "
                             "spring under auto; shipped: every other shipped scene")
    parser.add_argument("--method", default=None,
                        help="every FMU's solver.method (default: its scene's)")
    parser.add_argument("--python", action="append", default=[], metavar="LABEL=PATH",
                        help="also build the FMUs with this interpreter's mbdfmu")
    parser.add_argument("-o", "--output", default=str(ROOT / "docs" / "figures" / "performance"))
    args = parser.parse_args(argv)
    builds = [("this checkout", sys.executable)]
    for item in args.python:
        label, _, python = item.partition("=")
        if not python:
            parser.error(f"--python {item!r}: give LABEL=PATH of a Python interpreter")
        builds.append((label, python))
    rows, samples = [], {}
    cases, stem = SETS[args.set]
    with tempfile.TemporaryDirectory() as tmp:
        fmus = {}
        for i, (case, (scene, added, _, _)) in enumerate(cases.items()):
            if added:
                base = "" if scene is None else scene.read_text()
                scene = Path(tmp) / f"c{i}.toml"
                scene.write_text(base + added)
            for j, (label, python) in enumerate(builds):
                fmus[case, label] = build(python, scene, Path(tmp) / f"c{i}b{j}.fmu")
        stopped = []
        for case, (_, _, input_name, value) in cases.items():
            try:
                for _ in range(args.repeat):
                    for label, _ in builds:
                        times = step_times(fmus[case, label], input_name, value, args.t_end,
                                           args.method)
                        best = samples.get((case, label))
                        if best is None or times.mean() < best.mean():
                            samples[case, label] = times
            except FMICallException as exc:    # a method that cannot keep its accuracy
                stopped.append(f"{case}: {exc} (see the FMU's log above)")
                continue
            for label, _ in builds:
                rows.append(summary(case, label, samples[case, label]))
                print(rows[-1], flush=True)
    if args.method is not None:
        stem = f"{stem}_{args.method}"
    method = "" if args.method is None else f" --method {args.method}"
    header = (f"`python benchmarks/fmu_step_times.py --set {args.set}{method} --t-end "
              f"{args.t_end:g} --repeat {args.repeat}`: CPU time of each 1 ms doStep in fmpy "
              f"(set, step, get of every output), the round with the lowest mean of "
              f"{args.repeat}.")
    text = markdown(rows, header) + "".join(f"\nStopped: {line}\n" for line in stopped)
    print(text)
    out = Path(args.output)
    out.mkdir(parents=True, exist_ok=True)
    (out / f"{stem}.md").write_text(text)
    with open(out / f"{stem}.csv", "w", newline="") as f:
        writer = csv.DictWriter(f, fieldnames=list(rows[0]))
        writer.writeheader()
        writer.writerows(rows)
    chart(samples, out / f"{stem}.png")
    return 0


if __name__ == "__main__":
    sys.exit(main())
