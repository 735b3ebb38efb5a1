"""genalpha and ali3p per step: their Python step against their C step, and the C step's
two solvers (the banded Schur complement and the dense LU of implicit_dense.h) by size.

1. Per step at h = 1 ms, kernel "c" (an FMU's), as exudyn_compare.py measures a step: the
   CPU time of ``Simulation(...)`` and ``advance(t_end)`` over the steps taken; the
   slider-crank (P4, a translational joint), the hydraulic crane's mechanism
   (scenarios/hydraulic_crane/crane.toml, its cylinder force HOLD (1 + 0.05 sin 2 pi t) as
   benchmarks/fmu_speed.py sets it; rtol 1e-6, atol 1e-8: the scene's 1e-9 is beyond a
   1 ms step's stated accuracy), the rod in a slot (P11, a slot joint) and P2 N = 2. "Python
   step": ``implicit_c.ENABLED = False`` (the dense LAPACK LU, what these mechanisms ran
   before); "C step": the path ``kernel_newton`` chooses (named in the table).
2. P2 with N = 2 .. 20 (n + m = 29 .. 245 unknowns), genalpha at 1 ms: the banded C step,
   the same run forced onto the dense LU, and the Python step; where the dense LU stops
   paying is ``implicit_c.DENSE_MAX``.

CPU time (``time.process_time``), best of ``--repeat``, the variants interleaved.

    python benchmarks/implicit_speed.py [--repeat 3] [--t-end 0.5] [-o DIR]

Writes implicit_speed.md and implicit_speed.csv into DIR (default docs/figures/performance).
"""

from __future__ import annotations

import os

for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import argparse  # noqa: E402
import csv  # noqa: E402
import math  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402
import tomllib  # noqa: E402
from pathlib import Path  # noqa: E402

import mbdfmu  # noqa: E402
from mbdfmu.integrators import implicit_c  # noqa: E402
from mbdfmu.model.reader import scene_from_dict  # noqa: E402
from mbdfmu.scenes.generate_n_four_bar import scene_text  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
HOLD = 8420.0          # N: about the cylinder force that holds the crane's boom
CASES = {"slider-crank (P4)": (ROOT / "scenes" / "slider_crank.toml", {}),
         "crane mechanism": (ROOT / "scenarios" / "hydraulic_crane" / "crane.toml",
                             {"rtol": 1e-6, "atol": 1e-8}),
         "rod in a slot (P11)": (ROOT / "scenes" / "slot_rod.toml", {}),
         "P2 N = 2": (ROOT / "scenes" / "n_four_bar_2.toml", {})}
SIZES = (2, 5, 10, 20)
_CHOSEN = implicit_c.kernel_newton


def _forced_dense(method):
    chosen = _CHOSEN(method)
    return chosen and implicit_c.KernelNewton(method, chosen.kernel, False, dense=True)


def per_step(scene, method: str, t_end: float, path: str, **settings) -> tuple[float, str]:
    """(CPU s per step, the path taken) of one run at h = 1 ms."""
    implicit_c.ENABLED = path != "python"
    implicit_c.kernel_newton = _forced_dense if path == "dense" else _CHOSEN
    inputs = None
    if "cylinder" in {f.name for f in scene.forces}:
        inputs = {"cylinder": lambda t: HOLD * (1.0 + 0.05 * math.sin(2.0 * math.pi * t))}
    try:
        start = time.process_time()
        sim = mbdfmu.Simulation(scene, method=method, step=1e-3, kernel="c", **settings)
        for item, signal in (inputs or {}).items():
            sim.set_input_signal(item, signal)
        sim.advance(t_end)
        cpu = time.process_time() - start
        newton = sim.integrator.c_newton
    finally:
        implicit_c.ENABLED, implicit_c.kernel_newton = True, _CHOSEN
    taken = "Python" if newton is None else ("C, dense LU" if newton.dense else
                                             "C, banded Schur")
    return cpu / sim.integrator.stats.nsteps, taken


def best_of(repeat: int, jobs: dict) -> dict:
    best = {}
    for _ in range(repeat):
        for key, job in jobs.items():
            cpu, taken = job()
            best[key] = (min(cpu, best[key][0]) if key in best else cpu, taken)
    return best


def table(rows: list[dict]) -> str:
    cols = list(rows[0])
    lines = ["| " + " | ".join(cols) + " |", "|" + "---|" * len(cols)]
    return "\n".join(lines + ["| " + " | ".join(str(r[c]) for c in cols) + " |" for r in rows])


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--t-end", type=float, default=0.5)
    ap.add_argument("-o", "--out", type=Path, default=ROOT / "docs/figures/performance")
    args = ap.parse_args(argv)
    scenes = {name: (mbdfmu.load_scene(path), s) for name, (path, s) in CASES.items()}
    jobs = {(name, method, path): (lambda sc=sc, s=s, m=method, p=path:
                                   per_step(sc, m, args.t_end, p, **s))
            for name, (sc, s) in scenes.items() for method in ("genalpha", "ali3p")
            for path in ("python", "c")}
    per_step(scenes["P2 N = 2"][0], "genalpha", 0.01, "c")      # the kernel's first load
    best = best_of(args.repeat, jobs)
    rows = []
    for name, method, _ in list(jobs)[::2]:
        py, c = best[name, method, "python"], best[name, method, "c"]
        rows.append({"mechanism": name, "method": method, "Python step (µs)": f"{py[0] * 1e6:.0f}",
                     "C step (µs)": f"{c[0] * 1e6:.1f}", "C path": c[1],
                     "Python / C": f"{py[0] / c[0]:.0f}"})
    p2 = {n: scene_from_dict(tomllib.loads(scene_text(n)), source=f"<P2 N = {n}>") for n in SIZES}
    jobs = {(n, path): (lambda sc=p2[n], p=path: per_step(sc, "genalpha", args.t_end, p))
            for n in SIZES for path in ("c", "dense", "python")}
    sizes = best_of(args.repeat, jobs)
    size_rows = []
    for n in SIZES:
        eq = mbdfmu.Simulation(p2[n], method="genalpha").equations
        c, dense, py = (sizes[n, p][0] * 1e6 for p in ("c", "dense", "python"))
        size_rows.append({"P2 N": n, "n + m": eq.n + eq.m, "banded C (µs)": f"{c:.1f}",
                          "dense LU C (µs)": f"{dense:.1f}", "Python step (µs)": f"{py:.0f}"})
    text = (f"`python benchmarks/implicit_speed.py --repeat {args.repeat} --t-end {args.t_end:g}`:"
            f" CPU per step, h = 1 ms, best of {args.repeat}, kernel \"c\".\n\n" + table(rows)
            + f"\n\ngenalpha on P2 by size (t = 0..{args.t_end:g} s): the C step's two "
            "solvers and the Python step.\n\n" + table(size_rows) + "\n")
    print(text)
    args.out.mkdir(parents=True, exist_ok=True)
    (args.out / "implicit_speed.md").write_text(text)
    with open(args.out / "implicit_speed.csv", "w", newline="") as fh:
        writer = csv.DictWriter(fh, fieldnames=list(rows[0]))
        writer.writeheader()
        writer.writerows(rows)
    return 0


if __name__ == "__main__":
    sys.exit(main())
