"""The command line: subcommands whose flags mirror the Python API.

Every failure the project expects (bad scene, failed solve, bad input) ends with exit
status 2 and one line on stderr, never a traceback.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

from . import __version__
from .errors import InputError, MbdfmuError
from .cli_analysis import SCENE_HELP
from .cli_options import (SOLVER_NAMES, add_progress_option, add_set_option,
                          parse_assignments, print_warnings, progress_bar, show_progress,
                          split_solver)
from .integrators import DEFAULT_METHOD, METHOD_NAMES, SUMMARIES

EXAMPLES = """examples:
  mbdfmu demo                                   slider-crank FMU run in fmpy: CSV, plot, GIF
  mbdfmu check slider_crank                     bodies, joints, degrees of freedom
  mbdfmu simulate pendulum --t-end 10 --rtol 1e-10 --out pendulum.csv
  mbdfmu plot pendulum.csv "bob.*" -o pendulum.png
  mbdfmu animate pendulum pendulum.csv -o pendulum.gif
  mbdfmu equilibrium double_pendulum            where it rests, and whether that is stable
  mbdfmu linearize double_pendulum --equilibrium   A, B, C, D, frequencies, damping ratios
  mbdfmu sweep slider_crank --set load.fx=-100:0:10 --set rod.mass=0.1:0.5:10 --t-end 0.02
  mbdfmu build slider_crank -o SliderCrank.fmu --set load.fx=-50
  mbdfmu build slider_crank --fmi-version 3 -o SliderCrank3.fmu   FMI 3.0
  mbdfmu build scenarios/dc_motor_slider_crank/dc_motor.py -o DCMotor.fmu
  mbdfmu cosim hydraulic_crane --master libcosim   co-simulation scenario: CSV and plot
scenes: a .toml file, or a shipped scene's name (%s)
"""


# The CLI's names of the solver settings, for error messages.
FLAGS = {"method": "--method", "step": "--step", "rtol": "--rtol", "atol": "--atol",
         "output_interval": "--output-interval"}


def _methods_help() -> str:
    return "; ".join(f"{n}: {summary}" for n, summary in SUMMARIES.items())


def cmd_check(args) -> int:
    from .equations import Equations
    from .equations.projection import assemble, assembly_changes, initial_estimates, rank_report
    from .integrators.settings import settings_from_scene
    from .model import load_scene
    from .integrators.events import event_summary
    from .model.scene import has_events
    from .model.variables import inputs

    scene = load_scene(args.scene)
    settings_from_scene(scene)          # the [simulation] table's values, checked
    system = Equations(scene)
    q_est, _ = initial_estimates(system)
    residual0 = float(np.linalg.norm(system.constraints(0.0, q_est)[0])) if system.m else 0.0
    q, qd = assemble(system)
    changes = assembly_changes(system, initial_estimates(system), (q, qd))
    residual = float(np.linalg.norm(system.constraints(0.0, q)[0])) if system.m else 0.0
    report = rank_report(system, 0.0, q)
    print(f"scene {scene.name}: {scene.description}")
    print(f"  bodies ({len(scene.bodies)}):")
    for b in scene.bodies:
        print(f"    {b.name}: mass {b.mass:g} kg, inertia {b.inertia:g} kg.m2")
    print(f"  joints ({len(scene.joints)}):")
    for j in scene.joints:
        print(f"    {j.name}: {j.TYPE} {j.summary()}")
    print(f"  drivers ({len(scene.drivers)}):")
    for d in scene.drivers:
        target = f"joint {d.joint}" if d.joint else f"{d.body}.{d.coordinate}"
        print(f"    {d.name}: {type(d.motion).__name__} on {target}")
    print(f"  forces ({len(scene.forces)}): " + ", ".join(f"{f.name} ({type(f).__name__})"
                                                      for f in scene.forces))
    print(f"  coordinates {system.n}, constraints {system.m}, rank {report.rank}, "
          f"degrees of freedom {report.dof}")
    print("  redundant constraints: " + (", ".join(report.redundant) or "none"))
    if has_events(scene):
        print("  " + event_summary(scene, q, qd, report.dof))
    print(f"  assembly residual: {residual0:.3g} as given, {residual:.3g} after assembly")
    print(f"  inputs: {', '.join(v.name for v in inputs(scene)) or 'none'}")
    print_warnings("check", changes)
    return 0


def _read_inputs(path: str):
    try:
        table = np.genfromtxt(path, delimiter=",", names=True, dtype=float,
                              deletechars="", ndmin=1)
    except (OSError, ValueError, IndexError) as exc:
        raise InputError(f"{path}: cannot read the input table: {exc or 'empty file'}") from None
    if table.dtype.names is None:
        raise InputError(f"{path}: the input table needs a header row")
    if table.size == 0:
        raise InputError(f"{path}: the input table has a header but no rows")
    return table


def cmd_simulate(args) -> int:
    from .integrators.settings import settings_from_scene
    from .model import load_scene
    from .model.variables import with_parameters
    from .simulation import check_t_end, simulate

    scene = load_scene(args.scene)
    params, solver = split_solver(parse_assignments(args.set))
    scene = with_parameters(scene, params) if params else scene
    settings = settings_from_scene(scene).updated(names=SOLVER_NAMES, **solver).updated(
        names=FLAGS, method=args.method, step=args.step, rtol=args.rtol, atol=args.atol,
        output_interval=args.output_interval)
    t_end = check_t_end(args.t_end, "--t-end") if args.t_end is not None else None
    inputs = _read_inputs(args.input) if args.input else None
    horizon = t_end if t_end is not None else scene.simulation.t_end
    with progress_bar(args, horizon, "simulate", "s") as bar:
        result = simulate(scene, t_end, inputs=inputs, settings=settings,
                          progress=lambda t: bar.update(t - bar.n))
    out = Path(args.out or f"{scene.name}.csv")
    result.to_csv(out)
    print_warnings("simulate", result.warnings)
    print(f"{scene.name}: {len(result.time)} points to t = {result.time[-1]:g} s with "
          f"{result.method} ({result.stats['nsteps']} steps) -> {out}")
    if result.method_reason:
        print(f"  auto picked {result.method.split('->')[1]}: {result.method_reason}")
    for t, old, new, why in result.switches:
        print(f"  t = {t:.9g} s: auto switched from {old} to {new}: {why}")
    return 0


def cmd_plot(args) -> int:
    from .model import load_scene
    from .plotting import plot_result, scene_units, show
    from .result import read_csv

    result = read_csv(args.result)
    if args.scene:
        result.units = scene_units(load_scene(args.scene))
    out = args.output or Path(args.result).with_suffix(".png").name
    fig_path = plot_result(result, args.variables, out, title=Path(args.result).stem)
    print(fig_path)
    if args.show:
        print(show(result, args.variables, title=Path(args.result).stem))
    return 0


def cmd_animate(args) -> int:
    from .model import load_scene
    from .animation import animate
    from .result import read_csv

    result = read_csv(args.result)
    with progress_bar(args, 1, "animate", "frame") as bar:
        def advance(done: int, total: int) -> None:
            bar.total = total
            bar.update(done - bar.n)
        out = animate(load_scene(args.scene), result, args.output, progress=advance)
    print(out)
    return 0


def cmd_demo(args) -> int:
    """The product end to end: scene -> FMU -> fmpy run -> CSV, plot, animation."""
    from fmpy import simulate_fmu

    from .fmu_build.scene_fmu import build_fmu
    from .model import load_scene
    from .model.reader import bundled_scene
    from .model.variables import outputs
    from .animation import animate
    from .plotting import plot_result
    from .result import Result

    out = Path(args.output)
    out.mkdir(parents=True, exist_ok=True)
    scene_path = bundled_scene("slider_crank")
    scene = load_scene(scene_path)
    fmu = build_fmu(scene_path, output=out / f"{scene.name}.fmu")
    t_end, interval = 0.04, 2e-4  # two crank turns at 3000 rpm
    table = simulate_fmu(str(fmu), stop_time=t_end, output_interval=interval)
    names = list(table.dtype.names[1:])
    result = Result(time=np.asarray(table["time"]), names=names,
                    values=np.column_stack([table[n] for n in names]),
                    units={v.name: v.unit for v in outputs(scene)})
    csv = result.to_csv(out / "slider_crank.csv")
    png = plot_result(result, ["slider.x", "motor.effort", "B.Fx", "B.Fy"],
                      out / "slider_crank.png", title="Slider-crank FMU in fmpy, 3000 rpm")
    gif = animate(scene, result, out / "slider_crank.gif")
    effort = result["motor.effort"]
    print(f"{fmu.name} built and run in fmpy to t = {t_end} s (two crank turns) at a "
          f"{interval * 1e3:g} ms communication step: motor torque {effort.min():.1f} .. "
          f"{effort.max():.1f} N.m, slider {result['slider.x'].min():.3f} .. "
          f"{result['slider.x'].max():.3f} m")
    for p in (fmu, csv, png, gif):
        print(f"  {p}")
    return 0


def cmd_bench(args) -> int:
    from .bench import sweep

    if args.from_csv:
        done = sweep.redraw(args.from_csv, args.output)
    else:
        from .bench.comm import parse_comm_steps
        done = sweep.run_bench(args.scenes, methods=args.methods, scheduler=args.scheduler,
                               output=args.output, quick=args.quick, progress=show_progress(args),
                               comm_steps=parse_comm_steps(args.comm_steps),
                               settings_sweep=not args.comm_only)
    print(f"{len(done['rows'])} runs -> {done['csv']}, {done['summary']}, "
          f"{len(done['charts'])} charts in {Path(done['summary']).parent}")
    return 0


def _command(sub, name: str, func, help: str, examples: tuple[str, ...] = (), epilog: str = "",
             **kwargs) -> argparse.ArgumentParser:
    """A subcommand whose --help ends with its examples."""
    text = "\n".join(filter(None, [epilog, "examples:\n" + "\n".join(f"  {e}" for e in examples)
                                   if examples else ""]))
    p = sub.add_parser(name, help=help, epilog=text or None,
                       formatter_class=argparse.RawDescriptionHelpFormatter, **kwargs)
    p.set_defaults(func=func)
    return p


def _add_run_commands(sub) -> None:
    p = _command(sub, "check", cmd_check, "load, validate and assemble a scene; print its "
                 "structure and what assembly changed",
                 ("mbdfmu check slider_crank", "mbdfmu check my_scene.toml"))
    p.add_argument("scene", help=SCENE_HELP)
    p = _command(sub, "simulate", cmd_simulate, "simulate a scene and write a CSV",
                 ("mbdfmu simulate pendulum --t-end 10 --rtol 1e-10 --out pendulum.csv",
                  "mbdfmu simulate slider_force --input push.csv --method rk4p --step 1e-4"),
                 epilog=f"methods: {_methods_help()}")
    p.add_argument("scene", help=SCENE_HELP)
    p.add_argument("--t-end", type=float, default=None, help="end time (s); default from the scene")
    p.add_argument("--method", choices=list(METHOD_NAMES), default=None,
                   help=f"integration method (default {DEFAULT_METHOD})")
    p.add_argument("--step", type=float, default=None,
                   help="fixed step (s) of fixed-step methods; the largest step of adaptive ones")
    p.add_argument("--rtol", type=float, default=None, help="relative tolerance (adaptive methods)")
    p.add_argument("--atol", type=float, default=None, help="absolute tolerance (adaptive methods)")
    p.add_argument("--output-interval", type=float, default=None, help="time between output rows (s)")
    p.add_argument("--input", default=None,
                   help="CSV of inputs: time, then input names (e.g. motor.position)")
    p.add_argument("--out", default=None, help="output CSV (default <scene name>.csv)")
    add_set_option(p, "parameter or solver setting")
    add_progress_option(p)
    p = _command(sub, "plot", cmd_plot, "plot variables of a result CSV (mbdfmu's or fmpy's), "
                 "one axis per unit",
                 ('mbdfmu plot pendulum.csv "bob.*" -o pendulum.png',
                  'mbdfmu plot out.csv "*.phi" "motor.effort" --scene slider_crank --show'))
    p.add_argument("result", help="CSV with time first (mbdfmu simulate, fmpy simulate)")
    p.add_argument("variables", nargs="*", help="names or glob patterns (default *.x *.y *.phi)")
    p.add_argument("-o", "--output", default=None, help="PNG file (default <result>.png)")
    p.add_argument("--scene", default=None,
                   help="the scene the result is of: exact units (else from the names)")
    p.add_argument("--show", action="store_true", help="also open a window (needs a display)")
    p = _command(sub, "animate", cmd_animate, "animate a result CSV of a scene as a GIF",
                 ("mbdfmu animate pendulum pendulum.csv -o pendulum.gif",))
    p.add_argument("scene", help=SCENE_HELP)
    p.add_argument("result", help="CSV of a run of that scene")
    p.add_argument("-o", "--output", required=True, help="GIF file")
    add_progress_option(p)
    p = _command(sub, "demo", cmd_demo, "build the slider-crank FMU, run it in fmpy, write "
                 "CSV, plot, GIF", ("mbdfmu demo", "mbdfmu demo -o out"))
    p.add_argument("-o", "--output", default="mbdfmu-demo", help="output folder")


def _add_bench_command(sub) -> None:
    from .bench.cases import CASES, COMM_STEPS
    from .integrators import METHOD_NAMES
    comm = [k for k, c in CASES.items() if c.comm_t_end is not None]
    p = _command(sub, "bench", cmd_bench, "work-precision and stability benchmark of every "
                 "method, and the FMU's use pattern (needs mbdfmu[bench])",
                 ("mbdfmu bench -o bench",
                  "mbdfmu bench P1 P3 --methods rk4p dop853p --scheduler tcp://10.0.0.5:8786",
                  "mbdfmu bench --quick --scheduler synchronous",
                  "mbdfmu bench P2N2 --comm-only --comm-steps 1e-3,0.1",
                  "mbdfmu bench --comm-steps none"),
                 epilog="scenes: " + "; ".join(f"{k}: {c.title}" for k, c in CASES.items()) +
                 f"\ncommunication-step sweep (Simulation.advance at each step, as an FMU's "
                 f"master): {', '.join(comm)}")
    p.add_argument("scenes", nargs="*", metavar="SCENE",
                   help=f"scenes to run: {' '.join(CASES)} (default all)")
    p.add_argument("--methods", nargs="+", choices=list(METHOD_NAMES), default=None,
                   help="methods to run (default all, auto included)")
    p.add_argument("--comm-steps", default=None, metavar="H,H,...",
                   help="communication steps (s) of the communication-step sweep, comma-"
                   f"separated, or none (default {','.join(f'{h:g}' for h in COMM_STEPS)})")
    p.add_argument("--comm-only", action="store_true",
                   help="only the communication-step sweep (no settings sweep)")
    p.add_argument("--scheduler", default=None, help="address of a running Dask scheduler, or "
                   "'synchronous' (default: a local cluster, one single-threaded worker per "
                   "core)")
    p.add_argument("-o", "--output", default=None,
                   help="output folder (default bench, or the CSV's folder with --from-csv)")
    p.add_argument("--quick", action="store_true", help="a small sweep on short horizons")
    p.add_argument("--from-csv", nargs="+", default=None, metavar="CSV",
                   help="redraw charts and summary from results.csv files (several: merged "
                   "into the output folder's results.csv), without running")
    add_progress_option(p)


def build_parser() -> argparse.ArgumentParser:
    from .cli_analysis import add_analysis_commands
    from .cli_fmu import add_fmu_commands
    from .model.reader import shipped_scene_names

    parser = argparse.ArgumentParser(
        prog="mbdfmu", description="Planar multibody mechanisms as FMI 2.0 and 3.0 "
        "co-simulation FMUs.",
        epilog=EXAMPLES % ", ".join(shipped_scene_names()),
        formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--version", action="version", version=f"mbdfmu {__version__}")
    sub = parser.add_subparsers(dest="command", required=True)
    _add_run_commands(sub)
    add_analysis_commands(sub, _command)
    add_fmu_commands(sub, _command)
    _add_bench_command(sub)
    return parser


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        return args.func(args)
    except MbdfmuError as exc:
        print(f"mbdfmu {args.command}: {exc}", file=sys.stderr)
        return 2
    except (OSError, ValueError, ArithmeticError) as exc:  # files, bad numbers
        print(f"mbdfmu {args.command}: {type(exc).__name__}: {exc}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
