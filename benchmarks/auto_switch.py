"""``auto`` over the whole run against its choice at t0 alone (integrators/auto_watch.py).

Two mechanisms where the method ``auto`` picks at t0 stops fitting later in the run:

* P2 with N = 2 started at its singular configuration (cranks horizontal, theta' = -1
  rad/s), 10 s: at t0 auto picks ali3p; reference: the exact one-degree-of-freedom
  reduction (``bench.closed_forms.n_four_bar_B0``), error: B0's largest distance from it
  at the outputs (every 20 ms);
* a 1 kg bob on a spring of k = 1e10 N/m (rest length 1 m), released horizontally with the
  spring stretched by 0.1 mm and a damper of 1e3 N s/m, 0.1 s: at t0 auto picks dop853p
  (the stretch's oscillation is the motion's time scale); reference: dop853p at rtol 1e-8,
  error: the bob's largest distance from it at the outputs (every 5 ms).

Each at rtol 1e-6 and 1e-8 under ``auto`` (which watches the run and switches) and under
the method auto picks at t0, named, with the same tolerances (what auto did before it
watched the run). CPU time (process): best of ``--repeat``; steps: accepted + rejected.
The ``overhead`` table: the cost of watching a run that needs no switch, P2 N = 2 as
shipped under auto and under dop853p named, in ``simulate()`` (10 s) and through
``Simulation.advance`` at 1 ms communication steps (2 s).

    python benchmarks/auto_switch.py [--tables switch overhead] [--repeat 3] [-o DIR]

Writes ``auto_switch.md`` into DIR (default docs/figures/performance).
"""

from __future__ import annotations

import os

for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import argparse  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402
import tomllib  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402

import mbdfmu  # noqa: E402
from mbdfmu.bench.closed_forms import n_four_bar_B0  # noqa: E402
from mbdfmu.errors import SolverError  # noqa: E402
from mbdfmu.model.reader import scene_from_dict  # noqa: E402
from mbdfmu.scenes.generate_n_four_bar import scene_text  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
RTOLS = (1e-6, 1e-8)


def horizontal_p2():
    return scene_from_dict(tomllib.loads(scene_text(2, theta=0.0)), source="<P2 horizontal>")


def stretched_stiff_pendulum():
    return scene_from_dict({
        "name": "StretchedStiffPendulum", "gravity": [0.0, -9.81],
        "body": [{"name": "bob", "mass": 1.0, "inertia": 1e-6, "position": [1.0001, 0.0]}],
        "force": [{"name": "rod", "type": "spring_damper", "body_i": "ground",
                   "point_i": [0.0, 0.0], "body_j": "bob", "point_j": [0.0, 0.0],
                   "stiffness": 1e10, "damping": 1e3, "rest_length": 1.0}]})


def p2_error(res):
    exact = n_four_bar_B0(res.time, 2, theta0=0.0, theta_dot0=-1.0)
    phi = res["crank0.phi"]
    return float(np.max(np.hypot(res["crank0.x"] + 0.5 * np.cos(phi) - exact["x"],
                                 res["crank0.y"] + 0.5 * np.sin(phi) - exact["y"])))


CASES = {"P2 N = 2, horizontal start, 10 s": (horizontal_p2, 10.0, 0.02),
         "stretched stiff spring pendulum, 0.1 s": (stretched_stiff_pendulum, 0.1, 0.005)}


def run(make, t_end, interval, **kw):
    start = time.process_time()
    try:
        res = mbdfmu.simulate(make(), t_end, output_interval=interval, **kw)
    except SolverError as exc:
        return time.process_time() - start, None, str(exc)
    return time.process_time() - start, res, ""


def overhead(repeat: int) -> str:
    scene = mbdfmu.load_scene(ROOT / "scenes/n_four_bar_2.toml")

    def in_simulate(method):
        start = time.process_time()
        mbdfmu.simulate(scene, 10.0, method=method)
        return time.process_time() - start

    def at_1ms(method):
        sim = mbdfmu.Simulation(scene, method=method)
        start = time.process_time()
        for k in range(1, 2001):
            sim.advance(k * 1e-3)
        return time.process_time() - start

    lines = ["| run | auto (s) | dop853p (s) | auto / dop853p |", "|---|---|---|---|"]
    for label, run_ in (("simulate(), 10 s", in_simulate), ("advance at 1 ms, 2 s", at_1ms)):
        best = {"auto": float("inf"), "dop853p": float("inf")}
        for _ in range(repeat):
            for method in best:
                best[method] = min(best[method], run_(method))
        lines.append(f"| {label} | {best['auto']:.3g} | {best['dop853p']:.3g} | "
                     f"{best['auto'] / best['dop853p']:.2f} |")
    return ("\nCost of watching (P2 N = 2 as shipped, no switch; CPU time best of "
            f"{repeat}):\n\n" + "\n".join(lines) + "\n")


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--tables", nargs="+", choices=("switch", "overhead"),
                    default=["switch", "overhead"])
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("-o", "--out", type=Path, default=ROOT / "docs/figures/performance")
    args = ap.parse_args(argv)
    rows = []
    for case, (make, t_end, interval) in (CASES.items() if "switch" in args.tables else ()):
        reference = None
        if make is stretched_stiff_pendulum:
            reference = run(make, t_end, interval, method="dop853p", rtol=1e-8)[1]
        for rtol in RTOLS:
            sim = mbdfmu.Simulation(make(), rtol=rtol, output_interval=interval)
            picked, atol = sim.integrator.name, sim.integrator.atol
            for label, kw in (("auto", {}), (f"{picked} (auto's t0 pick)",
                                             {"method": picked, "atol": atol})):
                best, res, why = None, None, ""
                for _ in range(args.repeat):
                    cpu, res, why = run(make, t_end, interval, rtol=rtol, **kw)
                    best = cpu if best is None else min(best, cpu)
                if res is None:
                    rows.append([case, f"{rtol:g}", label, "stops: " + why[:90], "", "", f"{best:.3g}", ""])
                    continue
                err = p2_error(res) if reference is None else float(np.max(np.hypot(
                    res["bob.x"] - reference["bob.x"], res["bob.y"] - reference["bob.y"])))
                switches = "; ".join(f"t = {t:.4g} s {a} -> {b}" for t, a, b, _ in res.switches)
                rows.append([case, f"{rtol:g}", label, res.method, f"{err:.2g}",
                             str(res.stats["nsteps"] + res.stats["nrejected"]), f"{best:.3g}",
                             switches])
    cols = ["mechanism", "rtol", "run", "method / outcome", "error (m)", "steps", "CPU s",
            "switches"]
    table = ["| " + " | ".join(cols) + " |", "|" + "---|" * len(cols)]
    table += ["| " + " | ".join(r) + " |" for r in rows]
    text = (f"`python benchmarks/auto_switch.py --tables {' '.join(args.tables)} --repeat "
            f"{args.repeat}`: auto (watching the run) against the method it picks at t0 run "
            f"alone; CPU time best of {args.repeat} on the machine of the run (compare within "
            "a row pair).\n\n" + ("\n".join(table) + "\n" if rows else ""))
    if "overhead" in args.tables:
        text += overhead(args.repeat)
    out = args.out / "auto_switch.md"
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(text)
    print(text + f"\n-> {out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
