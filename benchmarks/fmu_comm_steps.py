"""P2 (scenes/n_four_bar_2.toml, _40.toml) as an FMU run by fmpy at communication steps of
0.1 ms to 0.1 s with default settings: B0's error against the exact one-degree-of-freedom
reduction (``bench.closed_forms.n_four_bar_B0``) at t = 10 and 20 s, or the reason the run
stopped. Issue 12's targets: within 1e-6 (N = 2) and 1e-5 (N = 40); with ``--rtol 1e-10``
(the FMU's ``solver.rtol`` parameter) within 1e-9 and 1e-7.

    python benchmarks/fmu_comm_steps.py [--n 2] [--steps 0.1 0.01 1e-3 1e-4] [--t-end 20]
        [--rtol 1e-10]
"""

from __future__ import annotations

import argparse
import math
import tempfile
import time
from pathlib import Path

import fmpy
import numpy as np

from mbdfmu.bench.closed_forms import n_four_bar_B0
from mbdfmu.fmu_build.scene_fmu import build_fmu

ROOT = Path(__file__).resolve().parents[1]
TARGETS = {None: {2: 1e-6, 40: 1e-5}, 1e-10: {2: 1e-9, 40: 1e-7}}


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n", type=int, nargs="+", default=[2])
    ap.add_argument("--steps", type=float, nargs="+", default=[0.1, 0.01, 1e-3, 1e-4])
    ap.add_argument("--t-end", type=float, default=20.0)
    ap.add_argument("--rtol", type=float, choices=[1e-10], default=None,
                    help="the FMU's solver.rtol (default: the FMU's own)")
    args = ap.parse_args(argv)
    targets = TARGETS[args.rtol]
    start_values = {} if args.rtol is None else {"solver.rtol": args.rtol}
    print(f"rtol: {'default' if args.rtol is None else args.rtol}")
    print("| N | step (s) | B0 error t=10 | B0 error t=20 | target | result | wall (s) |")
    print("|---|---|---|---|---|---|---|")
    with tempfile.TemporaryDirectory() as tmp:
        for n in args.n:
            fmu = build_fmu(ROOT / "scenes" / f"n_four_bar_{n}.toml", Path(tmp) / f"p2_{n}.fmu")
            for h in args.steps:
                start, verdict, errs = time.perf_counter(), "", [math.nan, math.nan]
                try:
                    res = fmpy.simulate_fmu(str(fmu), stop_time=args.t_end, step_size=h,
                                            output_interval=h, start_values=start_values,
                                            output=["crank0.x", "crank0.y", "crank0.phi"])
                    t = res["time"]
                    for j, tc in enumerate((10.0, 20.0)):
                        k = int(np.argmin(np.abs(t - tc)))
                        if abs(t[k] - tc) > 0.5 * h:
                            continue
                        ex = n_four_bar_B0(np.array([tc]), n)
                        bx = res["crank0.x"][k] + 0.5 * math.cos(res["crank0.phi"][k])
                        by = res["crank0.y"][k] + 0.5 * math.sin(res["crank0.phi"][k])
                        errs[j] = math.hypot(bx - ex["x"][0], by - ex["y"][0])
                    worst = max(errs)
                    verdict = "meets target" if worst <= targets.get(n, math.nan) else \
                        f"misses target (ended at t = {t[-1]:g})"
                except Exception as exc:     # fmpy raises on fmi2Error: the reason is logged
                    verdict = f"stopped: {str(exc)[:80]}"
                print(f"| {n} | {h:g} | {errs[0]:.2g} | {errs[1]:.2g} | "
                      f"{targets.get(n, math.nan):g} | {verdict} | "
                      f"{time.perf_counter() - start:.1f} |", flush=True)


if __name__ == "__main__":
    main()
