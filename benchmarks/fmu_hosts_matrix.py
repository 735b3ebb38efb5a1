"""Cross-check: every shipped scene's FMU in every host, against ``mbdfmu simulate``.

Hosts: fmpy (its command line), OSP libcosim (libcosimpy), Ecos through its Python API
(ecospy), Ecos' command line (C++, no Python inside) and the FMI Compliance Checker (C, no
Python inside). The hosts without Python run from a clean environment (no PYTHONPATH, no
LD_PRELOAD, no virtual environment on PATH). Each run is its own process, so a cell records:
the FMU loads (instantiates), simulates (every communication point), the process exits
cleanly (status 0) and the results agree with ``mbdfmu simulate`` at the same points
(the C kernel, as in the FMU): the largest difference relative to max(1, |value|) over all
outputs, 1e-9 required (Ecos' command line writes 6 decimals: 1e-6 there). The numpy
kernel parts from the C kernel at round-off, which an adaptive method's step decisions can
carry further than 1e-9 (Andrews' mechanism: 4e-9); the tests hold the two kernels to each
other within a fraction of the tolerance.

    python benchmarks/fmu_hosts_matrix.py [-o DIR] [--scenes a,b] [--fmi-version 3] [--write-docs]

writes DIR/fmu_hosts_matrix.csv and prints the markdown table; ``--write-docs`` puts it into
docs/fmu.md between its ``hosts-matrix`` markers (``hosts-matrix-fmi3`` for FMI 3.0).

With ``--fmi-version 3`` the FMUs are FMI 3.0 and the hosts those that load FMI 3.0 (fmpy,
ecospy, Ecos' command line); two more columns give the largest difference of the FMI 3.0
FMU's results from the FMI 2.0 FMU's of the same scene in fmpy and in ecospy, 1e-12
required. ``run HOST FMU T H OUT`` is one Python
host's run (the command of a libcosim or ecospy cell).
"""

from __future__ import annotations

import argparse
import csv
import math
import re
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path[:0] = [str(ROOT / "tests")]

STEPS = 50
TOLERANCE = {"ecos CLI": 1e-6}
FMI3_HOSTS = ("fmpy", "ecospy", "ecos CLI")
SAME_AS_FMI2 = {"= FMI 2.0 (fmpy)": "fmpy_run", "= FMI 2.0 (ecospy)": "ecospy_run"}
COMMANDS = {
    "fmpy": "fmpy simulate {fmu} --stop-time {T} --output-interval {h} --output-file out.csv",
    "libcosim": "python benchmarks/fmu_hosts_matrix.py run libcosim {fmu} {T} {h} out.csv",
    "ecospy": "python benchmarks/fmu_hosts_matrix.py run ecospy {fmu} {T} {h} out.csv",
    "ecos CLI": "env -i PATH=/usr/bin:/bin ecos simulate --path {fmu} --stopTime {T}+{h}/2 "
                "--stepSize {h}",
    "checker": "env -i PATH=/usr/bin:/bin fmuCheck.linux64 -k cs -s {T} -h {h} -n 0 "
               "-o out.csv {fmu}",
}


def outputs_of(fmu: str) -> list[str]:
    from fmu_models.fmi3_host import outputs     # any FMI version
    return outputs(Path(fmu))


def run_libcosim(fmu: str, t_end: float, h: float) -> dict:
    from fmpy import read_model_description
    from libcosimpy.CosimEnums import CosimVariableType
    from libcosimpy.CosimExecution import CosimExecution
    from libcosimpy.CosimObserver import CosimObserver
    from libcosimpy.CosimSlave import CosimLocalSlave
    vr = {v.name: v.valueReference for v in read_model_description(fmu).modelVariables}
    names, n = outputs_of(fmu), round(t_end / h)
    execution = CosimExecution.from_step_size(step_size=round(h * 1e9))
    index = execution.add_local_slave(CosimLocalSlave(fmu_path=fmu, instance_name="a"))
    series = CosimObserver.create_time_series(buffer_size=n + 16)
    execution.add_observer(series)
    for name in names:
        series.start_time_series(index, value_reference=vr[name],
                                 variable_type=CosimVariableType.REAL)
    assert execution.step(n + 1)
    columns = {}
    for name in names:
        t, _, values = series.time_series_real_samples(index, vr[name], from_step=0,
                                                       sample_count=n + 2)
        columns["time"], columns[name] = np.array(t[:n + 1]) * 1e-9, values[:n + 1]
    return columns


def run_ecospy(fmu: str, t_end: float, h: float) -> dict:
    from fmu_models.fmi3_host import ecospy_run  # the tests' ecospy run, any FMI version
    return ecospy_run(Path(fmu), t_end, h)


def run_one(host: str, fmu: str, t_end: float, h: float, out: str) -> int:
    """One Python host's run, written as CSV (time first)."""
    columns = {"libcosim": run_libcosim, "ecospy": run_ecospy}[host](fmu, t_end, h)
    with open(out, "w", newline="") as f:
        writer = csv.writer(f)
        writer.writerow(list(columns))
        writer.writerows(zip(*(map(repr, map(float, c)) for c in columns.values())))
    return 0


def read_columns(path: Path) -> dict[str, np.ndarray]:
    """A CSV of any host as columns by variable name (Ecos' "a::x[REAL]" becomes "x")."""
    lines = path.read_text().splitlines()
    # (FMI 3.0 names such as der(u,2) hold a comma: split outside parentheses)
    header = [n.strip().strip('"').split("::")[-1].split("[")[0]
              for n in re.split(r",(?![^(]*\))", lines[0])]
    rows = [[x.strip() for x in line.split(",")] for line in lines[1:] if line.strip()]
    out = {}
    for i, name in enumerate(header):
        try:
            out[name] = np.array([float(r[i]) for r in rows])
        except ValueError:
            pass            # String columns (solver.method)
    return out


def cell(host: str, fmu: Path, t_end: float, h: float, work: Path, expected) -> dict:
    """Run one host in a fresh process; what it showed."""
    from fmu_models import hosts
    work.mkdir(parents=True, exist_ok=True)
    if host == "fmpy":
        command = [str(Path(sys.executable).with_name("fmpy")), "simulate", str(fmu),
                   "--stop-time", repr(t_end), "--output-interval", repr(h),
                   "--output-file", str(work / "out.csv")]
        run = subprocess.run(command, capture_output=True, text=True, timeout=600, cwd=work)
    elif host in ("libcosim", "ecospy"):
        run = subprocess.run([sys.executable, __file__, "run", host, str(fmu), repr(t_end), repr(h),
                              str(work / "out.csv")], capture_output=True, text=True, timeout=600)
    elif host == "ecos CLI":
        # it stops a step short of stopTime when the sum of steps rounds below it
        run = hosts.run_ecos_cli(hosts.ecos_cli(work), fmu, work, t_end + h / 2, h, timeout=600)
        if (work / f"{fmu.stem}.csv").exists():
            (work / f"{fmu.stem}.csv").replace(work / "out.csv")
    else:
        run = hosts.run_checker(fmu, work, t_end, h, timeout=600)
    note = (run.stderr or run.stdout).strip().splitlines()[-1:] if run.returncode else []
    result = {"exit": run.returncode, "rows": 0, "error": math.inf, "note": note}
    if (work / "out.csv").exists():
        got = read_columns(work / "out.csv")
        names = [n for n in expected.names if n in got]
        t = got.get("time", np.zeros(0))
        # the expected points the host reached (each within 1e-9 h of one of its rows)
        covered = [k for k, tk in enumerate(expected.time)
                   if t.size and np.min(np.abs(t - tk)) <= 1e-9 * h]
        result["rows"] = len(covered)
        if names and covered:
            errors = [np.max(np.abs(np.interp(expected.time[covered], t, got[n])
                                    - expected[n][covered]))
                      / max(1.0, float(np.max(np.abs(expected[n])))) for n in names]
            result["error"] = float(max(errors))
    if host == "checker":
        report = run.stdout + run.stderr
        result["checker"] = "0 Warning(s)" in report and "0 Error(s)" in report
    return result


def mark(host: str, r: dict, points: int) -> str:
    ok = (r["exit"] == 0 and r["rows"] >= points and r["error"] <= TOLERANCE.get(host, 1e-9)
          and r.get("checker", True))
    status = "" if r["exit"] == 0 else f" (exit {r['exit']})"
    return f"{'✔' if ok else '✘'} {r['error']:.0e}{status}"


def main(argv=None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    if argv and argv[0] == "run":
        return run_one(argv[1], argv[2], float(argv[3]), float(argv[4]), argv[5])
    import mbdfmu
    from mbdfmu.fmu_build.scene_fmu import build_fmu
    from fmu_models import hosts
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("-o", "--out", type=Path, default=None)
    parser.add_argument("--scenes", default=None, help="comma-separated stems (default: all)")
    parser.add_argument("--fmi-version", type=int, choices=[2, 3], default=2)
    parser.add_argument("--write-docs", action="store_true")
    args = parser.parse_args(argv)
    v3 = args.fmi_version == 3
    out = args.out or Path(tempfile.mkdtemp(prefix="fmu_matrix_"))
    stems = args.scenes.split(",") if args.scenes else sorted(
        p.stem for p in (ROOT / "scenes").glob("*.toml"))
    host_names = [h for h in COMMANDS if (h != "checker" or hosts.CHECKER.exists())
                  and (not v3 or h in FMI3_HOSTS)]
    rows = []
    for stem in stems:
        scene = mbdfmu.load_scene(ROOT / "scenes" / f"{stem}.toml")
        h = 10.0 ** math.floor(math.log10(scene.simulation.t_end / 500))
        t_end = STEPS * h
        fmu = build_fmu(ROOT / "scenes" / f"{stem}.toml", out / f"{stem}.fmu",
                        fmi_version=args.fmi_version)
        expected = mbdfmu.simulate(scene, t_end=t_end, output_interval=h, kernel="c")
        row = {"scene": stem, "T": t_end, "h": h}
        for host in host_names:
            r = cell(host, fmu, t_end, h, out / stem / host.replace(" ", "_"), expected)
            row[host] = mark(host, r, len(expected.time))
            print(stem, host, r, flush=True)
        if v3:
            row.update(same_as_fmi2(stem, fmu, out, t_end, h))
        rows.append(row)
    with open(out / "fmu_hosts_matrix.csv", "w", newline="") as f:
        writer = csv.DictWriter(f, fieldnames=list(rows[0]))
        writer.writeheader()
        writer.writerows(rows)
    table = markdown(rows, host_names, list(SAME_AS_FMI2) if v3 else [])
    print(table)
    if args.write_docs:
        write_docs(table, "hosts-matrix-fmi3" if v3 else "hosts-matrix")
    return 0


def same_as_fmi2(stem: str, fmu3: Path, out: Path, t_end: float, h: float) -> dict:
    """The FMI 3.0 FMU's results against the FMI 2.0 FMU's, in fmpy and in ecospy."""
    from fmu_models import fmi3_host
    from mbdfmu.fmu_build.scene_fmu import build_fmu
    fmu2 = build_fmu(ROOT / "scenes" / f"{stem}.toml", out / f"{stem}_fmi2.fmu")
    cells = {}
    for column, runner in SAME_AS_FMI2.items():
        run = getattr(fmi3_host, runner)
        error = fmi3_host.largest_difference(run(fmu2, t_end, h), run(fmu3, t_end, h))
        cells[column] = f"{'✔' if error <= 1e-12 else '✘'} {error:.0e}"
    return cells


def markdown(rows: list[dict], host_names: list[str], same: list[str] = ()) -> str:
    columns = host_names + list(same)
    lines = ["| scene | T (s) | h (s) | " + " | ".join(columns) + " |",
             "|---|---|---|" + "---|" * len(columns)]
    lines += [f"| {r['scene']} | {r['T']:g} | {r['h']:g} | " + " | ".join(r[h] for h in columns)
              + " |" for r in rows]
    lines += ["", "Each cell: ✔ when the FMU loaded, gave every point, the process exited with "
              "status 0 (the checker also: 0 warnings, 0 errors) and the largest difference "
              "from `mbdfmu simulate` (shown) is within 1e-9 (Ecos' command line: 1e-6, its CSV "
              "has 6 decimals). The command of a cell, with `{fmu}` = `<scene>.fmu` from "
              "`mbdfmu build scenes/<scene>.toml`:", ""]
    lines += [f"- {host}: `{COMMANDS[host]}`" for host in host_names]
    if same:
        lines += ["", "FMI 3.0 (`mbdfmu build --fmi-version 3`): the last columns give the "
                  "largest difference of the FMI 3.0 FMU's results from the FMI 2.0 FMU's in "
                  "that host, relative to max(1, |value|); ✔ within 1e-12."]
    return "\n".join(lines) + "\n"


def write_docs(table: str, marker: str) -> None:
    doc = ROOT / "docs" / "fmu.md"
    text = doc.read_text()
    start, end = f"<!-- {marker}: start -->\n", f"<!-- {marker}: end -->"
    if start not in text:
        text += f"\n{start}{end}\n"
    before, _, rest = text.partition(start)
    _, _, after = rest.partition(end)
    doc.write_text(before + start + table + end + after)


if __name__ == "__main__":
    sys.exit(main())
