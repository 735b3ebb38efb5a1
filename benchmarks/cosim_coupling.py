"""Where coupling fails: coupling error and stability against the communication step, per
scenario and algorithm, and what the variable-step master does (docs/cosimulation.md).

    python benchmarks/cosim_coupling.py              # run everything (about 15 min, 2 cores)
    python benchmarks/cosim_coupling.py --plot-only  # redraw the charts from the CSV

For each scenario of scenarios/, algorithm (Jacobi, Gauss-Seidel) and communication step
the fmpy master runs the scenario to its t_end; the coupling error is the largest
difference from the scenario's reference (monolithic ODE or closed form) over the run,
relative to the range of the reference, the largest over the scenario's ``compare``
variables. A run *fails* when an FMU refuses a step (the master stops with the reason) or
its error exceeds 100 % of the range (it has left the reference's behaviour). The
variable-step master (both algorithms inside) runs at several tolerances; its points are
placed at its mean step (t_end / steps).

Results: benchmarks/results/cosim_coupling.csv (one row per run) and
benchmarks/results/cosim_crane_steps.csv (the step sizes the variable-step master chose
on the crane); charts: docs/figures/cosim_<scenario>.png, docs/figures/cosim_crane_steps.png.
"""

from __future__ import annotations

import argparse
import csv
import math
import sys
import tempfile
import time
from concurrent.futures import ProcessPoolExecutor
from dataclasses import replace
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
RESULTS = ROOT / "benchmarks" / "results"
FIGURES = ROOT / "docs" / "figures"
WORK = Path(tempfile.gettempdir()) / "mbdfmu_cosim_coupling_fmus"
# A run whose error exceeds this fraction of the reference's range has failed.
FAILED_ERROR = 1.0
# The prescribed motion with an unsteady crank rate (theta = w t + 0.3 sin(2 pi 40 t)).
UNSTEADY = {"trajectory.amplitude": 0.3, "trajectory.frequency": 40.0}

# (scenario, label, parameter overrides, steps, variable-step rtols)
CASES = [
    ("dc_motor_slider_crank", "", {}, [5e-4, 1e-3, 2e-3, 5e-3, 1e-2, 2e-2, 5e-2],
     [1e-1, 3e-2, 1e-2]),
    ("hydraulic_crane", "", {}, [1e-3, 2e-3, 5e-3, 1e-2, 2e-2, 5e-2], [3e-2, 1e-2, 3e-3]),
    ("prescribed_motion", "positions, P4", {}, [5e-5, 1e-4, 2e-4, 5e-4, 1e-3, 2e-3], []),
    ("prescribed_motion:derivatives", "derivatives, P4", {}, [5e-5, 1e-4, 2e-4, 5e-4, 1e-3, 2e-3], []),
    ("prescribed_motion", "positions, unsteady", UNSTEADY, [5e-5, 1e-4, 2e-4, 5e-4, 1e-3, 2e-3], []),
    ("prescribed_motion:derivatives", "derivatives, unsteady", UNSTEADY,
     [5e-5, 1e-4, 2e-4, 5e-4, 1e-3, 2e-3], []),
    ("cart_pendulum_pid", "", {}, [2.5e-3, 5e-3, 1e-2, 2e-2, 5e-2, 1e-1], [3e-2, 1e-2, 3e-3]),
]
FIELDS = ["scenario", "label", "algorithm", "variable", "step", "rtol", "steps", "rejected",
          "jumps", "error", "failed", "fail_time", "reason", "seconds"]


def run_one(task) -> dict:
    """One run of the fmpy master; a CSV row."""
    from mbdfmu.cosim.fmpy_master import run_fmpy
    from mbdfmu.cosim.scenario import reference_function
    from mbdfmu.cosim.scenario_reader import load_scenario
    from mbdfmu.cosim.settings import CosimError, CosimSettings

    name, label, overrides, algorithm, step, rtol = task
    scenario = load_scenario(name)
    scenario = replace(scenario, parameters={**scenario.parameters, **overrides})
    fmus = _build(scenario)
    row = dict(scenario=name.split(":")[0], label=label, algorithm=algorithm,
               variable=int(rtol is not None), step=step, rtol=rtol or "", steps="",
               rejected="", jumps="", error="", failed=0, fail_time="", reason="", seconds="")
    settings = CosimSettings(algorithm=algorithm, step=step, variable_step=rtol is not None,
                             rtol=rtol)
    t0 = time.perf_counter()
    try:
        result = run_fmpy(scenario, fmus, settings)
    except CosimError as exc:
        row.update(failed=1, fail_time=exc.t, reason=str(exc)[:160],
                   seconds=round(time.perf_counter() - t0, 2))
        return row
    row["seconds"] = round(time.perf_counter() - t0, 2)
    ref = reference_function(scenario)(result.time)
    # The prescribed motion's start-up (the position history filling) is not coupling error.
    skip = max(4, round(2e-3 / step)) if name.startswith("prescribed_motion") and rtol is None \
        else 0
    errors = []
    for n in scenario.compare:
        span = float(np.ptp(ref[n])) or 1.0
        diff = np.abs(result[n][skip:] - ref[n][skip:])
        errors.append(float(np.max(diff)) / span if np.all(np.isfinite(diff)) else math.inf)
    error = max(errors)
    row.update(steps=result.stats["steps"], rejected=result.stats["rejected"],
               jumps=result.stats.get("jumps", 0), error=error)
    if not error <= FAILED_ERROR:
        row.update(failed=1, reason=f"error {error:.3g} of the reference's range")
    if rtol is not None and name == "hydraulic_crane":
        steps = np.diff(result.time)
        with open(RESULTS / f"cosim_crane_steps_{algorithm}_{rtol:g}.csv", "w") as fh:
            fh.write("time,step\n" + "".join(f"{float(t)!r},{float(h)!r}\n" for t, h in
                                              zip(result.time[1:], steps)))
    return row


def _build(scenario):
    from mbdfmu.fmu_build.cache import build_fmus

    return build_fmus({i.name: i.source for i in scenario.instances},
                      WORK / scenario.folder.name)


def tasks():
    for name, label, overrides, steps, rtols in CASES:
        for algorithm in ("jacobi", "gauss-seidel"):
            for h in steps:
                yield (name, label, overrides, algorithm, h, None)
            for rtol in rtols:
                yield (name, label, overrides, algorithm, None, rtol)


def _selected(scenario: str, variable: bool, scenarios, kind: str) -> bool:
    return ((not scenarios or scenario.split(":")[0] in scenarios)
            and (kind == "all" or (kind == "variable") == variable))


def run_all(workers: int, scenarios=None, kind: str = "all") -> None:
    """Run the selected cases; with a selection, the other rows of the CSV are kept."""
    from mbdfmu.cosim.scenario_reader import load_scenario

    RESULTS.mkdir(parents=True, exist_ok=True)
    for name, *_ in CASES:  # build once, before the workers share the folders
        _build(load_scenario(name))
    kept = []
    if (scenarios or kind != "all") and (RESULTS / "cosim_coupling.csv").is_file():
        kept = [r for r in read_rows()
                if not _selected(r["scenario"], r["variable"] == "1", scenarios, kind)]
    rows = list(kept)
    todo = [t for t in tasks() if _selected(t[0], t[5] is not None, scenarios, kind)]
    todo.sort(key=lambda t: -(t[4] is None or t[4] < 1e-3))  # long ones first
    with ProcessPoolExecutor(max_workers=workers) as pool:
        for row in pool.map(run_one, todo):
            rows.append(row)
            error = f"{row['error']:.3g}" if row["error"] != "" else "-"
            failed = f"FAILED {row['reason'][:70]}" if row["failed"] else ""
            print(f"{row['scenario']:22s} {row['label']:22s} {row['algorithm']:12s} "
                  f"h={row['step'] or '-':<8} rtol={row['rtol'] or '-':<6} error={error:<10} "
                  f"{failed} ({row['seconds']} s)", flush=True)
    rows.sort(key=lambda r: (r["scenario"], r["label"], r["algorithm"], int(r["variable"]),
                             float(r["step"] or 0), -float(r["rtol"] or 0)))
    with open(RESULTS / "cosim_coupling.csv", "w", newline="") as fh:
        writer = csv.DictWriter(fh, FIELDS)
        writer.writeheader()
        writer.writerows(rows)


# ----------------------------------------------------------------------------- charts

TITLES = {
    "dc_motor_slider_crank": "DC motor + slider-crank (torque / speed)",
    "hydraulic_crane": "Hydraulic crane (force / displacement, stiff)",
    "prescribed_motion": "Prescribed motion (position -> effort), P4",
    "cart_pendulum_pid": "PID cart-pendulum (state feedback / force)",
}
COLORS = {"jacobi": "tab:red", "gauss-seidel": "tab:blue"}
STYLES = ["-", "--", ":", "-."]


def read_rows() -> list[dict]:
    with open(RESULTS / "cosim_coupling.csv") as fh:
        return list(csv.DictReader(fh))


def plot_all() -> list[Path]:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    rows = read_rows()
    FIGURES.mkdir(parents=True, exist_ok=True)
    out = []
    for scenario, title in TITLES.items():
        mine = [r for r in rows if r["scenario"] == scenario]
        labels = list(dict.fromkeys(r["label"] for r in mine))
        fig, ax = plt.subplots(figsize=(7.5, 4.6))
        for algorithm in ("jacobi", "gauss-seidel"):
            for k, label in enumerate(labels):
                fixed = [r for r in mine if r["algorithm"] == algorithm and r["label"] == label
                         and r["variable"] == "0"]
                ok = [(float(r["step"]), float(r["error"])) for r in fixed if r["failed"] == "0"]
                bad = [float(r["step"]) for r in fixed if r["failed"] == "1"]
                name = algorithm + (f" ({label})" if label else "")
                if ok:
                    x, y = zip(*sorted(ok))
                    ax.loglog(x, y, STYLES[k % 4], marker="o", color=COLORS[algorithm], label=name,
                              ms=4)
                if bad:
                    ax.plot(bad, [FAILED_ERROR * 1.6] * len(bad), "x", color=COLORS[algorithm],
                            ms=9, mew=2, label=f"{name}: failed")
                var = [r for r in mine if r["algorithm"] == algorithm and r["label"] == label
                       and r["variable"] == "1" and r["failed"] == "0"]
                if var:
                    t_end = _t_end(scenario)
                    pts = sorted((t_end / float(r["steps"]), float(r["error"])) for r in var)
                    x, y = zip(*pts)
                    ax.loglog(x, y, "s", mfc="none", color=COLORS[algorithm], ms=8,
                              label=f"{name}, variable step (mean step)")
        ax.axhline(FAILED_ERROR, color="0.5", lw=0.8, ls="--")
        ax.set_xlabel("communication step (s)")
        ax.set_ylabel("coupling error / reference range")
        ax.set_title(title, fontsize="medium")
        ax.grid(True, which="both", alpha=0.25)
        ax.legend(fontsize="x-small", loc="best")
        fig.tight_layout()
        path = FIGURES / f"cosim_{scenario}.png"
        fig.savefig(path, dpi=100)
        plt.close(fig)
        out.append(path)
    steps = sorted(RESULTS.glob("cosim_crane_steps_*.csv"))
    if steps:
        fig, ax = plt.subplots(figsize=(7.5, 3.8))
        fails = {alg: min((float(r["step"]) for r in rows
                           if r["scenario"] == "hydraulic_crane" and r["variable"] == "0"
                           and r["failed"] == "1" and r["algorithm"] == alg), default=None)
                 for alg in ("jacobi", "gauss-seidel")}
        for path in steps:
            algorithm, rtol = path.stem.split("_")[-2:]
            data = np.loadtxt(path, delimiter=",", skiprows=1, ndmin=2)
            ax.semilogy(data[:, 0], data[:, 1], lw=1, color=COLORS[algorithm],
                        ls="-" if float(rtol) >= 1e-2 else ":",
                        label=f"{algorithm}, rtol {rtol}")
        for algorithm, h in fails.items():
            if h:
                ax.axhline(h, color=COLORS[algorithm], lw=0.8, ls="--",
                           label=f"{algorithm}: smallest fixed step that failed")
        ax.axvspan(0.2, 1.3, color="0.9", zorder=0, label="valve open (ramps included)")
        ax.set_xlabel("time (s)")
        ax.set_ylabel("step chosen (s)")
        ax.set_title("Hydraulic crane: the variable-step master's steps", fontsize="medium")
        ax.grid(True, which="both", alpha=0.25)
        ax.legend(fontsize="x-small", loc="lower right", ncol=2)
        fig.tight_layout()
        path = FIGURES / "cosim_crane_steps.png"
        fig.savefig(path, dpi=100)
        plt.close(fig)
        out.append(path)
    return out


def _t_end(scenario: str) -> float:
    from mbdfmu.cosim.scenario_reader import load_scenario

    return load_scenario(scenario).t_end


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--plot-only", action="store_true", help="redraw the charts from the CSV")
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--scenarios", default="",
                        help="comma-separated scenario names to rerun (others kept from the CSV)")
    parser.add_argument("--kind", choices=["all", "fixed", "variable"], default="all",
                        help="rerun fixed-step runs, variable-step runs or both")
    args = parser.parse_args(argv)
    if not args.plot_only:
        run_all(args.workers, [s for s in args.scenarios.split(",") if s], args.kind)
    for p in plot_all():
        print(p)
    return 0


if __name__ == "__main__":
    sys.exit(main())
