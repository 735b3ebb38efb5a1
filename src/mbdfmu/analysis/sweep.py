"""Parameter sweeps on Dask: ``sweep(scene, {"crank.mass": values, ...}, t_end)``.

Every combination of the parameter values (names as the FMU's parameters) is one run, a
pure function of (scene, parameter values, settings): the same rows come out in this
process (``scheduler="synchronous"``), on a local Dask cluster of one single-threaded
worker process per core (the default) or on a running scheduler (its address). A run
records, for each selected output, its final value and its peak (the largest |value| at
the output times); a run that fails (a parameter out of range, a mechanism that cannot be
assembled, a solver failure) is a row with status "failed" and the reason, never the end
of the sweep. ``write_results`` writes results.csv; ``sweep_charts.draw`` the charts.
"""

from __future__ import annotations

import csv
import fnmatch
import itertools
import logging
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable

import numpy as np

from ..errors import InputError, MbdfmuError, SceneError, SettingError, suggest
from ..integrators.settings import SolverSettings, settings_from_scene
from ..model.scene import Scene
from ..model.variables import outputs, parameter_specs, selected_outputs, with_parameters
from ..simulation import Simulation, check_t_end, output_times

# Solver settings a sweep may vary (``solver.rtol``, names as the FMU's parameters).
SOLVER_SWEEPS = ("step", "rtol", "atol")
# Worker processes run single-threaded numerical libraries (one run per core).
WORKER_ENV = {"OMP_NUM_THREADS": "1", "OPENBLAS_NUM_THREADS": "1", "MKL_NUM_THREADS": "1"}


@dataclass
class SweepResult:
    """``rows`` one dict per run in combination order: the parameter values,
    ``<output>.final`` and ``<output>.peak``, ``status`` and ``reason``."""

    parameters: list[str]
    outputs: list[str]
    rows: list[dict]
    where: str = ""
    files: list[Path] = field(default_factory=list)

    @property
    def columns(self) -> list[str]:
        return (self.parameters + [f"{o}.{k}" for o in self.outputs for k in ("final", "peak")]
                + ["status", "reason"])

    @property
    def failed(self) -> list[dict]:
        return [r for r in self.rows if r["status"] != "ok"]


def select(scene: Scene, patterns: list[str] | None) -> list[str]:
    """Output names matching ``patterns`` (default: the scene's FMU outputs)."""
    if not patterns:
        return [v.name for v in selected_outputs(scene)]
    names = [v.name for v in outputs(scene)]
    chosen = [n for n in names if any(fnmatch.fnmatchcase(n, p) for p in patterns)]
    unmatched = [p for p in patterns if not fnmatch.filter(names, p)]
    if unmatched:
        raise InputError(f"{scene.source}: --outputs {' '.join(unmatched)} match no output; "
                         f"outputs: {', '.join(names)}")
    return chosen


def check_names(scene: Scene, names: list[str]) -> None:
    """Every name is a parameter of the scene (values are checked per run)."""
    known = list(parameter_specs(scene)) + [f"solver.{k}" for k in SOLVER_SWEEPS]
    unknown = [n for n in names if n not in known]
    if unknown:
        raise SceneError(f'{scene.source}: parameters: unknown parameter "{unknown[0]}"'
                         f"{suggest(unknown[0], known)}")


def combinations(values: dict[str, np.ndarray]) -> list[dict[str, float]]:
    """Every combination, the last parameter varying fastest."""
    names = list(values)
    return [dict(zip(names, map(float, combo)))
            for combo in itertools.product(*(values[n] for n in names))]


def run_case(task: dict) -> dict:
    """One run: a pure function of ``task`` (scene, parameters, settings, t_end, interval,
    outputs). Returns its row."""
    row = dict(task["parameters"])
    names = task["outputs"]
    final = np.full(len(names), np.nan)
    peak = np.full(len(names), np.nan)
    scene_values = {k: v for k, v in task["parameters"].items() if not k.startswith("solver.")}
    solver = {k[len("solver."):]: v for k, v in task["parameters"].items()
              if k.startswith("solver.")}
    try:
        scene = with_parameters(task["scene"], scene_values)
        settings = task["settings"].updated(
            "--set", names={k: f"solver.{k}" for k in SOLVER_SWEEPS}, **solver)
        sim = Simulation(scene, settings=settings)
        index = [sim.output_names.index(n) for n in names]
        peak[:] = 0.0
        for t in output_times(task["t_end"], task["interval"]):
            sim.advance(float(t))
            final = sim.output_vector()[index]
            peak = np.maximum(peak, np.abs(final))
        status, reason = "ok", ""
    except (MbdfmuError, ArithmeticError, ValueError, np.linalg.LinAlgError) as exc:
        status, reason = "failed", f"{type(exc).__name__}: {exc}"
        final[:], peak[:] = np.nan, np.nan
    for k, n in enumerate(names):
        row[f"{n}.final"], row[f"{n}.peak"] = float(final[k]), float(peak[k])
    row.update(status=status, reason=reason)
    return row


def _local_workers() -> int:
    return max(1, len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity")
               else os.cpu_count() or 1)


def run_all(tasks: list[dict], scheduler: str | None = None,
            advance: Callable[[], None] = lambda: None) -> tuple[list[dict], str]:
    """Rows of ``run_case`` for every task, in task order; ``advance()`` after each run.
    Returns (rows, where they ran)."""
    if scheduler == "synchronous":
        rows = []
        for task in tasks:
            rows.append(run_case(task))
            advance()
        return rows, "the synchronous scheduler (this process)"
    try:
        from dask.distributed import Client, LocalCluster, as_completed
    except ImportError:
        raise SettingError("--scheduler", "a sweep on Dask needs dask[distributed]: pip "
                           "install 'mbdfmu[bench]' (or use --scheduler synchronous)") from None
    cluster, where = None, f"the scheduler {scheduler}"
    if scheduler is None:
        workers = _local_workers()
        cluster = LocalCluster(n_workers=workers, threads_per_worker=1, processes=True,
                               dashboard_address=":0", env=WORKER_ENV,
                               silence_logs=logging.ERROR)
        where = f"a LocalCluster of {workers} single-threaded workers"
    try:
        client = Client(cluster if cluster is not None else scheduler, timeout="20s")
    except (OSError, TimeoutError) as exc:
        if cluster is not None:
            cluster.close()
        raise SettingError("--scheduler", f"cannot reach the Dask scheduler at {scheduler}: "
                           f"{exc}") from None
    try:
        with client:
            futures = client.map(run_case, tasks, pure=False)
            position = {f.key: k for k, f in enumerate(futures)}
            rows: list = [None] * len(tasks)
            for done in as_completed(futures):
                rows[position[done.key]] = done.result()
                advance()
    finally:
        if cluster is not None:
            cluster.close()
    return rows, where


def sweep(scene: Scene, values: dict[str, np.ndarray], t_end: float,
          output_patterns: list[str] | None = None, scheduler: str | None = None,
          settings: SolverSettings | None = None, output_interval: float | None = None,
          advance: Callable[[], None] = lambda: None) -> SweepResult:
    """Run ``scene`` for every combination of ``values`` (parameter name -> values) to
    ``t_end``; see the module docstring. Names are checked before any run."""
    t_end = check_t_end(t_end, "--t-end")
    check_names(scene, list(values))
    settings = settings or settings_from_scene(scene)
    names = select(scene, output_patterns)
    interval = settings.output_interval_for(t_end) if output_interval is None else output_interval
    tasks = [{"scene": scene, "parameters": p, "settings": settings, "t_end": t_end,
              "interval": interval, "outputs": names} for p in combinations(values)]
    rows, where = run_all(tasks, scheduler, advance)
    return SweepResult(list(values), names, rows, where)


def write_results(result: SweepResult, path: str | Path) -> Path:
    """results.csv: one row per run, floats at full precision (repr)."""
    path = Path(path)
    with open(path, "w", newline="", encoding="utf-8") as fh:
        w = csv.DictWriter(fh, fieldnames=result.columns)
        w.writeheader()
        for r in result.rows:
            w.writerow({k: (repr(v) if isinstance(v, float) else v) for k, v in r.items()})
    return path


def read_results(path: str | Path) -> list[dict]:
    with open(path, newline="", encoding="utf-8") as fh:
        return list(csv.DictReader(fh))


__all__ = ["SweepResult", "sweep", "run_case", "run_all", "combinations", "select",
           "write_results", "read_results"]
