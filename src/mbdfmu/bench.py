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

``run_bench`` writes ``results.csv``; ``bench_charts`` draws the charts and the summary
from that CSV (``mbdfmu bench --from-csv`` redraws them without running anything).
"""

from __future__ import annotations

import csv
import math
import sys
import time
from dataclasses import dataclass
from importlib import resources
from pathlib import Path

import numpy as np

from . import references
from .errors import MbdfmuError, SolverError
from .integrators import METHODS
from .scene import PointForce, Torque, load_scene
from .simulation import Simulation, output_times

# The method and tolerance of converged references (scenes without an exact one).
REFERENCE_METHOD = "dop853p"
REFERENCE_RTOL = 1e-12
REFERENCE_ATOL_FACTOR = 1e-2   # atol = rtol * this (times the scene's length scale)
CHECK_RTOL = 1e-11             # a second converged run: its difference bounds the reference's error
# Absolute tolerance of the sweep's adaptive runs, relative to rtol.
ATOL_FACTOR = 1e-2
# A run is stopped, and recorded as failed, once it has used this much CPU time.
CPU_BUDGET_S = 60.0
QUICK_CPU_BUDGET_S = 10.0
# Stability classes (per run): thresholds on the drifts and on the error.
STABLE_CONSTRAINT_DRIFT = 1e-6  # times the scene's length scale
STABLE_ENERGY_DRIFT = 1e-3      # relative to the largest kinetic energy
UNSTABLE_CONSTRAINT_DRIFT = 1e-1
UNSTABLE_ERROR = 1e-1           # in the scene's error units (m or rad on metre-sized scenes)
# Error levels of the summary.
LEVELS = (1e-4, 1e-6, 1e-8)
# Dask: a local cluster of this many single-threaded worker processes.
LOCAL_WORKERS = 2
WORKER_ENV = {"OMP_NUM_THREADS": "1", "OPENBLAS_NUM_THREADS": "1", "MKL_NUM_THREADS": "1"}

CSV_FIELDS = ["scene", "method", "kind", "setting", "status", "stability", "error",
              "energy_drift", "constraint_drift", "velocity_drift", "cpu_s", "t_reached",
              "nsteps", "nrejected", "naccel", "nprojections", "nnewton", "njev", "nlu",
              "reason"]


class BenchError(MbdfmuError):
    """A benchmark that cannot run (unknown scene or method, missing Dask)."""


@dataclass(frozen=True)
class Case:
    """A benchmark scene: the file, the horizon, the sweep ranges and the reference.

    ``steps`` are the fixed steps (s) of fixed-step methods, ``tols`` the rtol of adaptive
    ones (atol = rtol * ATOL_FACTOR); the ``quick_*`` ones are the ``--quick`` sweep.
    ``reference`` says what the error is measured against (shown in the summary).
    """

    key: str
    scene: str
    title: str
    t_end: float
    steps: tuple[float, ...]
    tols: tuple[float, ...]
    reference: str
    n_out: int = 20       # output times (errors are the largest over them); fewer if a step is longer
    quick_t_end: float = 1.0
    quick_steps: tuple[float, ...] = (1e-2, 5e-3)
    quick_tols: tuple[float, ...] = (1e-4, 1e-6)


TOLS = tuple(10.0 ** -k for k in range(2, 12))  # rtol 1e-2 .. 1e-11

CASES: dict[str, Case] = {c.key: c for c in (
    Case("P1", "pendulum", "P1 pendulum, t = 10 s", 10.0,
         (1e-1, 5e-2, 2e-2, 1e-2, 5e-3, 2e-3, 1e-3, 5e-4), TOLS,
         "exact: elliptic solution (bob position, m)"),
    Case("P2N2", "n_four_bar_2", "P2 N-four-bar, N = 2, t = 10 s", 10.0,
         (1e-1, 5e-2, 2e-2, 1e-2, 5e-3, 2e-3, 1e-3, 5e-4), TOLS,
         "exact: one-DOF reduction at 1e-13 (B0 position, m)"),
    Case("P2N40", "n_four_bar_40", "P2 N-four-bar, N = 40, t = 2.5 s (two singular passes)", 2.5,
         (5e-2, 2e-2, 1e-2, 5e-3), (1e-3, 1e-4, 1e-6, 1e-8),
         "exact: one-DOF reduction at 1e-13 (B0 position, m)", n_out=10,
         quick_t_end=0.2, quick_steps=(2e-2,), quick_tols=(1e-4,)),
    Case("P3", "andrews", "P3 Andrews' mechanism, t = 0.03 s", 0.03,
         (5e-4, 2e-4, 1e-4, 5e-5, 2e-5, 1e-5, 5e-6, 2e-6), TOLS,
         "converged run (body angles, rad)", n_out=30, quick_t_end=0.003,
         quick_steps=(1e-4, 5e-5)),
    Case("P4", "slider_crank", "slider-crank (P4), t = 0.04 s (two turns)", 0.04,
         (5e-3, 2e-3, 1e-3, 5e-4, 2e-4, 1e-4, 5e-5, 2e-5), TOLS,
         "exact: P4 closed form (slider and rod centre, m)", quick_t_end=0.004,
         quick_steps=(1e-3, 5e-4)),
    Case("P6", "light_cart_pole", "P6 light cart-pole, t = 2 s (two spikes)", 2.0,
         (1e-2, 1e-3, 1e-4), (1e-2, 1e-4, 1e-6, 1e-8, 1e-10),
         "exact invariants: momentum (cart x / l) and energy (theta'^2 / its peak)"),
)}
DEFAULT_SCENES = tuple(CASES)


def case_of(key: str) -> Case:
    if key not in CASES:
        raise BenchError(f'unknown bench scene "{key}"; expected one of {", ".join(CASES)}')
    return CASES[key]


# ---------------------------------------------------------------------------- scenes and errors

def bundled_scene_path(name: str) -> Path:
    """A scene shipped with the package (mbdfmu.scenes)."""
    return Path(str(resources.files("mbdfmu.scenes").joinpath(f"{name}.toml")))


def _scene(case: Case):
    return load_scene(bundled_scene_path(case.scene))


def _get(out: dict, name: str) -> np.ndarray:
    return np.asarray(out[name], dtype=float)


def _error_P1(case, scene, t, out, ref):
    bob = scene.bodies[0]
    exact = references.pendulum(t, L=1.0, m=bob.mass, J=bob.inertia)
    return float(np.max(np.hypot(_get(out, "bob.x") - exact["x"], _get(out, "bob.y") - exact["y"])))


def _B0(out):
    phi = _get(out, "crank0.phi")
    return _get(out, "crank0.x") + 0.5 * np.cos(phi), _get(out, "crank0.y") + 0.5 * np.sin(phi)


def _error_P2(case, scene, t, out, ref):
    x, y = _B0(out)
    return float(np.max(np.hypot(x - ref["x"], y - ref["y"])))


def _error_P4(case, scene, t, out, ref):
    motor = scene.drivers[0].motion
    exact = references.slider_crank(motor.start + motor.rate * t, r=0.1, l=0.3)
    e_slider = np.abs(_get(out, "slider.x") - exact["xB"])
    e_rod = np.hypot(_get(out, "rod.x") - exact["rod_x"], _get(out, "rod.y") - exact["rod_y"])
    return float(max(e_slider.max(), e_rod.max()))


def _error_P6(case, scene, t, out, ref):
    cart, bob = scene.bodies
    dx = _get(out, "bob.x") - _get(out, "cart.x")
    dy = _get(out, "bob.y") - _get(out, "cart.y")
    theta = np.arctan2(dx, -dy)
    inv = references.cart_pole_invariants(theta, M=cart.mass, m=bob.mass, l=1.0, J=bob.inertia)
    peak = float(references.cart_pole_invariants(0.0, M=cart.mass, m=bob.mass, l=1.0,
                                                 J=bob.inertia)["theta_dot_sq"])
    e_x = np.abs(_get(out, "cart.x") - inv["x"])
    e_w = np.abs(_get(out, "bob.omega") ** 2 - inv["theta_dot_sq"]) / peak
    return float(max(e_x.max(), e_w.max()))


def _angles(scene, out):
    return np.column_stack([_get(out, f"{b.name}.phi") for b in scene.bodies])


def _error_converged(case, scene, t, out, ref):
    return float(np.max(np.abs(_angles(scene, out) - ref["angles"])))


ERRORS = {"P1": _error_P1, "P2N2": _error_P2, "P2N40": _error_P2, "P3": _error_converged,
          "P4": _error_P4, "P6": _error_P6}
EXACT_P2 = {"P2N2": 2, "P2N40": 40}


def horizon(case: Case, quick: bool) -> tuple[float, np.ndarray]:
    """End time and output times. Runs land exactly on each output time, which caps the
    step of every method: the interval is kept at least the sweep's largest step."""
    t_end = case.quick_t_end if quick else case.t_end
    largest = max(case.quick_steps if quick else case.steps)
    n = max(1, min(case.n_out, int(math.floor(t_end / largest * (1 + 1e-9)))))
    return t_end, output_times(t_end, t_end / n)


# ---------------------------------------------------------------------------- one run

def _energy(scene, out) -> np.ndarray | None:
    """Kinetic + potential energy minus the work of constant torques; None if driven."""
    if scene.drivers or any(isinstance(f, PointForce) and (f.input or any(f.value))
                            for f in scene.forces):
        return None
    energy = _get(out, "energy.kinetic") + _get(out, "energy.potential")
    for f in scene.forces:
        if isinstance(f, Torque):
            if f.input:
                return None
            phi = _get(out, f"{f.body}.phi")
            energy = energy - f.value * (phi - phi[0])
    return energy


def _length_scale(scene) -> float:
    return max([1.0] + [abs(v) for b in scene.bodies for v in b.position])


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
        atol = setting * ATOL_FACTOR * _length_scale(scene)
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
    scene = _scene(case)
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
    row["stability"] = classify(row, _length_scale(scene))
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
        return references.n_four_bar_B0(t_out, EXACT_P2[case.key]), case.reference
    if ERRORS[case.key] is not _error_converged:
        return {}, case.reference
    method = REFERENCE_METHOD if REFERENCE_METHOD in METHODS else \
        next(n for n, c in METHODS.items() if c.adaptive)
    tag = f"{case.key}_{'quick' if quick else 'full'}_{method}_{REFERENCE_RTOL:g}"
    path = cache_dir / f"reference_{tag}.npz" if cache_dir is not None else None
    if path is not None and path.exists():
        data = np.load(path)
        if data["t"].shape == t_out.shape and np.allclose(data["t"], t_out, rtol=0, atol=0):
            return {"angles": data["angles"]}, _converged_note(case, method, float(data["check"]))
    scene = _scene(case)
    runs = []
    for rtol in (REFERENCE_RTOL, CHECK_RTOL):
        out, _, _, reason = simulate_outputs(scene, t_out, method, "rtol", rtol, math.inf)
        if reason:
            raise BenchError(f"{case.key}: the converged reference run failed: {reason}")
        runs.append(_angles(scene, out))
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
    from . import bench_charts

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
    charts = bench_charts.draw_all(rows, out)
    summary = bench_charts.write_summary(rows, out / "summary.md", notes=notes,
                                         footer=_run_note(scheduler, quick, wall, len(tasks)))
    return {"rows": rows, "csv": csv_path, "summary": summary, "charts": charts}


def _run_note(scheduler, quick, wall, n):
    where = {None: f"a LocalCluster of {LOCAL_WORKERS} single-threaded workers",
             "synchronous": "the synchronous scheduler"}.get(scheduler, f"the scheduler {scheduler}")
    return (f"{n} runs ({'quick' if quick else 'full'} sweep) on {where} in {wall:.0f} s wall "
            f"time; CPU budget per run {QUICK_CPU_BUDGET_S if quick else CPU_BUDGET_S:g} s; "
            f"mbdfmu methods: {', '.join(METHODS)}.")


def redraw(csv_path, output=None) -> dict:
    """Charts and summary again from an existing results.csv (no runs)."""
    from . import bench_charts

    csv_path = Path(csv_path)
    out = Path(output) if output else csv_path.parent
    out.mkdir(parents=True, exist_ok=True)
    rows = read_rows(csv_path)
    notes = {k: c.reference for k, c in CASES.items()}
    charts = bench_charts.draw_all(rows, out)
    summary = bench_charts.write_summary(rows, out / "summary.md", notes=notes)
    return {"rows": rows, "csv": csv_path, "summary": summary, "charts": charts}


__all__ = ["CASES", "Case", "BenchError", "run_bench", "run_task", "run_tasks", "make_tasks",
           "reference_for", "classify", "read_rows", "write_csv", "redraw"]
