"""The contact modes of a run with end stops and Coulomb friction (``events.py`` changes them).

``ContactModes`` keeps each event joint's state (``model/limits.py``), the equations of the
current mode (cached), the event functions of the mode (formulation.md eq. 33), the mode's
consistency at an instant (a stop that pulls lets go, a sticking joint that cannot hold
slips) and the outputs of the stops and of friction.
"""

from __future__ import annotations

import numpy as np

from ..equations.ckernel.model import EV_DISTANCE, EV_HELD, EV_RATE, EV_STICK, event_table
from ..equations.limits import Coordinate, ModeEquations, friction_bound
from ..equations.projection import (ASSEMBLY_TOL, PROJECTION_MAX_ITER, project_positions,
                                   project_velocities)
from ..errors import SettingError, SolverError
from ..model.limits import (FREE, HELD, LOWER, SLIDE_DOWN, SLIDE_UP, STICK, UPPER, JointMode,
                            event_joints, mode_scene, slip_text, sliding)
from ..model.scene import Scene
from ..model.variables import outputs

# Mode changes allowed at one instant before the run stops (a contact that cannot settle).
MAX_CHANGES_AT_ONCE = 8
# Modes' equations kept for reuse.
CACHE_SIZE = 16


class ContactModes:
    """The contact mode of a run (a state per event joint), its equations (``equations``:
    the current mode's; ``base``, the scene's own, where every joint is free), its event
    functions and outputs; ``log`` its transitions."""

    def __init__(self, scene: Scene, kernel: str | None, t0: float, q0, qd0, inputs,
                 base=None):
        self.scene, self.kernel, self.inputs = scene, kernel, inputs
        # the scene's own Equations (the Simulation's): those of a mode with nothing held
        # and nothing sliding, so that an FMU's wrapper reads their dense output as it
        # does for a scene without events (Simulation.dense_reads_ahead)
        self.base = base
        self.joints = event_joints(scene)
        self.coordinates = {k: Coordinate(scene, scene.joints[k]) for k in self.joints}
        self.base_drivers = len(scene.drivers)
        self.log: list[tuple[float, str, str]] = []
        self._cache: dict = {}
        self._last: tuple = (None, None)     # the last mode asked for, its equations
        self._event_tables: dict = {}     # c_events' tables, per joints' states
        self.mode = {k: JointMode(FREE) for k in self.joints}
        for k, c in self.coordinates.items():
            j = scene.joints[k]
            value, rate = c.value(q0), c.rate(q0, qd0)
            if j.limits is not None and not (j.limits[0] - self._tol_q(k) <= value
                                             <= j.limits[1] + self._tol_q(k)):
                raise SettingError("limits", f'joint "{j.name}" starts at {value:.9g}, outside '
                                   f"its limits [{j.limits[0]:g}, {j.limits[1]:g}]",
                                   scene.source)
            self.mode[k] = self._moving_state(k, value, rate, rest_at_stop=True)
        self.t, self.q, self.qd = float(t0), np.array(q0, float), np.array(qd0, float)
        self._settle(t0, self.q, self.qd, "starts")
        self.q, self.qd = self._project(t0, self.q, self.qd)
        self.watching = None            # (rollback point, event values) at the last step
        self.horizon = None             # no step past this time (s; events.py's advance)

    # ------------------------------------------------------------------ modes

    def _tol_q(self, k: int) -> float:
        return 1e3 * ASSEMBLY_TOL * self.equations_length()

    def equations_length(self) -> float:
        return max([1.0] + [abs(v) for b in self.scene.bodies for v in b.position])

    def _moving_state(self, k, value, rate, rest_at_stop=False) -> JointMode:
        """A joint's state from its coordinate and rate: at a stop, sticking, or moving."""
        j = self.scene.joints[k]
        tol_v = 1e-9 * max(1.0, abs(rate))
        if rest_at_stop and j.limits is not None:
            if abs(value - j.limits[0]) <= self._tol_q(k) and rate <= tol_v:
                return JointMode(LOWER, j.limits[0])
            if abs(value - j.limits[1]) <= self._tol_q(k) and rate >= -tol_v:
                return JointMode(UPPER, j.limits[1])
        if j.friction is None:
            return JointMode(FREE)
        if abs(rate) <= 1e-12:
            return JointMode(STICK, value)
        return JointMode(SLIDE_UP if rate > 0 else SLIDE_DOWN)

    @property
    def equations(self) -> ModeEquations:
        return self.mode_equations(self.mode)

    def mode_equations(self, mode) -> ModeEquations:
        if mode == self._last[0]:          # asked for at every event function and step
            return self._last[1]
        key = tuple(sorted(mode.items()))
        eq = self._cache.get(key)
        if eq is None and self.base is not None and \
                all(m.state == FREE for m in mode.values()):
            eq = self.base                     # nothing held: no held_rows
        elif eq is None:
            if len(self._cache) >= CACHE_SIZE:
                self._cache.pop(next(iter(self._cache)))
            eq = ModeEquations(mode_scene(self.scene, mode), sliding(mode), kernel=self.kernel)
            held = [k for k, m in mode.items() if m.state in HELD]
            eq.held_rows = {k: int(eq.constraint_set.driver_rows[self.base_drivers + i])
                            for i, k in enumerate(held)}
            self._cache[key] = eq
        self._last = (dict(mode), eq)
        return eq

    def _settle(self, t, q, qd, why: str) -> None:
        """Make the mode consistent at (t, q, q'): a stop that pulls lets go, a sticking
        joint whose holding force exceeds its bound slides (each change logged)."""
        for _ in range(MAX_CHANGES_AT_ONCE):
            eq = self.equations
            _, lam = eq.accelerations(t, q, qd, self.inputs(t))
            changed = False
            for k, row in eq.held_rows.items():
                state, effort = self.mode[k].state, -lam[row]
                name = self.scene.joints[k].name
                if state == LOWER and effort < 0 or state == UPPER and effort > 0:
                    self.mode[k] = self._moving_state(k, self.mode[k].held, 0.0)
                    self.log.append((float(t), name, f"leaves its {state} stop"))
                    changed = True
                elif state == STICK and abs(effort) > friction_bound(eq, k, q, lam):
                    self.mode[k] = JointMode(SLIDE_DOWN if effort > 0 else SLIDE_UP)
                    self.log.append((float(t), name, f"slips: {slip_text(self.mode[k].state)}"))
                    changed = True
                elif why:
                    self.log.append((float(t), name, {LOWER: "rests against its lower stop",
                                               UPPER: "rests against its upper stop",
                                               STICK: "sticks"}[state]))
            why = ""
            if not changed:
                return
        raise SolverError("the contact mode does not settle (stops and friction keep "
                          "switching at one instant)", t)

    def _project(self, t, q, qd):
        """(q, q') onto the current mode's constraints: in C where its kernel can (its
        positions on Psi alone, as project_positions for these scenes), else numpy's."""
        eq, u = self.equations, self.inputs(t)
        tol = ASSEMBLY_TOL * eq.length_scale
        done = None if eq.ckernel is None else eq.ckernel.project(
            q, qd, eq.motion_values(t, u), tol, PROJECTION_MAX_ITER)
        if done is not None:
            return done
        q, _ = project_positions(eq, t, q, tol=tol, u=u)
        return q, project_velocities(eq, t, q, qd, u)

    # ------------------------------------------------------------------ event functions

    def values(self, t, q, qd) -> dict:
        """The event functions of the current mode: {(joint index, kind): value}."""
        eq, out, lam = self.equations, {}, None
        for k, m in self.mode.items():
            j, c = self.scene.joints[k], self.coordinates[k]
            if m.state in (LOWER, UPPER, STICK):
                if lam is None:
                    lam = eq.accelerations(t, q, qd, self.inputs(t))[1]
                effort = -lam[eq.held_rows[k]]
                out[k, m.state] = (effort if m.state == LOWER else -effort if m.state == UPPER
                                   else friction_bound(eq, k, q, lam) - abs(effort))
                continue
            if j.limits is not None:
                value = c.value(q)
                out[k, "hit lower"] = value - j.limits[0]
                out[k, "hit upper"] = j.limits[1] - value
            if m.state in (SLIDE_UP, SLIDE_DOWN):
                rate = c.rate(q, qd)
                out[k, m.state] = rate if m.state == SLIDE_UP else -rate
        return out

    def c_events(self, t, q, qd) -> tuple:
        """The event functions of the current mode as the FMU wrapper's runs in C watch them
        (dense runs, rk4p's and landing steps: events.h; ``ckernel.model.event_table``), in
        the order of ``values``, and their values at (t, q, q'): (ints, reals, values)."""
        key = tuple((k, m.state) for k, m in self.mode.items())   # not the held values
        tables = self._event_tables.get(key)
        if tables is None:
            tables = self._event_tables[key] = self._event_table()
        return (*tables, np.array(list(self.values(t, q, qd).values()), dtype=float))

    def _event_table(self) -> tuple:
        eq, rows = self.equations, []
        for k, m in self.mode.items():
            j = self.scene.joints[k]
            if m.state in (LOWER, UPPER, STICK):
                rows.append((EV_STICK if m.state == STICK else EV_HELD, k, eq.held_rows[k],
                             0.0, -1.0 if m.state == UPPER else 1.0))
                continue
            if j.limits is not None:
                rows += [(EV_DISTANCE, k, -1, j.limits[0], 1.0),
                         (EV_DISTANCE, k, -1, j.limits[1], -1.0)]
            if m.state in (SLIDE_UP, SLIDE_DOWN):
                rows.append((EV_RATE, k, -1, 0.0, 1.0 if m.state == SLIDE_UP else -1.0))
        return event_table(eq, rows)

    # ------------------------------------------------------------------ outputs, state

    def accelerations(self, t, q, qd, m_base: int):
        """q'' and the multipliers of the scene's own rows (the mode's held rows left out)."""
        qdd, lam = self.equations.accelerations(t, q, qd, self.inputs(t))
        return qdd, lam[:m_base]

    def output_vector(self, t, q, qd, base_names: list[str]) -> np.ndarray:
        """The scene's outputs in the current mode, stops' and friction forces filled in."""
        eq, u = self.equations, self.inputs(t)
        qdd, lam = eq.accelerations(t, q, qd, u)
        values = eq.output_values(t, q, qd, qdd, lam, u)
        plan = getattr(eq, "output_plan", None)
        if plan is None:
            names = [v.name for v in outputs(eq.scene)]
            plan = eq.output_plan = np.array([names.index(n) for n in base_names], dtype=int)
        out = values[plan]
        index = {n: i for i, n in enumerate(base_names)}
        slides = list(sliding(self.mode))
        for k, m in self.mode.items():
            j = self.scene.joints[k]
            held = -lam[eq.held_rows[k]] if m.state in HELD else 0.0
            if j.limits is not None:
                out[index[f"{j.name}.limit"]] = held if m.state in (LOWER, UPPER) else 0.0
            if j.friction is not None:
                out[index[f"{j.name}.friction"]] = (
                    held if m.state == STICK else
                    eq.last_friction[slides.index(k)] if k in slides else 0.0)
        return out

    def get_state(self) -> dict:
        """The modes, the length of the log and the steps' horizon, as plain data."""
        return {"modes": [[k, m.state, m.held] for k, m in self.mode.items()],
                "logged": len(self.log), "horizon": self.horizon}

    def restore(self, integrator, state: dict) -> None:
        """Back to ``get_state()``'s modes (the log cut back to its length then)."""
        self.mode = {int(k): JointMode(str(s), float(h)) for k, s, h in state["modes"]}
        del self.log[int(state["logged"]):]
        self.horizon = state.get("horizon")
        integrator.equations = self.equations
