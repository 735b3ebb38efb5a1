"""Work-precision benchmark: every method of ``METHODS`` on the benchmark scenes.

For each scene and method, a sweep over step sizes (fixed-step methods) or tolerances
(adaptive ones). Each run is one task, a pure function of (scene, method, setting) and of
the scene's reference, so the sweep gives the same errors on any scheduler: in this
process (``scheduler="synchronous"``), on a local Dask cluster (the default) or on an
existing one (``scheduler="tcp://host:8786"``). A task records

- ``cpu_s``: ``time.process_time()`` of the run (assembly included) in the worker, after
  an untimed warm-up per worker (numba compiles the kernel once per installation, loads
  it once per process: neither is the method's work);
- ``error``: the error against the scene's reference (exact where one exists, otherwise a
  converged run of ``REFERENCE_METHOD``), see each ``Case``;
- ``energy_drift``: max |E(t) - E(0)| over the run, relative to the largest kinetic energy
  (E includes the work of constant torques; blank for driven scenes);
- ``constraint_drift`` / ``velocity_drift``: the largest norm of Psi and of Psi_q q' - nu;
- the integrator's work counters (``nsteps``, ``naccel``, ...);
- ``status`` ok / failed, and for failures the reason (a ``SolverError``'s message, or the
  bench's CPU budget per run).

``run_bench`` writes ``results.csv``; ``charts`` draws the charts and the summary from that
CSV (``mbdfmu bench --from-csv`` redraws them without running anything). The cases
(scenes, horizons, sweeps and error functions) are in ``cases.py``.
"""

from __future__ import annotations

import csv
import math
import os
import sys
import time
from pathlib import Path

import numpy as np

from ..errors import SolverError
from ..integrators import METHODS
from ..model.scene import PointForce, Torque
from ..simulation import Simulation
from . import closed_forms
from .cases import (ATOL_FACTOR, CASES, DEFAULT_SCENES, ERRORS, EXACT_P2, BenchError, Case,
                    angles, case_of, case_scene, error_converged, get, horizon, length_scale)

# The method and tolerance of converged references (scenes without an exact one).
REFERENCE_METHOD = "dop853p"
REFERENCE_RTOL = 1e-12
CHECK_RTOL = 1e-11             # a second converged run: its difference bounds the reference's error
# A run is stopped, and recorded as failed, once it has used this much CPU time.
CPU_BUDGET_S = 60.0
QUICK_CPU_BUDGET_S = 10.0
# Stability classes (per run): thresholds on the drifts and on the error.
STABLE_CONSTRAINT_DRIFT = 1e-6  # times the scene's length scale
STABLE_ENERGY_DRIFT = 1e-3      # relative to the largest kinetic energy
UNSTABLE_CONSTRAINT_DRIFT = 1e-1
UNSTABLE_ERROR = 1e-1           # in the scene's error units (m or rad on metre-sized scenes)
# Dask: a local cluster of this many single-threaded worker processes: one per core.
LOCAL_WORKERS = max(1, len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity")
                    else os.cpu_count() or 1)
WORKER_ENV = {"OMP_NUM_THREADS": "1", "OPENBLAS_NUM_THREADS": "1", "MKL_NUM_THREADS": "1"}

CSV_FIELDS = ["scene", "method", "kind", "setting", "status", "stability", "error",
              "energy_drift", "constraint_drift", "velocity_drift", "cpu_s", "t_reached",
              "nsteps", "nrejected", "naccel", "nprojections", "nnewton", "njev", "nlu",
              "reason"]


# ---------------------------------------------------------------------------- one run

def _energy(scene, out) -> np.ndarray | None:
    """Kinetic + potential energy minus the work of constant torques; None if driven."""
    if scene.drivers or any(isinstance(f, PointForce) and (f.input or any(f.value))
                            for f in scene.forces):
        return None
    energy = get(out, "energy.kinetic") + get(out, "energy.potential")
    for f in scene.forces:
        if isinstance(f, Torque):
            if f.input:
                return None
            phi = get(out, f"{f.body}.phi")
            energy = energy - f.value * (phi - phi[0])
    return energy


def simulate_outputs(scene, t_out, method, kind, setting, budget):
    """Run ``scene`` through the output times; returns (outputs dict, stats, t reached, reason).

    The loop of ``simulate()``, plus a CPU budget checked at each output time.
    """
    start = time.process_time()
    step, rtol, atol = None, None, None
    if kind == "step":
        step = setting
    else:
        rtol = setting
        atol = setting * ATOL_FACTOR * length_scale(scene)
    sim = None
    rows = []
    reason = ""
    try:
        sim = Simulation(scene, method=method, step=step, rtol=rtol, atol=atol)
        for t in t_out:
            sim.advance(float(t))
            rows.append(sim.output_vector())
            used = time.process_time() - start
            if used > budget and len(rows) < len(t_out):
                raise SolverError(f"bench: CPU budget of {budget:g} s per run used up", sim.t)
    except SolverError as exc:
        reason = str(exc)
    except (ArithmeticError, ValueError, np.linalg.LinAlgError) as exc:  # a bug, not a failure mode
        reason = f"unexpected {type(exc).__name__}: {exc}"
    names = sim.output_names if sim is not None else []
    values = np.array(rows) if rows else np.zeros((0, len(names)))
    out = {n: values[:, k] for k, n in enumerate(names)}
    stats = vars(sim.integrator.stats).copy() if sim is not None else {}
    t_reached = float(t_out[len(rows) - 1]) if rows else 0.0
    return out, stats, t_reached, reason


_warmed_up: set = set()


def _warm_up(case, scene, task, t_out) -> None:
    """A short untimed run of the task's scene and method, once per process."""
    key = (case.key, task["method"], task["kind"])
    if key in _warmed_up:
        return
    _warmed_up.add(key)
    simulate_outputs(scene, t_out[:2], task["method"], task["kind"], task["setting"], math.inf)


def run_task(task: dict) -> dict:
    """One run of the sweep: a pure function of ``task`` (scene key, method, kind, setting,
    quick, reference). Returns one CSV row (a dict over CSV_FIELDS)."""
    case = case_of(task["scene"])
    scene = case_scene(case)
    t_end, t_out = horizon(case, task["quick"])
    budget = QUICK_CPU_BUDGET_S if task["quick"] else CPU_BUDGET_S
    _warm_up(case, scene, task, t_out)
    start = time.process_time()
    out, stats, t_reached, reason = simulate_outputs(scene, t_out, task["method"], task["kind"],
                                                     task["setting"], budget)
    cpu = time.process_time() - start
    row = {f: "" for f in CSV_FIELDS}
    row.update(scene=case.key, method=task["method"], kind=task["kind"], setting=task["setting"],
               cpu_s=cpu, t_reached=t_reached, reason=reason)
    row.update({k: v for k, v in stats.items() if k in CSV_FIELDS})
    if reason:
        row["status"] = "failed"
    else:
        row["status"] = "ok"
        row["error"] = ERRORS[case.key](case, scene, t_out, out, task["reference"])
        row["constraint_drift"] = float(np.max(out["constraint.position_error"]))
        row["velocity_drift"] = float(np.max(out["constraint.velocity_error"]))
        energy = _energy(scene, out)
        if energy is not None:
            scale = max(float(np.max(out["energy.kinetic"])), 1e-300)
            row["energy_drift"] = float(np.max(np.abs(energy - energy[0]))) / scale
    row["stability"] = classify(row, length_scale(scene))
    return row


def classify(row: dict, length_scale: float = 1.0) -> str:
    """stable / drifting / unstable / failed, from a row's status, error and drifts."""
    if row["status"] != "ok":
        return "failed"
    err = _num(row["error"])
    drift = _num(row["constraint_drift"])
    energy = _num(row["energy_drift"])
    if not (math.isfinite(err) and err < UNSTABLE_ERROR) or \
            not drift < UNSTABLE_CONSTRAINT_DRIFT * length_scale:
        return "unstable"
    if drift > STABLE_CONSTRAINT_DRIFT * length_scale or \
            (math.isfinite(energy) and energy > STABLE_ENERGY_DRIFT):
        return "drifting"
    return "stable"


def _num(value) -> float:
    try:
        return float(value)
    except (TypeError, ValueError):
        return math.nan


# ---------------------------------------------------------------------------- references

def reference_for(case: Case, quick: bool, cache_dir: Path | None) -> tuple[dict, str]:
    """The data a case's error needs, and a line saying what it is and how good it is.

    Exact cases need nothing but their closed form (P2's reduction is evaluated here, once).
    Otherwise a converged run of REFERENCE_METHOD at REFERENCE_RTOL, cached as .npz in
    ``cache_dir``; a second run at CHECK_RTOL bounds its error.
    """
    t_end, t_out = horizon(case, quick)
    if case.key in EXACT_P2:
        return closed_forms.n_four_bar_B0(t_out, EXACT_P2[case.key]), case.reference
    if ERRORS[case.key] is not error_converged:
        return {}, case.reference
    method = REFERENCE_METHOD if REFERENCE_METHOD in METHODS else \
        next(n for n, c in METHODS.items() if c.adaptive)
    tag = f"{case.key}_{'quick' if quick else 'full'}_{method}_{REFERENCE_RTOL:g}"
    path = cache_dir / f"reference_{tag}.npz" if cache_dir is not None else None
    if path is not None and path.exists():
        data = np.load(path)
        if data["t"].shape == t_out.shape and np.allclose(data["t"], t_out, rtol=0, atol=0):
            return {"angles": data["angles"]}, _converged_note(case, method, float(data["check"]))
    scene = case_scene(case)
    runs = []
    for rtol in (REFERENCE_RTOL, CHECK_RTOL):
        out, _, _, reason = simulate_outputs(scene, t_out, method, "rtol", rtol, math.inf)
        if reason:
            raise BenchError(f"{case.key}: the converged reference run failed: {reason}")
        runs.append(angles(scene, out))
    check = float(np.max(np.abs(runs[0] - runs[1])))
    if path is not None:
        path.parent.mkdir(parents=True, exist_ok=True)
        np.savez(path, t=t_out, angles=runs[0], check=check)
    return {"angles": runs[0]}, _converged_note(case, method, check)


def _converged_note(case, method, check):
    return (f"{case.reference}: {method} at rtol {REFERENCE_RTOL:g}; differs from rtol "
            f"{CHECK_RTOL:g} by {check:.2g}")


# ---------------------------------------------------------------------------- the sweep

def make_tasks(scenes, methods, quick: bool, refs: dict) -> list[dict]:
    tasks = []
    for key in scenes:
        case = case_of(key)
        for name in methods:
            adaptive = METHODS[name].adaptive
            kind = "rtol" if adaptive else "step"
            if quick:
                settings = case.quick_tols if adaptive else case.quick_steps
            else:
                settings = case.tols if adaptive else case.steps
            for s in settings:
                tasks.append({"scene": key, "method": name, "kind": kind, "setting": float(s),
                              "quick": quick, "reference": refs[key]})
    return tasks


def _expected_cost(task) -> float:
    """Rough relative cost, to start the long runs first (better load balance)."""
    case = CASES[task["scene"]]
    t_end = case.quick_t_end if task["quick"] else case.t_end
    n = t_end / task["setting"] if task["kind"] == "step" else -math.log10(task["setting"]) * 50
    return n * (20.0 if task["scene"] == "P2N40" else 1.0)


def run_tasks(tasks: list[dict], scheduler: str | None = None, progress: bool = True) -> list[dict]:
    """Run the tasks and return their rows, in the order of ``tasks``.

    ``scheduler``: None starts a LocalCluster (LOCAL_WORKERS single-threaded processes);
    "synchronous" runs them here, one after the other; anything else is the address of a
    running Dask scheduler (its workers need mbdfmu installed).
    """
    try:
        from tqdm import tqdm
    except ImportError:
        raise BenchError("mbdfmu bench needs tqdm and dask[distributed]: "
                         "pip install 'mbdfmu[bench]'") from None
    order = sorted(range(len(tasks)), key=lambda i: -_expected_cost(tasks[i]))
    bar = tqdm(total=len(tasks), desc="bench", unit="run", disable=not progress, file=sys.stderr)
    rows: list[dict | None] = [None] * len(tasks)
    if scheduler == "synchronous":
        for i in order:
            rows[i] = run_task(tasks[i])
            bar.update()
        bar.close()
        return rows
    try:
        from dask.distributed import Client, LocalCluster, as_completed
    except ImportError:
        raise BenchError("mbdfmu bench needs dask[distributed]: pip install 'mbdfmu[bench]' "
                         "(or use --scheduler synchronous)") from None
    cluster = None
    try:
        if scheduler is None:
            cluster = LocalCluster(n_workers=LOCAL_WORKERS, threads_per_worker=1, processes=True,
                                   dashboard_address=":0", env=WORKER_ENV)
            client = Client(cluster)
        else:
            try:
                client = Client(scheduler, timeout="20s")
            except (OSError, TimeoutError) as exc:
                raise BenchError(f"cannot reach the Dask scheduler at {scheduler}: {exc}") from None
        with client:
            futures = {}
            for i in order:
                t = tasks[i]
                key = f"bench-{t['scene']}-{t['method']}-{t['kind']}-{t['setting']!r}-{i}"
                futures[client.submit(run_task, t, key=key, pure=False)] = i
            for fut in as_completed(futures):
                rows[futures[fut]] = fut.result()
                bar.update()
    finally:
        bar.close()
        if cluster is not None:
            cluster.close()
    return rows


def write_csv(rows: list[dict], path: Path) -> Path:
    with open(path, "w", newline="", encoding="utf-8") as fh:
        w = csv.DictWriter(fh, fieldnames=CSV_FIELDS, extrasaction="ignore")
        w.writeheader()
        for r in rows:
            w.writerow({k: (repr(v) if isinstance(v, float) else v) for k, v in r.items()})
    return path


def read_rows(path: Path) -> list[dict]:
    """Rows of a results.csv, numbers as floats (blank: nan)."""
    numeric = {"setting", "error", "energy_drift", "constraint_drift", "velocity_drift", "cpu_s",
               "t_reached", "nsteps", "nrejected", "naccel", "nprojections", "nnewton", "njev",
               "nlu"}
    with open(path, newline="", encoding="utf-8") as fh:
        return [{k: (_num(v) if k in numeric else v) for k, v in r.items()}
                for r in csv.DictReader(fh)]


def run_bench(scenes=None, methods=None, scheduler=None, output=None, quick=False,
              progress=True) -> dict:
    """The whole benchmark: references, the sweep, results.csv, the charts and summary.md.

    Returns ``{"rows": [...], "csv": path, "summary": path, "charts": [paths]}``.
    """
    from . import charts

    scenes = list(scenes or DEFAULT_SCENES)
    for key in scenes:
        case_of(key)
    methods = list(methods or METHODS)
    unknown = [m for m in methods if m not in METHODS]
    if unknown:
        raise BenchError(f'unknown method {", ".join(unknown)}; expected one of '
                         f'{", ".join(METHODS)}')
    out = Path(output or "bench")
    out.mkdir(parents=True, exist_ok=True)
    refs, notes = {}, {}
    for key in scenes:
        refs[key], notes[key] = reference_for(CASES[key], quick, out / "reference_cache")
    tasks = make_tasks(scenes, methods, quick, refs)
    wall = time.perf_counter()
    rows = run_tasks(tasks, scheduler, progress)
    wall = time.perf_counter() - wall
    csv_path = write_csv(rows, out / "results.csv")
    rows = read_rows(csv_path)  # charts and summary are drawn from the CSV
    drawn = charts.draw_all(rows, out)
    summary = charts.write_summary(rows, out / "summary.md", notes=notes,
                                   footer=_run_note(scheduler, quick, wall, len(tasks)))
    return {"rows": rows, "csv": csv_path, "summary": summary, "charts": drawn}


def _run_note(scheduler, quick, wall, n):
    where = {None: f"a LocalCluster of {LOCAL_WORKERS} single-threaded workers",
             "synchronous": "the synchronous scheduler"}.get(scheduler, f"the scheduler {scheduler}")
    return (f"{n} runs ({'quick' if quick else 'full'} sweep) on {where} in {wall:.0f} s wall "
            f"time; CPU budget per run {QUICK_CPU_BUDGET_S if quick else CPU_BUDGET_S:g} s; "
            f"mbdfmu methods: {', '.join(METHODS)}.")


def redraw(csv_path, output=None) -> dict:
    """Charts and summary again from an existing results.csv (no runs)."""
    from . import charts

    csv_path = Path(csv_path)
    out = Path(output) if output else csv_path.parent
    out.mkdir(parents=True, exist_ok=True)
    rows = read_rows(csv_path)
    notes = {k: c.reference for k, c in CASES.items()}
    drawn = charts.draw_all(rows, out)
    summary = charts.write_summary(rows, out / "summary.md", notes=notes)
    return {"rows": rows, "csv": csv_path, "summary": summary, "charts": drawn}


__all__ = ["CASES", "Case", "BenchError", "run_bench", "run_task", "run_tasks", "make_tasks",
           "reference_for", "classify", "read_rows", "write_csv", "redraw"]
