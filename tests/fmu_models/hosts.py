"""Hosts that run an FMU in a fresh process: fmpy, libcosimpy, a tiny C host, the checker.

Each run loads the FMU, steps it, frees it and lets the process exit; the exit status
tells whether the host survived (a crash at exit shows as -11 or -6 here). Used by
tests/test_native_fmu.py (a few runs) and benchmarks/fmu_hosts_stress.py (hundreds).
"""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
from pathlib import Path



def _checker() -> Path:
    """The FMI Compliance Checker binary: $MBDFMU_FMU_CHECKER, else fmuCheck.linux64 on PATH
    (a path that does not exist when neither is there: what needs it skips)."""
    named = os.environ.get("MBDFMU_FMU_CHECKER") or shutil.which("fmuCheck.linux64")
    return Path(named) if named else Path("/nonexistent/fmuCheck.linux64")


CHECKER = _checker()
CHECKER_MISSING = ("the FMI Compliance Checker was not found: set MBDFMU_FMU_CHECKER to "
                   "fmuCheck.linux64 or put it on PATH")

FMPY_RUN = r'''
import sys
from fmpy import extract, read_model_description
from fmpy.fmi2 import FMU2Slave
path, steps, h = sys.argv[1], int(sys.argv[2]), float(sys.argv[3])
name = sys.argv[4] if len(sys.argv) > 4 else "x"
md = read_model_description(path)
vr = {v.name: v.valueReference for v in md.modelVariables}
fmu = FMU2Slave(guid=md.guid, unzipDirectory=extract(path),
                modelIdentifier=md.coSimulation.modelIdentifier, instanceName="a")
fmu.instantiate()
fmu.setupExperiment(startTime=0.0)
fmu.enterInitializationMode()
fmu.exitInitializationMode()
for k in range(steps):
    fmu.doStep(k * h, h)
print("RESULT", repr(fmu.getReal([vr[name]])[0]))
fmu.terminate()
fmu.freeInstance()
fmu.freeLibrary()
'''

LIBCOSIM_RUN = r'''
import sys
from fmpy import read_model_description
from libcosimpy.CosimEnums import CosimVariableType
from libcosimpy.CosimExecution import CosimExecution
from libcosimpy.CosimLogging import CosimLogLevel, log_output_level
from libcosimpy.CosimObserver import CosimObserver
from libcosimpy.CosimSlave import CosimLocalSlave
log_output_level(CosimLogLevel.WARNING)
path, steps, h = sys.argv[1], int(sys.argv[2]), float(sys.argv[3])
name = sys.argv[4] if len(sys.argv) > 4 else "x"
vr = {v.name: v.valueReference for v in read_model_description(path).modelVariables}
execution = CosimExecution.from_step_size(step_size=int(round(h * 1e9)))
index = execution.add_local_slave(CosimLocalSlave(fmu_path=path, instance_name="a"))
observer = CosimObserver.create_last_value()
execution.add_observer(observer)
assert execution.simulate_until(target_time=int(round(steps * h * 1e9)))
print("RESULT", repr(observer.last_real_values(index, [vr[name]])[0]))
'''

# Findings D9: libcosim, then fmpy, on the same FMU file in one process.
LIBCOSIM_THEN_FMPY = LIBCOSIM_RUN + FMPY_RUN

# A C host with no Python: dlopen the FMU's binary, run `steps` steps of two instances of
# each FMU given, print x of each, free, dlclose, exit 0 (3 when instantiate fails).
HOST_C = r'''
#include <dlfcn.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include "fmi2Functions.h"

static void logger(fmi2ComponentEnvironment e, fmi2String name, fmi2Status s, fmi2String cat,
                   fmi2String message, ...) {
    (void)e; (void)name;
    va_list args;
    va_start(args, message);
    printf("LOG %d %s ", (int)s, cat);
    vprintf(message, args);
    printf("\n");
    va_end(args);
}

#define LOAD(f) fmi2##f##TYPE *f = (fmi2##f##TYPE *)dlsym(lib, "fmi2" #f); if (!f) return 2;

static int run(const char *dir, const char *id, const char *guid, int steps, double h) {
    char path[4096], uri[4200];
    snprintf(path, sizeof path, "%s/binaries/linux64/%s.so", dir, id);
    snprintf(uri, sizeof uri, "file://%s/resources", dir);
    void *lib = dlopen(path, RTLD_NOW | RTLD_LOCAL);
    if (!lib) { printf("dlopen: %s\n", dlerror()); return 2; }
    LOAD(Instantiate) LOAD(FreeInstance) LOAD(SetupExperiment) LOAD(EnterInitializationMode)
    LOAD(ExitInitializationMode) LOAD(DoStep) LOAD(GetReal) LOAD(Terminate)
    fmi2CallbackFunctions cb = {logger, calloc, free, NULL, NULL};
    fmi2Component c[2];
    for (int i = 0; i < 2; i++) {
        c[i] = Instantiate(i ? "b" : "a", fmi2CoSimulation, guid, uri, &cb, fmi2False, fmi2False);
        if (!c[i]) return 3;
        if (SetupExperiment(c[i], fmi2False, 0, 0, fmi2False, 0) || EnterInitializationMode(c[i])
            || ExitInitializationMode(c[i])) return 4;
    }
    for (int k = 0; k < steps; k++)
        for (int i = 0; i < 2; i++)
            if (DoStep(c[i], k * h, h, fmi2True) != fmi2OK) return 5;
    for (int i = 0; i < 2; i++) {
        const fmi2ValueReference vr = 6;    /* x in the toy */
        fmi2Real x;
        if (GetReal(c[i], &vr, 1, &x) != fmi2OK) return 6;
        printf("x %.17g\n", x);
        Terminate(c[i]);
        FreeInstance(c[i]);
    }
    dlclose(lib);
    return 0;
}

int main(int argc, char **argv) {   /* host STEPS H (DIR ID GUID)... */
    int steps = atoi(argv[1]);
    double h = atof(argv[2]);
    for (int i = 3; i + 2 < argc; i += 3) {
        int rc = run(argv[i], argv[i + 1], argv[i + 2], steps, h);
        if (rc) return rc;
    }
    return 0;
}
'''


def clean_env(home: Path, **extra: str) -> dict[str, str]:
    """What a user's C master sees: no LD_PRELOAD, no PYTHONPATH, no virtual environment."""
    return {"PATH": "/usr/bin:/bin", "HOME": str(home), **extra}


def compile_host(folder: Path) -> Path:
    """The C host, compiled against fmpy's FMI headers (no libpython)."""
    import fmpy
    source, binary = folder / "host.c", folder / "host"
    source.write_text(HOST_C)
    headers = Path(fmpy.__file__).parent / "c-code"
    subprocess.run([shutil.which("gcc") or "cc", "-O1", "-I", str(headers), "-o", str(binary),
                    str(source), "-ldl"], check=True, capture_output=True)
    return binary


def run_python(script: str, fmu: Path, steps: int, h: float, timeout: float = 120,
               variable: str = "x"):
    """Run ``script`` (FMPY_RUN or LIBCOSIM_RUN) in a fresh Python process; it prints the
    value of ``variable`` at the end."""
    env = {k: v for k, v in os.environ.items() if k not in ("LD_PRELOAD", "PYTHONPATH")}
    return subprocess.run([sys.executable, "-c", script, str(fmu), str(steps), repr(h), variable],
                          capture_output=True, text=True, timeout=timeout, env=env)


def result(stdout: str) -> float:
    """The number a Python host run printed after RESULT."""
    return float([line for line in stdout.splitlines() if line.startswith("RESULT")][-1].split()[1])


def run_checker(fmu: Path, workdir: Path, stop: float, h: float, timeout: float = 120,
                **env: str):
    """The Compliance Checker on ``fmu`` from a clean environment (plus ``env``); writes
    out.csv in workdir."""
    command = [str(CHECKER), "-k", "cs", "-s", repr(stop), "-h", repr(h), "-n", "0",
               "-o", str(workdir / "out.csv"), "-t", str(workdir), str(fmu)]
    return subprocess.run(command, capture_output=True, text=True, timeout=timeout,
                          env=clean_env(workdir, **env), cwd=workdir)


def ecos_cli(folder: Path) -> Path:
    """Ecos' command-line host copied from the ecospy wheel with its execute bit."""
    import shutil as _shutil

    import ecospy
    shipped = Path(ecospy.__file__).parent / "binaries" / "ecos"
    target = folder / "ecos"
    if not target.exists():
        _shutil.copy(shipped, target)
        target.chmod(0o755)
    return target


def run_ecos_cli(ecos: Path, fmu: Path, workdir: Path, stop: float, h: float, timeout: float = 120):
    """``ecos simulate`` of one FMU from a clean environment; the CSV is <file stem>.csv."""
    return subprocess.run([str(ecos), "simulate", "--path", str(fmu), "--stopTime", repr(stop),
                           "--stepSize", repr(h)], capture_output=True, text=True,
                          timeout=timeout, cwd=workdir, env=clean_env(workdir))


def read_ecos_csv(path: Path) -> dict[str, list[float]]:
    """Ecos' Real columns (6 decimals): "time" and the variable names without "instance::"
    and "[REAL]"."""
    rows = path.read_text().splitlines()
    header = [n.strip().split("::")[-1].split("[")[0] for n in rows[0].split(",")]
    real = [i for i, n in enumerate(rows[0].split(",")) if "[REAL]" in n or n.strip() == "time"]
    columns = list(zip(*(map(str.strip, row.split(",")) for row in rows[1:])))
    return {header[i]: [float(x) for x in columns[i]] for i in real}
