"""Running a scene: the stateful ``Simulation`` (one stepping path for the Python API, the
CLI and the FMU) and ``simulate``, which loops it over output times."""

from __future__ import annotations

import copy
import math
from pathlib import Path

import numpy as np

from .assembly import ASSEMBLY_TOL, assemble, project_positions, project_velocities
from .errors import InputError, SolverError
from .integrators import make_integrator, method_class
from .motion import InputMotion
from .result import Result
from .scene import PointForce, Scene, SpringDamper, Torque, load_scene
from .signals import DriverTable, Held, LinearTable, SampledDriver
from .system import System

# Output points when neither the call nor the scene gives an output interval.
DEFAULT_OUTPUT_POINTS = 500


class Simulation:
    """A scene being simulated: assembled at ``t0``, then advanced step by step.

    Inputs are set by name (``<driver>.position`` / ``.velocity`` / ``.acceleration``,
    ``<force>.fx`` / ``.fy`` / ``.torque`` / ``.actuator``) and hold until set again, or
    given as functions of time with ``set_input_signal``.
    """

    def __init__(self, scene: Scene, method=None, step=None, rtol=None, atol=None,
                 t0: float = 0.0, method_options: dict | None = None,
                 kernel: str | None = None):
        settings = scene.simulation
        self.scene = scene
        self.system = System(scene, kernel=kernel)
        self.method = method_class(method if method is not None else settings.method)
        self._force_items = {}
        for f in scene.forces:
            if isinstance(f, PointForce) and f.input:
                self._force_items[f.name] = (("fx", "fy"), np.zeros(2))
            elif isinstance(f, Torque) and f.input:
                self._force_items[f.name] = (("torque",), np.zeros(1))
            elif isinstance(f, SpringDamper) and f.actuator_input:
                self._force_items[f.name] = (("actuator",), np.zeros(1))
        for name, (_, values) in self._force_items.items():
            self.system.force_signals[name] = Held(values)
        self._drivers = {d.name: SampledDriver(d.motion.initial) for d in scene.drivers
                         if isinstance(d.motion, InputMotion)}
        self.system.driver_signals.update(self._drivers)
        self.input_names = [v.name for v in self.system.inputs]
        self.output_names = [v.name for v in self.system.outputs]
        self._inputs_changed = False
        q0, qd0 = assemble(self.system, t0)
        self.integrator = make_integrator(
            self.method, self.system, t0, q0, qd0,
            step=step if step is not None else settings.step,
            rtol=rtol if rtol is not None else settings.rtol,
            atol=atol if atol is not None else settings.atol,
            options=method_options)
        self._cache = None

    @property
    def t(self) -> float:
        return self.integrator.t

    @property
    def method_name(self) -> str:
        """The method that runs: its name, or e.g. "auto->dop853p" when auto picked it."""
        name = self.integrator.name
        return name if name == self.method.name else f"{self.method.name}->{name}"

    @property
    def method_reason(self) -> str:
        """Why ``auto`` picked the method ("" when the method was named)."""
        return getattr(self.integrator, "reason", "")

    @property
    def q(self) -> np.ndarray:
        return self.integrator.q

    @property
    def qd(self) -> np.ndarray:
        return self.integrator.qd

    # ------------------------------------------------------------------ inputs

    def _split(self, name: str) -> tuple[str, str]:
        item, _, field = name.rpartition(".")
        if name not in self.input_names:
            hint = f"; this scene's inputs: {', '.join(self.input_names)}" if self.input_names \
                else "; this scene has no inputs"
            raise InputError(f'unknown input "{name}"{hint}')
        return item, field

    def set_input(self, name: str, value: float) -> None:
        """Set an input at the current time; it holds until set again."""
        item, field = self._split(name)
        value = float(value)
        if not math.isfinite(value):
            raise InputError(f'input "{name}" is not finite ({value})')
        if item in self._drivers:
            self._drivers[item].set(self.t, **{field: value})
            self.system.driver_signals[item] = self._drivers[item]
        else:
            fields, values = self._force_items[item]
            values[fields.index(field)] = value
            self.system.force_signals[item] = Held(values)
        self._inputs_changed = True
        self._cache = None

    def input_values(self) -> dict[str, float]:
        """The current value of every input at ``t`` (driver velocity and acceleration as
        the motion over the next step has them, given or derived from the history)."""
        values = {}
        for item, driver in self._drivers.items():
            f = self.system.driver_signals[item](self.t)
            for field, value in zip(("position", "velocity", "acceleration"), f):
                values[f"{item}.{field}"] = float(value)
        for item, (fields, _) in self._force_items.items():
            current = self.system.force_signals[item](self.t)
            for field, value in zip(fields, current):
                values[f"{item}.{field}"] = float(value)
        return values

    def set_input_signal(self, item: str, signal) -> None:
        """Drive a force item or a driver with a function of time (see ``signals``)."""
        if item in self._drivers:
            self.system.driver_signals[item] = signal
        elif item in self._force_items:
            self.system.force_signals[item] = signal
        else:
            raise InputError(f'"{item}" is not an input-driven driver or force of this scene')
        self._inputs_changed = True
        self._cache = None

    def _reinitialize(self) -> None:
        """After inputs change: the state is made consistent with the new driver positions."""
        tol = ASSEMBLY_TOL * self.system.length_scale * 100
        q, _ = project_positions(self.system, self.t, self.q, tol=tol)
        qd = project_velocities(self.system, self.t, q, self.qd)
        self.integrator.reset_state(q, qd)
        self._inputs_changed = False

    # ------------------------------------------------------------------ stepping

    def advance(self, t_target: float) -> None:
        """Integrate to exactly ``t_target``; on failure the state stays where it was."""
        # Only the integrator and the flag change while stepping (inputs and signals do not),
        # so that is all the rollback keeps: no per-step copy of the whole state.
        snapshot, inputs_changed = self.integrator.get_state(), self._inputs_changed
        try:
            if self._inputs_changed:
                self._reinitialize()
            self.integrator.advance(t_target)
        except SolverError:
            self.integrator.set_state(snapshot)
            self._inputs_changed = inputs_changed
            self._cache = None
            raise
        self._cache = None

    def accelerations(self) -> tuple[np.ndarray, np.ndarray]:
        """q'' and lam at the current state and inputs (cached until either changes).

        Inputs set since the last step take effect here already (direct feedthrough): the
        state is first made consistent with new driver positions, as ``advance`` would."""
        if self._inputs_changed:
            self._reinitialize()
        if self._cache is None:
            self._cache = self.system.accelerations(self.t, self.q, self.qd)
        return self._cache

    def output_vector(self) -> np.ndarray:
        qdd, lam = self.accelerations()
        return self.system.output_values(self.t, self.q, self.qd, qdd, lam)

    def outputs(self) -> dict[str, float]:
        return dict(zip(self.output_names, self.output_vector().tolist()))

    # ------------------------------------------------------------------ state

    def get_state(self) -> dict:
        """Everything needed to continue bit for bit: integrator, inputs, flags."""
        return copy.deepcopy({
            "integrator": self.integrator.get_state(),
            "driver_signals": self.system.driver_signals,
            "force_signals": self.system.force_signals,
            "drivers": self._drivers,
            "force_items": self._force_items,
            "inputs_changed": self._inputs_changed,
        })

    def set_state(self, state: dict) -> None:
        state = copy.deepcopy(state)
        self.integrator.set_state(state["integrator"])
        self.system.driver_signals = state["driver_signals"]
        self.system.force_signals = state["force_signals"]
        self._drivers = state["drivers"]
        self._force_items = state["force_items"]
        self._inputs_changed = state["inputs_changed"]
        self._cache = None


def _apply_table(sim: Simulation, table) -> None:
    """Inputs from a structured array with 'time' first (fmpy's layout)."""
    names = table.dtype.names
    if not names or names[0] != "time":
        raise InputError('an input table needs a "time" column first')
    time = np.asarray(table["time"], dtype=float)
    if np.any(np.diff(time) < 0):
        raise InputError("input table: time must not decrease")
    columns = set(names[1:])
    for name in columns:
        sim._split(name)  # unknown names are an error, not silently ignored
        if not np.all(np.isfinite(table[name])):
            raise InputError(f'input table: column "{name}" has non-finite values')
    for item in sim._drivers:
        cols = [f"{item}.{k}" for k in ("position", "velocity", "acceleration")]
        if cols[0] in columns:
            extra = [table[c] if c in columns else None for c in cols[1:]]
            sim.set_input_signal(item, DriverTable(time, table[cols[0]], *extra))
    for item, (fields, _) in sim._force_items.items():
        cols = [f"{item}.{k}" for k in fields]
        if any(c in columns for c in cols):
            values = np.column_stack([table[c] if c in columns else np.zeros(len(time))
                                      for c in cols])
            sim.set_input_signal(item, LinearTable(time, values))


def output_times(t_end: float, interval: float) -> np.ndarray:
    """0, h, 2h, ... (as k h, never accumulated) and t_end."""
    n = int(math.floor(t_end / interval * (1 + 1e-12)))
    times = np.arange(n + 1) * interval
    if t_end - times[-1] > 1e-9 * interval:
        times = np.append(times, t_end)
    else:
        times[-1] = t_end
    return times


def simulate(scene: Scene | str | Path, t_end: float | None = None, method=None, step=None,
             rtol=None, atol=None, output_interval=None, inputs=None,
             method_options: dict | None = None, kernel: str | None = None) -> Result:
    """Simulate a scene (or a scene file) from 0 to ``t_end`` and return every variable.

    ``inputs``: a structured array with ``time`` first and input names as columns (forces
    interpolated linearly; driver positions by splines), or a dict ``{item: signal(t)}``.
    ``method_options``: the method's own settings (see ``METHODS[name].option_names``).
    ``kernel``: "numpy" or "numba" (default: numba when installed, see ``system.py``).
    """
    if not isinstance(scene, Scene):
        scene = load_scene(scene)
    t_end = float(t_end if t_end is not None else scene.simulation.t_end)
    if not (math.isfinite(t_end) and t_end > 0):
        raise InputError(f"t_end must be positive and finite, got {t_end}")
    interval = output_interval or scene.simulation.output_interval or t_end / DEFAULT_OUTPUT_POINTS
    sim = Simulation(scene, method=method, step=step, rtol=rtol, atol=atol,
                     method_options=method_options, kernel=kernel)
    if isinstance(inputs, dict):
        for item, signal in inputs.items():
            sim.set_input_signal(item, signal)
    elif inputs is not None:
        _apply_table(sim, inputs)
    times = output_times(t_end, interval)
    rows, qs, qds, qdds, lams = [], [], [], [], []
    for t in times:
        sim.advance(t)
        qdd, lam = sim.accelerations()
        rows.append(sim.output_vector())
        qs.append(sim.q.copy()), qds.append(sim.qd.copy()), qdds.append(qdd), lams.append(lam)
    stats = vars(sim.integrator.stats).copy()
    return Result(time=times, names=list(sim.output_names), values=np.array(rows),
                  q=np.array(qs), qd=np.array(qds), qdd=np.array(qdds), lam=np.array(lams),
                  units={v.name: v.unit for v in sim.system.outputs},
                  method=sim.method_name, stats=stats)
