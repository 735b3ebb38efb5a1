"""An FMU's communication steps taken by its C wrapper without Python, seen from the
``Simulation``: which kind of step the C kernel can take next (``arm``), and the state,
counters and inputs to take over when the slave catches up (``catch_up``).

Three kinds, each the same arithmetic as the Python step it replaces, so the values the
wrapper serves are Python's bit for bit (tests/test_fmu_fast.py):

* ``dense``: a step that ends inside an adaptive method's last step reads its dense output
  (``ckernel/dense.h``; ``Simulation.dense_reads_ahead``);
* ``fixed``: rk4p's steps, the drivers' motions evaluated in C (``ckernel/fixed.h``);
* ``prk``: an embedded pair's steps landing on the communication point, with the force
  inputs the master sets before each step (``ckernel/adaptive.h``; the wrapper takes those
  fmi2SetReal calls too).

The last two need no events, no input changed since the step, every force input held, no
driver taking its motion from the inputs and auto switching nothing; ``c_steps``'s
``fast_run`` and ``fast_prk_run`` say the rest. This module reads ``Simulation``'s input
bookkeeping (its ``_inputs_changed``, ``_drivers``, ``_forces``) as the class itself does.
"""

from __future__ import annotations

import numpy as np

from .equations.ckernel.fixed import motion_table
from .equations.projection import ASSEMBLY_TOL
from .integrators.c_steps import adopt_fast_run, adopt_prk_run, fast_prk_run, fast_run, tableau
from .integrators.projected_rk import MAX_FACTOR, MIN_FACTOR, SAFETY
from .signals import Held
from .simulation import REINITIALIZE_TOL_FACTOR


def settable_inputs(sim, table) -> tuple[np.ndarray, np.ndarray]:
    """(value references, places in the force inputs u.forces) of the inputs the wrapper may
    set itself before a ``prk`` step: every force input, by its FMU variable (``table``: the
    runtime's ``VariableTable``)."""
    value_reference = {v.name: v.value_reference for v in table.by_type["Real"].values()}
    layout, pairs = sim.equations.layout, []
    for item, where in layout.forces.items():
        for j, field in enumerate(layout.fields[item]):
            pairs.append((value_reference[f"{item}.{field}"], where.start + j))
    return (np.array([p[0] for p in pairs], dtype=np.int64),
            np.array([p[1] for p in pairs], dtype=np.int64))


def fast_steps_ahead(sim, limit, time_tol: float):
    """("fixed", kernel, the arguments of ``arm_fixed_steps`` before the published values),
    ("prk", kernel, those of ``arm_prk_steps`` before the inputs), or None."""
    kernel, integrator, eq = sim.equations.ckernel, sim.integrator, sim.equations
    watcher = getattr(integrator, "watcher", None)
    if kernel is None or sim.events is not None or sim._inputs_changed or sim._drivers or \
            any(type(f) is not Held for f in sim._forces.values()) or \
            (watcher is not None and watcher.pending is not None):
        return None
    u = sim.inputs_at(sim.t)
    table = motion_table(eq.constraint_set)
    run = None if table is None else fast_run(integrator, limit, time_tol)
    if run is not None:
        return "fixed", kernel, (run, table, eq.constraint_set.offsets, u.forces)
    run = None if sim.scene.drivers or sim.inputs_known_ahead() else \
        fast_prk_run(integrator, limit, time_tol, (SAFETY, MIN_FACTOR, MAX_FACTOR))
    if run is None:
        return None
    run.update(motion=np.concatenate(eq.motion_values(sim.t, u)), uf=u.forces,
               reinit_tol=ASSEMBLY_TOL * eq.length_scale * REINITIALIZE_TOL_FACTOR)
    return "prk", kernel, (run, tableau(integrator)[:5])


def arm(sim, limit, time_tol: float, inputs, published) -> tuple | None:
    """The arguments of the slave's ``arm_fast_steps`` for the coming communication steps
    (the dense, fixed or prk kind, in that order of preference), or None when they must go
    through Python. ``inputs``: ``settable_inputs``; ``published``: (value references,
    places in (outputs, q, q', q'')) of the values each step writes."""
    kernel = sim.dense_reads_ahead()
    if kernel is not None:
        return kernel.arm_dense_steps(sim.t, time_tol, *published)
    fast = fast_steps_ahead(sim, limit, time_tol)
    if fast is None:
        return None
    kind, kernel, arguments = fast
    if kind == "fixed":
        return kernel.arm_fixed_steps(*arguments, *published)
    return kernel.arm_prk_steps(*arguments, inputs, *published)


def catch_up(sim, inputs) -> tuple[bool, list, list]:
    """After steps the wrapper took: ``sim`` where they ended (the same arithmetic), and
    (whether it moved; [(value reference, value)] of the ``settable_inputs`` as ``sim``
    now holds them, when it moved; those the wrapper took from fmi2SetReal after its last
    step, for the FMU to treat as set)."""
    kernel = sim.equations.ckernel
    if kernel is None:
        return False, [], []
    fixed, (_, prk, pending) = kernel.fixed_taken(), kernel.prk_taken()
    if fixed is not None:
        adopt_fast_run(sim.integrator, *fixed)
    if prk is not None:
        adopt_prk_run(sim.integrator, prk)
        for item, where in sim.equations.layout.forces.items():
            sim._forces[item] = Held(prk["uf"][where].copy())
        sim._cache = sim._held = None
    elif fixed is not None:
        sim._cache = None
    elif kernel.dense.t_now > sim.t:
        sim.advance(kernel.dense.t_now)
    else:
        return False, [], pending
    forces = sim.inputs_at(sim.t).forces
    return True, [(int(vr), float(forces[slot])) for vr, slot in zip(*inputs)], pending
