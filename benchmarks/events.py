"""Event location and work-precision of the end-stop and friction scenes (issue 14).

Each scene (slider_stop, incline_stick, incline_slide, crane_stop) runs with rk4p over a sweep
of steps and with rk45p and dop853p over a sweep of rtol (atol = rtol); errors against the
closed forms of ``tests/event_checks.py`` (the crane: its Lagrange equation in scipy):

* event error: the largest |t - t_exact| (s) over the transitions that have a closed form
  (for the slider and the crane, the rest time at the accumulation of impacts included);
* position error: the largest error of the positions at the output times (m or rad);
* time: wall seconds, the best of ``--repeat`` runs (a loaded machine: compare within a run).

``--kernel`` (default c, what FMUs run): the equations' kernel, for every run.

    python benchmarks/events.py [--repeat 3] [--kernel c] [--quick] [-o DIR]

Writes ``events.md``, ``events.csv`` and ``events.png`` into DIR (default benchmarks/results).
"""

from __future__ import annotations

import argparse
import csv
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "tests"))      # the closed forms the tests use

import mbdfmu  # noqa: E402
import event_checks as ref  # noqa: E402

SCENES = ("slider_stop", "incline_stick", "incline_slide", "crane_stop")
STEPS = (1e-2, 3e-3, 1e-3)
TOLS = (1e-4, 1e-6, 1e-8, 1e-10)


def position_error(name: str, res) -> float:
    t = res.time
    if name == "slider_stop":
        x, _ = ref.slider_stop_motion(t)
        return float(np.max(np.abs(res["slider.x"] - x)))
    if name == "crane_stop":
        impacts, rest, rest_angle, segments = ref.CRANE
        phi = np.full_like(t, rest_angle)
        for a, b, sol in segments:
            inside = (t >= a) & (t <= b) & (t < rest)
            if inside.any():
                phi[inside] = sol(t[inside])[0]
        return float(np.max(np.abs(res["boom.phi"] - phi)))
    s, _, _ = ref.incline_motion(t, 0.8 if name == "incline_stick" else 0.2)
    return float(np.max(np.abs(res["block.x"] - s * ref.C)))


def event_error(name: str, events) -> float:
    expected = ref.expected_events(name, len(events))
    errors = [abs(e[0] - x[0]) for e, x in zip(events, expected) if x[0] is not None]
    return max(errors) if errors else float("nan")


def run(name: str, settings: dict, repeat: int):
    best, res = float("inf"), None
    for _ in range(repeat):
        start = time.perf_counter()
        res = mbdfmu.simulate(ROOT / "scenes" / f"{name}.toml", **settings)
        best = min(best, time.perf_counter() - start)
    return res, best


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeat", type=int, default=3)
    parser.add_argument("--quick", action="store_true", help="one step and two tolerances")
    parser.add_argument("--kernel", choices=("c", "numpy", "numba"), default="c")
    parser.add_argument("-o", "--out", type=Path, default=ROOT / "benchmarks" / "results")
    args = parser.parse_args(argv)
    steps, tols = (STEPS[:1], TOLS[1:3]) if args.quick else (STEPS, TOLS)
    runs = [("rk4p", "step", h, dict(method="rk4p", step=h, kernel=args.kernel)) for h in steps]
    runs += [(m, "rtol", r, dict(method=m, rtol=r, atol=r, kernel=args.kernel))
             for m in ("rk45p", "dop853p") for r in tols]
    rows = []
    for name in SCENES:
        for method, kind, value, settings in runs:
            res, seconds = run(name, settings, args.repeat)
            rows.append(dict(scene=name, method=method, setting=f"{kind} {value:g}",
                             events=len(res.events), event_error=event_error(name, res.events),
                             position_error=position_error(name, res), seconds=seconds,
                             steps=res.stats["nsteps"]))
            r = rows[-1]
            print(f"{name:14s} {method:8s} {r['setting']:12s} events {r['events']:3d}  "
                  f"event error {r['event_error']:.2e} s  position error "
                  f"{r['position_error']:.2e}  {seconds:.3f} s", flush=True)
    args.out.mkdir(parents=True, exist_ok=True)
    with open(args.out / "events.csv", "w", newline="") as f:
        writer = csv.DictWriter(f, fieldnames=list(rows[0]))
        writer.writeheader()
        writer.writerows(rows)
    lines = [f"`python benchmarks/events.py --repeat {args.repeat} --kernel {args.kernel}`", "",
             "| scene | method | setting | events | event error (s) | position error | "
             "time (s) |", "|---|---|---|---|---|---|---|"]
    lines += [f"| {r['scene']} | {r['method']} | {r['setting']} | {r['events']} | "
              f"{r['event_error']:.2e} | {r['position_error']:.2e} | {r['seconds']:.3f} |"
              for r in rows]
    (args.out / "events.md").write_text("\n".join(lines) + "\n")
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    fig, axes = plt.subplots(1, len(SCENES), figsize=(4 * len(SCENES), 3.6), sharey=True)
    for ax, name in zip(axes, SCENES):
        for method in ("rk4p", "rk45p", "dop853p"):
            sel = [r for r in rows if r["scene"] == name and r["method"] == method]
            ax.loglog([r["seconds"] for r in sel],
                      [max(r["event_error"], 1e-16) for r in sel], "o-", label=method)
        ax.set_title(name)
        ax.set_xlabel("wall time (s)")
    axes[0].set_ylabel("event time error (s)")
    axes[0].legend()
    fig.tight_layout()
    fig.savefig(args.out / "events.png", dpi=100)
    return 0


if __name__ == "__main__":
    sys.exit(main())
