"""The FMU commands of the command line: ``mbdfmu build`` (a scene or a companion source
into an FMI 2.0 or 3.0 FMU) and ``mbdfmu cosim`` (a co-simulation scenario in one master)."""

from __future__ import annotations

import warnings
from pathlib import Path

from .cli_options import (Ticker, add_progress_option, add_set_option, parse_assignments,
                          print_warnings)


def cmd_build(args) -> int:
    from .fmu_build import build  # a scene (.toml) or a companion source (.py)
    from .fmu_build.osp import write_beside

    with Ticker(args, "build"), warnings.catch_warnings(record=True) as said:
        warnings.simplefilter("always", UserWarning)
        path = build(args.scene, output=args.output,
                     parameters=parse_assignments(args.set) or None,
                     fmi_version=args.fmi_version,
                     scene_kernel=False if args.generic_kernel else None)
    print_warnings("build", [str(w.message) for w in said])  # e.g. the scene's kernel
    write_beside(Path(path))      # <name>_OspModelDescription.xml: where OSP's tools look
    print(path)
    return 0


def cmd_cosim(args) -> int:
    from .cosim.cosimulate import cosimulate, write
    from .cosim.settings import CosimSettings

    out = Path(args.output)
    with Ticker(args, "cosim"):
        run = cosimulate(args.scenario, CosimSettings(
            master=args.master, algorithm=args.algorithm, step=args.step, t_end=args.t_end,
            variable_step=args.variable_step, rtol=args.rtol, start=args.start,
            extrapolation=args.extrapolation, jacobian=args.jacobian,
            fmi_version=args.fmi_version),
            work_dir=out / "fmus")
    r = run.result
    stats = ", ".join(f"{k} {v:g}" for k, v in r.stats.items())
    print(f"{run.scenario.name}: {r.method}, {len(r.time)} points to t = {r.time[-1]:g} s "
          f"in {run.seconds:.2f} s ({stats})")
    for name, err in run.errors.items():
        print(f"  {name}: max |error| against the reference {err:.3g}")
    for p in write(run, out):
        print(f"  {p}")
    return 0


def add_fmu_commands(sub, _command) -> None:
    """The build and cosim subcommands (``_command``: cli.py's subcommand factory)."""
    p = _command(sub, "build", cmd_build, "build the FMI 2.0 (or 3.0) co-simulation FMU of a "
                 "scene (.toml) or of a companion source (.py, see scenarios/)",
                 ("mbdfmu build slider_crank -o SliderCrank.fmu",
                  "mbdfmu build slider_crank --fmi-version 3 -o SliderCrank3.fmu",
                  "mbdfmu build scenarios/dc_motor_slider_crank/dc_motor.py -o DCMotor.fmu"))
    p.add_argument("scene", help="scene file (.toml), shipped scene name, or companion "
                   "FMU source (.py)")
    p.add_argument("-o", "--output", default=None, help="FMU file (default <scene name>.fmu)")
    add_set_option(p, "parameter's start value in the FMU")
    p.add_argument("--fmi-version", type=int, choices=[2, 3], default=2,
                   help="FMI version of the FMU (default 2; 3: FMI 3.0, the same variables)")
    p.add_argument("--generic-kernel", action="store_true",
                   help="ship only the generic C kernel, not also the one built for this "
                   "scene (a build some seconds shorter, steps slower)")
    add_progress_option(p)
    p = _command(sub, "cosim", cmd_cosim, "run a co-simulation scenario (scenarios/): CSV and "
                 "plot", ("mbdfmu cosim dc_motor_slider_crank",
                          "mbdfmu cosim hydraulic_crane --master libcosim --step 2e-3",
                          "mbdfmu cosim hydraulic_crane --algorithm jacobi --variable-step",
                          "mbdfmu cosim dc_motor_slider_crank --extrapolation 2",
                          "mbdfmu cosim hydraulic_crane --algorithm implicit --step 0.05",
                          "mbdfmu cosim hydraulic_crane --algorithm implicit --jacobian "
                          "directional --step 0.05",
                          "mbdfmu cosim prescribed_motion:derivatives --master ssp",
                          "mbdfmu cosim dc_motor_slider_crank --fmi-version 3"),
                 description="Run a scenario of scenarios/ (NAME, NAME:VARIANT, a folder or a "
                 "connections file) with the fmpy master, fmpy's SSP runner or OSP libcosim.")
    p.add_argument("scenario")
    p.add_argument("--master", choices=["fmpy", "ssp", "libcosim", "ecos"], default="fmpy")
    p.add_argument("--algorithm", choices=["jacobi", "gauss-seidel", "implicit", "ecco"],
                   default=None, help="default: the scenario's (fmpy), jacobi (ssp, libcosim); "
                   "implicit: interface-Jacobian iteration with rollback (fmpy); ecco: "
                   "libcosim's energy-conservation-based step control (libcosim)")
    p.add_argument("--extrapolation", type=int, choices=[0, 1, 2], default=0,
                   help="inputs follow polynomials of this order over a step (fmpy; 0: "
                   "zero-order hold)")
    p.add_argument("--jacobian", choices=["differences", "directional"], default="differences",
                   help="implicit coupling: the interface Jacobian from finite differences of "
                   "whole steps (default) or from the FMUs' directional derivatives")
    p.add_argument("--fmi-version", type=int, choices=[2, 3], default=2,
                   help="build and run FMI 2.0 (default) or FMI 3.0 FMUs (fmpy master)")
    p.add_argument("--step", type=float, default=None, help="communication step (s)")
    p.add_argument("--t-end", type=float, default=None, help="end time (s)")
    p.add_argument("--variable-step", action="store_true",
                   help="error-controlled step with rollback (fmpy master)")
    p.add_argument("--rtol", type=float, default=None,
                   help="variable step: allowed change of a coupled variable per step")
    p.add_argument("--start", choices=["exchange", "zero"], default="exchange",
                   help="connected inputs start at the upstream outputs (default) or at 0")
    p.add_argument("-o", "--output", default="cosim-out", help="output folder")
    add_progress_option(p)
