"""The C++ masters with their threads held to one core and free: what ``cosim/threads.py``
buys a scenario run in libcosim and in Ecos.

Both masters step their slaves on worker threads (libcosim's own, Ecos' TBB threads). On
an idle machine a handoff to a thread on another core waits for that core to wake, at
every communication step; mbdfmu's runners hold the calling thread to one core while the
master is made and run, and the threads the master starts inherit that. Here each run is
a fresh process (a master's thread pool lives as long as its process) that runs the
scenario with ``cosimulate`` as ``mbdfmu cosim`` does, the FMUs built once beforehand,
and reports the master's run alone (``CosimRun.seconds``: the master made, run and
read, without the builds). "free": the runners' ``one_core`` replaced by a context that
does nothing. The two modes alternate, ``--repeat`` pairs each; run it on an idle machine
(another busy process on the second core hides the wait).

    python benchmarks/cosim_threads.py [--scenarios hydraulic_crane] [--repeat 5] [-o DIR]

Writes ``cosim_threads.md``, ``cosim_threads.csv`` and ``cosim_threads.png`` into DIR
(default docs/figures/performance).
"""

from __future__ import annotations

import argparse
import contextlib
import csv
import statistics
import subprocess
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
MASTERS = ("libcosim", "ecos")
MODES = ("one core", "free")


def one_run(scenario: str, master: str, mode: str, work_dir: str) -> float:
    """This process: the scenario in ``master`` with the threads held (``mode`` "one
    core") or free; the master's run in s."""
    from mbdfmu.cosim import ecco_runner, ecos_runner, libcosim_runner
    from mbdfmu.cosim.cosimulate import cosimulate
    from mbdfmu.cosim.settings import CosimSettings
    if mode == "free":
        for module in (libcosim_runner, ecco_runner, ecos_runner):
            module.one_core = contextlib.nullcontext
    run = cosimulate(scenario, CosimSettings(master=master), work_dir=work_dir, compare=False)
    return run.seconds


def measure(scenario: str, master: str, repeat: int, work_dir: str) -> dict:
    """``repeat`` pairs of fresh processes, the modes alternating: the runs' seconds."""
    cosim_threads = Path(__file__).resolve()
    one_run(scenario, master, "one core", work_dir)          # builds the FMUs, once
    seconds: dict[str, list[float]] = {m: [] for m in MODES}
    for _ in range(repeat):
        for mode in MODES:
            out = subprocess.run([sys.executable, str(cosim_threads), "--one", scenario, master,
                                  mode, work_dir], capture_output=True, text=True, check=True)
            seconds[mode].append(float(out.stdout.split()[-1]))
    ratios = [a / b for a, b in zip(seconds["one core"], seconds["free"])]
    return {"scenario": scenario, "master": master,
            **{f"{m}_median_s": statistics.median(v) for m, v in seconds.items()},
            **{f"{m}_best_s": min(v) for m, v in seconds.items()},
            "ratio_median": statistics.median(ratios), "ratio_min": min(ratios),
            "ratio_max": max(ratios)}


def markdown(rows: list[dict], repeat: int) -> str:
    scenarios = ",".join(dict.fromkeys(r["scenario"] for r in rows))
    lines = [f"`python benchmarks/cosim_threads.py --scenarios {scenarios} --repeat {repeat}`: "
             "the master's run (s, "
             "without the FMUs' builds), each a fresh process, the modes alternating; median "
             f"(best) of {repeat}; ratio one core / free, pair by pair: median (range).", "",
             "| scenario | master | threads on one core | free | ratio |", "|---|---|---|---|---|"]
    for r in rows:
        lines.append(f"| {r['scenario']} | {r['master']} | {r['one core_median_s']:.3f} "
                     f"({r['one core_best_s']:.3f}) | {r['free_median_s']:.3f} "
                     f"({r['free_best_s']:.3f}) | {r['ratio_median']:.2f} "
                     f"({r['ratio_min']:.2f}-{r['ratio_max']:.2f}) |")
    return "\n".join(lines) + "\n"


def chart(rows: list[dict], path: Path) -> None:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import numpy as np
    fig, ax = plt.subplots(figsize=(6, 3.2))
    x = np.arange(len(rows))
    for k, mode in enumerate(MODES):
        ax.bar(x + (k - 0.5) * 0.35, [r[f"{mode}_median_s"] for r in rows], 0.35, label=mode)
    ax.set_xticks(x, [f"{r['scenario']}\n{r['master']}" for r in rows])
    ax.set_ylabel("the master's run (s)")
    ax.legend(title="the master's threads")
    ax.set_title("A scenario in a C++ master: its threads held to one core or free")
    fig.tight_layout()
    fig.savefig(path, dpi=110)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scenarios", default="hydraulic_crane", help="comma-separated names")
    parser.add_argument("--repeat", type=int, default=5)
    parser.add_argument("-o", "--output", default=str(ROOT / "docs" / "figures" / "performance"))
    parser.add_argument("--one", nargs=4, metavar=("SCENARIO", "MASTER", "MODE", "WORK_DIR"),
                        help=argparse.SUPPRESS)   # one run in this process (the child)
    args = parser.parse_args(argv)
    if args.one:
        print(one_run(*args.one))
        return 0
    if args.repeat < 1:
        parser.error("--repeat must be at least 1")
    from mbdfmu.errors import MbdfmuError
    rows = []
    with tempfile.TemporaryDirectory() as work_dir:
        for scenario in args.scenarios.split(","):
            for master in MASTERS:
                try:
                    rows.append(measure(scenario, master, args.repeat, work_dir))
                except (MbdfmuError, subprocess.CalledProcessError) as exc:
                    why = exc.stderr.strip().splitlines()[-1] if isinstance(
                        exc, subprocess.CalledProcessError) and exc.stderr else exc
                    print(f"cosim_threads: {scenario} in {master}: {why}", file=sys.stderr)
                    return 1
    text = markdown(rows, args.repeat)
    print(text)
    out = Path(args.output)
    out.mkdir(parents=True, exist_ok=True)
    (out / "cosim_threads.md").write_text(text)
    with open(out / "cosim_threads.csv", "w", newline="") as f:
        writer = csv.DictWriter(f, fieldnames=list(rows[0]))
        writer.writeheader()
        writer.writerows(rows)
    chart(rows, out / "cosim_threads.png")
    return 0


if __name__ == "__main__":
    sys.exit(main())
