"""Where a communication step of the solver goes: the C kernel's calls against the Python
around them (issue 13: "measure where the time goes first").

For each case of ``fmu_speed.py`` (the slider-crank, P2 N = 2, the crane's mechanism with
its actuator force set before every step as the master does), the solver is called as an
FMU's ``doStep`` calls it: ``Simulation.advance(t + h)`` then ``output_vector()``, with
the C kernel. Every ctypes entry into the kernel is timed (wall clock around the call),
and the rest of the step is Python: the step-size decisions, the energy audit, rollback
points, input signals, the bookkeeping of ``Simulation``. Best of ``--repeat`` runs of
``--steps`` steps each (the minimum total, with its own split); a loaded machine inflates
both parts, so read the shares, not the absolute times.

    python benchmarks/step_breakdown.py [--h 0.001] [--steps 1000] [--repeat 5] [-o DIR]

Writes ``step_breakdown.md`` into DIR (default docs/figures/performance).
"""

from __future__ import annotations

import os

for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import argparse  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

import mbdfmu  # noqa: E402
from mbdfmu.equations import ckernel  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parent))
from fmu_speed import CASES, stepper  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
# The Kernel methods that cross into C (each is one ctypes call, or two for ``project``).
C_CALLS = ("accelerations", "outputs", "project", "state_outputs", "rk4p_steps",
           "prk_trial", "mc_trial", "singularity_indicator", "dense_state")


class CallTimer:
    """Wraps the Kernel's C-calling methods, summing their wall time and counting calls."""

    def __init__(self):
        self.seconds, self.calls, self.saved = 0.0, 0, {}

    def __enter__(self):
        for name in C_CALLS:
            original = getattr(ckernel.Kernel, name)
            self.saved[name] = original

            def timed(kernel, *args, _original=original, **kwargs):
                start = time.perf_counter()
                try:
                    return _original(kernel, *args, **kwargs)
                finally:
                    self.seconds += time.perf_counter() - start
                    self.calls += 1
            setattr(ckernel.Kernel, name, timed)
        return self

    def __exit__(self, *exc):
        for name, original in self.saved.items():
            setattr(ckernel.Kernel, name, original)


def one_run(path: Path, case: str, h: float, steps: int) -> tuple[float, float, int, str]:
    """(wall s per step, of it in C, C calls per step, method) of ``steps`` steps."""
    sim = mbdfmu.Simulation(mbdfmu.load_scene(path), kernel="c")
    run = stepper(sim, case, h)
    run(20)
    with CallTimer() as timer:
        start = time.perf_counter()
        run(steps)
        total = time.perf_counter() - start
    return total / steps, timer.seconds / steps, round(timer.calls / steps), sim.method_name


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--h", type=float, default=1e-3)
    ap.add_argument("--steps", type=int, default=1000)
    ap.add_argument("--repeat", type=int, default=5)
    ap.add_argument("-o", "--out", type=Path, default=ROOT / "docs/figures/performance")
    args = ap.parse_args(argv)
    lines = [f"`python benchmarks/step_breakdown.py --h {args.h:g} --steps {args.steps} "
             f"--repeat {args.repeat}`: one communication step of {args.h * 1e3:g} ms "
             "(`Simulation.advance` + `output_vector`, kernel c), wall µs, best of "
             f"{args.repeat}.", "",
             "| case | method | µs per step | in C (µs) | C calls per step | Python (µs) | Python share |",
             "|---|---|---|---|---|---|---|"]
    for case, path in CASES.items():
        best = min((one_run(path, case, args.h, args.steps) for _ in range(args.repeat)),
                   key=lambda r: r[0])
        total, in_c, calls, method = best
        lines.append(f"| {case} | {method} | {total * 1e6:.1f} | {in_c * 1e6:.1f} | {calls} | "
                     f"{(total - in_c) * 1e6:.1f} | {(total - in_c) / total:.0%} |")
        print(lines[-1], flush=True)
    text = "\n".join(lines) + "\n"
    print(text)
    args.out.mkdir(parents=True, exist_ok=True)
    (args.out / "step_breakdown.md").write_text(text)
    return 0


if __name__ == "__main__":
    sys.exit(main())
