"""The cost of ``Simulation()``: a scene object to a run ready to step (equations, the C
kernel's model, assembly, the integrator's start), as every ``p2_limit.py`` repeat and every
FMU instantiation pays it.

For each case a new ``Simulation`` is built ``--repeat`` times (after a few unmeasured
ones) and the best process CPU time is kept; nothing is shared between the instances but
the loaded kernel library. Cases: P2 N = 2 and N = 40 (dop853p at rtol 5e-6, p2_limit.py's
run) and the hydraulic crane's mechanism (its scene's settings), all on the C kernel.
To compare with another tree: ``PYTHONPATH=/tmp/before/src python benchmarks/setup_cost.py``.

    python benchmarks/setup_cost.py [--repeat 30] [-o DIR]

Writes ``setup_cost.md``, ``setup_cost.csv`` and ``setup_cost.png`` into DIR (default
docs/figures/performance).
"""

from __future__ import annotations

import os

for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import argparse  # noqa: E402
import csv  # noqa: E402
import statistics  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

import matplotlib  # noqa: E402

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402

import mbdfmu  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
P2_RUN = dict(kernel="c", method="dop853p", rtol=5e-6, atol=5e-8)
CASES = (("P2 N = 2", ROOT / "scenes" / "n_four_bar_2.toml", P2_RUN),
         ("P2 N = 40", ROOT / "scenes" / "n_four_bar_40.toml", P2_RUN),
         ("crane mechanism", ROOT / "scenarios" / "hydraulic_crane" / "crane.toml",
          dict(kernel="c")))


def setup_times(scene, settings: dict, repeat: int) -> list[float]:
    """CPU seconds of each of ``repeat`` new Simulations (after three warm-up ones)."""
    for _ in range(3):
        mbdfmu.Simulation(scene, **settings)
    times = []
    for _ in range(repeat):
        t0 = time.process_time()
        mbdfmu.Simulation(scene, **settings)
        times.append(time.process_time() - t0)
    return times


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--repeat", type=int, default=30)
    parser.add_argument("-o", "--output", default=str(ROOT / "docs" / "figures" / "performance"))
    args = parser.parse_args()
    out = Path(args.output)
    out.mkdir(parents=True, exist_ok=True)
    rows = []
    for name, path, settings in CASES:
        times = setup_times(mbdfmu.load_scene(path), settings, args.repeat)
        rows.append({"case": name, "best_ms": 1e3 * min(times),
                     "median_ms": 1e3 * statistics.median(times)})
        print(rows[-1], flush=True)
    lines = [f"`python benchmarks/setup_cost.py --repeat {args.repeat}`: CPU time of "
             f"`Simulation()` (ms), best and median of {args.repeat}; package from "
             f"`{Path(mbdfmu.__file__).parent}`.", "",
             "| case | best (ms) | median (ms) |", "|---|---|---|"]
    lines += [f"| {r['case']} | {r['best_ms']:.3f} | {r['median_ms']:.3f} |" for r in rows]
    text = "\n".join(lines) + "\n"
    print(text)
    (out / "setup_cost.md").write_text(text)
    with open(out / "setup_cost.csv", "w", newline="") as f:
        writer = csv.DictWriter(f, fieldnames=list(rows[0]))
        writer.writeheader()
        writer.writerows(rows)
    fig, ax = plt.subplots(figsize=(6, 3))
    ax.barh([r["case"] for r in rows], [r["best_ms"] for r in rows])
    ax.set_xlabel("Simulation() CPU time, best (ms)")
    fig.tight_layout()
    fig.savefig(out / "setup_cost.png", dpi=120)


if __name__ == "__main__":
    main()
