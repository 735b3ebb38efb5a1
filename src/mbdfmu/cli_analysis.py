"""The CLI's analysis commands: equilibrium, linearize, sweep (``analysis/``)."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np

from .cli_options import (SOLVER_NAMES, add_progress_option, add_set_option, parse_assignments,
                          parse_ranges, progress_bar, split_solver)

SCENE_HELP = "scene file (.toml) or the name of a shipped scene (listed in mbdfmu --help)"


def _scene(args):
    """The scene of ``args.scene`` and its ``--set`` values (scene parameters, solver)."""
    from .model import load_scene

    scene = load_scene(args.scene)
    params, solver = split_solver(parse_assignments(args.set))
    return scene, params, solver


def _write_json(path: str, data: dict) -> None:
    Path(path).write_text(json.dumps(data, indent=1) + "\n", encoding="utf-8")
    print(f"  -> {path}")


def cmd_equilibrium(args) -> int:
    from .analysis import equilibrium
    from .model.reader import resolve_scene_path
    from .model.writer import write_scene

    scene, params, _ = _scene(args)
    eq = equilibrium(scene, params)
    print(f"{scene.name}: static equilibrium, {eq.stability.upper()} "
          f"({eq.method}, {eq.iterations} steps)")
    print(f"  {'body':<14}{'x (m)':>16}{'y (m)':>16}{'phi (rad)':>16}")
    for name, (x, y, phi) in eq.positions.items():
        print(f"  {name:<14}{x:>16.10g}{y:>16.10g}{phi:>16.10g}")
    stiff = ", ".join(f"{k:.6g}" for k in eq.stiffness) or "none (no degrees of freedom)"
    print(f"  independent coordinates: {', '.join(eq.coordinates) or 'none'}; reduced "
          f"stiffness eigenvalues: {stiff}")
    print(f"  residual: unbalanced force {eq.residual:.3g} (N or N.m), constraints "
          f"{eq.constraint_residual:.3g}")
    if eq.stability == "unstable":
        print("  unstable: a negative stiffness; a small disturbance moves the mechanism away")
    elif eq.stability == "neutral":
        print("  neutral: a zero stiffness; the mechanism can move along it without force")
    if args.output:
        path = write_scene(resolve_scene_path(args.scene), args.output, scene, eq.positions,
                           params)
        print(f"  scene with these positions -> {path}")
    if args.json:
        _write_json(args.json, eq.to_dict())
    return 0


def _matrix(name: str, M: np.ndarray, rows: list[str], cols: list[str]) -> None:
    print(f"  {name} ({M.shape[0]} x {M.shape[1]}):")
    if not M.size:
        return
    print("    " + " " * 18 + "".join(f"{c[:13]:>14}" for c in cols))
    for label, row in zip(rows, M):
        print(f"    {label[:18]:<18}" + "".join(f"{v:>14.6g}" for v in row))


def cmd_linearize(args) -> int:
    from .analysis import linearize

    scene, params, _ = _scene(args)
    lin = linearize(scene, t=args.at, equilibrium=args.equilibrium, parameters=params)
    where = ("the static equilibrium" if lin.at_equilibrium else f"t = {lin.t:g} s")
    print(f"{scene.name} linearized at {where} ({lin.stability}): {len(lin.states)} states, "
          f"{len(lin.inputs)} inputs, {len(lin.outputs)} outputs")
    print(f"  independent coordinates (chosen by QR of Psi_q at the operating point): "
          f"{', '.join(lin.coordinates) or 'none: the constraints fix the motion'}")
    if lin.eigenvalues.size:
        print(f"  {'eigenvalue (1/s)':>30}{'frequency (Hz)':>18}{'damping ratio':>16}")
        for e, f, z in zip(lin.eigenvalues, lin.frequencies_hz, lin.damping_ratios):
            print(f"  {e.real:>14.6g} {e.imag:+14.6g}i{f:>18.8g}"
                  f"{'-' if z is None else format(z, '.6g'):>16}")
    if len(lin.states) <= 12:
        _matrix("A", lin.A, lin.states, lin.states)
        _matrix("B", lin.B, lin.states, lin.inputs)
    print("  C and D (outputs: " + (", ".join(lin.outputs[:6]) + (", ..." if len(lin.outputs) > 6
                                                                    else "")) + "): in --json")
    if args.json:
        _write_json(args.json, lin.to_dict())
    return 0


def cmd_sweep(args) -> int:
    from .analysis import sweep_charts
    from .analysis.sweep import sweep, write_results
    from .integrators.settings import settings_from_scene
    from .model import load_scene
    from .model.variables import outputs

    scene = load_scene(args.scene)
    values = parse_ranges(args.set)
    settings = settings_from_scene(scene).updated(
        names={**SOLVER_NAMES, "method": "--method"}, method=args.method)
    runs = math.prod(len(v) for v in values.values())
    out = Path(args.output)
    out.mkdir(parents=True, exist_ok=True)
    with progress_bar(args, runs, "sweep", "run") as bar:
        result = sweep(scene, values, args.t_end, args.outputs, args.scheduler, settings,
                       advance=bar.update)
    csv = write_results(result, out / "results.csv")
    charts = sweep_charts.draw(result, out, {v.name: v.unit for v in outputs(scene)})
    print(f"{scene.name}: {len(result.rows)} runs on {result.where}, "
          f"{len(result.failed)} failed -> {csv}, {len(charts)} charts in {out}")
    for r in result.failed[:5]:
        values_text = ", ".join(f"{p} = {r[p]:g}" for p in result.parameters)
        print(f"  failed at {values_text}: {r['reason']}")
    return 0


def add_analysis_commands(sub, command) -> None:
    """Add equilibrium, linearize and sweep to the CLI's subparsers (``command`` makes one
    with examples)."""
    p = command(sub, "equilibrium", cmd_equilibrium, "the static equilibrium nearest the "
                "initial positions (drivers held, at rest) and its stability",
                ("mbdfmu equilibrium rod_pendulum",
                 "mbdfmu equilibrium double_pendulum --json eq.json -o rest.toml",
                 "mbdfmu equilibrium my_arm.toml --set spring.stiffness=200"))
    p.add_argument("scene", help=SCENE_HELP)
    p.add_argument("-o", "--output", default=None, metavar="OUT.toml",
                   help="write the scene with the equilibrium positions (and --set values)")
    p.add_argument("--json", default=None, metavar="FILE", help="write the result as JSON")
    add_set_option(p)
    p = command(sub, "linearize", cmd_linearize, "state-space model (A, B, C, D) in minimal "
                "coordinates, eigenvalues, natural frequencies and damping ratios",
                ("mbdfmu linearize double_pendulum --equilibrium",
                 "mbdfmu linearize pendulum_torque --equilibrium --json lin.json",
                 "mbdfmu linearize four_bar --at 0.5",
                 "mbdfmu linearize rod_pendulum --equilibrium --set rod.mass=2"),
                epilog="States: the independent coordinates the tool picks (named after the "
                "scene's bodies) and their rates. Inputs: the scene's inputs (a driver's "
                "position, velocity and acceleration are three). Outputs: the scene's FMU "
                "outputs. Frequencies are |eigenvalue| / 2 pi, damping ratios -Re / |eigenvalue|.")
    p.add_argument("scene", help=SCENE_HELP)
    p.add_argument("--at", type=float, default=0.0, metavar="T",
                   help="linearize at the state a run reaches at T seconds (default 0)")
    p.add_argument("--equilibrium", action="store_true",
                   help="linearize at the static equilibrium (drivers held at t = 0)")
    p.add_argument("--json", default=None, metavar="FILE", help="write the model as JSON")
    add_set_option(p)
    _add_sweep(sub, command)


def _add_sweep(sub, command) -> None:
    from .integrators import METHOD_NAMES

    p = command(sub, "sweep", cmd_sweep, "run every combination of parameter values as Dask "
                "tasks: results.csv and charts",
                ("mbdfmu sweep slider_crank --set load.fx=-100:0:10 --set rod.mass=0.1:0.5:10 "
                 "--t-end 0.02 -o sweep",
                 "mbdfmu sweep pendulum --set bob.mass=0.5:2:4 --t-end 2 --outputs 'bob.*' "
                 "--scheduler tcp://10.0.0.5:8786",
                 "mbdfmu sweep rod_pendulum --set solver.rtol=1e-8:1e-4:5 --t-end 1 "
                 "--scheduler synchronous"),
                epilog="Each row of DIR/results.csv: the parameter values, <output>.final and "
                "<output>.peak (largest |value| at the output times), status and reason. A "
                "failed run is a row with its reason; the sweep goes on.")
    p.add_argument("scene", help=SCENE_HELP)
    p.add_argument("--set", action="append", required=True, metavar="NAME=START:STOP:COUNT",
                   help="a parameter and its values (names as the FMU's parameters; "
                   "repeatable: every combination runs)")
    p.add_argument("--t-end", type=float, required=True, help="end time of each run (s)")
    p.add_argument("--outputs", nargs="+", default=None, metavar="GLOB",
                   help="outputs to record (default: the scene's FMU outputs)")
    p.add_argument("--method", choices=list(METHOD_NAMES), default=None,
                   help="integration method (default: the scene's, else auto)")
    p.add_argument("--scheduler", default=None, help="address of a running Dask scheduler, "
                   "or 'synchronous' (default: a local cluster, one worker per core)")
    p.add_argument("-o", "--output", default="sweep", metavar="DIR", help="output folder")
    add_progress_option(p)
