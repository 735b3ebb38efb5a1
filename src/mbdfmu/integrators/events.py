"""Events of end stops and Coulomb friction: found after each step, located inside it.

``EventRunner`` drives any integrator that takes single steps through ``Integrator.watch``
(the explicit methods: rk4p, rk45p, dop853p). After each accepted step it evaluates the
event functions of the current mode (``equations/limits.py``, formulation.md eq. 33):

* free of a stop: ``q - lower`` and ``upper - q`` (an impact when one turns negative);
* resting against a stop: the stop's force, signed to push away from it (it leaves);
* sticking: the friction bound minus the force that holds (it slips);
* sliding: the rate, signed along the sliding direction (it stops, then sticks or turns).

A sign change stops the step; the runner re-steps from the step's start to the Illinois
estimates of the root until the bracket is below ``EVENT_TIME_TOL`` and continues from its
earlier end with the new mode: Newton's restitution as a velocity jump projected onto the
other constraints (eq. 32), or a stop's or a sticking joint's coordinate held by a row.
Impacts whose remaining bounces would all fit in ``SETTLE_TIME`` (an accumulation of
impacts) settle into contact. Every transition is recorded in ``log`` (time, joint, what).
"""

from __future__ import annotations

import math

import numpy as np

from ..equations.limits import velocity_jump
from ..errors import SettingError, SolverError
from ..model.limits import (HELD, LOWER, SLIDE_DOWN, SLIDE_UP, STICK, UPPER, JointMode,
                            slip_text)
from ..model.scene import Scene, has_events
from .modes import ContactModes

# The methods whose steps the runner watches and repeats (one step from any state).
EVENT_METHODS = ("rk4p", "rk45p", "dop853p")
# Width (s) of the bracket at which an event counts as located.
EVENT_TIME_TOL = 1e-12
# Secant / Illinois iterations allowed to locate one event.
LOCATE_MAX_ITER = 200
# How far towards the estimated time of an event past the communication point the steps
# may go before they close in on it again (``EventRunner.advance``).
HORIZON_FRACTION = 0.9
# ... and within what (relative) a step's end counts as having reached it.
HORIZON_REACHED = 1e-12
# An impact whose remaining bounces would all end within this time (s) rests at once.
SETTLE_TIME = 1e-10
# Events handled at one time, the time not advancing, before the run stops with an error
# (a mode that chatters between states at one instant would otherwise never end).
MAX_EVENTS_AT_ONCE = 1000


class EventFound(Exception):
    """Raised from ``watch`` inside a step: the keys whose event functions changed sign."""


class EventRunner(ContactModes):
    """Runs an integrator through the events of the contact modes (``ContactModes``)."""

    def watch(self, integrator) -> None:
        """Called after each accepted step (``Integrator.watch``)."""
        g = self.values(integrator.t, integrator.q, integrator.qd)
        g0 = self.watching[1]
        crossed = [key for key, v in g.items() if v < 0 and (g0[key] >= 0 or v < g0[key])]
        if crossed:
            raise EventFound(crossed, g)
        self.watching = (integrator.rollback_point(), g, integrator.t)

    # ------------------------------------------------------------------ running

    def advance(self, integrator, t_target: float, limit=None, dense: bool = False,
                restarted: bool = False) -> None:
        """``integrator.advance(t_target, limit, dense=dense)`` with every event on the way
        handled. ``restarted``: the inputs changed at the start (Simulation._reinitialize),
        so that a held coordinate's effort jumped with them; one that a stop would now
        have to pull, or that friction can no longer hold, changes its mode at once
        (``_released``).

        With ``dense`` (an adaptive method, inputs known ahead) a step may end past
        t_target, its dense output giving the state there, when its event functions keep
        their signs. A step past t_target in which one changes sign is taken again: landing
        on t_target when the sign change (by linear interpolation) comes before it, so that
        the event is located as any other; else ending at ``horizon``, HORIZON_FRACTION of
        the way to that estimate, and no step passes the horizon until it is reached, so
        the steps close in on an event still to come while the communication steps before
        it read their dense output."""
        integrator.equations = self.equations
        if restarted:
            self._released(integrator)
        at, count = integrator.t, 0
        while integrator.t < t_target:
            self.watching = (integrator.rollback_point(),
                             self.values(integrator.t, integrator.q, integrator.qd), integrator.t)
            if self.horizon is not None and \
                    integrator.t >= self.horizon - HORIZON_REACHED * max(1.0, self.horizon):
                self.horizon = None          # reached (a step to it ends there to round-off)
            integrator.watch, integrator.watch_each_step = self.watch, True
            max_step = integrator.max_step if integrator.adaptive else None
            if dense and self.horizon is not None:
                integrator.max_step = min(max_step, self.horizon - integrator.t)
            try:
                integrator.advance(t_target, limit, dense=dense)
            except EventFound as found:
                integrator.watch, integrator.watch_each_step = None, False
                crossed, g1 = found.args
                if dense and integrator.t > t_target:
                    start, g0, t0 = self.watching
                    coming = t0 + (integrator.t - t0) * min(_fraction(g0[c], g1[c])
                                                            for c in crossed)
                    integrator.set_state(start)
                    horizon = t0 + HORIZON_FRACTION * (coming - t0)
                    if horizon > t_target:
                        self.horizon = horizon
                    else:
                        dense = False
                    continue
                self._handle(integrator, crossed, g1)
                at, count = integrator.t, (count + 1 if integrator.t == at else 1)
                if count > MAX_EVENTS_AT_ONCE:
                    raise SolverError(
                        f"{count} events at t = {at!r} s without the time advancing (the last: "
                        f"joint {self.log[-1][1]} {self.log[-1][2]}): the contact modes "
                        "chatter; change the inputs or the scene's stops", at) from None
            finally:
                integrator.watch, integrator.watch_each_step = None, False
                if max_step is not None:
                    integrator.max_step = max_step

    def _released(self, integrator) -> None:
        """After an input change: each held coordinate whose event function (the stop's
        force, the friction's margin) is now negative leaves its stop or slips, at once.
        The watch after a step sees a sign change only within the step (or a value that
        falls further), so a change the inputs made at the step's start went unseen until
        the effort happened to fall: a crane resting on its stop under a rising cylinder
        force left it at times that depended on the method, or never."""
        while True:
            g = self.values(integrator.t, integrator.q, integrator.qd)
            held = [key for key, v in g.items() if v < 0 and key[1] in HELD]
            if not held:
                return
            self._transition(integrator, held[0])

    def _state_at(self, integrator, start, t: float):
        integrator.set_state(start)
        if t > integrator.t:
            integrator.advance(t)
        return integrator.rollback_point()

    def _handle(self, integrator, crossed, g1) -> None:
        start, g0, t0 = self.watching
        t1 = integrator.t
        # the earliest crossing by linear interpolation first; any earlier one found at
        # the located time is located in turn
        key = min(crossed, key=lambda c: _fraction(g0[c], g1[c]))
        a, point, b = t0, start, t1
        while True:
            a, point = self._locate(integrator, start, key, t0, g0[key], b, g1[key])
            integrator.set_state(point)
            g = self.values(integrator.t, integrator.q, integrator.qd)
            earlier = [c for c, v in g.items() if c != key and v < 0 <= g0[c]]
            if not earlier or a <= t0:
                break
            key, b, g1 = earlier[0], a, g
        self._transition(integrator, key)

    def _locate(self, integrator, start, key, a, ga, b, gb):
        """(time, rollback point) of the bracket's earlier end once ``b - a`` is within
        ``EVENT_TIME_TOL``: Illinois (secant with halving of a retained end's value); for a
        stop's distance, whose slope is the coordinate's rate, the quadratic through the
        earlier end's value and slope and the later end's value, aimed a quarter of the
        tolerance past the last side found (so that the bracket closes from both sides)."""
        point, last = start, 0
        sa = self._slope(key, start["q"], start["qd"])
        if ga < 0:
            if sa is None or sa < 0 or ga < -integrator._projection_tol():
                return a, point   # already past it at the step's start: change at once
            # On its stop to the projection's tolerance and not moving in: it has just left
            # it (its held row held it there to that tolerance). A return to the stop is
            # later in the step; taken at once, it would be an impact at zero rate that
            # leaves again, at the same instant, for ever.
            ga = 0.0
        for _ in range(LOCATE_MAX_ITER):
            if b - a <= max(EVENT_TIME_TOL, 4 * np.spacing(b)):
                return a, point
            if sa is not None and sa < 0 and ga <= -sa * 0.5 * EVENT_TIME_TOL:
                return a, point   # moving in, its distance reached within the tolerance
            t = _quadratic_root(a, ga, sa, b, gb) if sa is not None else None
            if t is not None:
                t += 0.25 * EVENT_TIME_TOL * last
            elif gb != ga:
                t = b - gb * (b - a) / (gb - ga)
            if t is None or not a < t < b:
                t = 0.5 * (a + b)
            state = self._state_at(integrator, start, t)
            g = self.values(integrator.t, integrator.q, integrator.qd)[key]
            if g >= 0:
                a, ga, point = t, g, state
                sa = self._slope(key, integrator.q, integrator.qd)
                if last == 1:
                    gb *= 0.5
                last = 1
            else:
                b, gb = t, g
                if last == -1:
                    ga *= 0.5
                last = -1
        raise SolverError(f"the event of joint {self.scene.joints[key[0]].name} could not be "
                          f"located within {EVENT_TIME_TOL:g} s", a)

    def _slope(self, key, q, qd) -> float | None:
        """The time derivative of a stop's distance (the coordinate's rate); None for the
        other event functions."""
        k, kind = key
        if kind == "hit lower":
            return self.coordinates[k].rate(q, qd)
        if kind == "hit upper":
            return -self.coordinates[k].rate(q, qd)
        return None

    def _transition(self, integrator, key) -> None:
        k, kind = key
        t, q, qd = integrator.t, integrator.q.copy(), integrator.qd.copy()
        j, c, eq = self.scene.joints[k], self.coordinates[k], self.equations
        state = self.mode[k].state
        if kind in ("hit lower", "hit upper"):
            stop = LOWER if kind == "hit lower" else UPPER
            before = c.rate(q, qd)
            after = -j.restitution * before
            if self._settles(t, q, qd, k, stop, after):
                self.mode[k] = JointMode(stop, j.limits[0 if stop == LOWER else 1])
                self.log.append((float(t), j.name, f"hits its {stop} stop at rate {before:.9g} and "
                                 "rests against it"))
                self._settle(t, q, qd, "")
            else:
                qd = velocity_jump(eq, t, q, qd, c.gradient(q), after, self.inputs(t))
                self.log.append((float(t), j.name, f"hits its {stop} stop at rate {before:.9g}, "
                                 f"leaves at {after:.9g}"))
                if state in (SLIDE_UP, SLIDE_DOWN):
                    self.mode[k] = JointMode(SLIDE_UP if after > 0 else SLIDE_DOWN)
        elif kind in (LOWER, UPPER):
            self.mode[k] = self._moving_state(k, c.value(q), 0.0)
            self.log.append((float(t), j.name, f"leaves its {kind} stop"))
            self._settle(t, q, qd, "")
        elif kind == STICK:
            _, lam = eq.accelerations(t, q, qd, self.inputs(t))
            effort = -lam[eq.held_rows[k]]
            self.mode[k] = JointMode(SLIDE_DOWN if effort > 0 else SLIDE_UP)
            self.log.append((float(t), j.name, f"slips: {slip_text(self.mode[k].state)}"))
        else:                            # a sliding joint's rate reaches zero: stick if it can
            self.log.append((float(t), j.name, "stops sliding"))
            self.mode[k] = JointMode(STICK, c.value(q))
            self._settle(t, q, qd, "stops")
        q, qd = self._project(t, q, qd)
        integrator.equations = self.equations
        integrator.reset_state(q, qd)
        self.horizon = None

    def _settles(self, t, q, qd, k, stop, after) -> bool:
        """An impact ends in contact: no rebound, or the remaining bounces (a geometric
        series of flights 2 v / a, each e times the last) all fit in ``SETTLE_TIME``."""
        j, c = self.scene.joints[k], self.coordinates[k]
        if after == 0.0:
            return True
        e = j.restitution
        qdd, _ = self.equations.accelerations(t, q, qd, self.inputs(t))
        d = 1e-6
        accel = (c.rate(q + d * qd, qd + d * qdd) - c.rate(q, qd)) / d
        toward = -accel if stop == LOWER else accel
        if toward <= 0 or e >= 1.0:
            return False
        return 2.0 * abs(after) / toward / (1.0 - e) < SETTLE_TIME


def event_summary(scene: Scene, q0, qd0, dof: int) -> str:
    """``mbdfmu check``'s line on stops and friction: their rows and the mode at the start."""
    runner = EventRunner(scene, "numpy", 0.0, q0, qd0, lambda t: None)
    stops = [scene.joints[k].name for k in runner.joints if scene.joints[k].limits is not None]
    rubs = [scene.joints[k].name for k in runner.joints if scene.joints[k].friction is not None]
    held = sum(m.state in HELD for m in runner.mode.values())
    start = ", ".join(f"{scene.joints[k].name} {m.state}" for k, m in runner.mode.items())
    return (f"end stops on {', '.join(stops) or 'none'} (one row each while resting on a "
            f"stop), friction on {', '.join(rubs) or 'none'} (one row each while sticking); "
            f"at the start: {start}: {held} rows held, degrees of freedom {dof - held}")


def check_method(integrator, scene: Scene) -> None:
    """Only methods that take single steps from any state can locate events (the only ones
    a scene with stops or friction may run)."""
    if has_events(scene) and integrator.name not in EVENT_METHODS:
        raise SettingError("method", f'method "{integrator.name}" does not locate the events '
                           f"of joint limits and friction: use one of {', '.join(EVENT_METHODS)}",
                           scene.source)


def _quadratic_root(a, ga, sa, b, gb) -> float | None:
    """The first root in (a, b) of the quadratic with value ga and slope sa at a, gb at b."""
    h = b - a
    c = (gb - ga - sa * h) / (h * h)
    if abs(c) * h < 1e-14 * (abs(sa) + abs(gb - ga) / h):
        return a - ga / sa if sa < 0 else None
    disc = sa * sa - 4 * c * ga
    if disc < 0:
        return None
    r = math.sqrt(disc)
    inside = [a + tau for tau in ((-sa - r) / (2 * c), (-sa + r) / (2 * c)) if 0 < tau < h]
    return min(inside) if inside else None


def _fraction(g0: float, g1: float) -> float:
    """Where in the step a linear g crosses zero (0 at its start)."""
    return 0.0 if g0 <= 0 else g0 / (g0 - g1)
