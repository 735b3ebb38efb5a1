"""Load, step, free and exit the toy FMU in many fresh processes of each host; count exits.

The crash this looks for happens at process exit (SIGSEGV or an abort after numpy was
imported), so each run is its own process, and its exit status is the result: 0 is a
clean exit, a negative number is the signal that killed it (-11 SIGSEGV, -6 SIGABRT).

Hosts: fmpy and libcosimpy (Python), the FMU Compliance Checker, a small C host and
Ecos' command line (C/C++, no Python inside; run from a clean environment). With
``--pythonfmu`` the same toy built with pythonfmu 0.7 runs too, plainly and in the
checker with LD_PRELOAD and PYTHONPATH set by hand (the only way it loads there). With
``--scene NAME`` a shipped scene's FMU (mbdfmu build) runs instead of the toy, in fmpy,
libcosimpy, libcosim then fmpy, the checker and Ecos' command line.

    python benchmarks/fmu_hosts_stress.py [--runs 200] [--pythonfmu] [--scene NAME] [-o DIR]

Writes fmu_hosts_stress.csv (runtime, host, exit status, count) in DIR and prints it.
"""

from __future__ import annotations

import argparse
import collections
import csv
import os
import shutil
import subprocess
import sys
import sysconfig
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path[:0] = [str(ROOT), str(ROOT / "tests"), str(ROOT / "benchmarks")]

from fmpy import extract, read_model_description  # noqa: E402

from fmu_models import hosts  # noqa: E402

STEPS, H = 10, 0.01


_UNZIPPED: dict[Path, tuple[str, object]] = {}


def c_host_run(binary: Path, fmu: Path, workdir: Path) -> subprocess.CompletedProcess:
    if fmu not in _UNZIPPED:
        _UNZIPPED[fmu] = (extract(fmu), read_model_description(fmu))
    directory, md = _UNZIPPED[fmu]
    return subprocess.run([str(binary), str(STEPS), repr(H), str(directory),
                           md.coSimulation.modelIdentifier, md.guid],
                          capture_output=True, text=True, timeout=120, env=hosts.clean_env(workdir))


def ecos_run(ecos: Path, fmu: Path, workdir: Path) -> subprocess.CompletedProcess:
    return subprocess.run([str(ecos), "simulate", "--path", str(fmu), "--stopTime",
                           repr(STEPS * H), "--stepSize", repr(H), "--noCsv"],
                          capture_output=True, text=True, timeout=120, cwd=workdir,
                          env=hosts.clean_env(workdir))


def preloaded_checker_run(fmu: Path, workdir: Path) -> subprocess.CompletedProcess:
    """The checker with libpython preloaded and the environment's site-packages on PYTHONPATH."""
    library = Path(sysconfig.get_config_var("LIBDIR")) / sysconfig.get_config_var("INSTSONAME")
    command = [str(hosts.CHECKER), "-k", "cs", "-s", repr(STEPS * H), "-h", repr(H),
               "-o", str(workdir / "out.csv"), "-t", str(workdir), str(fmu)]
    env = hosts.clean_env(workdir, LD_PRELOAD=str(library),
                          PYTHONPATH=os.pathsep.join(sys.path[3:]),
                          PYTHONHOME=sys.base_prefix)
    return subprocess.run(command, capture_output=True, text=True, timeout=120, env=env, cwd=workdir)


def host_runners(workdir: Path, pythonfmu: bool, variable: str = "x") -> dict:
    """Host name -> function(fmu, run folder) -> CompletedProcess, for the hosts available
    (the Python hosts print ``variable``; the C host only runs the toy)."""
    runners = {
        "fmpy": lambda fmu, d: hosts.run_python(hosts.FMPY_RUN, fmu, STEPS, H, variable=variable),
        "libcosim": lambda fmu, d: hosts.run_python(hosts.LIBCOSIM_RUN, fmu, STEPS, H,
                                                    variable=variable),
    }
    if variable == "x":
        c_host = hosts.compile_host(workdir)
        runners["C host"] = lambda fmu, d: c_host_run(c_host, fmu, d)
    else:
        runners["libcosim then fmpy"] = lambda fmu, d: hosts.run_python(
            hosts.LIBCOSIM_THEN_FMPY, fmu, STEPS, H, variable=variable)
    if hosts.CHECKER.exists():
        runners["checker"] = lambda fmu, d: hosts.run_checker(fmu, d, STEPS * H, H)
        if pythonfmu:
            runners["checker + LD_PRELOAD"] = preloaded_checker_run
    try:
        import ecospy
        ecos = workdir / "ecos"
        shutil.copy(Path(ecospy.__file__).parent / "binaries" / "ecos", ecos)
        ecos.chmod(0o755)
        runners["ecos CLI"] = lambda fmu, d: ecos_run(ecos, fmu, d)
    except ImportError:
        print("ecospy is not installed: no Ecos runs (pip install ecospy; apt-get install libtbb12)")
    return runners


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--runs", type=int, default=200)
    parser.add_argument("--pythonfmu", action="store_true", help="also run pythonfmu's toy")
    parser.add_argument("--scene", default=None, help="a shipped scene's FMU instead of the toy")
    parser.add_argument("-o", "--out", type=Path, default=None)
    args = parser.parse_args(argv)
    out = args.out or Path(tempfile.mkdtemp(prefix="fmu_stress_"))
    out.mkdir(parents=True, exist_ok=True)
    variable = "x"
    if args.scene:
        from mbdfmu.fmu_build.scene_fmu import build_fmu
        path = build_fmu(args.scene, out / f"{args.scene}.fmu")
        fmus = {f"native {args.scene}": path}
        variable = [v.name for v in read_model_description(path).modelVariables
                    if v.causality == "output"][0]
    else:
        from fmu_models.toy import build_toy
        fmus = {"native": build_toy(out / "MassSpring.fmu", cache_dir=out / "cache")}
    if args.pythonfmu:
        from fmu_native_vs_pythonfmu import build_both
        fmus["pythonfmu"] = build_both(out)["pythonfmu"]
    runners = host_runners(out, args.pythonfmu, variable)
    counts: collections.Counter = collections.Counter()
    for runtime, fmu in fmus.items():
        for host, run in runners.items():
            if host == "checker + LD_PRELOAD" and runtime.startswith("native"):
                continue
            folder = out / f"{runtime}-{host}".replace(" ", "_").replace("+", "")
            for i in range(args.runs):
                work = folder / str(i % 4)   # a few folders: checker unpacks into its own
                work.mkdir(parents=True, exist_ok=True)
                counts[(runtime, host, run(fmu, work).returncode)] += 1
            print(runtime, host, {rc: n for (r, h, rc), n in counts.items()
                                  if (r, h) == (runtime, host)}, flush=True)
    name = f"fmu_hosts_stress_{args.scene}.csv" if args.scene else "fmu_hosts_stress.csv"
    with open(out / name, "w", newline="") as f:
        writer = csv.writer(f)
        writer.writerow(["runtime", "host", "exit_status", "count"])
        writer.writerows([*key, n] for key, n in sorted(counts.items(), key=str))
    print(f"written: {out / name}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
