"""mbdfmu against Exudyn's generalized-alpha, side by side, on P1 and P2 (N = 2).

Exudyn (``pip install exudyn``, a compiled C++ multibody code) models the same two
mechanisms, translated body for body and joint for joint from our scene files
(``exudyn_model``): every body a ``NodeRigidBody2D`` (reference coordinates = the scene's
x, y, angle; initial velocities = the scene's) with an ``ObjectRigidBody2D`` of the same mass
and inertia, gravity a ``LoadMassProportional`` per body, every revolute joint an
``ObjectJointRevolute2D`` between ``MarkerBodyPosition`` markers at the same body-fixed points.
The same builder translates what benchmarks/fmu_speed.py's other mechanisms add: a
translational joint (``ObjectJointPrismatic2D``, rotation locked), a constant-rate driver of a
revolute joint to the ground (a velocity-level ``CoordinateConstraint`` on the body's angle:
compiled, no Python user function), a constant point force (``LoadForceVector``) and a
spring-damper with an actuator force (``ObjectConnectorSpringDamper``'s ``force``).

- P1 (scenes/pendulum.toml): the 1 kg bob is a rigid body with the scene's tiny inertia
  1e-6 kg m^2, pinned to the ground by a revolute joint 1 m from its centre: the same
  physics as our scene, so both tools are measured against the same exact elliptic
  solution ``references.pendulum(t, J=1e-6)``. Error: bob position at t_end (m).
- P2, N = 2 (scenes/n_four_bar_2.toml): 3 cranks and 2 couplers, 7 revolute joints (two of
  the 14 constraints are redundant only at the singular configurations, where the cranks
  pass the horizontal, twice per revolution). Error: position of B0 (top of crank0) at
  t_end against the exact one-DOF reduction ``references.n_four_bar_B0(t, 2)`` (m).

Exudyn solves with ``exu.SolveDynamic`` and its default implicit solver,
``DynamicSolverType.GeneralizedAlpha`` (index 3, spectral radius 0.9, modified Newton with
its default tolerances, its default step reduction when Newton fails); no renderer,
no solution or sensor files, console output off. mbdfmu runs ``Simulation(scene, method=...)``
and ``advance(t_end)`` (genalpha there uses rho_inf = 0.8, each tool at its own default).

Measured in one process (BLAS single-threaded), after a warm-up (numba compiles mbdfmu's
kernel); CPU time is ``time.process_time`` of model building, assembly and the solve:
1. cost per step: CPU time over the steps taken, the median of ``--repeat`` runs, the
   repetitions interleaved so that load on the machine hits both tools alike; Exudyn's generalized-alpha
   against mbdfmu's fixed-step methods at the same step, and mbdfmu's adaptive methods per
   accepted step;
2. work-precision: the error at t_end against CPU time for a sweep of steps (Exudyn;
   mbdfmu's fixed-step methods) and of tolerances (mbdfmu's adaptive methods, atol = rtol
   x 1e-2 x the scene's size, as ``mbdfmu bench``), one run per setting (runs under 0.5 s:
   the median of ``--repeat``, as noise is largest there); then the CPU time
   each needs to reach an error level: the cheapest run of the sweep whose error is <= the
   level (no interpolation), and the ratio mbdfmu-best / Exudyn. A failed run (mbdfmu's
   ``SolverError``, Exudyn's ``SolverError``) is recorded with its reason and time.

Results: benchmarks/results/exudyn_compare.csv, docs/figures/performance/exudyn_compare.md
(the tables printed), exudyn_work_precision.png and exudyn_cost_per_step.png there.

    python benchmarks/exudyn_compare.py [--quick] [-o DIR] [--repeat N]

``--quick`` (about a minute) runs 2 s horizons and short sweeps and writes to
``./exudyn_compare_quick`` unless ``-o`` is given; ``-o DIR`` puts every output in DIR.
"""

from __future__ import annotations

import os

# Before numpy: one BLAS thread, as mbdfmu bench's workers, so both tools run on one core.
for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import argparse  # noqa: E402
import csv  # noqa: E402
import math  # noqa: E402
import platform  # noqa: E402
import statistics  # noqa: E402
import subprocess  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402
from dataclasses import dataclass, field  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402

import mbdfmu  # noqa: E402
from mbdfmu.bench import closed_forms as references  # noqa: E402

try:
    import exudyn as exu
    from exudyn.itemInterface import (  # noqa: E402
        CoordinateConstraint, LoadForceVector, LoadMassProportional, MarkerBodyMass,
        MarkerBodyPosition, MarkerBodyRigid, MarkerNodeCoordinate, NodePointGround, NodeRigidBody2D,
        ObjectConnectorSpringDamper, ObjectGround, ObjectJointPrismatic2D,
        ObjectJointRevolute2D, ObjectRigidBody2D)
except ImportError:  # the script says how to install it; the test skips
    exu = None

ROOT = Path(__file__).resolve().parents[1]
CSV_DEFAULT = ROOT / "benchmarks" / "results" / "exudyn_compare.csv"
FIGURES_DEFAULT = ROOT / "docs" / "figures" / "performance"
QUICK_DEFAULT = Path("exudyn_compare_quick")

LEVELS = (1e-4, 1e-6, 1e-8)
ATOL_FACTOR = 1e-2          # atol = rtol * this * the scene's size (as mbdfmu bench)
FIXED_METHODS = ("rk4p", "genalpha", "ali3p")
ADAPTIVE_METHODS = ("dop853p", "rk45p", "auto")
COST_STEP = 1e-3            # the fixed step of the cost-per-step table (s)
COST_RTOL = 1e-8            # the tolerance of the adaptive methods there
SHORT_RUN_S = 0.5           # sweep runs shorter than this are repeated (median CPU time)


@dataclass(frozen=True)
class Sweep:
    """What one run of the script does: horizons, repetitions and the settings swept."""

    t_end: float                       # horizon of the work-precision runs (s)
    cost_t_end: float                  # horizon of the cost-per-step runs (s)
    exudyn_steps: tuple[float, ...]
    fixed_steps: tuple[float, ...]     # mbdfmu rk4p, genalpha, ali3p
    rtols: tuple[float, ...]           # mbdfmu dop853p, rk45p, auto


FULL = Sweep(t_end=10.0, cost_t_end=10.0,
             exudyn_steps=(1e-2, 5e-3, 2e-3, 1e-3, 5e-4, 2e-4, 1e-4, 5e-5, 2e-5, 1e-5),
             fixed_steps=(2e-2, 1e-2, 5e-3, 2e-3, 1e-3, 5e-4),
             rtols=tuple(10.0 ** -k for k in range(3, 12)))
QUICK = Sweep(t_end=2.0, cost_t_end=1.0, exudyn_steps=(1e-2, 1e-3, 1e-4),
              fixed_steps=(1e-2, 5e-3), rtols=(1e-4, 1e-6, 1e-8))


# ---------------------------------------------------------------------------- problems

@dataclass(frozen=True)
class Problem:
    """A benchmark problem: its scene, the measured point (body-fixed, m) and its exact path."""

    key: str
    scene: str
    title: str
    body: str
    point: tuple[float, float]


PROBLEMS = {p.key: p for p in (
    Problem("P1", "pendulum", "P1 pendulum (bob position)", "bob", (0.0, 0.0)),
    Problem("P2N2", "n_four_bar_2", "P2 double four-bar, N = 2 (B0 position)", "crank0",
            (0.5, 0.0)),
)}


def load_problem_scene(problem: Problem):
    return mbdfmu.load_scene(ROOT / "scenes" / f"{problem.scene}.toml")


def exact_point(problem: Problem, scene, t: float) -> tuple[float, float]:
    """The measured point at time t from the closed form (P1: elliptic; P2: the reduction)."""
    if problem.key == "P1":
        bob = scene.bodies[0]
        e = references.pendulum(t, L=1.0, m=bob.mass, J=bob.inertia)
        return float(e["x"]), float(e["y"])
    e = references.n_four_bar_B0([t], 2)
    return float(e["x"][0]), float(e["y"][0])


def singular_note(problem: Problem, t: float | None) -> str:
    """Where a P2 run stopped, in degrees of the cranks from the horizontal (exact motion)."""
    if problem.key != "P2N2" or t is None or t <= 0.0:
        return ""
    theta = float(references.n_four_bar_B0([t], 2)["theta"][0])
    off = abs(math.degrees(math.remainder(theta, math.pi)))
    return f"cranks {off:.2g} deg from the horizontal (singular at 0)"


def length_scale(scene) -> float:
    """The scene's size, as mbdfmu bench scales atol with it."""
    return max([1.0] + [abs(v) for b in scene.bodies for v in b.position])


# ---------------------------------------------------------------------------- Exudyn models

@dataclass
class ExudynModel:
    """An Exudyn system built from a scene; ``bodies`` maps body names to object numbers,
    ``drivers`` driver names to their coordinate constraints, ``actuators`` spring-damper
    names to their connectors (the actuator force is the connector's ``force``, N, positive
    pulling the ends together: minus our actuator input). The SystemContainer is kept: the
    system lives in it."""

    sc: object
    mbs: object
    bodies: dict
    drivers: dict = field(default_factory=dict)
    actuators: dict = field(default_factory=dict)


def exudyn_model(scene, *, actuators: dict | None = None) -> ExudynModel:
    """The scene as an Exudyn system: rigid bodies, gravity, revolute and translational
    joints, constant-rate drivers of revolute joints, constant point forces and spring-dampers
    (``actuators``: an actuator input's force by spring-damper name, N, held constant)."""
    if exu is None:
        raise ImportError("exudyn is not installed: pip install exudyn")
    sc = exu.SystemContainer()
    mbs = sc.AddSystem()
    model = ExudynModel(sc, mbs, {"ground": mbs.AddObject(ObjectGround(
        referencePosition=[0.0, 0.0, 0.0]))})
    gx, gy = scene.gravity
    nodes = {}
    for b in scene.bodies:
        nodes[b.name] = mbs.AddNode(NodeRigidBody2D(
            referenceCoordinates=[b.position[0], b.position[1], b.angle],
            initialVelocities=[b.velocity[0], b.velocity[1], b.angular_velocity]))
        body = mbs.AddObject(ObjectRigidBody2D(nodeNumber=nodes[b.name], mass=b.mass,
                                               inertia=b.inertia))
        mass = mbs.AddMarker(MarkerBodyMass(bodyNumber=body))
        mbs.AddLoad(LoadMassProportional(markerNumber=mass, loadVector=[gx, gy, 0.0]))
        model.bodies[b.name] = body
    angles = {b.name: b.angle for b in scene.bodies} | {"ground": 0.0}
    for j in scene.joints:
        _exudyn_joint(scene, model, j, angles)
    for d in scene.drivers:
        model.drivers[d.name] = _exudyn_driver(scene, model, d, nodes, angles)
    for f in scene.forces:
        _exudyn_force(scene, model, f, actuators or {})
    mbs.Assemble()
    return model


def set_before_each_step(model: ExudynModel, name: str, force_of_t) -> None:
    """The actuator force of spring-damper ``name`` set to ``force_of_t(t)`` (N, pushing the
    ends apart) at the start of every step, as a co-simulation master sets an input: a
    pre-step user function (Python, called by Exudyn once per step)."""
    number = model.actuators[name]

    def pre_step(mbs, t):
        mbs.SetObjectParameter(number, "force", -force_of_t(t))
        return True
    model.mbs.SetPreStepUserFunction(pre_step)


def _marker(mbs, body: int, point, rigid: bool = False) -> int:
    kind = MarkerBodyRigid if rigid else MarkerBodyPosition  # rigid: position and orientation
    return mbs.AddMarker(kind(bodyNumber=body, localPosition=[point[0], point[1], 0.0]))


def _exudyn_joint(scene, model: ExudynModel, j, angles: dict) -> None:
    mbs, bodies = model.mbs, model.bodies
    rigid = j.TYPE == "translational"
    mi = _marker(mbs, bodies[j.body_i], j.point_i, rigid)
    mj = _marker(mbs, bodies[j.body_j], j.point_j, rigid)
    if j.TYPE == "revolute":
        mbs.AddObject(ObjectJointRevolute2D(markerNumbers=[mi, mj]))
    elif j.TYPE == "translational":
        # Ours: point_j on the line along axis_i, the relative angle kept at its initial
        # value; Exudyn's: the normal is given in body_j's frame, so turn ours into it.
        ax, ay = j.axis_i
        turn = angles[j.body_i] - angles[j.body_j]
        nx, ny = -ay, ax
        c, s = math.cos(turn), math.sin(turn)
        mbs.AddObject(ObjectJointPrismatic2D(
            markerNumbers=[mi, mj], axisMarker0=[ax, ay, 0.0],
            normalMarker1=[c * nx - s * ny, s * nx + c * ny, 0.0], constrainRotation=True))
    else:
        raise ValueError(f'{scene.name}: joint "{j.name}" ({j.TYPE}) is not translated')


def _exudyn_driver(scene, model: ExudynModel, d, nodes: dict, angles: dict) -> int:
    """A constant-rate driver of a revolute joint to the ground: a velocity-level coordinate
    constraint on the body's angle (no Python user function, so Exudyn stays compiled);
    the angle is right at t = 0, so it stays ``start + rate t``."""
    joint = {j.name: j for j in scene.joints}.get(d.joint)
    motion = d.motion
    if (joint is None or joint.TYPE != "revolute" or joint.body_i != "ground"
            or type(motion).__name__ != "LinearMotion"
            or not math.isclose(motion.start, angles[joint.body_j], abs_tol=1e-12)):
        raise ValueError(f'{scene.name}: driver "{d.name}" is not translated (only a linear '
                         "motion of a revolute joint to the ground, from the body's angle)")
    mbs = model.mbs
    ground = mbs.AddNode(NodePointGround(referenceCoordinates=[0.0, 0.0, 0.0]))
    m0 = mbs.AddMarker(MarkerNodeCoordinate(nodeNumber=nodes[joint.body_j], coordinate=2))
    m1 = mbs.AddMarker(MarkerNodeCoordinate(nodeNumber=ground, coordinate=0))
    # Exudyn's equation: factor1 q'(marker 1) - q'(marker 0) = offset, so the body goes second.
    return mbs.AddObject(CoordinateConstraint(markerNumbers=[m1, m0], offset=motion.rate,
                                              velocityLevel=True))


def _exudyn_force(scene, model: ExudynModel, f, actuators: dict) -> None:
    mbs, bodies = model.mbs, model.bodies
    if f.TYPE == "force" and not f.input:
        mbs.AddLoad(LoadForceVector(markerNumber=_marker(mbs, bodies[f.body], f.point),
                                    loadVector=[f.value[0], f.value[1], 0.0]))
    elif f.TYPE == "spring_damper":
        markers = [_marker(mbs, bodies[f.body_i], f.point_i),
                   _marker(mbs, bodies[f.body_j], f.point_j)]
        push = actuators.get(f.name, 0.0) if f.actuator_input else 0.0
        model.actuators[f.name] = mbs.AddObject(ObjectConnectorSpringDamper(
            markerNumbers=markers, referenceLength=f.rest_length, stiffness=f.stiffness,
            damping=f.damping, force=-push))
    else:
        raise ValueError(f'{scene.name}: force "{f.name}" ({f.TYPE}) is not translated')


def exudyn_settings(*, step: float, t_end: float):
    """Default generalized-alpha at a fixed step, with nothing written and nothing printed."""
    s = exu.SimulationSettings()
    s.timeIntegration.solverType = exu.DynamicSolverType.GeneralizedAlpha
    s.timeIntegration.numberOfSteps = max(1, int(round(t_end / step)))
    s.timeIntegration.endTime = t_end
    s.timeIntegration.verboseMode = 0
    if hasattr(s, "solution"):  # Exudyn >= 1.12 names (the old ones still work, with warnings)
        s.solution.file.write = False
        s.solution.sensors.active = False
        s.show.computationTime = False
        s.show.statistics = False
    else:
        s.solutionSettings.writeSolutionToFile = False
        s.displayComputationTime = False
        s.displayStatistics = False
    return s


def _console(on: bool) -> bool:
    """Switch Exudyn's console output; returns the previous setting."""
    if hasattr(exu, "config"):  # Exudyn >= 1.13
        previous = bool(exu.config.printToConsole)
        exu.config.printToConsole = on
        return previous
    exu.SetWriteToConsole(on)
    return True


def solve_exudyn(model: ExudynModel, *, step: float, t_end: float) -> dict:
    """Run ``exu.SolveDynamic``; returns status ok/failed, reason, t reached and counters."""
    settings = exudyn_settings(step=step, t_end=t_end)
    reason = ""
    console = _console(False)  # its failure banner and hints go to the console otherwise
    try:
        exu.SolveDynamic(model.mbs, settings, storeSolver=True)
    except exu.SolverError as exc:
        reason = str(exc)
    finally:
        _console(console)
    solver = model.mbs.sys["dynamicSolver"]
    it = solver.it
    if reason:
        detail = solver.GetErrorString()
        reason = f"exudyn: t = {it.currentTime:.9g} s: {reason}" + (f" ({detail})" if detail else "")
    return {"status": "failed" if reason else "ok", "reason": reason,
            "t_reached": float(it.currentTime),
            "nsteps": int(it.currentStepIndex) - 1,  # the index of the next step, from 1
            "nnewton": int(it.newtonStepsCount), "njev": int(it.newtonJacobiCount)}


def exudyn_point(model: ExudynModel, body: str, point) -> tuple[float, float]:
    """Ground-frame position of a body-fixed point at the current (final) state."""
    p = model.mbs.GetObjectOutputBody(model.bodies[body], exu.OutputVariableType.Position,
                                      localPosition=[point[0], point[1], 0.0])
    return float(p[0]), float(p[1])


# ---------------------------------------------------------------------------- runs

ROW_FIELDS = ["part", "problem", "tool", "method", "kind", "setting", "t_end", "status",
              "error", "cpu_s", "nsteps", "nrejected", "naccel", "nnewton", "njev",
              "us_per_step", "repeats", "t_reached", "reason", "note"]


def _row(problem, tool, method, kind, setting, t_end, **values) -> dict:
    row = {f: "" for f in ROW_FIELDS}
    row.update(problem=problem.key, tool=tool, method=method, kind=kind, setting=setting,
               t_end=t_end)
    row.update(values)
    return row


def _point_error(problem, scene, t, xy) -> float:
    ex, ey = exact_point(problem, scene, t)
    return math.hypot(xy[0] - ex, xy[1] - ey)


def run_exudyn(problem: Problem, scene, *, step: float, t_end: float) -> dict:
    """One Exudyn run; CPU time covers building the model, assembling and solving."""
    start = time.process_time()
    model = exudyn_model(scene)
    info = solve_exudyn(model, step=step, t_end=t_end)
    cpu = time.process_time() - start
    row = _row(problem, "exudyn", "genalpha", "step", step, t_end, cpu_s=cpu, **info)
    if info["status"] == "ok":
        row["error"] = _point_error(problem, scene, t_end,
                                    exudyn_point(model, problem.body, problem.point))
    else:
        row["note"] = singular_note(problem, info["t_reached"])
    return row


def run_mbdfmu(problem: Problem, scene, *, method: str, kind: str, setting: float,
               t_end: float) -> dict:
    """One mbdfmu run (Simulation + advance); a SolverError is a failed row, not a crash."""
    step = setting if kind == "step" else None
    rtol = setting if kind == "rtol" else None
    atol = setting * ATOL_FACTOR * length_scale(scene) if kind == "rtol" else None
    start = time.process_time()
    sim = None
    reason, t_fail = "", None
    try:
        sim = mbdfmu.Simulation(scene, method=method, step=step, rtol=rtol, atol=atol)
        sim.advance(t_end)
    except mbdfmu.SolverError as exc:
        reason, t_fail = str(exc), exc.t
    cpu = time.process_time() - start
    name = sim.method_name if sim is not None else method
    row = _row(problem, "mbdfmu", name, kind, setting, t_end, cpu_s=cpu,
               status="failed" if reason else "ok", reason=reason)
    if sim is not None:
        row.update({k: v for k, v in vars(sim.integrator.stats).items() if k in ROW_FIELDS})
    if reason:
        # A failed advance restores the state it started from, counters included.
        row.update(nsteps="", nrejected="", naccel="", nnewton="", njev="")
        row["t_reached"] = t_fail if t_fail is not None else ""
        row["note"] = singular_note(problem, t_fail)
        return row
    row["t_reached"] = sim.t
    out = sim.outputs()
    x, y, phi = (out[f"{problem.body}.{v}"] for v in ("x", "y", "phi"))
    px, py = problem.point
    xy = (x + math.cos(phi) * px - math.sin(phi) * py, y + math.sin(phi) * px + math.cos(phi) * py)
    row["error"] = _point_error(problem, scene, t_end, xy)
    return row


def warm_up(scenes: dict) -> None:
    """Short runs first: numba compiles mbdfmu's kernel and caches fill before timing."""
    for key, scene in scenes.items():
        problem = PROBLEMS[key]
        run_exudyn(problem, scene, step=1e-3, t_end=0.01)
        for m in FIXED_METHODS:
            run_mbdfmu(problem, scene, method=m, kind="step", setting=1e-3, t_end=0.01)
        for m in ADAPTIVE_METHODS:
            run_mbdfmu(problem, scene, method=m, kind="rtol", setting=1e-6, t_end=0.05)


# ---------------------------------------------------------------------------- 1. cost per step

def cost_per_step(scenes: dict, *, t_end: float, repeat: int, log=print) -> list[dict]:
    """Median CPU time per step of each tool and method; repetitions interleaved."""
    runs = [("exudyn", "genalpha", "step", COST_STEP)]
    runs += [("mbdfmu", m, "step", COST_STEP) for m in FIXED_METHODS]
    runs += [("mbdfmu", m, "rtol", COST_RTOL) for m in ADAPTIVE_METHODS if m != "auto"]
    samples: dict[tuple, list[dict]] = {}
    for r in range(repeat):
        for key, scene in scenes.items():
            problem = PROBLEMS[key]
            for tool, method, kind, setting in runs:
                if tool == "exudyn":
                    row = run_exudyn(problem, scene, step=setting, t_end=t_end)
                else:
                    row = run_mbdfmu(problem, scene, method=method, kind=kind, setting=setting,
                                     t_end=t_end)
                samples.setdefault((key, tool, method), []).append(row)
        log(f"  cost per step: repetition {r + 1}/{repeat} done")
    rows = []
    for (key, tool, method), rs in samples.items():
        row = dict(rs[0])
        cpus = [x["cpu_s"] for x in rs]
        row.update(part="cost", cpu_s=statistics.median(cpus),
                   repeats=" ".join(f"{c:.4g}" for c in cpus))
        if any(x["status"] != "ok" for x in rs):
            row["status"] = "failed"
            row["reason"] = next(x["reason"] for x in rs if x["status"] != "ok")
        elif row["nsteps"]:
            row["us_per_step"] = row["cpu_s"] / row["nsteps"] * 1e6
        rows.append(row)
    for row in rows:  # ratio to Exudyn on the same problem
        ref = next(r for r in rows if r["problem"] == row["problem"] and r["tool"] == "exudyn")
        if row["us_per_step"] != "" and ref["us_per_step"] != "":
            row["ratio"] = row["us_per_step"] / ref["us_per_step"]
    return rows


# ---------------------------------------------------------------------------- 2. work-precision

def _median_of_short(run, repeat: int) -> dict:
    """A run, repeated up to ``repeat`` times while it is short: the median CPU time of
    runs under SHORT_RUN_S (they are the ones other load on the machine skews most); the
    results are deterministic, so only the time changes."""
    rows = [run()]
    while len(rows) < repeat and rows[0]["cpu_s"] < SHORT_RUN_S:
        rows.append(run())
    row = dict(rows[0])
    cpus = [r["cpu_s"] for r in rows]
    row.update(cpu_s=statistics.median(cpus), repeats=" ".join(f"{c:.4g}" for c in cpus))
    return row


def work_precision(scenes: dict, sweep: Sweep, *, repeat: int = 1, log=print) -> list[dict]:
    """One row per tool, method and setting: the error at sweep.t_end and the CPU time."""
    rows = []

    def add(run):
        rows.append(_median_of_short(run, repeat))
        _log_run(log, rows[-1])

    for key, scene in scenes.items():
        problem = PROBLEMS[key]
        for h in sweep.exudyn_steps:
            add(lambda: run_exudyn(problem, scene, step=h, t_end=sweep.t_end))
        for m in FIXED_METHODS:
            for h in sweep.fixed_steps:
                add(lambda: run_mbdfmu(problem, scene, method=m, kind="step", setting=h,
                                       t_end=sweep.t_end))
        for m in ADAPTIVE_METHODS:
            for rtol in sweep.rtols:
                add(lambda: run_mbdfmu(problem, scene, method=m, kind="rtol", setting=rtol,
                                       t_end=sweep.t_end))
    for row in rows:
        row["part"] = "sweep"
    return rows


def _log_run(log, row):
    what = f"error {row['error']:.3g}" if row["status"] == "ok" else f"FAILED ({row['reason']})"
    log(f"  {row['problem']} {row['tool']} {row['method']} {row['kind']}={row['setting']:g}: "
        f"{row['cpu_s']:.3g} s, {what}")


def _series(rows, problem_key):
    """(tool, method) -> the rows of that line, in sweep order. auto's rows are one line
    whatever it picked."""
    lines: dict[tuple, list] = {}
    for r in rows:
        if r["problem"] == problem_key:
            method = "auto" if str(r["method"]).startswith("auto") else r["method"]
            lines.setdefault((r["tool"], method), []).append(r)
    return lines


def cheapest(rows: list[dict], level: float) -> dict | None:
    """The cheapest successful run with error <= level (no interpolation)."""
    ok = [r for r in rows if r["status"] == "ok" and r["error"] <= level]
    return min(ok, key=lambda r: r["cpu_s"]) if ok else None


def level_table(rows: list[dict], problem_key: str) -> list[dict]:
    """Per level: each line's cheapest run, mbdfmu's best, Exudyn's, and their ratio."""
    lines = _series(rows, problem_key)
    out = []
    for level in LEVELS:
        entry = {"level": level, "lines": {k: cheapest(v, level) for k, v in lines.items()}}
        mb = [(r["cpu_s"], k[1], r) for k, r in entry["lines"].items()
              if k[0] == "mbdfmu" and r is not None]
        entry["mbdfmu_best"] = min(mb, key=lambda x: x[0]) if mb else None
        entry["exudyn"] = entry["lines"].get(("exudyn", "genalpha"))
        if entry["mbdfmu_best"] and entry["exudyn"]:
            entry["ratio"] = entry["mbdfmu_best"][0] / entry["exudyn"]["cpu_s"]
        out.append(entry)
    return out


# ---------------------------------------------------------------------------- output

def _fmt_setting(row) -> str:
    s = row["setting"]
    return f"h = {s:g} s" if row["kind"] == "step" else f"rtol = {s:g}"


def _work_per_step(row) -> str:
    """Newton iterations per step (implicit) or q'' evaluations per accepted step (explicit,
    rejected steps' evaluations included)."""
    if not row["nsteps"]:
        return ""
    if row["nnewton"]:
        return f"{row['nnewton'] / row['nsteps']:.2g} Newton it."
    if row["naccel"]:
        return f"{row['naccel'] / row['nsteps']:.3g} q'' evals"
    return ""


def markdown(cost_rows, sweep_rows, sweep: Sweep, header: str) -> str:
    lines = [header, ""]
    lines += ["## 1. Cost per step", "",
              f"Horizon {sweep.cost_t_end:g} s; fixed step h = {COST_STEP * 1e3:g} ms for Exudyn "
              f"and mbdfmu's fixed-step methods; mbdfmu's adaptive methods at rtol = "
              f"{COST_RTOL:g} (atol = rtol x {ATOL_FACTOR:g} x size), per accepted step. CPU time "
              "(model building, assembly and solve) over steps taken, median of the repetitions.",
              ""]
    for key, problem in PROBLEMS.items():
        rs = [r for r in cost_rows if r["problem"] == key]
        if not rs:
            continue
        lines += [f"### {problem.title}", "",
                  "| tool | method | setting | steps | work per step | CPU s (median) | "
                  "µs per step | ratio to Exudyn |", "|---|---|---|---|---|---|---|---|"]
        for r in rs:
            if r["status"] != "ok":
                lines.append(f"| {r['tool']} | {r['method']} | {_fmt_setting(r)} | | | | failed: "
                             f"{r['reason']} | |")
                continue
            lines.append(f"| {r['tool']} | {r['method']} | {_fmt_setting(r)} | {r['nsteps']} | "
                         f"{_work_per_step(r)} | {r['cpu_s']:.3g} | {r['us_per_step']:.1f} | "
                         f"{r.get('ratio', float('nan')):.1f} |")
        lines.append("")
    lines += ["## 2. CPU time to reach an error at t = "
              f"{sweep.t_end:g} s", "",
              "The cheapest run of the sweep whose error at t_end is <= the level (no "
              "interpolation; the setting that reached it in brackets). \"not reached\": no run "
              "of the sweep did (failed runs count as not reaching). Ratio: mbdfmu's best "
              "method / Exudyn genalpha.", ""]
    for key, problem in PROBLEMS.items():
        table = level_table(sweep_rows, key)
        if not any(e["lines"] for e in table):
            continue
        names = list(table[0]["lines"])
        lines += [f"### {problem.title}", "",
                  "| tool / method | " + " | ".join(f"{lv:g}" for lv in LEVELS) + " |",
                  "|---|" + "---|" * len(LEVELS)]
        for name in names:
            cells = []
            for e in table:
                r = e["lines"][name]
                cells.append("not reached" if r is None else
                             f"{r['cpu_s']:.3g} s ({_fmt_setting(r)})")
            lines.append(f"| {name[0]} {name[1]} | " + " | ".join(cells) + " |")
        best = [f"{e['mbdfmu_best'][0]:.3g} s ({e['mbdfmu_best'][1]})" if e["mbdfmu_best"]
                else "not reached" for e in table]
        lines.append("| **mbdfmu best** | " + " | ".join(best) + " |")
        ratio = [f"**{e['ratio']:.2g}**" if "ratio" in e else "—" for e in table]
        lines.append("| **ratio mbdfmu best / Exudyn** | " + " | ".join(ratio) + " |")
        lines.append("")
    lines += ["## 3. Every run of the sweep", "",
              "| problem | tool | method | setting | error at t_end (m) | CPU s | steps | "
              "status / note |", "|---|---|---|---|---|---|---|---|"]
    for r in sweep_rows:
        err = f"{r['error']:.3g}" if r["status"] == "ok" else ""
        status = "ok" if r["status"] == "ok" else f"failed: {r['reason']}"
        if r["note"]:
            status += f"; {r['note']}"
        lines.append(f"| {r['problem']} | {r['tool']} | {r['method']} | {_fmt_setting(r)} | {err} "
                     f"| {r['cpu_s']:.3g} | {r['nsteps']} | {status} |")
    lines.append("")
    return "\n".join(lines)


def write_csv(rows: list[dict], path: Path) -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    with open(path, "w", newline="", encoding="utf-8") as fh:
        w = csv.DictWriter(fh, fieldnames=ROW_FIELDS + ["ratio"], extrasaction="ignore")
        w.writeheader()
        for r in rows:
            w.writerow({k: (repr(v) if isinstance(v, float) else v) for k, v in r.items()})
    return path


def charts(cost_rows, sweep_rows, out: Path) -> list[Path]:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    out.mkdir(parents=True, exist_ok=True)
    keys = [k for k in PROBLEMS if any(r["problem"] == k for r in sweep_rows)]
    fig, axes = plt.subplots(1, len(keys), figsize=(6.2 * len(keys), 4.8), squeeze=False)
    colours = {"rk4p": "C0", "genalpha": "C1", "ali3p": "C2", "dop853p": "C3", "rk45p": "C4",
               "auto": "C5"}
    for ax, key in zip(axes[0], keys):
        for (tool, method), rs in _series(sweep_rows, key).items():
            ok = [r for r in rs if r["status"] == "ok"]
            failed = len(rs) - len(ok)
            label = f"{tool} {method}" + (f" ({failed} failed)" if failed else "")
            if tool == "exudyn":
                style = dict(color="k", marker="s", lw=2.2)
            else:
                style = dict(color=colours.get(method, "C7"), lw=1.2,
                             marker="o" if rs[0]["kind"] == "step" else "^",
                             ls="-" if rs[0]["kind"] == "step" else "--")
            ax.loglog([r["cpu_s"] for r in ok], [max(r["error"], 1e-16) for r in ok],
                      label=label, ms=4, **style)
        for level in LEVELS:
            ax.axhline(level, color="0.7", lw=0.8, ls=":")
        ax.set_xlabel("CPU time (s)")
        ax.set_ylabel(f"error at t = {sweep_rows[0]['t_end']:g} s (m)")
        ax.set_title(PROBLEMS[key].title, fontsize=10)
        ax.grid(True, which="major", alpha=0.3)
        ax.legend(fontsize=7)
    fig.suptitle("Work-precision: mbdfmu vs Exudyn generalized-alpha")
    fig.tight_layout()
    wp = out / "exudyn_work_precision.png"
    fig.savefig(wp, dpi=110)
    plt.close(fig)

    keys = [k for k in PROBLEMS if any(r["problem"] == k for r in cost_rows)]
    fig, axes = plt.subplots(1, len(keys), figsize=(6.2 * len(keys), 3.6), squeeze=False)
    for ax, key in zip(axes[0], keys):
        rs = [r for r in cost_rows if r["problem"] == key and r["us_per_step"] != ""]
        labels = [f"{r['tool']} {r['method']}\n({_fmt_setting(r)})" for r in rs]
        values = [r["us_per_step"] for r in rs]
        ax.barh(labels, values, color=["k" if r["tool"] == "exudyn" else
                                       colours.get(r["method"], "C7") for r in rs])
        for y, (v, r) in enumerate(zip(values, rs)):
            ax.text(v, y, f" {v:.3g} µs (x{r.get('ratio', 1.0):.0f})", va="center", fontsize=7)
        ax.set_xscale("log")
        ax.set_xlim(1.0, max(values) * 20)
        ax.invert_yaxis()
        ax.tick_params(axis="y", labelsize=7)
        ax.set_xlabel("CPU time per step (µs), log scale")
        ax.set_title(PROBLEMS[key].title, fontsize=10)
    fig.tight_layout()
    bars = out / "exudyn_cost_per_step.png"
    fig.savefig(bars, dpi=110)
    plt.close(fig)
    return [wp, bars]


def run_header(sweep: Sweep, repeat: int, quick: bool) -> str:
    try:
        commit = subprocess.run(["git", "-C", str(ROOT), "describe", "--always", "--dirty"],
                                capture_output=True, text=True, timeout=10).stdout.strip()
        # "-dirty": say which of the solver's files differ from the commit (work in flight)
        changed = subprocess.run(["git", "-C", str(ROOT), "status", "--porcelain", "--", "src"],
                                 capture_output=True, text=True, timeout=10).stdout.split("\n")
        changed = [line[3:] for line in changed if line.strip()]
        if changed:
            commit += f"; uncommitted changes in {', '.join(changed)}"
    except (OSError, subprocess.SubprocessError):
        commit = "?"
    try:
        from mbdfmu.equations.constraints import choose_kernel
        kernel = choose_kernel(None)
    except ImportError:
        kernel = "numpy"
    return (f"# mbdfmu vs Exudyn ({'quick' if quick else 'full'} run)\n\n"
            f"`python benchmarks/exudyn_compare.py{' --quick' if quick else ''} --repeat "
            f"{repeat}`: Exudyn {exu.__version__} (generalized-alpha, index 3, defaults), "
            f"mbdfmu {mbdfmu.__version__} at `{commit}` (constraint kernel: {kernel}), "
            f"numpy {np.__version__}, Python {platform.python_version()}, "
            f"{os.cpu_count()} cores, one process, BLAS single-threaded. "
            f"Work-precision runs: horizon {sweep.t_end:g} s, one run per setting (the "
            f"median of {repeat} for runs under {SHORT_RUN_S:g} s of CPU time).")


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="short horizons and sweeps (~1 min)")
    parser.add_argument("-o", "--output", default=None,
                        help="directory for every output (default: benchmarks/results and "
                             "docs/figures/performance; ./exudyn_compare_quick with --quick)")
    parser.add_argument("--repeat", type=int, default=3, help="repetitions of the cost runs")
    args = parser.parse_args(argv)
    if exu is None:
        print("exudyn_compare: Exudyn is not installed; install it with `pip install exudyn` "
              '(or `pip install ".[bench]"`) and run again.', file=sys.stderr)
        return 2
    sweep = QUICK if args.quick else FULL
    if args.output:
        csv_path, figures = Path(args.output) / "exudyn_compare.csv", Path(args.output)
    elif args.quick:
        csv_path, figures = QUICK_DEFAULT / "exudyn_compare.csv", QUICK_DEFAULT
    else:
        csv_path, figures = CSV_DEFAULT, FIGURES_DEFAULT

    def log(msg):
        print(msg, file=sys.stderr, flush=True)

    wall = time.perf_counter()
    scenes = {k: load_problem_scene(p) for k, p in PROBLEMS.items()}
    warm_up(scenes)
    log("cost per step ...")
    cost_rows = cost_per_step(scenes, t_end=sweep.cost_t_end, repeat=max(1, args.repeat), log=log)
    log("work-precision sweep ...")
    sweep_rows = work_precision(scenes, sweep, repeat=max(1, args.repeat), log=log)
    wall = time.perf_counter() - wall
    header = run_header(sweep, max(1, args.repeat), args.quick) + f" Wall time {wall:.0f} s."
    text = markdown(cost_rows, sweep_rows, sweep, header)
    print(text)
    write_csv(cost_rows + sweep_rows, csv_path)
    figures.mkdir(parents=True, exist_ok=True)
    md = figures / "exudyn_compare.md"
    md.write_text(text, encoding="utf-8")
    paths = [csv_path, md] + charts(cost_rows, sweep_rows, figures)
    for p in paths:
        print(p)
    return 0


if __name__ == "__main__":
    sys.exit(main())
