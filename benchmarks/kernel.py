"""The two constraint kernels side by side: vectorised numpy against numba-compiled loops.

For each scene and kernel: CPU µs per evaluation of ``Equations.constraints`` (Psi, Psi_q,
nu, gamma), of ``Equations.accelerations`` (eq. 14) and per step of ``rk4p`` at h = 1 ms and
of ``dop853p`` at its default tolerance, best of ``--repeat`` (process CPU time, one run;
numba's compilation is excluded by a warm-up call). The large P2 mechanisms use the banded
Schur complement with either kernel (``linalg.py``).

    python benchmarks/kernel.py [--repeat 5] [-o DIR]

Writes ``kernel.md``, ``kernel.csv`` and ``kernel.png`` into DIR (default
docs/figures/performance).
"""

from __future__ import annotations

import os

for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import argparse  # noqa: E402
import csv  # noqa: E402
import time  # noqa: E402
import tomllib  # noqa: E402
from pathlib import Path  # noqa: E402

import matplotlib  # noqa: E402

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

import mbdfmu  # noqa: E402
from mbdfmu.equations import Equations  # noqa: E402
from mbdfmu.equations.constraints import numba_installed  # noqa: E402
from mbdfmu.equations.projection import assemble  # noqa: E402
from mbdfmu.model import scene_from_dict  # noqa: E402
from mbdfmu.scenes.generate_n_four_bar import scene_text  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
SCENES = ("slider_crank", "andrews", "n_four_bar_2", "P2 N = 40", "P2 N = 160")
OPERATIONS = ("constraints", "accelerations", "rk4p step", "dop853p step")


def load(name: str):
    if name.startswith("P2 N = "):
        n = int(name.rsplit(" ", 1)[1])
        return scene_from_dict(tomllib.loads(scene_text(n)), source=name)
    return mbdfmu.load_scene(ROOT / "scenes" / f"{name}.toml")


def per_call(function, repeat: int, budget: float = 0.2) -> float:
    """Best CPU µs per call, with enough calls per repetition to fill ``budget`` seconds."""
    function()                                        # warm-up (numba compiles here)
    t0 = time.process_time()
    function()
    calls = max(1, int(budget / max(time.process_time() - t0, 1e-6)))
    best = np.inf
    for _ in range(repeat):
        t0 = time.process_time()
        for _ in range(calls):
            function()
        best = min(best, (time.process_time() - t0) / calls)
    return 1e6 * best


def per_step(scene, kernel: str, method: str, repeat: int, **settings) -> float:
    """Best CPU µs per step of ``method`` over 0.2 s of the scene (assembly excluded)."""
    best = np.inf
    for _ in range(repeat + 1):                      # the first run warms up
        sim = mbdfmu.Simulation(scene, method=method, kernel=kernel, **settings)
        t0 = time.process_time()
        sim.advance(0.2)
        best = min(best, (time.process_time() - t0) / sim.integrator.stats.nsteps)
    return 1e6 * best


def measure(name: str, kernel: str, repeat: int) -> dict:
    scene = load(name)
    system = Equations(scene, kernel=kernel)
    q, qd = assemble(system)
    return {"scene": name, "kernel": kernel, "n": system.n, "m": system.m,
            "banded": system.pattern.banded,
            "constraints": per_call(lambda: system.constraints(0.1, q, qd, sparse=True), repeat),
            "accelerations": per_call(lambda: system.accelerations(0.1, q, qd), repeat),
            "rk4p step": per_step(scene, kernel, "rk4p", repeat, step=1e-3),
            "dop853p step": per_step(scene, kernel, "dop853p", repeat)}


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeat", type=int, default=5)
    parser.add_argument("-o", "--output", default=str(ROOT / "docs" / "figures" / "performance"))
    args = parser.parse_args(argv)
    if not numba_installed():
        raise SystemExit('benchmarks/kernel.py compares with numba: pip install "mbdfmu[jit]"')
    rows = []
    for name in SCENES:
        for kernel in ("numpy", "numba"):       # one after the other, so load hits both alike
            rows.append(measure(name, kernel, args.repeat))
            r = rows[-1]
            print(f"{name:14s} {kernel:6s} " + "  ".join(f"{op} {r[op]:8.1f}" for op in OPERATIONS),
                  flush=True)
    out = Path(args.output)
    out.mkdir(parents=True, exist_ok=True)
    with open(out / "kernel.csv", "w", newline="") as fh:
        w = csv.DictWriter(fh, fieldnames=list(rows[0]))
        w.writeheader()
        w.writerows(rows)
    lines = [f"CPU µs per call, best of {args.repeat} (`python benchmarks/kernel.py`); "
             "ratio = numpy / numba", "",
             "| scene | n | m | form | " + " | ".join(f"{op}: numpy / numba (ratio)" for op in OPERATIONS) + " |",
             "|---|---|---|---|" + "---|" * len(OPERATIONS)]
    for name in SCENES:
        a, b = (r for r in rows if r["scene"] == name)
        cells = [f"{a[op]:.1f} / {b[op]:.1f} ({a[op] / b[op]:.1f}x)" for op in OPERATIONS]
        lines.append(f"| {name} | {a['n']} | {a['m']} | {'banded' if a['banded'] else 'dense'} | "
                     + " | ".join(cells) + " |")
    (out / "kernel.md").write_text("\n".join(lines) + "\n")
    print("\n".join(lines))
    fig, axes = plt.subplots(1, len(OPERATIONS), figsize=(14, 3.8), sharey=False)
    x = np.arange(len(SCENES))
    for ax, op in zip(axes, OPERATIONS):
        for k, kernel in enumerate(("numpy", "numba")):
            values = [next(r[op] for r in rows if r["scene"] == s and r["kernel"] == kernel)
                      for s in SCENES]
            ax.bar(x + (k - 0.5) * 0.38, values, 0.38, label=kernel)
        ax.set_yscale("log")
        ax.set_xticks(x, SCENES, rotation=35, ha="right", fontsize=8)
        ax.set_title(f"{op} (CPU µs)")
        ax.grid(True, axis="y", which="both", alpha=0.3)
    axes[0].legend()
    fig.tight_layout()
    fig.savefig(out / "kernel.png", dpi=110)


if __name__ == "__main__":
    main()
