"""The cost of a fixed-step run's error estimate (integrators/stated_accuracy.py).

Each run twice: as shipped, with its step-doubling checks, and with the checks off (the
first check at t0 only), CPU time (process) best of ``--repeat``, in both compiled kernels
(numba, the C kernel FMUs run); through ``simulate()`` (20 outputs) and through
``Simulation.advance`` at 1 ms communication steps (the FMU's pattern). The ratio is the
slowdown the estimate costs.

    python benchmarks/fixed_step_estimate.py [--repeat 5] [-o FILE]

Prints a markdown table and writes it to FILE (default
benchmarks/results/fixed_step_estimate.md).
"""

from __future__ import annotations

import os

for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import argparse  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402

import mbdfmu  # noqa: E402
from mbdfmu.integrators import stated_accuracy  # noqa: E402
from mbdfmu.model.reader import bundled_scene  # noqa: E402

# (scene, method, step s, horizon s, communication step s or None for simulate())
RUNS = [("pendulum", "rk4p", 1e-3, 10.0, None),
        ("n_four_bar_2", "rk4p", 1e-3, 10.0, None),
        ("n_four_bar_40", "rk4p", 5e-3, 2.5, None),
        ("andrews", "rk4p", 1e-5, 0.03, None),
        ("pendulum", "baumgarte", 1e-3, 10.0, None),
        ("pendulum", "genalpha", 1e-3, 2.0, None),
        ("n_four_bar_2", "rk4p", 1e-3, 2.0, 1e-3)]
SHIPPED = (stated_accuracy.SPOT_CHECK_EVERY, stated_accuracy.SPOT_CHECK_MAX)


def checks(on: bool) -> None:
    every, most = SHIPPED if on else (10 ** 12, 10 ** 12)
    stated_accuracy.SPOT_CHECK_EVERY, stated_accuracy.SPOT_CHECK_MAX = every, most


def one_run(scene, method, step, t_end, comm, kernel) -> None:
    if comm is None:
        mbdfmu.simulate(scene, t_end, method=method, step=step, output_interval=t_end / 20,
                        kernel=kernel)
        return
    sim = mbdfmu.Simulation(scene, method=method, step=step, kernel=kernel)
    for t in np.arange(1, round(t_end / comm) + 1) * comm:
        sim.advance(float(t))


def best_time(args, repeat: int) -> float:
    best = np.inf
    for _ in range(repeat):
        start = time.process_time()
        one_run(*args)
        best = min(best, time.process_time() - start)
    return best


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--repeat", type=int, default=5)
    parser.add_argument("-o", "--output", type=Path,
                        default=Path(__file__).parent / "results" / "fixed_step_estimate.md")
    args = parser.parse_args(argv)
    lines = ["| scene | method, step | run | kernel | checks off (s) | with the estimate (s) "
             "| ratio |", "|---|---|---|---|---|---|---|"]
    for name, method, step, t_end, comm in RUNS:
        scene = mbdfmu.load_scene(bundled_scene(name))
        for kernel in ("numba", "c"):
            run = (scene, method, step, t_end, comm, kernel)
            one_run(*run)                                   # compile and load, untimed
            times = []
            for on in (False, True):
                checks(on)
                times.append(best_time(run, args.repeat))
            checks(True)
            how = f"simulate() {t_end:g} s" if comm is None else \
                f"advance at {comm * 1e3:g} ms, {t_end:g} s"
            lines.append(f"| {name} | {method} {step:g} s | {how} | {kernel} | {times[0]:.3f} | "
                         f"{times[1]:.3f} | {times[1] / times[0]:.3f} |")
            print(lines[-1], flush=True)
    args.output.parent.mkdir(parents=True, exist_ok=True)
    args.output.write_text("\n".join(lines) + "\n", encoding="utf-8")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
