"""The crane's mechanism with its cylinder force set by the master before every 1 ms step:
cost and error of each method against Exudyn, in one run.

The force is ``fmu_speed.actuator`` (a hold force plus a swing), sampled at the start of each
1 ms communication step and held over it, for every tool. For each method (the scene's
dop853p, rk45p, rk4p and auto, all at the scene's rtol 1e-9 and atol 1e-11):

- cost: CPU µs per 1 ms step of the FMU (best of ``--repeat``), stepped by fmpy
  (``setReal`` + ``doStep`` + ``getReal`` of every output, as fmu_speed.py) and by a minimal
  master calling the same three FMI functions through ctypes with arguments made once
  (``fmu_speed.ctypes_run``: the FMU's own cost plus about a microsecond per call);
- error: the load's position against a reference (dop853p at rtol 1e-13, atol 1e-15) driven
  by the same force sequence, largest over the run and at its end. The solver is called
  directly for it: the FMU's values are the solver's bit for bit (tests/test_fmu_fast.py).

Exudyn: generalized-alpha at h = 1 ms, the force set by a pre-step user function
(``exudyn_compare.set_before_each_step``), CPU µs per step (model building and assembly
included, as fmu_speed.py), and its load position's error at the end.

    python benchmarks/crane_methods.py [--t-end 1.0] [--repeat 3] [-o DIR]

Writes ``crane_methods.md`` into DIR (default docs/figures/performance).
"""

from __future__ import annotations

import os

for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import argparse  # noqa: E402
import math  # noqa: E402
import sys  # noqa: E402
import tempfile  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402

import mbdfmu  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parent))
import fmu_speed as fs  # noqa: E402

CASE, H = "crane mechanism", 1e-3
METHODS = ("dop853p", "rk45p", "rk4p", "auto")
REFERENCE = dict(method="dop853p", rtol=1e-13, atol=1e-15)


def force(t: float) -> float:
    """The master's force at the start of the 1 ms step holding t (Exudyn's pre-step t)."""
    return fs.actuator(math.floor(t / H + 1e-6) * H)


def scene_for(method: str, folder: Path) -> Path:
    path = folder / f"crane_{method}.toml"
    path.write_text(fs.CASES[CASE].read_text().replace('method = "dop853p"', f'method = "{method}"'))
    return path


def load_path(scene_path: Path, n: int, **settings) -> np.ndarray:
    """(n, 2): the load's position after each 1 ms step, the solver called directly."""
    sim = mbdfmu.Simulation(mbdfmu.load_scene(scene_path), **settings)
    out = np.zeros((n, 2))
    for k in range(n):
        sim.set_input("cylinder.actuator", fs.actuator(k * H))
        sim.advance((k + 1) * H)
        o = sim.outputs()
        out[k] = o["load.x"], o["load.y"]
    return out


def exudyn_error_and_cost(scene_path: Path, t_end: float, reference_end, repeat: int):
    """(load position error at t_end, best CPU s per step), or (None, None) without Exudyn."""
    try:
        import exudyn_compare as ex
    except ImportError:
        return None, None
    if ex.exu is None:
        return None, None
    model = ex.exudyn_model(mbdfmu.load_scene(scene_path), actuators={"cylinder": fs.HOLD})
    ex.set_before_each_step(model, "cylinder", force)
    info = ex.solve_exudyn(model, step=H, t_end=t_end)
    if info["status"] != "ok":
        raise RuntimeError(info["reason"])
    error = float(np.hypot(*(np.array(ex.exudyn_point(model, "load", (0.0, 0.0))) - reference_end)))
    fs.exudyn_run(CASE, scene_path, 0.01, per_step=True)            # warm-up
    cost = min(fs.exudyn_run(CASE, scene_path, t_end, per_step=True) for _ in range(repeat))
    return error, cost


def measure(t_end: float, repeat: int, folder: Path) -> tuple[list[dict], float]:
    n = int(round(t_end / H))
    paths = {m: scene_for(m, folder) for m in METHODS}
    reference = load_path(paths["dop853p"], n, **REFERENCE)
    rows = []
    for method, path in paths.items():
        errors = np.hypot(*(load_path(path, n) - reference).T)
        fmu = fs.build_fmu(path, output=folder / f"crane_{method}.fmu")
        fmpy, direct = [], []
        for _ in range(repeat):
            run = fs.FmpyRun(fmu, CASE, H)
            fmpy.append(run.timed(n)[1])
            run.free()
            direct.append(fs.ctypes_run(fmu, CASE, H, n))
        rows.append({"tool": "mbdfmu FMU", "method": method, "fmpy_us": min(fmpy) * 1e6,
                     "ctypes_us": min(direct) * 1e6, "error_max": float(errors.max()),
                     "error_end": float(errors[-1])})
        print(rows[-1], flush=True)
    error, cost = exudyn_error_and_cost(paths["dop853p"], t_end, reference[-1], repeat)
    if error is not None:
        rows.append({"tool": "Exudyn", "method": "generalized-alpha, h = 1 ms",
                     "exudyn_us": cost * 1e6, "error_end": error})
        print(rows[-1], flush=True)
    travel = float(np.hypot(*(reference - reference[0]).T).max())
    return rows, travel


def markdown(rows: list[dict], travel: float, header: str) -> str:
    lines = [header, "", f"The load moves up to {travel:.3g} m from where it starts.", "",
             "| tool | method | CPU µs per 1 ms, fmpy | CPU µs per 1 ms, ctypes master "
             "| load position error, largest | at the end |", "|---|---|---|---|---|---|"]
    for r in rows:
        if r["tool"] == "Exudyn":
            lines.append(f"| Exudyn | {r['method']} | {r['exudyn_us']:.1f} (its solver, "
                         f"force set by a Python pre-step function) | | | {r['error_end']:.2g} |")
        else:
            lines.append(f"| {r['tool']} | {r['method']} | {r['fmpy_us']:.1f} | {r['ctypes_us']:.1f} "
                         f"| {r['error_max']:.2g} | {r['error_end']:.2g} |")
    return "\n".join(lines) + "\n"


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("-o", "--output", default=str(fs.ROOT / "docs" / "figures" / "performance"))
    parser.add_argument("--repeat", type=int, default=3, help="timed runs, the best kept")
    parser.add_argument("--t-end", type=float, default=1.0, help="simulated s per run")
    args = parser.parse_args(argv)
    with tempfile.TemporaryDirectory() as tmp:
        rows, travel = measure(args.t_end, args.repeat, Path(tmp))
    header = (f"`python benchmarks/crane_methods.py --t-end {args.t_end:g} --repeat {args.repeat}`: "
              f"the crane's mechanism, its cylinder force set before every 1 ms step; CPU time "
              f"per 1 ms step, best of {args.repeat}; errors against dop853p at rtol 1e-13 "
              "driven by the same force sequence.")
    Path(args.output).mkdir(parents=True, exist_ok=True)
    table = Path(args.output) / "crane_methods.md"
    table.write_text(markdown(rows, travel, header))
    print(table.read_text())
    return 0


if __name__ == "__main__":
    sys.exit(main())
