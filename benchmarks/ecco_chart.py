"""ECCO against libcosim's fixed step at the same mean step: the interface energy residual
and the coupling error against the monolithic reference over time (docs/cosimulation.md,
"ECCO against a fixed step at the same mean step").

    python benchmarks/ecco_chart.py [--tolerance 1e-2] [--sweep 1e-1,1e-2,1e-3]
                                    [--only a,b] [--start-factor 0.01]

For the quarter car, the hydraulic crane and the motor + crank: ECCO (from the
OspSystemStructure.xml written for the FMUs' power bond) at the tolerance, then libcosim's
fixed-step Jacobi at the step nearest ECCO's mean step that divides t_end in whole
nanoseconds; the energy residual of both from the recorded bond variables
(``ecco_runner.energy_residual``). Prints the table and writes docs/figures/cosim_ecco.png.
``--start-factor``: ECCO's first step relative to the scenario's step (libcosim takes its
first two steps at it whatever the tolerance; the sweep's chart then gets that suffix).
With ``--sweep``, the same pair of runs at each tolerance: a table of mean step, error and
largest residual of both, the ratio of ECCO's error to the fixed step's, and
docs/figures/cosim_ecco_sweep.png (error and residual against the mean step).
"""

from __future__ import annotations

import argparse
import sys
import tempfile
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
FIGURE = ROOT / "docs" / "figures" / "cosim_ecco.png"
SWEEP_FIGURE = ROOT / "docs" / "figures" / "cosim_ecco_sweep.png"
WORK = Path(tempfile.gettempdir()) / "mbdfmu_ecco_chart_fmus"
CASES = {"quarter_car": 1.0, "hydraulic_crane": 2.0,     # scenario: t_end (s)
         "dc_motor_slider_crank": 0.5}


def error_over_time(scenario, result) -> np.ndarray:
    from mbdfmu.cosim.scenario import reference_function
    ref = reference_function(scenario)(result.time)
    return np.max([np.abs(result[n] - ref[n]) / np.ptp(ref[n]) for n in scenario.compare], axis=0)


def runs(name: str, t_end: float, tolerance: float, start: float = 1.0) -> dict:
    from mbdfmu.cosim.ecco_config import find_bond
    from mbdfmu.cosim.ecco_runner import RESIDUAL, bond_variables, energy_residual, run_ecco
    from mbdfmu.cosim.libcosim_runner import run_libcosim
    from mbdfmu.cosim.scenario_reader import load_scenario
    from mbdfmu.fmu_build.cache import build_fmus

    scenario = load_scenario(name)
    fmus = build_fmus({i.name: i.source for i in scenario.instances}, WORK / scenario.folder.name)
    bonds = find_bond(scenario, fmus).as_table()
    ecco = run_ecco(scenario, fmus, t_end=t_end, rtol=tolerance, atol=tolerance,
                    start_step=start * scenario.step)
    mean = ecco.stats["mean_step"]
    steps = max(1, round(t_end / mean))
    h = round(t_end / steps * 1e9) / 1e9
    fixed = run_libcosim(scenario, fmus, step=h, t_end=h * steps,
                         record=list(dict.fromkeys(scenario.recorded() + bond_variables(bonds))))
    residual = energy_residual(fixed.time, {n: fixed[n] for n in fixed.names}, bonds)
    return {"ECCO": (ecco.time, error_over_time(scenario, ecco), ecco[RESIDUAL], mean),
            "fixed step": (fixed.time, error_over_time(scenario, fixed), residual, h)}


def _dress(axes, col, name, top, bottom, xlabel, which="major") -> None:
    """Title, labels, legend and grid of one scenario's column of two panels."""
    axes[0, col].set_title(name, fontsize="medium")
    axes[0, col].set_ylabel(top, fontsize="small")
    axes[1, col].set_ylabel(bottom, fontsize="small")
    axes[1, col].set_xlabel(xlabel)
    axes[0, col].legend(fontsize="small")
    for ax in axes[:, col]:
        ax.grid(True, which=which, alpha=0.3)


def sweep(tolerances, names, start: float) -> Path:
    """ECCO and the fixed step at ECCO's mean step, at every tolerance, per scenario."""
    from matplotlib.figure import Figure

    fig = Figure(figsize=(11, 6))
    axes = fig.subplots(2, len(names), squeeze=False)
    print("| scenario | tolerance | ECCO: mean step, error, largest |residual| | fixed step: "
          "error, largest |residual| | error ratio ECCO / fixed |\n|---|---|---|---|---|")
    for col, name in enumerate(names):
        points = {"ECCO": [], "fixed step": []}
        for tol in tolerances:
            for label, (_, error, residual, h) in runs(name, CASES[name], tol, start).items():
                points[label].append((h, error.max(), np.abs(residual).max()))
            (h, ee, er), (_, fe, fr) = points["ECCO"][-1], points["fixed step"][-1]
            print(f"| {name} ({CASES[name]:g} s) | {tol:g} | {h * 1e3:.3g} ms, {ee:.3g}, "
                  f"{er:.3g} J | {fe:.3g}, {fr:.3g} J | {ee / fe:.2f} |", flush=True)
        for k, (label, pts) in enumerate(points.items()):
            h, error, residual = np.array(sorted(pts)).T
            axes[0, col].loglog(h, error, "o-", color=f"C{k}", label=label)
            axes[1, col].loglog(h, residual, "o-", color=f"C{k}", label=label)
        _dress(axes, col, name, "largest error / range", "largest |energy residual| (J)",
               "communication step, mean (s)", which="both")
    fig.tight_layout()
    path = SWEEP_FIGURE if start == 1.0 else SWEEP_FIGURE.with_name(
        f"{SWEEP_FIGURE.stem}_start{start:g}.png")
    fig.savefig(path, dpi=90)
    return path


def over_time(names, tolerance: float, start: float) -> Path:
    """ECCO and the fixed step at one tolerance: residual and error over time."""
    from matplotlib.figure import Figure

    fig = Figure(figsize=(11, 6))
    axes = fig.subplots(2, len(names), squeeze=False)
    print("| scenario | ECCO: mean step, error, largest |residual| | fixed step: step, error, "
          "largest |residual| |\n|---|---|---|")
    for col, name in enumerate(names):
        cells = []
        for label, (t, error, residual, h) in runs(name, CASES[name], tolerance, start).items():
            axes[0, col].plot(t, residual, lw=1, label=f"{label} ({h * 1e3:.3g} ms)")
            axes[1, col].semilogy(t[1:], np.maximum(error[1:], 1e-12), lw=1, label=label)
            cells.append(f"{h * 1e3:.3g} ms, {error.max():.3g}, {np.abs(residual).max():.3g} J")
        print(f"| {name} ({CASES[name]:g} s, tolerance {tolerance:g}) | "
              + " | ".join(cells) + " |")
        _dress(axes, col, name, "interface energy residual (J)", "error / range", "time (s)")
    fig.tight_layout()
    fig.savefig(FIGURE, dpi=90)
    return FIGURE


def main(argv=None) -> int:
    import matplotlib
    matplotlib.use("Agg")

    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--tolerance", type=float, default=1e-2)
    parser.add_argument("--sweep", default=None,
                        help="comma-separated tolerances: the sweep table and chart instead")
    parser.add_argument("--only", default=",".join(CASES), help="comma-separated scenarios")
    parser.add_argument("--start-factor", type=float, default=1.0,
                        help="ECCO's first step relative to the scenario's step")
    args = parser.parse_args(argv)
    names = args.only.split(",")
    if args.sweep:
        print(sweep([float(x) for x in args.sweep.split(",")], names, args.start_factor))
    else:
        print(over_time(names, args.tolerance, args.start_factor))
    return 0


if __name__ == "__main__":
    sys.exit(main())
