"""The communication-step sweep of ``mbdfmu bench``: the FMU's use pattern (issue 12).

A co-simulation master steps an FMU at a fixed communication step h: every point
t_k = k h ends one ``Simulation.advance`` call, as in the FMU's doStep. Each method runs
each case of the sweep (``cases.Case.comm_t_end``) so, at each h of ``cases.COMM_STEPS``:
fixed-step methods at the case's ``comm_step``, which the points only clip; adaptive ones
and ``auto`` at each rtol of ``cases.COMM_TOLS`` with atol by the solver's own rule (so
rtol 1e-6 is the default settings). The outputs are recorded at about ``n_out`` of the
points, where the error is measured as in the settings sweep; rows carry ``comm_step``.
"""

from __future__ import annotations

import math
import time

import numpy as np

from ..integrators import METHODS
from .cases import COMM_STEPS, COMM_TOLS, Case, case_of, case_scene
from .runs import result_row, simulate_outputs


def comm_cases(scenes) -> list[str]:
    """The scenes of ``scenes`` that are in the communication-step sweep."""
    return [k for k in scenes if case_of(k).comm_t_end is not None]


def comm_points(t_end: float, h: float) -> np.ndarray:
    """The communication points k h up to ``t_end`` (the last one clipped to it)."""
    n = max(1, math.ceil(t_end / h - 1e-9))
    return np.minimum(np.arange(1, n + 1) * h, t_end)


def comm_samples(case: Case, h: float, quick: bool) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(points, indices of the recorded ones, their times): every ``stride``-th point, so
    about ``n_out`` of them, and always the last."""
    t_end = case.quick_comm_t_end if quick else case.comm_t_end
    points = comm_points(t_end, h)
    stride = max(1, round(t_end / case.n_out / h))
    idx = np.arange(stride - 1, len(points), stride)
    if idx.size == 0 or idx[-1] != len(points) - 1:
        idx = np.append(idx, len(points) - 1)
    return points, idx, points[idx]


def is_adaptive(method: str) -> bool:
    """``auto`` runs at rtol (whatever it picks), as the adaptive methods."""
    return method not in METHODS or METHODS[method].adaptive


def make_comm_tasks(scenes, methods, comm_steps, quick: bool, refs: dict) -> list[dict]:
    """One task per case, method, setting and communication step; ``refs[(key, h)]`` is the
    reference data of the case's recorded times at h."""
    tasks = []
    for key in comm_cases(scenes):
        case = case_of(key)
        for name in methods:
            adaptive = is_adaptive(name)
            for s in (COMM_TOLS if adaptive else (case.comm_step,)):
                for h in comm_steps:
                    tasks.append({"scene": key, "method": name, "kind": "rtol" if adaptive
                                  else "step", "setting": float(s), "comm_step": float(h),
                                  "quick": quick, "reference": refs[(key, float(h))]})
    return tasks


def run_comm_task(task: dict, budget: float) -> dict:
    """One run of the communication-step sweep: one CSV row."""
    case = case_of(task["scene"])
    scene = case_scene(case)
    points, idx, t_rec = comm_samples(case, task["comm_step"], task["quick"])
    start = time.process_time()
    run = simulate_outputs(scene, points, task["method"], task["kind"], task["setting"], budget,
                           record=idx, bench_atol=False)
    cpu = time.process_time() - start
    return result_row(case, scene, task, run, cpu, t_rec, comm_step=task["comm_step"])


def expected_cost(task) -> float:
    """Rough relative cost (the number of points, more for small steps and N = 40)."""
    case = case_of(task["scene"])
    t_end = case.quick_comm_t_end if task["quick"] else case.comm_t_end
    n = t_end / min(task["comm_step"], task["setting"] if task["kind"] == "step" else math.inf)
    return n * (20.0 if task["scene"] == "P2N40" else 1.0)


def parse_comm_steps(text: str | None) -> tuple[float, ...]:
    """``--comm-steps``: comma-separated steps (s), "none" for no communication-step sweep,
    None for ``cases.COMM_STEPS``."""
    from .cases import BenchError

    if text is None:
        return COMM_STEPS
    if text.strip().lower() == "none":
        return ()
    steps = []
    for item in text.split(","):
        try:
            h = float(item)
        except ValueError:
            h = math.nan
        if not (math.isfinite(h) and h > 0):
            raise BenchError(f'--comm-steps: "{item.strip()}" is not a positive step in s '
                             '(expected e.g. 1e-4,1e-3,1e-2,0.1 or none)')
        steps.append(h)
    return tuple(steps)


__all__ = ["comm_cases", "comm_points", "comm_samples", "make_comm_tasks", "run_comm_task",
           "parse_comm_steps", "is_adaptive"]
