"""One scenario, one master: build the FMUs, run, compare with the reference, write CSV
and a plot. ``mbdfmu cosim`` is this module's ``cosimulate`` plus ``write``."""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..fmu_build.cache import build_fmus
from ..plotting import figure
from ..result import Result
from .ecco_runner import RESIDUAL, run_ecco
from .ecos_runner import run_ecos
from .fmpy_master import run_fmpy
from .libcosim_runner import run_libcosim
from .scenario import Scenario, reference_function
from .scenario_reader import load_scenario
from .settings import CosimSettings
from .ssp_runner import run_ssp


@dataclass
class CosimRun:
    """What a run gives: the result, its wall time and, with a reference, the error of each
    compared variable (largest absolute difference over the run)."""

    scenario: Scenario
    settings: CosimSettings
    result: Result
    seconds: float
    algorithm: str = "jacobi"
    errors: dict[str, float] = field(default_factory=dict)
    reference: dict[str, np.ndarray] | None = None


def cosimulate(scenario: Scenario | str, settings: CosimSettings = CosimSettings(),
               work_dir: str | Path = "cosim-fmus", compare: bool = True) -> CosimRun:
    """Run a scenario with one master; FMUs are built (or reused) in
    ``work_dir/<scenario folder>``, the SSP written there too."""
    if not isinstance(scenario, Scenario):
        scenario = load_scenario(scenario)
    # One folder per scenario folder: variants share their FMUs, other scenarios may have
    # sources of the same name.
    work_dir = Path(work_dir) / scenario.folder.name
    fmus = build_fmus({i.name: i.source for i in scenario.instances}, work_dir,
                      fmi_version=settings.fmi_version)
    algorithm = settings.algorithm_for(scenario)
    t0 = time.perf_counter()
    if settings.master == "fmpy":
        result = run_fmpy(scenario, fmus, settings)
    elif settings.master == "ssp":
        result = run_ssp(scenario, fmus, work_dir / f"{scenario.name}.ssp", step=settings.step,
                         t_end=settings.t_end, algorithm=algorithm, start=settings.start)
    elif settings.master == "ecos":
        result = run_ecos(scenario, fmus, work_dir / f"{scenario.name}.ssp", step=settings.step,
                          t_end=settings.t_end, algorithm=algorithm)
    elif algorithm == "ecco":
        result = run_ecco(scenario, fmus, step=settings.step, t_end=settings.t_end,
                          rtol=settings.rtol, atol=settings.atol)
    else:
        result = run_libcosim(scenario, fmus, step=settings.step, t_end=settings.t_end,
                              algorithm=algorithm)
    seconds = time.perf_counter() - t0
    run = CosimRun(scenario, settings, result, seconds, algorithm=algorithm)
    ref = reference_function(scenario) if compare else None
    if ref is not None:
        run.reference = ref(result.time)
        run.errors = {n: float(np.max(np.abs(result[n] - run.reference[n])))
                      for n in scenario.compare if n in run.reference}
    return run


def plot(run: CosimRun, path: str | Path) -> Path:
    """One panel per plotted variable against time, with the reference dashed."""
    names = [n for n in (run.scenario.plot or run.result.names) if n in run.result]
    if RESIDUAL in run.result and RESIDUAL not in names:   # ECCO: the bond's energy residual
        names.append(RESIDUAL)
    fig = figure(figsize=(8, 1.9 * len(names) + 0.8))
    axes = fig.subplots(len(names), 1, sharex=True, squeeze=False)
    for ax, name in zip(axes[:, 0], names):
        ax.plot(run.result.time, run.result[name], lw=1.2, label="co-simulation")
        if run.reference is not None and name in run.reference:
            ax.plot(run.result.time, run.reference[name], "k--", lw=0.9, label="reference")
        unit = run.result.units.get(name, "")
        ax.set_ylabel(f"{name}\n({unit})" if unit else name, fontsize="small")
        ax.grid(True, alpha=0.3)
    axes[0, 0].legend(loc="best", fontsize="small")
    axes[-1, 0].set_xlabel("time (s)")
    h = run.settings.step or run.scenario.step
    axes[0, 0].set_title(f"{run.scenario.name}: {run.result.method}, step {h:g} s", fontsize="medium")
    fig.tight_layout()
    path = Path(path)
    fig.savefig(path, dpi=100)
    return path


def write(run: CosimRun, out_dir: str | Path) -> list[Path]:
    """CSV and plot of a run in ``out_dir``; returns their paths."""
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    s = run.settings
    tag = f"{run.scenario.name}_{s.master}_{run.algorithm}" \
          + ("_variable" if s.variable_step else "")
    csv = run.result.to_csv(out_dir / f"{tag}.csv")
    png = plot(run, out_dir / f"{tag}.png")
    return [csv, png]
