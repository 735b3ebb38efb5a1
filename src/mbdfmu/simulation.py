"""Running a scene: the stateful ``Simulation`` (one stepping path for the Python API, the
CLI and the FMU) and ``simulate``, which loops it over output times.

A ``Simulation`` owns everything that changes during a run: the integrator's state and the
input signals. The equations stay pure: the integrator asks ``inputs_at(t)`` for the input
values and passes them on.
"""

from __future__ import annotations

import math
import os
from pathlib import Path

import numpy as np

from .equations import Equations
from .equations.dynamics import for_another_run
from .equations.projection import (ASSEMBLY_TOL, PROJECTION_MAX_ITER, assemble,
                                   assembly_changes, initial_estimates, project_positions,
                                   project_velocities)
from .errors import InputError, SettingError, SolverError
from .integrators import make_integrator
from .integrators.auto_watch import method_chain, switches_of
from .integrators.base import WorkLimit
from .integrators.events import EventRunner, check_method
from .integrators.projected_rk import ProjectedRK
from .integrators.settings import SolverSettings, settings_from_scene
from .model.reader import load_scene
from .model.scene import Scene
from .model.variables import inputs, outputs
from .plain import decode, encode
from .result import Result
from .signals import Held, SampledDriver, apply_input_table, large_error_warnings
from .simulation_inputs import InputsAt, SimulationInputs

# After an input jump the state is re-projected to this many times the assembly tolerance.
REINITIALIZE_TOL_FACTOR = 100
# Time step (s) of the central differences of output_time_derivatives.
DELTA = 2e-4


class Simulation(SimulationInputs):
    """A scene being simulated: assembled at ``t0``, then advanced step by step.

    Inputs are set by name (``<driver>.position`` / ``.velocity`` / ``.acceleration``,
    ``<force>.fx`` / ``.fy`` / ``.torque`` / ``.actuator``) and hold until set again, or
    given as functions of time with ``set_input_signal``. Settings: a ``SolverSettings``
    (default: the scene's), updated by the keyword values given. ``scene``: a ``Scene``, a
    scene file's path or a shipped scene's name (loaded, as ``simulate`` and the CLI do), or
    another Simulation's ``equations``, their structure reused (``for_another_run``).
    """

    def __init__(self, scene: Scene | str | Path | Equations, method=None, step=None,
                 rtol=None, atol=None, t0: float = 0.0, method_options: dict | None = None,
                 kernel: str | None = None, *, settings: SolverSettings | None = None,
                 output_interval: float | None = None):
        built = scene if isinstance(scene, Equations) else None
        self.scene = scene = as_scene(scene) if built is None else built.scene
        self.settings = (settings or settings_from_scene(scene)).updated(   # before any work
            method=method, step=step, rtol=rtol, atol=atol, options=method_options,
            output_interval=output_interval)
        self.equations = (Equations(scene, kernel=kernel) if built is None
                          else for_another_run(built, kernel))
        layout = self.equations.layout
        self.input_names = [v.name for v in inputs(scene)]
        self._output_table = None        # (names, units): built when first asked for
        self._drivers = {name: SampledDriver(x0) for name, x0 in
                         zip(layout.drivers, layout.driver_initial)}
        self._forces = {name: Held(np.zeros(len(f))) for name, f in layout.fields.items()}
        self._inputs_changed = False
        self._motion_changed = False     # a driver's input among them (the constraints move)
        self._held = None                # the inputs while all are held (inputs_at)
        estimates = initial_estimates(self.equations)
        q0, qd0 = assemble(self.equations, t0, self.inputs_at(t0), estimates=estimates)
        self.warnings = assembly_changes(self.equations, estimates, (q0, qd0))  # for the user
        self.events = None                          # stops and friction: their contact mode
        if self.equations.has_events:
            self.events = EventRunner(scene, self.equations.kernel, t0, q0, qd0,
                                      self.inputs_at, base=self.equations)
            q0, qd0 = self.events.q, self.events.qd
        self.integrator = make_integrator(      # auto watches runs without events
            None, self.events.equations if self.events else self.equations, t0, q0, qd0,
            self.settings, inputs=InputsAt(self), watch=self.events is None,
            output_interval=self.settings.output_interval_for(scene.simulation.t_end))
        if self.equations.has_events:       # check_method's condition, known already
            check_method(self.integrator, scene)
        self._cache = None

    @property
    def output_names(self) -> list[str]:
        """Every output's name, in ``output_vector``'s order (``model.variables.outputs``)."""
        return self._outputs_table()[0]

    @property
    def units(self) -> dict[str, str]:
        """Each output's unit, by name."""
        return self._outputs_table()[1]

    def _outputs_table(self):
        # built on first use: a run that only steps never reads it (an FMU reads it once,
        # when instantiated)
        if self._output_table is None:
            variables = outputs(self.scene)
            self._output_table = ([v.name for v in variables], {v.name: v.unit for v in variables})
        return self._output_table

    @property
    def t(self) -> float:
        return self.integrator.output_state[0]

    @property
    def method_name(self) -> str:
        """Its name, or "auto->dop853p" when auto picked it ("auto->ali3p->dop853p": switched)."""
        return method_chain(self.integrator)

    @property
    def method_reason(self) -> str:
        """Why ``auto`` picked the method ("" when the method was named)."""
        return self.integrator.reason

    @property
    def q(self) -> np.ndarray:
        return self.integrator.output_state[1]

    @property
    def qd(self) -> np.ndarray:
        return self.integrator.output_state[2]

    # ------------------------------------------------------------------ inputs

    def _reinitialize(self) -> None:
        """After inputs change: the state is made consistent with the new driver positions.

        When only force inputs changed, a projected Runge-Kutta method (an embedded pair or
        rk4p) restarts from its state as it is: the constraints do not depend on forces and
        its last step (or dense read) ended projected, so a projection there would only move
        q' by round-off (the FMU wrapper's restarts, ``ckernel/adaptive.h`` and
        ``fixed.h``, do the same). In a contact mode too: its held rows are constraints
        of the same kind, and a transition ends projected onto the new mode's."""
        current = getattr(self.integrator, "current", self.integrator)  # auto's of the moment
        if not self._motion_changed and isinstance(current, ProjectedRK):
            self.integrator.reset_state(self.q, self.qd, self.t)
            self._inputs_changed = False
            return
        eq = self.equations if self.events is None else self.events.equations
        tol = self.reinitialize_tolerance()
        u, kernel = self.inputs_at(self.t), eq.ckernel
        done = None if kernel is None else kernel.project(
            self.q, self.qd, eq.motion_values(self.t, u), tol, PROJECTION_MAX_ITER)
        if done is None:
            q, _ = project_positions(eq, self.t, self.q, tol=tol, u=u)
            done = q, project_velocities(eq, self.t, q, self.qd, u)
        self.integrator.reset_state(*done, self.t)
        self._inputs_changed = self._motion_changed = False

    def reinitialize_tolerance(self) -> float:
        """The position projection's tolerance (m) after a driver's motion was set."""
        eq = self.equations if self.events is None else self.events.equations
        return ASSEMBLY_TOL * eq.length_scale * REINITIALIZE_TOL_FACTOR

    # ------------------------------------------------------------------ stepping

    def advance(self, t_target: float, limit: WorkLimit | None = None, *,
                dense: bool | None = None) -> None:
        """Integrate to exactly ``t_target``, within ``limit`` (bounded internal steps and
        CPU time) if given; on failure the state stays where it was.

        ``dense``: whether an adaptive method may step past ``t_target`` and give the state
        there from its dense output (its step sequence then does not depend on the output
        times); None: when the inputs beyond it are known (``inputs_known_ahead``)."""
        if dense is None:
            dense = self.inputs_known_ahead()
        if not self._inputs_changed and self.integrator.interpolates_to(t_target, dense):
            # a time inside the last step: the state there from its dense output, which
            # changes nothing a failure would have to undo (the common case of an FMU
            # stepped at communication steps shorter than the method's steps); with events,
            # a step whose event functions kept their signs (the runner's watch)
            self.integrator.advance(t_target, limit, dense=True)
            self._cache = None
            return
        # Only the integrator and the flag change while stepping (inputs do not), so that
        # is all the rollback keeps.
        snapshot, inputs_changed = self.integrator.rollback_point(), self._inputs_changed
        motion_changed = self._motion_changed
        saved = self.events.get_state() if self.events is not None else None
        try:
            if self._inputs_changed:
                self._reinitialize()
            if self.events is None:
                self.integrator.advance(t_target, limit, dense=dense)
            else:       # located events: the steps land on them
                self.events.advance(self.integrator, t_target, limit, dense, inputs_changed)
        except SolverError:
            if self.events is not None:
                self.events.restore(self.integrator, saved)
            self.integrator.set_state(snapshot)
            self._inputs_changed, self._motion_changed = inputs_changed, motion_changed
            raise
        finally:
            self._cache = None

    @property
    def stepped_equations(self) -> Equations:
        """The equations the integrator steps: the current contact mode's with stops or
        friction, else the scene's."""
        return self.equations if self.events is None else self.events.equations

    def dense_reads_ahead(self):
        """The C kernel, holding the last step's dense output (``Kernel.load_dense``), when
        the coming communication steps inside that step can only read it: no input changed,
        the inputs beyond now known, any drivers' motions of kinds the kernel evaluates
        (``Kernel.motion_table`` of the stepped equations); else None. An FMU's wrapper
        then takes those steps by itself."""
        # with events, the current mode's equations: the steps whose dense output is read
        # were watched for events (fast_steps.mode_published: its outputs)
        integrator, kernel = self.integrator, self.stepped_equations.ckernel
        driven = bool(self.scene.drivers)
        if kernel is None or (driven and (self._drivers or kernel.motion_table(
                self.stepped_equations.constraint_set) is None)) or \
                self._inputs_changed or not integrator.interpolates_to(integrator.t, True) or \
                not self.inputs_known_ahead() or \
                not getattr(integrator, "load_dense_output", lambda t: False)(self.t):
            return None
        return kernel

    def accelerations(self) -> tuple[np.ndarray, np.ndarray]:
        """q'' and lam at the current state and inputs (cached until either changes).

        Inputs set since the last step take effect here already (direct feedthrough): the
        state is first made consistent with new driver positions, as ``advance`` would."""
        if self._inputs_changed:
            self._reinitialize()
        if self._cache is None and self.events is not None:
            self._cache = self.events.accelerations(self.t, self.q, self.qd, self.equations.m)
        if self._cache is None:
            self._cache = self.equations.accelerations(self.t, self.q, self.qd,
                                                       self.inputs_at(self.t))
        return self._cache

    def output_vector(self) -> np.ndarray:
        if self.events is not None:
            if self._inputs_changed:
                self._reinitialize()
            return self.events.output_vector(self.t, self.q, self.qd, self.output_names)
        kernel = self.equations.ckernel
        if kernel is not None and not self._inputs_changed:   # one call, q'' kept from the step
            u = self.inputs_at(self.t)
            done = kernel.state_outputs(self.q, self.qd, self.equations.motion_values(self.t, u),
                                        u.forces)
            if done is not None:
                values, qdd, lam = done
                self._cache = (qdd, lam)       # what accelerations() returns until a change
                return values
        qdd, lam = self.accelerations()
        return self.equations.output_values(self.t, self.q, self.qd, qdd, lam,
                                            self.inputs_at(self.t))

    def outputs(self) -> dict[str, float]:
        return dict(zip(self.output_names, self.output_vector().tolist()))

    # ------------------------------------------------------------------ state

    def get_state(self) -> dict:
        """Everything needed to continue bit for bit (integrator, inputs, flags), as plain
        data (``plain.py``)."""
        return {"integrator": self.integrator.get_state(), "drivers": encode(self._drivers),
                "forces": encode(self._forces), "inputs_changed": self._inputs_changed,
                "modes": None if self.events is None else self.events.get_state()}

    def set_state(self, state: dict) -> None:
        self.integrator.set_state(state["integrator"])
        self._drivers, self._forces = decode(state["drivers"]), decode(state["forces"])
        self._inputs_changed = bool(state["inputs_changed"])
        self._motion_changed = self._inputs_changed   # not kept in the state: project to be safe
        if self.events is not None and state.get("modes") is not None:
            self.events.restore(self.integrator, state["modes"])
        self._cache = self._held = None


def run_log(sim: Simulation) -> list[str]:
    """What the run did so far, one line each, in time order (a master logs the new ones
    after each step): transitions of end stops and friction, or auto's changes of method
    (``auto_watch.py``; auto does not watch runs with events)."""
    events = [] if sim.events is None else [f"t = {t!r} s: joint {joint} {what}"
                                            for t, joint, what in sim.events.log]
    return events + [f"t = {t!r} s: auto switched from {old} to {new}: {why}"
                     for t, old, new, why in switches_of(sim.integrator)]


def input_warnings(sim: Simulation) -> list[str]:
    """Driver positions whose derived acceleration's estimated error is large, one line each
    (``signals.large_error_warnings``; a master logs them after each step)."""
    return large_error_warnings(sim._drivers, sim.t)


def output_time_derivatives(sim: Simulation) -> tuple[np.ndarray, np.ndarray]:
    """The first and second time derivatives of ``sim.output_vector()`` at ``sim.t``, along
    the motion the equations give from the current state, the inputs following their
    signals (held, Taylor polynomials, driver motions).

    The states at ``t +- d`` are the motion's Taylor polynomials to third order, the third
    derivative of q from a central difference of eq. (14); the outputs (reactions and
    efforts too: eq. 14 solved at those states and inputs) are differenced centrally. Each
    difference is an even function of ``d``; Richardson's extrapolation from ``d`` =
    ``DELTA`` and ``DELTA / 2`` removes its O(d^2) term: errors O((omega d)^4) for motions
    of angular frequency omega, plus round-off (eps / d and eps / d^2 of the outputs)."""
    eq, t, q, qd = sim.equations, sim.t, sim.q, sim.qd
    qdd, _ = sim.accelerations()
    y0 = sim.output_vector()

    def at(d, jerk):
        qs = q + d * qd + d * d / 2 * qdd + d ** 3 / 6 * jerk
        qds = qd + d * qdd + d * d / 2 * jerk
        u = sim.inputs_at(t + d)
        if sim.events is not None:       # the current contact mode's equations and outputs
            a = sim.events.equations.accelerations(t + d, qs, qds, u)[0]
            return sim.events.output_vector(t + d, qs, qds, sim.output_names), a
        a, mult = eq.accelerations(t + d, qs, qds, u)
        return eq.output_values(t + d, qs, qds, a, mult, u), a

    def differences(d):
        jerk = (at(d, 0 * q)[1] - at(-d, 0 * q)[1]) / (2 * d)
        plus, minus = at(d, jerk)[0], at(-d, jerk)[0]
        return (plus - minus) / (2 * d), (plus - 2 * y0 + minus) / (d * d)

    (f1, s1), (f2, s2) = differences(DELTA), differences(DELTA / 2)
    return (4 * f2 - f1) / 3, (4 * s2 - s1) / 3


def output_times(t_end: float, interval: float) -> np.ndarray:
    """0, h, 2h, ... (as k h, never accumulated) and t_end."""
    n = int(math.floor(t_end / interval * (1 + 1e-12)))
    times = np.arange(n + 1) * interval
    if t_end - times[-1] > 1e-9 * interval:
        times = np.append(times, t_end)
    else:
        times[-1] = t_end
    return times


def as_scene(scene) -> Scene:
    """A ``Scene`` as given, or loaded from a scene file's path or a shipped scene's name;
    ``InputError`` for anything else."""
    if isinstance(scene, Scene):
        return scene
    if isinstance(scene, os.PathLike):
        scene = os.fspath(scene)
    if isinstance(scene, str):
        return load_scene(scene)
    raise InputError(f"scene must be a Scene, a scene file's path or a shipped scene's name, "
                     f"got a {type(scene).__name__}")


def check_t_end(t_end, name: str = "t_end", where: str = "") -> float:
    if isinstance(t_end, bool) or not isinstance(t_end, (int, float)) or \
            not (math.isfinite(t_end) and t_end > 0):
        raise SettingError(name, f"{name} must be positive and finite (s), got {t_end!r}", where)
    return float(t_end)


def simulate(scene: Scene | str | Path, t_end: float | None = None, method=None, step=None,
             rtol=None, atol=None, output_interval=None, inputs=None,
             method_options: dict | None = None, kernel: str | None = None, *,
             settings: SolverSettings | None = None, progress=None) -> Result:
    """Simulate a scene (or a scene file) from 0 to ``t_end`` and return every variable.

    ``inputs``: a structured array with ``time`` first and input names as columns (forces
    interpolated linearly; driver positions by splines), or a dict ``{item: signal(t)}``.
    ``method_options``: the method's own settings (see ``METHODS[name].option_names``).
    ``kernel``: "numpy" or "numba" (default: numba when installed). ``progress``: called
    with each output time reached (a progress bar). Every setting is checked before any
    work (``SettingError``). ``Result.warnings`` lists the initial values that assembly
    changed.
    """
    scene = as_scene(scene)
    t_end = check_t_end(t_end if t_end is not None else scene.simulation.t_end)
    sim = Simulation(scene, method=method, step=step, rtol=rtol, atol=atol,
                     method_options=method_options, kernel=kernel, settings=settings,
                     output_interval=output_interval)
    if isinstance(inputs, dict):
        for item, signal in inputs.items():
            sim.set_input_signal(item, signal)
    elif inputs is not None:
        apply_input_table(sim, inputs)
    times = output_times(t_end, sim.settings.output_interval_for(t_end))
    rows, qs, qds, qdds, lams = [], [], [], [], []
    for t in times:
        sim.advance(t, dense=True)     # the inputs of the whole run are given here
        qdd, lam = sim.accelerations()
        rows.append(sim.output_vector())
        qs.append(sim.q.copy()), qds.append(sim.qd.copy()), qdds.append(qdd), lams.append(lam)
        if progress is not None:
            progress(float(t))
    return Result(time=times, names=list(sim.output_names), values=np.array(rows),
                  q=np.array(qs), qd=np.array(qds), qdd=np.array(qdds), lam=np.array(lams),
                  units=dict(sim.units), method=sim.method_name, method_reason=sim.method_reason,
                  stats=vars(sim.integrator.stats).copy(), warnings=list(sim.warnings),
                  events=list(sim.events.log) if sim.events is not None else [],
                  switches=switches_of(sim.integrator))
