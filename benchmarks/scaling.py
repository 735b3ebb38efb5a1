"""Cost against mechanism size: P2's N-four-bar with N = 2, 10, 40, 160 (5 to 321 moving bodies).

For each N and method, the run from t = 0 to ``--t-end`` (through the first singular
crossing at the default 1 s) is timed (process CPU time, best of ``--repeat``; assembly not
included) and reported per step and per simulated second, with the log-log slope of both
against N from N = 10 to the largest N (target: at most 1.1, i.e. linear cost). Methods:
``rk4p`` at a fixed step (the cost of one step is all there is) and ``dop853p`` at its default
tolerance (steps chosen by the error control). The B0 error at the end against P2's exact
one-degree-of-freedom reduction shows the runs are right, not only fast.

    python benchmarks/scaling.py [--sizes 2 10 40 160] [--t-end 1.0] [--repeat 3]
                                 [--kernel c|numba|numpy] [-o DIR]

Writes ``scaling.csv``, ``scaling.md`` and ``scaling.png`` into DIR (default
docs/figures/performance).
"""

from __future__ import annotations

import os

for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")  # threads only slow these small factorisations down

import argparse  # noqa: E402
import csv  # noqa: E402
import math  # noqa: E402
import time  # noqa: E402
import tomllib  # noqa: E402
from pathlib import Path  # noqa: E402

import matplotlib  # noqa: E402

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

import mbdfmu  # noqa: E402
from mbdfmu.bench import closed_forms as references  # noqa: E402
from mbdfmu.model.reader import scene_from_dict  # noqa: E402
from mbdfmu.scenes.generate_n_four_bar import scene_text  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
METHODS = {"rk4p": {"method": "rk4p", "step": 1e-3}, "dop853p": {"method": "dop853p"}}


def n_four_bar(n: int):
    return scene_from_dict(tomllib.loads(scene_text(n)), source=f"<P2 N = {n}>")


def time_run(scene, t_end: float, settings: dict, repeat: int) -> dict:
    """Best CPU time of ``repeat`` runs 0 -> t_end, with the work counters and B0's error."""
    best = math.inf
    for _ in range(repeat):
        sim = mbdfmu.Simulation(scene, **settings)
        t0 = time.process_time()
        sim.advance(t_end)
        best = min(best, time.process_time() - t0)
    b0 = np.array([sim.q[0] + 0.5 * math.cos(sim.q[2]), sim.q[1] + 0.5 * math.sin(sim.q[2])])
    ref = references.n_four_bar_B0([t_end], len(scene.bodies) // 2)
    error = float(np.hypot(b0[0] - ref["x"][-1], b0[1] - ref["y"][-1]))
    return {"cpu_s": best, "nsteps": sim.integrator.stats.nsteps,
            "naccel": sim.integrator.stats.naccel, "error": error,
            "kernel": sim.equations.kernel, "banded": sim.equations.pattern.banded}


def slope(x, y) -> float:
    return float(np.polyfit(np.log(x), np.log(y), 1)[0])


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sizes", type=int, nargs="+", default=[2, 10, 40, 160])
    parser.add_argument("--t-end", type=float, default=1.0)
    parser.add_argument("--repeat", type=int, default=3)
    parser.add_argument("--kernel", choices=("c", "numba", "numpy"), default="c",
                        help="constraint kernel (default c: what FMUs run)")
    parser.add_argument("-o", "--output", default=str(ROOT / "docs" / "figures" / "performance"))
    args = parser.parse_args(argv)
    out = Path(args.output)
    out.mkdir(parents=True, exist_ok=True)
    rows = []
    for n in args.sizes:
        scene = n_four_bar(n)
        for name, settings in METHODS.items():
            r = time_run(scene, args.t_end, {**settings, "kernel": args.kernel}, args.repeat)
            r.update(N=n, bodies=len(scene.bodies), method=name,
                     us_per_step=1e6 * r["cpu_s"] / r["nsteps"],
                     s_per_sim_s=r["cpu_s"] / args.t_end)
            rows.append(r)
            print(f"N = {n:4d} {name:8s} {r['us_per_step']:10.1f} us/step "
                  f"{r['s_per_sim_s']:8.3f} s per simulated s  steps {r['nsteps']:5d}  "
                  f"B0 error {r['error']:.1e}", flush=True)
    fields = ["N", "bodies", "method", "kernel", "banded", "nsteps", "naccel", "cpu_s",
              "us_per_step", "s_per_sim_s", "error"]
    with open(out / "scaling.csv", "w", newline="") as fh:
        w = csv.DictWriter(fh, fieldnames=fields, extrasaction="ignore")
        w.writeheader()
        w.writerows(rows)
    lines = [f"P2 N-four-bar, t = 0..{args.t_end:g} s, CPU time best of {args.repeat} "
             f"(`python benchmarks/scaling.py`), kernel {rows[0]['kernel']}", "",
             "| N | bodies | method | steps | µs per step | s per simulated s | B0 error |",
             "|---|---|---|---|---|---|---|"]
    lines += [f"| {r['N']} | {r['bodies']} | {r['method']} | {r['nsteps']} | "
              f"{r['us_per_step']:.0f} | {r['s_per_sim_s']:.3g} | {r['error']:.1e} |" for r in rows]
    lines += ["", "| method | slope per step, N = 10..max | slope per simulated s, N = 10..max |",
              "|---|---|---|"]
    fig, axes = plt.subplots(1, 2, figsize=(10, 4))
    for name in METHODS:
        sel = [r for r in rows if r["method"] == name]
        ns = np.array([r["N"] for r in sel], dtype=float)
        per_step = np.array([r["us_per_step"] for r in sel])
        per_sim = np.array([r["s_per_sim_s"] for r in sel])
        fit = ns >= 10
        if fit.sum() >= 2:
            s1, s2 = slope(ns[fit], per_step[fit]), slope(ns[fit], per_sim[fit])
            lines.append(f"| {name} | {s1:.2f} | {s2:.2f} |")
            print(f"{name}: log-log slope N = 10..{int(ns.max())}: per step {s1:.2f}, "
                  f"per simulated second {s2:.2f}")
        axes[0].loglog(ns, per_step, "o-", label=name)
        axes[1].loglog(ns, per_sim, "o-", label=name)
    for ax, label in zip(axes, ("CPU µs per step", "CPU s per simulated second")):
        ns = np.array(args.sizes, dtype=float)
        ax.set_xlabel("N (windows of the N-four-bar)")
        ax.set_ylabel(label)
        ax.grid(True, which="both", alpha=0.3)
    y0 = [r["us_per_step"] for r in rows if r["method"] == "rk4p" and r["N"] == max(args.sizes)]
    if y0:
        ns = np.array(sorted(args.sizes), dtype=float)
        axes[0].loglog(ns, y0[0] * ns / ns.max(), "k:", label="slope 1")
    axes[0].legend()
    fig.suptitle("Cost against mechanism size (P2)")
    fig.tight_layout()
    fig.savefig(out / "scaling.png", dpi=120)
    (out / "scaling.md").write_text("\n".join(lines) + "\n")
    print("\n".join(lines))


if __name__ == "__main__":
    main()
