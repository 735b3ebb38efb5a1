"""The FMU's use pattern: P2 (N = 2 and 40) stepped through ``Simulation.advance`` at
communication steps of 0.1 ms to 0.1 s, as a co-simulation master steps an FMU (every
communication point ends a call; the scene has no inputs, so adaptive methods keep their
step sequence and give the points from dense output).

Error: B0's position (the top of crank0) against the exact one-degree-of-freedom reduction
(``bench.closed_forms.n_four_bar_B0``) at t = 10 and 20 s (m). A run that stops prints its
SolverError; a run that claims success with an error above 100 x rtol (times the
mechanism's size, 1 m) counts as silently wrong. Targets (issue 12): default settings
within 1e-6 (N = 2) and 1e-5 (N = 40); rtol 1e-10 within 1e-9 and 1e-7.
``--api simulate``: ``mbdfmu.simulate(scene, t_end, output_interval=h)`` instead, the steps
being output intervals.

    python benchmarks/comm_steps.py [--kernel c] [--n 2 40] [--steps 1e-4 1e-3 1e-2 0.1]
                                    [--rtol default 1e-10] [--t-end 20] [-o FILE.md]
                                    [--api advance|simulate]
"""

from __future__ import annotations

import os

for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import argparse  # noqa: E402
import math  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402

import mbdfmu  # noqa: E402
from mbdfmu.bench.closed_forms import n_four_bar_B0  # noqa: E402
from mbdfmu.integrators.settings import DEFAULT_RTOL  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
TARGETS = {("default", 2): 1e-6, ("default", 40): 1e-5, ("1e-10", 2): 1e-9, ("1e-10", 40): 1e-7}
SILENT_FACTOR = 100.0


def b0(sim) -> np.ndarray:
    out = sim.outputs()
    phi = out["crank0.phi"]
    return np.array([out["crank0.x"] + 0.5 * math.cos(phi), out["crank0.y"] + 0.5 * math.sin(phi)])


def run_simulate(n: int, h: float, rtol: str, kernel: str, t_end: float) -> dict:
    """The same through ``mbdfmu.simulate`` at output interval h."""
    scene = mbdfmu.load_scene(ROOT / "scenes" / f"n_four_bar_{n}.toml")
    kw = {} if rtol == "default" else {"rtol": float(rtol)}
    checks = [t for t in (10.0, 20.0) if t <= t_end]
    exact = n_four_bar_B0(np.array(checks), n)
    errors, stopped, method = {}, "", ""
    rtol_value = DEFAULT_RTOL if rtol == "default" else float(rtol)
    start = time.process_time()
    try:
        res = mbdfmu.simulate(scene, t_end, kernel=kernel, output_interval=h, **kw)
        method = res.method
        for j, tc in enumerate(checks):
            k = int(np.argmin(np.abs(res.time - tc)))
            phi = res["crank0.phi"][k]
            bx, by = res["crank0.x"][k] + 0.5 * math.cos(phi), res["crank0.y"][k] + 0.5 * math.sin(phi)
            errors[tc] = float(math.hypot(bx - exact["x"][j], by - exact["y"][j]))
    except mbdfmu.SolverError as exc:
        stopped = str(exc)
    return {"n": n, "h": h, "rtol": rtol, "method": method, "errors": errors,
            "stopped": stopped, "cpu": time.process_time() - start, "rtol_value": rtol_value}


def run(n: int, h: float, rtol: str, kernel: str, t_end: float) -> dict:
    scene = mbdfmu.load_scene(ROOT / "scenes" / f"n_four_bar_{n}.toml")
    kw = {} if rtol == "default" else {"rtol": float(rtol)}
    sim = mbdfmu.Simulation(scene, kernel=kernel, **kw)
    checks = [t for t in (10.0, 20.0) if t <= t_end]
    exact = n_four_bar_B0(np.array(checks), n)
    errors, stopped = {}, ""
    start = time.process_time()
    steps = round(t_end / h)
    try:
        for k in range(1, steps + 1):
            t = k * h
            sim.advance(t)
            for j, tc in enumerate(checks):
                if abs(t - tc) < 0.5 * h:
                    errors[tc] = float(np.hypot(*(b0(sim) - np.array([exact["x"][j],
                                                                         exact["y"][j]]))))
    except mbdfmu.SolverError as exc:
        stopped = str(exc)
    return {"n": n, "h": h, "rtol": rtol, "method": sim.method_name, "errors": errors,
            "stopped": stopped, "cpu": time.process_time() - start,
            "rtol_value": sim.integrator.rtol}


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--kernel", default="c")
    ap.add_argument("--n", type=int, nargs="+", default=[2, 40])
    ap.add_argument("--steps", type=float, nargs="+", default=[1e-4, 1e-3, 1e-2, 0.1])
    ap.add_argument("--rtol", nargs="+", default=["default", "1e-10"])
    ap.add_argument("--t-end", type=float, default=20.0)
    ap.add_argument("-o", "--output", type=Path)
    ap.add_argument("--api", choices=["advance", "simulate"], default="advance")
    args = ap.parse_args(argv)
    runner = run if args.api == "advance" else run_simulate
    lines = ["| N | rtol | step (s) | method | B0 error t=10 | B0 error t=20 | target | "
             "result | CPU (s) |", "|---|---|---|---|---|---|---|---|---|"]
    silent = 0
    for n in args.n:
        for rtol in args.rtol:
            for h in args.steps:
                r = runner(n, h, rtol, args.kernel, args.t_end)
                target = TARGETS.get((rtol, n), math.nan)
                errs = [r["errors"].get(t, math.nan) for t in (10.0, 20.0)]
                worst = max((e for e in errs if not math.isnan(e)), default=math.nan)
                if r["stopped"]:
                    verdict = "stopped: " + r["stopped"][:90]
                elif worst > SILENT_FACTOR * r["rtol_value"]:
                    verdict, silent = "SILENTLY WRONG", silent + 1
                else:
                    verdict = "meets target" if worst <= target else "misses target"
                lines.append(f"| {n} | {rtol} | {h:g} | {r['method']} | {errs[0]:.2g} | "
                             f"{errs[1]:.2g} | {target:g} | {verdict} | {r['cpu']:.1f} |")
                print(lines[-1], flush=True)
    lines.append(f"\nSilently wrong runs (success claimed, error above {SILENT_FACTOR:g} x "
                 f"rtol): {silent}; kernel {args.kernel}; {args.api}.")
    print(lines[-1])
    if args.output:
        args.output.write_text("\n".join(lines) + "\n")


if __name__ == "__main__":
    main()
