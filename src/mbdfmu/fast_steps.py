"""An FMU's communication steps taken by its C wrapper without Python, seen from the
``Simulation``: which kind of step the C kernel can take next (``arm``), and the state,
counters and inputs to take over when the slave catches up (``catch_up``).

Three kinds, each the same arithmetic as the Python step it replaces, so the values the
wrapper serves are Python's bit for bit (tests/test_fmu_fast.py):

* ``dense``: a step that ends inside an adaptive method's last step reads its dense output
  (``ckernel/dense.h``; ``Simulation.dense_reads_ahead``); with dop853p, one that ends past
  it takes the next steps and their interpolant first (``ckernel/dense_run.h``,
  ``integrators.dense_runs``), the drivers' motions evaluated at every time they need
  (``ckernel/motions.h``). In a scene with end stops or friction these read the
  current contact mode's equations (``mode_published``) and the runs watch its event
  functions after each step (``ckernel/events.h``);
* ``fixed``: rk4p's steps, the drivers' motions evaluated in C (``ckernel/fixed.h``), the
  energy audit's check after each in C too; in a scene with end stops or friction the
  current contact mode's equations, its event functions watched after each step;
* ``prk``: an embedded pair's steps landing on the communication point (``ckernel/adaptive.h``);
* ``implicit``: genalpha's and ali3p's steps landing on it, controlled (auto's stiff
  scenes) or fixed with the stated accuracy's checks (``ckernel/implicit_run.h``,
  ``integrators.implicit_runs``), the energy audit's check after each; the force inputs
  the master sets taken too; no sampled drivers, end stops or friction.

The last two take the force inputs the master sets before each step (the wrapper takes
those fmi2SetReal calls too, then restarts as Python does; rk4p where the restart starts
no energy audit), and with end stops or friction watch the contact mode's event
functions after each step, from their values at the restart with the new inputs. They
evaluate the drivers' motions at every stage's time (``ckernel/motions.h``), and take the
positions (velocities, accelerations) the master sets for drivers driven by the inputs,
each a ``SampledDriver``: the next step applies the set as
``Simulation.set_input``, restarts with the projection of ``_reinitialize``, and hands
itself to Python where the driver's derived-acceleration warning would turn on or off.
All need no input changed since the step, every force input held, and under ``auto`` a
watcher at rest (no switch pending, no stiff step
counted; dop853p's steps checked in C against its stiffness test, ``auto_stiff_limit``);
``rk4p_c.fast_run`` and ``c_steps.fast_prk_run`` say the rest. This module reads
``Simulation``'s input bookkeeping (its ``_inputs_changed``, ``_drivers``, ``_forces``) as
the class itself does.
"""

from __future__ import annotations

import numpy as np

from .equations.ckernel.fixed import DRIVER_STATE, DRV_SIZE, motion_table
from .equations.projection import PROJECTION_MAX_ITER
from .integrators.c_steps import adopt_prk_run, fast_prk_run, tableau
from .integrators.auto_watch import STIFF_HLAMBDA
from .integrators.dense_runs import adopt_dense_run, dense_run
from .integrators.implicit_runs import adopt_fast_implicit, arm_fast_implicit
from .integrators.rk4p_c import adopt_fast_run, fast_run
from .integrators.projected_rk import DOP853P, MAX_FACTOR, MIN_FACTOR, SAFETY
from .integrators.tableaux import DOP853_C_EXTRA
from .model.limits import HELD, STICK, hold_driver_name
from .model.scene import Body, SpringDamper
from .model.variables import GLOBAL_OUTPUTS, TABLES, outputs
from .signals import DRIVER_FIELDS, Held, SampledDriver


def settable_inputs(sim, table) -> tuple[np.ndarray, np.ndarray]:
    """(value references, places) of the inputs the wrapper may set itself before a step,
    by their FMU variables (``table``: the runtime's ``VariableTable``): every force input
    (its place in u.forces), then each field of the drivers that take their motion from the
    inputs (places ``max(nf, 1) + 3 d + field`` past them: ``Kernel.arm_fixed_steps``,
    ``arm_prk_steps``)."""
    value_reference = {v.name: v.value_reference for v in table.by_type["Real"].values()}
    layout, pairs = sim.equations.layout, []
    for item, where in layout.forces.items():
        for j, field in enumerate(layout.fields[item]):
            pairs.append((value_reference[f"{item}.{field}"], where.start + j))
    first = max(layout.size, 1)
    for d, item in enumerate(layout.drivers):
        for j, field in enumerate(DRIVER_FIELDS):
            if f"{item}.{field}" in value_reference:
                pairs.append((value_reference[f"{item}.{field}"], first + 3 * d + j))
    return (np.array([p[0] for p in pairs], dtype=np.int64),
            np.array([p[1] for p in pairs], dtype=np.int64))


def driver_state(driver: SampledDriver) -> list[float]:
    """A ``SampledDriver`` as ckernel/motions.h's state (``DRIVER_STATE``)."""
    count = len(driver.times)
    return [float(count), float(driver.fresh), *driver.times, *[0.0] * (4 - count),
            *driver.positions, *[0.0] * (4 - count), float(driver.velocity is not None),
            driver.velocity or 0.0, float(driver.acceleration is not None),
            driver.acceleration or 0.0, driver.error, driver.scale, float(driver.reported)]


def adopt_driver_state(driver: SampledDriver, state) -> None:
    """``driver_state`` back: the samples and estimate the wrapper's sets left."""
    fields, k = {}, 0
    for name, size in DRIVER_STATE:
        fields[name], k = state[k:k + size].tolist(), k + size
    count = int(fields["count"][0])
    driver.times, driver.positions = fields["times"][:count], fields["positions"][:count]
    driver.fresh = bool(fields["fresh"][0])
    driver.velocity = fields["velocity"][0] if fields["has_velocity"][0] else None
    driver.acceleration = fields["acceleration"][0] if fields["has_acceleration"][0] else None
    driver.error, driver.scale = fields["error"][0], fields["scale"][0]


def sampled_drivers(sim) -> list | None:
    """The drivers that take their motion from the inputs, in the layout's order, when
    the wrapper's steps can follow them: each a ``SampledDriver`` (not a table or a
    function of time); else None. [] without such drivers."""
    drivers = [sim._drivers[name] for name in sim.equations.layout.drivers]
    if any(type(d) is not SampledDriver for d in drivers):
        return None
    return drivers


def unchanged_by_force_inputs(sim, table, published) -> np.ndarray:
    """Value references of the Real variables (``table``: the runtime's ``VariableTable``)
    whose values a force input set since the last step leaves as they are, so the wrapper
    may serve a get between such a set and the next step: the positions and velocities
    (the restart after a force input does not project: ``Simulation._reinitialize``), the
    outputs that depend on them alone (body states, spring lengths and rates, energies,
    constraint norms), and every variable that is not published (parameters, settings,
    the inputs themselves, which the set function writes). Not the accelerations, joint
    outputs, driver efforts or spring tensions, which follow the forces. ``published``:
    the names the model publishes after each step."""
    kept = {v.name for v in GLOBAL_OUTPUTS}
    kept |= {f"{b.name}.{s.suffix}" for b in sim.scene.bodies for s in TABLES[Body].outputs}
    kept |= {f"{f.name}.{s}" for f in sim.scene.forces if isinstance(f, SpringDamper)
             for s in ("length", "velocity")}
    published = set(published)
    return np.array(sorted(vr for vr, v in table.by_type["Real"].items()
                           if v.name not in published or v.name in kept), dtype=np.intp)


def auto_stiff_limit(integrator, watcher) -> float | None:
    """For ``fast_prk_run``: None when a watch after each step keeps the steps in Python;
    0.0 when there is none or it is auto's and can only act on what adaptive.h checks
    (rk45p: nothing; dop853p: Hairer's STIFF_HLAMBDA, against which adaptive.h checks an
    upper bound of the h |lambda| numpy computes, so a step near it goes to Python).
    ``watcher``: auto's ``AutoWatch`` or None."""
    if integrator.watch is None:
        return 0.0
    # auto's watcher at rest: a step under the limit leaves it as it is (no pending
    # switch, no stiff step counted, so a non-stiff one counts nothing either)
    if watcher is None or integrator.watch != watcher.after_step or \
            watcher.pending is not None or watcher.stiff:
        return None
    return STIFF_HLAMBDA if integrator.name == DOP853P.name else 0.0


def steady(sim) -> bool:
    """What every step the wrapper takes with inputs needs: no input set since the last
    step, every force input held, and under auto no switch pending."""
    watcher = getattr(sim.integrator, "watcher", None)
    return not sim._inputs_changed and all(type(f) is Held for f in sim._forces.values()) \
        and (watcher is None or watcher.pending is None)


def fast_steps_ahead(sim, limit, time_tol: float, inputs=None):
    """("fixed", kernel, the arguments of ``arm_fixed_steps`` before the published values,
    and the keywords after them), ("prk", kernel, those of ``arm_prk_steps`` before the
    inputs, and the keywords after them: with end stops or friction the contact mode's
    event functions), or None. ``inputs``: ``settable_inputs``, which rk4p's steps take
    from fmi2SetReal too where a restart starts no energy audit."""
    integrator, eq = sim.integrator, sim.stepped_equations
    kernel, watcher = eq.ckernel, getattr(integrator, "watcher", None)
    drivers = sampled_drivers(sim)
    if kernel is None or drivers is None or not steady(sim):
        return None
    current = getattr(integrator, "current", integrator)     # auto's integrator of the moment
    u = sim.inputs_at(sim.t)
    table = motion_table(eq.constraint_set, [d.step_motion() for d in drivers] or None)
    run = None if table is None else fast_run(current, limit, time_tol)
    if run is not None:
        sets = {} if inputs is None or not len(inputs[0]) or eq.nonconservative_reason() is None \
            else dict(inputs=inputs)
        if drivers:
            sets["drivers"] = sampled_states(sim, drivers)
        return "fixed", kernel, (run, table, eq.constraint_set.offsets, u.forces), \
            {**sets, **watched_events(sim, current)}
    stiff_limit = auto_stiff_limit(current, watcher)
    # with drivers the steps evaluate their motions (the table), not with stops or friction
    driven = bool(sim.scene.drivers)
    run = None if (driven and table is None) or \
        sim.inputs_known_ahead() or stiff_limit is None else \
        fast_prk_run(current, limit, time_tol, (SAFETY, MIN_FACTOR, MAX_FACTOR), stiff_limit)
    if run is None:
        return None
    run.update(motion=np.concatenate(eq.motion_values(sim.t, u)), uf=u.forces)
    motions = dict(motions=(table, eq.constraint_set.offsets, tableau(current)[-1],
                            sampled_states(sim, drivers) if drivers else None)) if driven else {}
    return "prk", kernel, (run, tableau(current)[:5]), {**watched_events(sim, current),
                                                        **motions}


def sampled_states(sim, drivers) -> tuple:
    """The sampled drivers as ``Kernel.arm_fixed_steps`` and ``arm_prk_steps`` take them:
    their states, the restart's projection tolerance and iterations."""
    return (np.array([x for d in drivers for x in driver_state(d)]),
            sim.reinitialize_tolerance(), PROJECTION_MAX_ITER)


def watched_events(sim, integrator) -> dict:
    """The keywords that make a run watch the contact mode's event functions after each
    step, from their values at the integrator's state ({} without end stops or friction)."""
    if sim.events is None:
        return {}
    return dict(events=sim.events.c_events(integrator.t, integrator.q, integrator.qd))


def arm(sim, limit, time_tol: float, inputs, published) -> tuple | None:
    """The arguments of the slave's ``arm_fast_steps`` for the coming communication steps
    (the dense, fixed or prk kind, in that order of preference), or None when they must go
    through Python. ``inputs``: ``settable_inputs``; ``published``: (value references,
    places in (outputs, q, q', q'')) of the values each step writes."""
    kernel = sim.dense_reads_ahead()
    if kernel is not None:
        stepped = sim.stepped_equations.constraint_set     # a contact mode's, with stops
        table = (kernel.motion_table(stepped), stepped.offsets) if sim.scene.drivers else None
        armed = kernel.arm_dense_steps(sim.t, time_tol, *mode_published(sim, published),
                                       motions=table)
        run = dense_run_ahead(sim, limit)
        if run is None:
            return armed
        integrator = getattr(sim.integrator, "current", sim.integrator)
        motions = None if table is None else (*table, tableau(integrator)[-1], DOP853_C_EXTRA)
        return kernel.arm_dense_run(*run, motions=motions)
    fast = fast_steps_ahead(sim, limit, time_tol, inputs)
    if fast is None:
        return implicit_ahead(sim, limit, time_tol, inputs, published)
    kind, kernel, arguments, keywords = fast
    if kind == "fixed":
        return kernel.arm_fixed_steps(*arguments, *mode_published(sim, published), **keywords)
    return kernel.arm_prk_steps(*arguments, inputs, *mode_published(sim, published), **keywords)


def implicit_ahead(sim, limit, time_tol: float, inputs, published) -> tuple | None:
    """The arguments of ``arm_fast_steps`` for the coming steps as genalpha's or ali3p's
    controlled or fixed steps (``implicit_runs.arm_fast_implicit``), the force inputs among
    ``inputs`` (``settable_inputs``) taken from fmi2SetReal too, or None: they need every
    force input held and none set since the step, no driver driven by the inputs, no end
    stops or friction, and under auto a watcher at rest."""
    eq = sim.stepped_equations
    if eq.ckernel is None or sim.events is not None or sim.equations.layout.drivers or \
            not steady(sim):
        return None
    current = getattr(sim.integrator, "current", sim.integrator)
    if getattr(current, "c_newton", None) is None:
        return None
    forces = inputs if inputs is not None else ((), ())
    return arm_fast_implicit(current, eq.ckernel, limit, time_tol, sim.inputs_at(sim.t),
                             forces, published, sim.reinitialize_tolerance())


def mode_published(sim, published) -> tuple:
    """``published`` (value references, places in the scene's (outputs, q, q', q'')) as
    places in the current contact mode's: its output vector has the effort of each
    held coordinate's driver too (model.limits.hold_driver_name), which is the stop's force
    (``<joint>.limit``) of a joint resting on a stop and the friction (``<joint>.friction``)
    of a sticking one, as ``ContactModes.output_vector`` reads them; a sliding joint's
    friction is its own output there (``ModeEquations.sliding_forces``)."""
    eq = sim.stepped_equations
    if eq is sim.equations:
        return published
    kept = getattr(eq, "published_places", None)
    if kept is not None and kept[0] is published:
        return kept[1]
    names = [v.name for v in outputs(eq.scene)]
    place = {name: i for i, name in enumerate(names)}
    for k, mode in sim.events.mode.items():
        if mode.state in HELD:
            joint = sim.scene.joints[k].name
            what = "friction" if mode.state == STICK else "limit"
            place[f"{joint}.{what}"] = place[f"{hold_driver_name(joint)}.effort"]
    base, (vrs, sources) = sim.output_names, published
    shift = len(names) - len(base)
    mapped = vrs, np.array([place[base[s]] if s < len(base) else s + shift for s in sources])
    eq.published_places = (published, mapped)
    return mapped


def dense_run_ahead(sim, limit) -> tuple | None:
    """The arguments of ``Kernel.arm_dense_run`` when the wrapper may also take the steps
    past the step it reads (``integrators.dense_runs``: dop853p, auto's watcher at rest;
    with stops or friction, the mode's event functions to watch), else None.
    ``sim.dense_reads_ahead()`` said yes: no drivers, inputs held."""
    integrator = getattr(sim.integrator, "current", sim.integrator)
    watcher = getattr(sim.integrator, "watcher", None)
    run = dense_run(integrator, limit, auto_stiff_limit(integrator, watcher))
    if run is None:
        return None
    u, eq = sim.inputs_at(sim.t), sim.stepped_equations
    settings, tableau, gaps, audit, a_extra, D = run
    # with stops or friction the run watches the mode's event functions after each step,
    # from their values at the last step's end, within the event runner's horizon
    events = watched_events(sim, integrator).get("events")
    return (settings, tableau[:5], gaps, np.concatenate((integrator.q, integrator.qd)),
            integrator.f, np.concatenate(eq.motion_values(sim.t, u)), u.forces,
            audit, a_extra, D, events, None if sim.events is None else sim.events.horizon)


def catch_up(sim, inputs) -> tuple[bool, list, list]:
    """After steps the wrapper took: ``sim`` where they ended (the same arithmetic), and
    (whether it moved; [(value reference, value)] of the ``settable_inputs`` as ``sim``
    now holds them, when it moved; those the wrapper took from fmi2SetReal after its last
    step, for the FMU to treat as set)."""
    kernel = sim.stepped_equations.ckernel
    if kernel is None:
        return False, [], []
    (fixed, fixed_pending), (_, prk, pending) = kernel.fixed_taken(), kernel.prk_taken()
    pending = pending + fixed_pending
    if fixed is not None:
        *taken, restarts, uf, states = fixed
        adopt_fast_run(sim.integrator, *taken)
        sim.integrator.stats.naccel += restarts       # each restart's f, as Python's
        if restarts:
            hold_forces(sim, uf)
        adopt_driver_states(sim, states)
    implicit, implicit_pending = kernel.implicit_taken()
    pending = pending + implicit_pending
    if implicit is not None:
        adopt_fast_implicit(getattr(sim.integrator, "current", sim.integrator), implicit)
        hold_forces(sim, implicit["uf"])
        return True, held_inputs(sim, inputs), pending
    run = kernel.dense_run_taken()
    if prk is not None:
        adopt_prk_run(sim.integrator, prk)
        hold_forces(sim, prk["uf"])
        adopt_driver_states(sim, prk["drivers"])
    elif fixed is not None:
        sim._cache = None
    elif run is not None or kernel.dense.t_now > sim.t:
        if run is not None:     # past its step: the wrapper's steps, then the read inside
            adopt_dense_run(sim.integrator, run)
            if sim.events is not None:
                sim.events.horizon = run["horizon"]
        sim.advance(kernel.dense.t_now)
    else:
        return False, [], pending
    return True, held_inputs(sim, inputs), pending


def held_inputs(sim, inputs) -> list:
    """[(value reference, value)] of the ``settable_inputs`` as ``sim`` now holds them: the
    force inputs, and the fields of the sampled drivers the master set (the last
    position, the velocity and acceleration it gave)."""
    forces, layout = sim.inputs_at(sim.t).forces, sim.equations.layout
    first, held = max(layout.size, 1), []
    for vr, slot in zip(*inputs):
        if slot < layout.size:
            held.append((int(vr), float(forces[slot])))
            continue
        if slot < first:
            continue
        driver = sim._drivers[layout.drivers[(slot - first) // 3]]
        if not isinstance(driver, SampledDriver):
            continue
        value = (driver.positions[-1] if driver.fresh else None, driver.velocity,
                 driver.acceleration)[(slot - first) % 3]
        if value is not None:
            held.append((int(vr), float(value)))
    return held


def adopt_driver_states(sim, states) -> None:
    """The sampled drivers' states (``driver_state`` each, in the layout's order) the
    wrapper's steps left, into ``sim``'s drivers."""
    for d, name in enumerate(sim.equations.layout.drivers if states.size else ()):
        adopt_driver_state(sim._drivers[name], states[d * DRV_SIZE:(d + 1) * DRV_SIZE])


def hold_forces(sim, uf) -> None:
    """The force inputs ``uf`` the wrapper's steps held, as ``Simulation.set_input`` and
    its reinitialization leave them."""
    for item, where in sim.equations.layout.forces.items():
        sim._forces[item] = Held(uf[where].copy())
    sim._cache = sim._held = None
