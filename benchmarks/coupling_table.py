"""Every scenario and coupling algorithm in one table: the measured convergence order of the
coupling error and the largest stable communication step; and the cross-check of masters
(docs/cosimulation.md, "Every scenario and algorithm").

    python benchmarks/coupling_table.py [--workers 2] [--only a,b] [--rerun LABEL ...]
                                        [--tables-only] [--write-docs]

Algorithms (fmpy master unless said): Jacobi and Gauss-Seidel with zero-order hold, Jacobi
with input extrapolation of order 1 and 2, the implicit coupling with the interface
Jacobian from directional derivatives, the variable step with rollback (Jacobi inside) and
libcosim's ECCO (where the FMUs declare a power bond).

* **Order**: the coupling error (largest difference from the scenario's reference over the
  compared variables, relative to the reference's range) at three steps h, h/2, h/4 over a
  short horizon; the two orders log2(e(h)/e(h/2)), log2(e(h/2)/e(h/4)). For the variable
  step and ECCO the three runs are three tolerances and the orders are the slopes of the
  error against the mean step.
* **Largest stable step**: the largest step of a grid at which the run over the stability
  horizon neither stops (an FMU refuses a step, the iteration fails) nor leaves the
  reference (error above 100 % of its range); scanned from the largest step down.

The cross-check runs each scenario at its step over the order horizon in every master
(fmpy, fmpy's SSP runner, libcosim, Ecos) with Jacobi, and the other algorithms in the
master that has them: whether it runs, whether it agrees (Jacobi: the largest difference
from the fmpy master's Jacobi run, relative to the range, within 1e-9; the others: an
error against the reference no larger than the fmpy Jacobi run's) and its error.

Rows are cached in benchmarks/results/coupling_table.csv (a rerun computes only what is
missing; ``--rerun LABEL`` drops the cached rows of that algorithm, or of that cross-check
master and algorithm such as "fmpy implicit", in the ``--only`` scenarios first; delete the
file to start over); charts: docs/figures/cosim_orders.png.
"""

from __future__ import annotations

import argparse
import csv
import math
import sys
import tempfile
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
RESULTS = ROOT / "benchmarks" / "results" / "coupling_table.csv"
FIGURE = ROOT / "docs" / "figures" / "cosim_orders.png"
WORK = Path(tempfile.gettempdir()) / "mbdfmu_coupling_table_fmus"
FAILED_ERROR = 1.0
MS = 1e-3
COARSE = [200 * MS, 100 * MS, 50 * MS, 20 * MS, 10 * MS, 5 * MS, 2 * MS, 1 * MS]
FINE = [5 * MS, 2 * MS, 1 * MS, 0.5 * MS, 0.2 * MS, 0.1 * MS]
# scenario: (order horizon, h, stability horizon, stability grid)
CASES = {
    "two_mass_oscillator": (1.0, 4 * MS, 2.0, COARSE),
    "two_mass_oscillator:dd": (0.5, 4 * MS, 1.0, COARSE),
    "quarter_car": (0.5, 4 * MS, 1.0, COARSE),
    "dc_motor_slider_crank": (0.12, 4 * MS, 0.5, COARSE[2:]),
    "hydraulic_crane": (0.3, 2 * MS, 2.0, COARSE[2:]),
    "cart_pendulum_pid": (0.5, 4 * MS, 2.0, COARSE[1:]),
    "prescribed_motion": (0.012, 0.4 * MS, 0.04, FINE),
    "prescribed_motion:derivatives": (0.012, 0.4 * MS, 0.04, FINE),
}
ALGORITHMS = {   # label: CosimSettings fields
    "Jacobi": dict(algorithm="jacobi"),
    "Gauss-Seidel": dict(algorithm="gauss-seidel"),
    "Jacobi, extrapolation 1": dict(algorithm="jacobi", extrapolation=1),
    "Jacobi, extrapolation 2": dict(algorithm="jacobi", extrapolation=2),
    "implicit, directional derivatives": dict(algorithm="implicit", jacobian="directional"),
    "variable step, rollback": dict(algorithm="jacobi", variable_step=True),
    "ECCO (libcosim)": dict(master="libcosim", algorithm="ecco"),
}
ADAPTIVE = {"variable step, rollback": [1e-1, 3e-2, 1e-2], "ECCO (libcosim)": [1e-2, 1e-3, 1e-4]}
CROSS = [("fmpy", "jacobi"), ("ssp", "jacobi"), ("libcosim", "jacobi"), ("ecos", "jacobi"),
         ("fmpy", "gauss-seidel"), ("fmpy", "implicit"), ("libcosim", "ecco")]
FIELDS = ["kind", "scenario", "algorithm", "step", "tol", "t_end", "ok", "error", "mean_step",
          "difference", "reason"]


def _error(scenario, result) -> float:
    from mbdfmu.cosim.scenario import reference_function
    ref = reference_function(scenario)(result.time)
    return max(float(np.abs(result[n] - ref[n]).max() / np.ptp(ref[n]))
               for n in scenario.compare)


def run(task) -> dict:
    """One run; a CSV row (``ok`` 0 with the reason when it stopped or left the reference)."""
    from mbdfmu.cosim.cosimulate import cosimulate
    from mbdfmu.cosim.scenario_reader import load_scenario
    from mbdfmu.cosim.settings import CosimSettings
    from mbdfmu.errors import MbdfmuError

    kind, name, label, step, tol, t_end, fields = task
    row = dict(kind=kind, scenario=name, algorithm=label, step=step, tol=tol or "", t_end=t_end,
               ok=0, error="", mean_step="", difference="", reason="")
    scenario = load_scenario(name)
    extra = {}
    if tol is not None:
        extra = dict(rtol=tol, atol=tol) if fields.get("algorithm") == "ecco" else dict(rtol=tol)
    try:
        settings = CosimSettings(step=step, t_end=t_end, **fields, **extra)
        r = cosimulate(scenario, settings, work_dir=WORK, compare=False).result
        error = _error(scenario, r)
    except (MbdfmuError, ValueError, ArithmeticError) as exc:
        row["reason"] = str(exc).splitlines()[0][:150]
        return row
    row.update(error=error, mean_step=float(r.time[-1] / max(len(r.time) - 1, 1)),
               ok=int(math.isfinite(error) and error <= FAILED_ERROR))
    if not row["ok"]:
        row["reason"] = f"error {error:.3g} of the range"
    if kind == "cross":
        np.save(WORK / f"cross_{name}_{label}.npy".replace(":", "_").replace(" ", "_"),
                np.column_stack([r.time] + [r[n] for n in scenario.compare]))
    return row


def _tasks(names, done) -> list:
    tasks = []
    for name in names:
        t_order, h, _, _ = CASES[name]
        for label, fields in ALGORITHMS.items():
            for k in range(3):
                tol = ADAPTIVE[label][k] if label in ADAPTIVE else None
                step = h if label in ADAPTIVE else h / 2 ** k
                tasks.append(("order", name, label, step, tol, t_order, fields))
        for master, algorithm in CROSS:
            fields = dict(master=master, algorithm=algorithm)
            if algorithm == "implicit":
                fields["jacobian"] = "directional"
            tasks.append(("cross", name, f"{master} {algorithm}", h, None, t_order, fields))
    return [t for t in tasks if _key(t) not in done]


def _key(task_or_row) -> tuple:
    if isinstance(task_or_row, dict):
        r = task_or_row
        return (r["kind"], r["scenario"], r["algorithm"], float(r["step"]), str(r["tol"]))
    kind, name, label, step, tol, *_ = task_or_row
    return (kind, name, label, float(step), str(tol or ""))


def _stability(name, label, pool_rows, done) -> list:
    """Rows of the stability scan of one scenario and algorithm (largest step down)."""
    _, _, horizon, grid = CASES[name]
    rows = []
    for step in grid:
        task = ("stable", name, label, step, None, horizon, ALGORITHMS[label])
        row = done.get(_key(task)) or run(task)
        rows.append(row)
        if int(row["ok"]):
            break
    return rows


def load_rows() -> dict:
    if not RESULTS.exists():
        return {}
    with open(RESULTS) as f:
        return {_key(r): r for r in csv.DictReader(f)}


def save_rows(rows: dict) -> None:
    RESULTS.parent.mkdir(parents=True, exist_ok=True)
    with open(RESULTS, "w", newline="") as f:
        writer = csv.DictWriter(f, fieldnames=FIELDS)
        writer.writeheader()
        writer.writerows(rows.values())


def _stability_task(args):
    name, label, done = args
    return _stability(name, label, None, done)


def measure(names, workers: int) -> dict:
    from mbdfmu.cosim.scenario_reader import load_scenario
    from mbdfmu.fmu_build.cache import build_fmus

    rows = load_rows()
    for name in names:        # every FMU once, before the workers share them
        scenario = load_scenario(name)
        build_fmus({i.name: i.source for i in scenario.instances}, WORK / scenario.folder.name)
    tasks = _tasks(names, rows)
    scans = [(n, label, rows) for n in names for label in ALGORITHMS if label not in ADAPTIVE]
    with ProcessPoolExecutor(workers) as pool:
        for row in pool.map(run, tasks):
            rows[_key(row)] = row
            print(row["kind"], row["scenario"], row["algorithm"], row["step"], row["tol"],
                  row["ok"], row["error"], row["reason"], flush=True)
            save_rows(rows)
        for found in pool.map(_stability_task, scans):
            for row in found:
                rows[_key(row)] = row
                print(row["kind"], row["scenario"], row["algorithm"], row["step"], row["ok"],
                      row["error"], row["reason"], flush=True)
            save_rows(rows)
    return rows


def _differences(rows, names) -> None:
    """Fill the cross rows' difference from the fmpy Jacobi run (same times)."""
    for name in names:
        path = lambda label: WORK / f"cross_{name}_{label}.npy".replace(":", "_").replace(" ", "_")
        if not path("fmpy jacobi").exists():
            continue
        base = np.load(path("fmpy jacobi"))
        scale = np.ptp(base[:, 1:], axis=0)
        for row in rows.values():
            if row["kind"] == "cross" and row["scenario"] == name and path(row["algorithm"]).exists():
                other = np.load(path(row["algorithm"]))
                # the points both have (fmpy's SSP runner leaves out t = 0)
                k = np.searchsorted(base[:, 0], other[:, 0]).clip(0, len(base) - 1)
                if np.allclose(base[k, 0], other[:, 0], rtol=0, atol=1e-9):
                    row["difference"] = float(np.max(np.abs(other[:, 1:] - base[k, 1:]) / scale))


def _orders(errors, steps) -> str:
    if len(errors) < 3 or not all(e and math.isfinite(e) and e > 0 for e in errors):
        return "—"
    return ", ".join(f"{math.log(errors[k] / errors[k + 1]) / math.log(steps[k] / steps[k + 1]):.2f}"
                     for k in range(2))


def table(rows: dict, names) -> str:
    out = ["| scenario | algorithm | errors (h, h/2, h/4 or 3 tolerances) | order | largest "
           "stable step |", "|---|---|---|---|---|"]
    for name in names:
        t_order, h, horizon, grid = CASES[name]
        for label in ALGORITHMS:
            order = sorted((r for r in rows.values() if r["kind"] == "order"
                            and r["scenario"] == name and r["algorithm"] == label),
                           key=lambda r: -float(r["step"]) if not r["tol"] else -float(r["tol"]))
            ok = [r for r in order if int(r["ok"])]
            if not order:
                continue
            if len(ok) < len(order):
                errors_text = "stops: " + "; ".join(dict.fromkeys(
                    r["reason"][:110] for r in order if not int(r["ok"])))
                out.append(f"| {name} | {label} | {errors_text} | — | — |")
                continue
            errors = [float(r["error"]) for r in ok]
            steps = [float(r["mean_step"]) for r in ok]
            stable = [r for r in rows.values() if r["kind"] == "stable" and r["scenario"] == name
                      and r["algorithm"] == label and int(r["ok"])]
            scanned = [r for r in rows.values() if r["kind"] == "stable" and r["scenario"] == name
                       and r["algorithm"] == label]
            if label in ADAPTIVE:
                limit = "adapts"
            elif stable:
                top = max(float(r["step"]) for r in stable)
                limit = f"{top / MS:g} ms" + (" (grid's largest)" if top == grid[0] else "")
            else:
                limit = f"none down to {grid[-1] / MS:g} ms" if scanned else "—"
            out.append(f"| {name} | {label} | " + ", ".join(f"{e:.2e}" for e in errors)
                       + f" | {_orders(errors, steps)} | {limit} |")
    return "\n".join(out) + "\n"


def cross_table(rows: dict, names) -> str:
    out = ["| scenario | master | algorithm | runs | agrees | error |", "|---|---|---|---|---|---|"]
    for name in names:
        base = next((r for r in rows.values() if r["kind"] == "cross" and r["scenario"] == name
                     and r["algorithm"] == "fmpy jacobi"), None)
        for master, algorithm in CROSS:
            r = next((r for r in rows.values() if r["kind"] == "cross" and r["scenario"] == name
                      and r["algorithm"] == f"{master} {algorithm}"), None)
            if r is None:
                continue
            if not int(r["ok"]):
                out.append(f"| {name} | {master} | {algorithm} | ✘ {r['reason'][:70]} | — | — |")
                continue
            if algorithm == "jacobi" and r["difference"] != "":
                agrees = f"{'✔' if float(r['difference']) <= 1e-9 else '✘'} {float(r['difference']):.0e}"
            elif base is not None and base["error"] != "":
                agrees = "✔" if float(r["error"]) <= float(base["error"]) else "✘"
            else:
                agrees = "—"
            out.append(f"| {name} | {master} | {algorithm} | ✔ | {agrees} | {float(r['error']):.2e} |")
    return "\n".join(out) + "\n"


def chart(rows: dict, names) -> Path:
    import matplotlib
    matplotlib.use("Agg")
    from matplotlib.figure import Figure

    cols = 4
    fig = Figure(figsize=(16, 3.4 * math.ceil(len(names) / cols)))
    axes = fig.subplots(math.ceil(len(names) / cols), cols, squeeze=False).ravel()
    for ax, name in zip(axes, names):
        for k, label in enumerate(ALGORITHMS):   # one colour per algorithm in every panel
            pts = sorted((float(r["mean_step"]), float(r["error"])) for r in rows.values()
                         if r["scenario"] == name and r["algorithm"] == label
                         and r["kind"] == "order" and int(r["ok"]))
            if pts:
                ax.loglog(*zip(*pts), "o-", ms=3, color=f"C{k}", label=label)
        ax.set_title(name, fontsize="small")
        ax.set_xlabel("communication step, mean (s)", fontsize="x-small")
        ax.set_ylabel("error / range", fontsize="x-small")
        ax.grid(True, which="both", alpha=0.3)
    axes[0].legend(fontsize="xx-small")
    for ax in axes[len(names):]:
        ax.set_visible(False)
    fig.tight_layout()
    FIGURE.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(FIGURE, dpi=90)
    return FIGURE


def write_docs(text: str, marker: str) -> None:
    doc = ROOT / "docs" / "cosimulation.md"
    content = doc.read_text()
    start, end = f"<!-- {marker}: start -->\n", f"<!-- {marker}: end -->"
    before, _, rest = content.partition(start)
    _, _, after = rest.partition(end)
    doc.write_text(before + start + text + end + after)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--only", default=None, help="comma-separated scenarios")
    parser.add_argument("--rerun", action="append", default=[], metavar="LABEL",
                        help="recompute the cached rows of this algorithm (repeatable)")
    parser.add_argument("--write-docs", action="store_true")
    parser.add_argument("--tables-only", action="store_true",
                        help="no runs: the tables and chart from the cached rows")
    args = parser.parse_args(argv)
    names = args.only.split(",") if args.only else list(CASES)
    WORK.mkdir(parents=True, exist_ok=True)
    unknown = [label for label in args.rerun if label not in ALGORITHMS
               and label not in {f"{m} {a}" for m, a in CROSS}]
    if unknown:
        parser.error(f"--rerun {unknown[0]!r}: not an algorithm of the table "
                     f"({', '.join(ALGORITHMS)}) nor a cross-check run")
    if args.rerun:
        kept = {k: r for k, r in load_rows().items()
                if not (r["scenario"] in names and r["algorithm"] in args.rerun)}
        save_rows(kept)
    rows = load_rows() if args.tables_only else measure(names, args.workers)
    _differences(rows, names)
    save_rows(rows)
    every, cross = table(rows, list(CASES)), cross_table(rows, list(CASES))
    print(every)
    print(cross)
    chart(rows, [n for n in CASES if any(r["scenario"] == n for r in rows.values())])
    if args.write_docs:
        write_docs(every, "coupling-table")
        write_docs(cross, "cross-check")
    return 0


if __name__ == "__main__":
    sys.exit(main())
