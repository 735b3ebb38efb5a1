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

from ..integrators import METHOD_NAMES, METHODS
from . import closed_forms, comm
from .cases import (CASES, COMM_STEPS, DEFAULT_SCENES, ERRORS, EXACT_P2, BenchError, Case, angles, case_of,
                    case_scene, error_converged, horizon)
from .runs import CSV_FIELDS, classify, num, result_row, simulate_outputs

# The method and tolerance of converged references (scenes without an exact one).
REFERENCE_METHOD = "dop853p"
REFERENCE_RTOL = 1e-12
CHECK_RTOL = 1e-11             # a second converged run: its difference bounds the reference's error
# A run is stopped, and recorded as failed, once it has used this much CPU time.
CPU_BUDGET_S = 60.0
QUICK_CPU_BUDGET_S = 10.0
# Dask: a local cluster of this many single-threaded worker processes: one per core.
LOCAL_WORKERS = max(1, len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity")
                    else os.cpu_count() or 1)
WORKER_ENV = {"OMP_NUM_THREADS": "1", "OPENBLAS_NUM_THREADS": "1", "MKL_NUM_THREADS": "1"}

# ---------------------------------------------------------------------------- one run

_warmed_up: set = set()


def _warm_up(case, scene, task, t_out) -> None:
    """A short untimed run of the task's scene and method, once per process."""
    key = (case.key, task["method"], task["kind"])
    if key in _warmed_up:
        return
    _warmed_up.add(key)
    simulate_outputs(scene, t_out[:2], task["method"], task["kind"], task["setting"], math.inf)


def run_task(task: dict) -> dict:
    """One run of the bench: a pure function of ``task`` (scene key, method, kind, setting,
    quick, reference; ``comm_step`` in the communication-step sweep). Returns one CSV row
    (a dict over CSV_FIELDS)."""
    case = case_of(task["scene"])
    scene = case_scene(case)
    t_end, t_out = horizon(case, task["quick"])
    budget = QUICK_CPU_BUDGET_S if task["quick"] else CPU_BUDGET_S
    _warm_up(case, scene, task, t_out)
    if "comm_step" in task:
        return comm.run_comm_task(task, budget)
    start = time.process_time()
    run = simulate_outputs(scene, t_out, task["method"], task["kind"], task["setting"], budget)
    return result_row(case, scene, task, run, time.process_time() - start, t_out)


# ---------------------------------------------------------------------------- references

def reference_for(case: Case, quick: bool, cache_dir: Path | None, t_out=None,
                  tag: str = "") -> tuple[dict, str]:
    """The data a case's error needs at ``t_out`` (default: the sweep's output times), and a
    line saying what it is and how good it is.

    Exact cases need nothing but their closed form (P2's reduction is evaluated here, once).
    Otherwise a converged run of REFERENCE_METHOD at REFERENCE_RTOL, cached as .npz in
    ``cache_dir`` (``tag`` tells other output times apart); a second run at CHECK_RTOL
    bounds its error.
    """
    if t_out is None:
        t_out = horizon(case, quick)[1]
    if case.key in EXACT_P2:
        return closed_forms.n_four_bar_B0(t_out, EXACT_P2[case.key]), case.reference
    if ERRORS[case.key] is not error_converged:
        return {}, case.reference
    method = REFERENCE_METHOD if REFERENCE_METHOD in METHODS else \
        next(n for n, c in METHODS.items() if c.adaptive)
    tag = f"{case.key}_{'quick' if quick else 'full'}{tag}_{method}_{REFERENCE_RTOL:g}"
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
            adaptive = comm.is_adaptive(name)
            kind = "rtol" if adaptive else "step"
            if quick:
                settings = case.quick_tols if adaptive else case.quick_steps
            else:
                settings = case.tols if adaptive else case.steps_for(name)
            for s in settings:
                tasks.append({"scene": key, "method": name, "kind": kind, "setting": float(s),
                              "quick": quick, "reference": refs[key]})
    return tasks


def _expected_cost(task) -> float:
    """Rough relative cost, to start the long runs first (better load balance)."""
    if "comm_step" in task:
        return comm.expected_cost(task)
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
                key = f"bench-{t['scene']}-{t['method']}-{t['kind']}-{t['setting']!r}-" \
                    f"{t.get('comm_step', '')!r}-{i}"
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
    numeric = {"setting", "comm_step", "error", "energy_drift", "constraint_drift", "velocity_drift",
               "error_estimate", "cpu_s",
               "t_reached", "nsteps", "nrejected", "naccel", "nprojections", "nnewton", "njev",
               "nlu"}
    with open(path, newline="", encoding="utf-8") as fh:
        return [{k: (num(v) if k in numeric else v) for k, v in r.items()}
                for r in csv.DictReader(fh)]


def run_bench(scenes=None, methods=None, scheduler=None, output=None, quick=False,
              progress=True, comm_steps=COMM_STEPS, settings_sweep=True) -> dict:
    """The whole benchmark: references, the settings sweep (unless not ``settings_sweep``),
    the communication-step sweep at ``comm_steps`` (s; empty: none), results.csv, the charts
    and summary.md.

    Returns ``{"rows": [...], "csv": path, "summary": path, "charts": [paths]}``.
    """
    from . import charts

    scenes = list(scenes or DEFAULT_SCENES)
    for key in scenes:
        case_of(key)
    methods = list(methods or METHOD_NAMES)
    unknown = [m for m in methods if m not in METHOD_NAMES]
    if unknown:
        raise BenchError(f'unknown method {", ".join(unknown)}; expected one of '
                         f'{", ".join(METHOD_NAMES)}')
    comm_steps = tuple(float(h) for h in comm_steps)
    if not settings_sweep and not (comm_steps and comm.comm_cases(scenes)):
        raise BenchError("nothing to run: no settings sweep, and no communication steps or no "
                         f"scene of the communication-step sweep "
                         f"({', '.join(comm.comm_cases(DEFAULT_SCENES))}) chosen")
    out = Path(output or "bench")
    out.mkdir(parents=True, exist_ok=True)
    cache = out / "reference_cache"
    refs, notes, tasks = {}, {}, []
    if settings_sweep:
        for key in scenes:
            refs[key], notes[key] = reference_for(CASES[key], quick, cache)
        tasks = make_tasks(scenes, methods, quick, refs)
    if comm_steps:
        for key in comm.comm_cases(scenes):
            for h in comm_steps:
                t_rec = comm.comm_samples(CASES[key], h, quick)[2]
                refs[(key, h)], notes[key] = reference_for(CASES[key], quick, cache, t_rec,
                                                           f"_comm{h:g}")
        tasks += comm.make_comm_tasks(scenes, methods, comm_steps, quick, refs)
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
            f"mbdfmu methods: {', '.join(METHOD_NAMES)}.")


def _part(row: dict) -> tuple:
    """The part of the bench a row belongs to: its scene, method and sweep."""
    comm_step = row.get("comm_step")
    settings = comm_step is None or comm_step == "" or (
        isinstance(comm_step, float) and math.isnan(comm_step))
    return row["scene"], row["method"], "settings" if settings else "comm"


def merged_rows(earlier: list[dict], later: list[dict]) -> list[dict]:
    """``earlier``'s rows with those of every part (scene, method, sweep) that ``later``
    has replaced by ``later``'s: a rerun of a part supersedes it as a whole."""
    rerun = {_part(r) for r in later}
    return [r for r in earlier if _part(r) not in rerun] + list(later)


def redraw(csv_paths, output=None) -> dict:
    """Charts and summary again from existing results.csv files (no runs). Several CSVs
    (e.g. the two sweeps run apart) are merged into ``output``/results.csv first, a later
    file's rows replacing an earlier one's for the same scene, method and sweep."""
    from . import charts

    paths = [Path(p) for p in ([csv_paths] if isinstance(csv_paths, (str, Path)) else csv_paths)]
    out = Path(output) if output else paths[0].parent
    out.mkdir(parents=True, exist_ok=True)
    rows = []
    for p in paths:
        if not p.is_file():
            raise BenchError(f"--from-csv: {p}: no such file")
        rows = merged_rows(rows, read_rows(p))
    csv_path = paths[0]
    if len(paths) > 1:
        csv_path = write_csv(rows, out / "results.csv")
        rows = read_rows(csv_path)
    notes = {k: c.reference for k, c in CASES.items()}
    drawn = charts.draw_all(rows, out)
    summary = charts.write_summary(rows, out / "summary.md", notes=notes)
    return {"rows": rows, "csv": csv_path, "summary": summary, "charts": drawn}


__all__ = ["CASES", "Case", "BenchError", "run_bench", "run_task", "run_tasks", "make_tasks",
           "reference_for", "classify", "read_rows", "write_csv", "merged_rows", "redraw"]
