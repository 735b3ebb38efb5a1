"""ECCO against libcosim's fixed step at the same mean step: the interface energy residual
and the coupling error against the monolithic reference over time (docs/cosimulation.md,
"ECCO against a fixed step at the same mean step").

    python benchmarks/ecco_chart.py [--tolerance 1e-2]

For the quarter car and the hydraulic crane: ECCO (from the OspSystemStructure.xml written
for the FMUs' power bond) at the tolerance, then libcosim's fixed-step Jacobi at the step
nearest ECCO's mean step that divides t_end in whole nanoseconds; the energy residual of
both from the recorded bond variables (``ecco_runner.energy_residual``). Prints the table
and writes docs/figures/cosim_ecco.png.
"""

from __future__ import annotations

import argparse
import sys
import tempfile
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
FIGURE = ROOT / "docs" / "figures" / "cosim_ecco.png"
WORK = Path(tempfile.gettempdir()) / "mbdfmu_ecco_chart_fmus"
CASES = {"quarter_car": 1.0, "hydraulic_crane": 2.0}     # scenario: t_end (s)


def error_over_time(scenario, result) -> np.ndarray:
    from mbdfmu.cosim.scenario import reference_function
    ref = reference_function(scenario)(result.time)
    return np.max([np.abs(result[n] - ref[n]) / np.ptp(ref[n]) for n in scenario.compare], axis=0)


def runs(name: str, t_end: float, tolerance: float) -> dict:
    from mbdfmu.cosim.ecco_config import find_bond
    from mbdfmu.cosim.ecco_runner import RESIDUAL, bond_variables, energy_residual, run_ecco
    from mbdfmu.cosim.libcosim_runner import run_libcosim
    from mbdfmu.cosim.scenario_reader import load_scenario
    from mbdfmu.fmu_build.cache import build_fmus

    scenario = load_scenario(name)
    fmus = build_fmus({i.name: i.source for i in scenario.instances}, WORK / scenario.folder.name)
    bonds = find_bond(scenario, fmus).as_table()
    ecco = run_ecco(scenario, fmus, t_end=t_end, rtol=tolerance, atol=tolerance)
    mean = ecco.stats["mean_step"]
    steps = max(1, round(t_end / mean))
    h = round(t_end / steps * 1e9) / 1e9
    fixed = run_libcosim(scenario, fmus, step=h, t_end=h * steps,
                         record=list(dict.fromkeys(scenario.recorded() + bond_variables(bonds))))
    residual = energy_residual(fixed.time, {n: fixed[n] for n in fixed.names}, bonds)
    return {"ECCO": (ecco.time, error_over_time(scenario, ecco), ecco[RESIDUAL], mean),
            "fixed step": (fixed.time, error_over_time(scenario, fixed), residual, h)}


def main(argv=None) -> int:
    import matplotlib
    matplotlib.use("Agg")
    from matplotlib.figure import Figure

    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--tolerance", type=float, default=1e-2)
    args = parser.parse_args(argv)
    fig = Figure(figsize=(11, 6))
    axes = fig.subplots(2, len(CASES), squeeze=False)
    print("| scenario | ECCO: mean step, error, largest |residual| | fixed step: step, error, "
          "largest |residual| |\n|---|---|---|")
    for col, (name, t_end) in enumerate(CASES.items()):
        found = runs(name, t_end, args.tolerance)
        cells = []
        for label, (t, error, residual, h) in found.items():
            axes[0, col].plot(t, residual, lw=1, label=f"{label} ({h * 1e3:.3g} ms)")
            axes[1, col].semilogy(t[1:], np.maximum(error[1:], 1e-12), lw=1, label=label)
            cells.append(f"{h * 1e3:.3g} ms, {error.max():.3g}, {np.abs(residual).max():.3g} J")
        print(f"| {name} ({t_end:g} s, tolerance {args.tolerance:g}) | " + " | ".join(cells) + " |")
        axes[0, col].set_title(name, fontsize="medium")
        axes[0, col].set_ylabel("interface energy residual (J)", fontsize="small")
        axes[1, col].set_ylabel("error / range", fontsize="small")
        axes[1, col].set_xlabel("time (s)")
        axes[0, col].legend(fontsize="small")
        for ax in axes[:, col]:
            ax.grid(True, alpha=0.3)
    fig.tight_layout()
    fig.savefig(FIGURE, dpi=90)
    print(FIGURE)
    return 0


if __name__ == "__main__":
    sys.exit(main())
