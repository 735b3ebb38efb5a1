"""What an FMU costs a C/C++ master: a minimal master written in C (no Python in the loop)
that loads the FMU's binary with dlopen, sets its input (when it has one) before every
communication step, calls fmi2DoStep and reads every output with one fmi2GetReal, and
reports the process's CPU time per communication step (CLOCK_PROCESS_CPUTIME_ID: the
FMU's embedded Python, where it runs, is in the same process and counted).

Used by ``fmu_speed.py`` (the "C master" column): fmpy's Python around each FMI call costs
its own time on each call (docs/performance.md measures it), a C/C++ master's (libcosim,
the FMI Compliance Checker, an engine's host) next to nothing, so this is the FMU's own
cost per step.

    from c_master import compile_master, c_master_cpu
    binary = compile_master(folder)
    cpu_s_per_step = c_master_cpu(binary, fmu, h=1e-3, n=20000, input_vr=5, hold=8420.0,
                                  swing=0.05, outputs=[0, 1, 2])
"""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
from pathlib import Path

from fmpy import extract, read_model_description

SOURCE = r'''
#include <dlfcn.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <time.h>
#include "fmi2Functions.h"

static void logger(fmi2ComponentEnvironment e, fmi2String name, fmi2Status s, fmi2String cat,
                   fmi2String message, ...) {
    (void)e; (void)name; (void)cat;
    if (s > fmi2Warning) fprintf(stderr, "FMU: %s\n", message);
}

static double cpu_seconds(void) {
    struct timespec ts;
    clock_gettime(CLOCK_PROCESS_CPUTIME_ID, &ts);
    return (double)ts.tv_sec + 1e-9 * (double)ts.tv_nsec;
}

#define LOAD(f) fmi2##f##TYPE *f = (fmi2##f##TYPE *)dlsym(lib, "fmi2" #f); \
    if (!f) { fprintf(stderr, "no fmi2" #f "\n"); return 2; }

/* master DIR ID GUID H N INPUT_VR HOLD SWING VR...: the input (INPUT_VR < 0: none) is
 * HOLD * (1 + SWING sin(2 pi t)) at the start of each step, as fmu_speed.actuator. */
int main(int argc, char **argv) {
    if (argc < 9) { fprintf(stderr, "usage: DIR ID GUID H N INPUT_VR HOLD SWING VR...\n"); return 1; }
    const char *dir = argv[1], *id = argv[2], *guid = argv[3];
    double h = atof(argv[4]), hold = atof(argv[7]), swing = atof(argv[8]);
    long n = atol(argv[5]), input = atol(argv[6]);
    size_t nout = (size_t)(argc - 9);
    fmi2ValueReference *vr = calloc(nout + 1, sizeof *vr);
    fmi2Real *values = calloc(nout + 1, sizeof *values);
    for (size_t i = 0; i < nout; i++) vr[i] = (fmi2ValueReference)atol(argv[9 + i]);
    char path[4096], uri[4200];
    snprintf(path, sizeof path, "%s/binaries/linux64/%s.so", dir, id);
    snprintf(uri, sizeof uri, "file://%s/resources", dir);
    void *lib = dlopen(path, RTLD_NOW | RTLD_LOCAL);
    if (!lib) { fprintf(stderr, "dlopen: %s\n", dlerror()); return 2; }
    LOAD(Instantiate) LOAD(FreeInstance) LOAD(SetupExperiment) LOAD(EnterInitializationMode)
    LOAD(ExitInitializationMode) LOAD(DoStep) LOAD(GetReal) LOAD(SetReal) LOAD(Terminate)
    fmi2CallbackFunctions cb = {logger, calloc, free, NULL, NULL};
    fmi2Component c = Instantiate("c_master", fmi2CoSimulation, guid, uri, &cb, fmi2False,
                                  fmi2False);
    if (!c) return 3;
    if (SetupExperiment(c, fmi2False, 0, 0, fmi2False, 0) || EnterInitializationMode(c)
        || ExitInitializationMode(c)) return 4;
    const fmi2ValueReference in = (fmi2ValueReference)(input < 0 ? 0 : input);
    double t = 0.0, start = 0.0;
    int failed = 0;
    for (long k = 0; k < n + 20; k++) {        /* 20 steps first: caches, the first restart */
        if (k == 20) start = cpu_seconds();
        if (input >= 0) {
            fmi2Real force = hold * (1.0 + swing * sin(2.0 * M_PI * t));
            failed |= SetReal(c, &in, 1, &force) != fmi2OK;
        }
        failed |= DoStep(c, t, h, fmi2True) != fmi2OK;
        t += h;
        failed |= GetReal(c, vr, nout, values) != fmi2OK;
    }
    double cpu = (cpu_seconds() - start) / (double)n;
    if (failed) { fprintf(stderr, "an FMI call failed\n"); return 5; }
    printf("RESULT %.9g %.17g\n", cpu, values[0]);
    Terminate(c);
    FreeInstance(c);
    return 0;
}
'''


def compile_master(folder: Path) -> Path:
    """The C master, compiled with gcc against fmpy's FMI 2.0 headers (no libpython)."""
    import fmpy
    source, binary = folder / "c_master.c", folder / "c_master"
    source.write_text(SOURCE)
    headers = Path(fmpy.__file__).parent / "c-code"
    subprocess.run([shutil.which("gcc") or "cc", "-O2", "-I", str(headers), "-o", str(binary),
                    str(source), "-ldl", "-lm"], check=True, capture_output=True)
    return binary


def c_master_run_values(binary: Path, fmu: Path, *, h: float, n: int, input_vr: int | None,
                        hold: float, swing: float, outputs: list[int]) -> dict:
    """``n`` steps of ``h`` in a fresh process of the C master (after 20 untimed steps):
    ``cpu_s`` per communication step and ``first_output``, the first of ``outputs`` at the
    end."""
    md = read_model_description(fmu)
    folder = extract(fmu)
    env = {k: v for k, v in os.environ.items() if k not in ("LD_PRELOAD", "PYTHONPATH")}
    args = [str(binary), folder, md.coSimulation.modelIdentifier, md.guid, repr(h), str(n),
            str(-1 if input_vr is None else input_vr), repr(hold), repr(swing),
            *map(str, outputs)]
    run = subprocess.run(args, capture_output=True, text=True, timeout=600, env=env)
    shutil.rmtree(folder, ignore_errors=True)
    line = [x for x in run.stdout.splitlines() if x.startswith("RESULT ")]
    if run.returncode != 0 or not line:
        raise RuntimeError(f"{fmu.name}: the C master failed ({run.returncode}): "
                           f"{run.stderr.strip()[-300:]}")
    _, cpu, first = line[-1].split()
    return {"cpu_s": float(cpu), "first_output": float(first)}


def c_master_cpu(binary: Path, fmu: Path, **settings) -> float:
    """CPU s per communication step of the C master (``c_master_run_values``' settings)."""
    return c_master_run_values(binary, fmu, **settings)["cpu_s"]


if __name__ == "__main__":      # python benchmarks/c_master.py FMU [H] [N]
    import tempfile
    fmu = Path(sys.argv[1])
    with tempfile.TemporaryDirectory() as tmp:
        binary = compile_master(Path(tmp))
        outs = [v.valueReference for v in read_model_description(fmu).modelVariables
                if v.causality == "output"]
        cpu = c_master_cpu(binary, fmu, h=float(sys.argv[2]) if len(sys.argv) > 2 else 1e-3,
                           n=int(sys.argv[3]) if len(sys.argv) > 3 else 20000, input_vr=None,
                           hold=0.0, swing=0.0, outputs=outs)
        print(f"{fmu.name}: {cpu * 1e6:.2f} CPU µs per communication step")
