"""One run of the bench: stepping a scene through a list of points, the row it gives.

A run is ``Simulation.advance`` to each point in turn, the outputs recorded at some of
them: every output time in the settings sweep (``sweep.py``), every few communication
points in the communication-step sweep (``comm.py``), as a co-simulation master steps an
FMU. ``result_row`` turns a run into one row of results.csv and ``classify`` gives it its
stability class.
"""

from __future__ import annotations

import math
import time

import numpy as np

from ..errors import SolverError, WorkLimitError
from ..integrators.base import WorkLimit
from ..integrators.c_steps import MIN_CPU_LIMIT
from ..model.scene import PointForce, Torque
from ..simulation import Simulation
from .cases import ATOL_FACTOR, ERRORS, get, length_scale

# Stability classes (per run): thresholds on the drifts and on the error.
STABLE_CONSTRAINT_DRIFT = 1e-6  # times the scene's length scale
STABLE_ENERGY_DRIFT = 1e-3      # relative to the largest kinetic energy
UNSTABLE_CONSTRAINT_DRIFT = 1e-1
UNSTABLE_ERROR = 1e-1           # in the scene's error units (m or rad on metre-sized scenes)

CSV_FIELDS = ["scene", "method", "kind", "setting", "comm_step", "status", "stability", "error",
              "energy_drift", "constraint_drift", "velocity_drift", "error_estimate", "cpu_s",
              "t_reached", "nsteps", "nrejected", "naccel", "nprojections", "nnewton", "njev", "nlu",
              "reason"]


def energy(scene, out) -> np.ndarray | None:
    """Kinetic + potential energy minus the work of constant torques; None if driven."""
    if scene.drivers or any(isinstance(f, PointForce) and (f.input or any(f.value))
                            for f in scene.forces):
        return None
    total = get(out, "energy.kinetic") + get(out, "energy.potential")
    for f in scene.forces:
        if isinstance(f, Torque):
            if f.input:
                return None
            phi = get(out, f"{f.body}.phi")
            total = total - f.value * (phi - phi[0])
    return total


def tolerances(scene, kind, setting, bench_atol=True):
    """(step, rtol, atol) of a run: a fixed step, or rtol with atol = rtol x ATOL_FACTOR x
    the scene's size (``bench_atol``) or atol left to the solver's default rule."""
    if kind == "step":
        return setting, None, None
    return None, setting, setting * ATOL_FACTOR * length_scale(scene) if bench_atol else None


def simulate_outputs(scene, t_out, method, kind, setting, budget, record=None, bench_atol=True):
    """Advance ``scene`` to each point of ``t_out``; returns (outputs dict, stats, t reached,
    reason). ``record``: the indices of the points whose outputs are kept (default all).

    The loop of ``simulate()``, plus a CPU budget checked at each point and, as a work
    limit, within each ``advance``.
    """
    start = time.process_time()
    step, rtol, atol = tolerances(scene, kind, setting, bench_atol)
    keep = np.zeros(len(t_out), bool)
    keep[np.arange(len(t_out)) if record is None else np.asarray(record, int)] = True
    sim, rows, reason, reached = None, [], "", 0.0
    try:
        sim = Simulation(scene, method=method, step=step, rtol=rtol, atol=atol)
        for k, t in enumerate(t_out):
            left = budget - (time.process_time() - start)
            try:     # inside a call too: one point can take longer than the whole budget
                sim.advance(float(t), WorkLimit(max_cpu=max(left, MIN_CPU_LIMIT)))
            except WorkLimitError:
                raise SolverError(f"bench: CPU budget of {budget:g} s per run used up",
                                  sim.t) from None
            reached = float(t)
            if keep[k]:
                rows.append(sim.output_vector())
            if k + 1 < len(t_out) and time.process_time() - start > budget:
                raise SolverError(f"bench: CPU budget of {budget:g} s per run used up", sim.t)
    except SolverError as exc:
        reason = str(exc)
    except (ArithmeticError, ValueError, np.linalg.LinAlgError) as exc:  # a bug, not a failure mode
        reason = f"unexpected {type(exc).__name__}: {exc}"
    names = sim.output_names if sim is not None else []
    values = np.array(rows) if rows else np.zeros((0, len(names)))
    out = {n: values[:, k] for k, n in enumerate(names)}
    stats = vars(sim.integrator.stats).copy() if sim is not None else {}
    return out, stats, reached, reason


def result_row(case, scene, task, run, cpu, t_out, comm_step=math.nan) -> dict:
    """One CSV row of a run: ``run`` is what ``simulate_outputs`` returned, ``t_out`` the
    times of its recorded outputs (where the error is measured)."""
    out, stats, t_reached, reason = run
    row = {f: "" for f in CSV_FIELDS}
    row.update(scene=case.key, method=task["method"], kind=task["kind"], setting=task["setting"],
               comm_step=comm_step if math.isfinite(comm_step) else "", cpu_s=cpu,
               t_reached=t_reached, reason=reason)
    row.update({k: v for k, v in stats.items() if k in CSV_FIELDS})
    if reason:
        row["status"] = "failed"
    else:
        row["status"] = "ok"
        row["error"] = ERRORS[case.key](case, scene, t_out, out, task["reference"])
        row["constraint_drift"] = float(np.max(out["constraint.position_error"]))
        row["velocity_drift"] = float(np.max(out["constraint.velocity_error"]))
        e = energy(scene, out)
        if e is not None:
            scale = max(float(np.max(out["energy.kinetic"])), 1e-300)
            row["energy_drift"] = float(np.max(np.abs(e - e[0]))) / scale
    row["stability"] = classify(row, length_scale(scene))
    return row


def classify(row: dict, length_scale: float = 1.0) -> str:
    """stable / drifting / unstable / failed, from a row's status, error and drifts."""
    if row["status"] != "ok":
        return "failed"
    err = num(row["error"])
    drift = num(row["constraint_drift"])
    e = num(row["energy_drift"])
    if not (math.isfinite(err) and err < UNSTABLE_ERROR) or \
            not drift < UNSTABLE_CONSTRAINT_DRIFT * length_scale:
        return "unstable"
    if drift > STABLE_CONSTRAINT_DRIFT * length_scale or \
            (math.isfinite(e) and e > STABLE_ENERGY_DRIFT):
        return "drifting"
    return "stable"


def num(value) -> float:
    try:
        return float(value)
    except (TypeError, ValueError):
        return math.nan
