"""An FMU's communication steps of rk4p taken by its wrapper without Python (fixed.h): the
drivers' motions as a table the kernel evaluates, the run's state and its step-doubling
charge, armed by the slave after a Python step and read back when it catches up
(``fmu_build/runtime/real_cache.py`` FastSteps); with the force inputs the master sets
before a step taken by the wrapper too (``mbd_fixed_set``), as adaptive.py's.

``FixedSteps`` is a mixin of ``Kernel``: it uses the kernel's ``n``, ``m``, ``nf``,
``nout``, ``address``, ``library`` and ``_dense_scratch`` (the published values' buffer,
shared with dense.py's steps: only one kind is armed at a time).
"""

from __future__ import annotations

import ctypes

import numpy as np

from ...model.motion import ConstantMotion, HarmonicMotion, LinearMotion
from .model import watch_events

_P, _I, _D = ctypes.c_void_p, ctypes.c_int64, ctypes.c_double
# fixed.h's MOTION_* codes of the motions it evaluates; any other kind stays with Python.
# fixed.h's statuses beyond kernel.c's: a check's step failed; the next charge stops the
# run; a step changed an event function's sign.
CHECK, ESTIMATE, EVENT = 16, 17, 18
AUDIT_SIZE = 13                 # kernel.c's A_FIELDS: the energy check's state
MOTION_CODES = {ConstantMotion: 0, LinearMotion: 1, HarmonicMotion: 2}
MOTION_SAMPLED = 3              # a driver position the master sets (motions.h)
# motions.h's state of such a driver, DRV_SIZE doubles: (name, count) in its order
DRIVER_STATE = (("count", 1), ("fresh", 1), ("times", 4), ("positions", 4), ("has_velocity", 1),
                ("velocity", 1), ("has_acceleration", 1), ("acceleration", 1), ("error", 1),
                ("scale", 1), ("reported", 1))
DRV_SIZE = sum(k for _, k in DRIVER_STATE)


class FixedRun(ctypes.Structure):
    """fixed.h's ``FixedRun``."""

    _fields_ = [("t_now", _D), ("time_tol", _D), ("h_max", _D), ("slack", _D),
                ("max_steps", _I), ("tol", _D),
                ("max_iter", _I), ("nmotion", _I), ("mrow", _P), ("mkind", _P), ("mcoef", _P),
                ("offsets", _P), ("ufs", _P), ("y", _P), ("f", _P), ("save", _P),
                ("motions", _P), ("steps", _I), ("nout", _I), ("npub", _I), ("pub_dst", _P),
                ("pub_src", _P), ("V", _P), ("uf", _P), ("nvr", _I),
                ("vrs", _P), ("slots", _P), ("set", _P), ("changed", _I), ("restarts", _I),
                ("est", _P), ("check", _P), ("audit", _P), ("divergence", _D), ("roundoff", _D),
                ("kept", _P), ("nevent", _I), ("ev_int", _P), ("ev_real", _P), ("ev_g", _P),
                ("ndrv", _I), ("dslot", _I), ("dmot", _P), ("drv", _P), ("reinit_tol", _D),
                ("reinit_iter", _I)]


class Estimate(ctypes.Structure):
    """fixed.h's ``Estimate``: the fields of ``stated_accuracy.ErrorEstimate``, the run's
    step count, and the rule's constants (filled by the integrators' layer)."""

    _fields_ = [("local", _D), ("local_v", _D), ("sum_q", _D), ("sum_v", _D), ("sum_vt", _D),
                ("charged", _I), ("unchecked", _I), ("every", _I), ("since", _I),
                ("nsteps", _I), ("checks", _I), ("estimate", _D), ("allowed", _D),
                ("floor", _D), ("factor_q", _D), ("factor_v", _D), ("carry", _I),
                ("first", _I), ("share", _I), ("most", _I), ("change", _D), ("decay", _D)]


def estimate_values(e: Estimate) -> dict:
    """An ``Estimate``'s fields as a dict (Python numbers)."""
    return {name: getattr(e, name) for name, _ in Estimate._fields_}


def motion_coefficients(motion) -> list[float] | None:
    """The four numbers fixed.h's ``motion_at`` reads for ``motion`` (a harmonic's angular
    frequency computed here as motion.py computes it), or None for a kind it does not
    know."""
    kind = type(motion)
    if kind is ConstantMotion:
        return [motion.value, 0.0, 0.0, 0.0]
    if kind is LinearMotion:
        return [motion.start, motion.rate, 0.0, 0.0]
    if kind is HarmonicMotion:
        w = 2.0 * np.pi * motion.frequency      # math.pi: the same double
        return [motion.offset, motion.amplitude, float(w), motion.phase]
    return None


def motion_table(constraint_set, sampled=None):
    """(count, rows, codes, coefficients) of the drivers' motions, or None when one is of
    a kind fixed.h does not evaluate. Drivers that take their motion from the inputs need
    ``sampled``: for each (in ``input_rows``' order) the four numbers of its motion over the
    next step (the last sample's time, p, v, a; motions.h ``drv_coefficients``), entered
    after the scene's motions; without it, None."""
    if constraint_set.input_rows.size and sampled is None:
        return None
    rows, codes, coefficients = [], [], []
    for row, motion in constraint_set.motion_rows:
        c = motion_coefficients(motion)
        if c is None:
            return None
        rows.append(int(row)), codes.append(MOTION_CODES[type(motion)]), coefficients.append(c)
    for row, c in zip(constraint_set.input_rows.tolist() if sampled else [], sampled or []):
        rows.append(int(row)), codes.append(MOTION_SAMPLED), coefficients.append(list(c))
    return (len(rows), np.array(rows or [0], dtype=np.int64), np.array(codes or [0], dtype=np.int64),
            np.array(coefficients or [[0.0] * 4], dtype=float).ravel())


def table_arrays(r, table, offsets) -> tuple:
    """The drivers' motion ``table`` (``motion_table``) and the constraints' ``offsets``
    into the ``MotionTable`` fields of ``r`` (a ``DenseRead``, ``PrkRun``); the arrays it
    points at."""
    arrays = (np.ascontiguousarray(table[1], dtype=np.int64),
              np.ascontiguousarray(table[2], dtype=np.int64), np.array(table[3], dtype=float),
              np.ascontiguousarray(offsets, dtype=float))
    r.nmotion = table[0]
    r.mrow, r.mkind, r.mcoef, r.offsets = (a.ctypes.data for a in arrays)
    return arrays


def sampled_arrays(r, drivers, nmotion: int) -> tuple:
    """The sampled drivers (``drivers``: their states, ``DRV_SIZE`` each; the restart's
    projection tolerance and iterations; or None) into the run ``r``'s ``SampledSet``
    fields (a ``FixedRun`` or ``PrkRun``), their entries the last of a motion table of
    ``nmotion``. Returns (their count, the arrays ``r`` points at)."""
    states, reinit_tol, reinit_iter = drivers if drivers is not None else ([], 0.0, 0)
    ndrv = len(states) // DRV_SIZE
    drv = np.zeros(max(2 * len(states) + 4 * ndrv, 1))     # the states, a copy, the table's
    drv[:len(states)] = states
    dmot = np.arange(nmotion - ndrv, nmotion + (not ndrv), dtype=np.int64)
    r.ndrv, r.dmot, r.drv = ndrv, dmot.ctypes.data, drv.ctypes.data
    r.reinit_tol, r.reinit_iter = reinit_tol, reinit_iter
    return ndrv, (dmot, drv)


class FixedSteps:
    """The fixed-step calls of ``Kernel`` (see the module docstring)."""

    fixed: FixedRun | None = None

    def _fixed_struct(self, run: dict, table, offsets, uf, extra=(), ndrv: int = 0,
                      r: FixedRun | None = None) -> tuple:
        """A ``FixedRun`` from ``run`` (its fields by name, with y, f and ``estimate``, a
        dict of ``Estimate``'s fields), the drivers' motion ``table`` (``motion_table``),
        the constraints' ``offsets`` and the held force inputs ``uf`` (followed by room for
        the three fields of ``ndrv`` sampled drivers as set); and the arrays it points at
        (``extra`` appended); into ``r`` if given."""
        r, estimate = r or FixedRun(), Estimate(**run.pop("estimate"))    # {}: zeros
        n2, m, nf = 2 * self.n, self.m, max(self.nf, 1)
        y = np.zeros(7 * n2)                    # y, f, their saved copy, a check's room
        y[:n2], y[n2:2 * n2] = run.pop("y"), run.pop("f")
        held = np.asarray(uf if self.nf else [0.0], dtype=float)
        # three stages' copies, then uf and the drivers' fields
        forces = np.concatenate((np.tile(held, 3), held, np.zeros(3 * ndrv)))
        arrays = (*table_arrays(r, table, offsets), forces, y, np.zeros(9 * max(m, 1)), *extra)
        for name, value in run.items():
            setattr(r, name, value)
        r.ufs = forces.ctypes.data
        r.uf = forces.ctypes.data + 8 * 3 * nf
        r.y, r.f, r.save = y.ctypes.data, y.ctypes.data + 8 * n2, y.ctypes.data + 16 * n2
        r.check, r.motions = y.ctypes.data + 32 * n2, arrays[6].ctypes.data
        r.est = ctypes.addressof(estimate)
        return r, estimate, arrays

    def arm_fixed_steps(self, run: dict, table, offsets, uf, pub_dst, pub_src,
                        inputs=None, events=None, drivers=None) -> tuple:
        """Let an FMU's wrapper take rk4p's communication steps (``mbd_fixed_step``) from
        the state in ``run`` (t_now, time_tol, h_max, slack, max_steps, tol, max_iter, y,
        f and ``estimate``: ``Estimate``'s fields), the drivers' motion ``table``
        (``motion_table``), the constraints' ``offsets`` and the held force inputs ``uf``,
        publishing as ``DenseReads.arm_dense_steps`` does. With ``inputs`` (value
        references and places in uf of the inputs fmi2SetReal may set here) the wrapper
        takes those sets too (``mbd_fixed_set``; the steps then restart without a
        projection, as ``Simulation._reinitialize``). In a scene with end stops or
        friction, ``events`` are the contact mode's event functions the steps watch
        (``ContactModes.c_events``): a step that changes a sign hands the doStep to Python.
        ``drivers``: (the sampled drivers' states, ``DRV_SIZE`` each; the restart's
        projection tolerance and iterations) when drivers take their motion from the inputs
        (``table`` then ends with their entries, and ``inputs`` may name their fields with
        places ``max(nf, 1) + 3 d + field`` past uf's: the step after such a set applies it
        and projects, as ``Simulation._reinitialize``).
        Returns (the address of ``mbd_fixed_step``, of the model, of the FixedRun), then
        that of ``mbd_fixed_set`` with ``inputs``."""
        vrs, slots = (np.ascontiguousarray(a, dtype=np.int64) for a in
                      (inputs if inputs is not None else ([], [])))
        dst, src = (np.ascontiguousarray(a, dtype=np.int64) for a in (pub_dst, pub_src))
        size = self.library.mbd_fixed_kept_size
        size.restype, size.argtypes = _I, [_P]
        kept = np.zeros(size(self.address))        # nothing kept yet (its flag 0)
        audit = run.pop("audit", None)        # the energy check's state, then its copy
        checks = np.zeros(2 * AUDIT_SIZE)
        checks[:AUDIT_SIZE] = audit if audit is not None else 0.0
        r = FixedRun()
        ndrv, sampled = sampled_arrays(r, drivers, table[0])
        known = slots < max(self.nf, 1) + 3 * ndrv       # no room for a driver not armed
        vrs, slots = vrs[known], slots[known]
        r, estimate, arrays = self._fixed_struct(run, table, offsets, uf, (
            dst, src, vrs, slots, np.zeros(max(vrs.size, 1), dtype=np.int64), kept, checks),
            ndrv, r)
        r.audit = None if audit is None else checks.ctypes.data
        r.dslot = max(self.nf, 1)
        self.fixed, self._fixed_arrays = r, (*arrays, watch_events(r, events), *sampled,
                                             estimate)
        r.kept = kept.ctypes.data
        r.pub_dst, r.pub_src, r.vrs, r.slots, r.set = (a.ctypes.data for a in arrays[7:12])
        r.npub, r.nout, r.V = dst.size, self.nout, self._dense_scratch.ctypes.data
        r.nvr = vrs.size
        function = ctypes.cast(self.library.mbd_fixed_step, ctypes.c_void_p).value
        armed = (function, self.address, ctypes.addressof(r))
        if inputs is None:
            return armed
        return (*armed, ctypes.cast(self.library.mbd_fixed_set, ctypes.c_void_p).value)

    def motion_table(self, constraint_set):
        """``motion_table(constraint_set)``, kept while the set and its motions are the
        same objects (``fixed_advance`` keeps its arrays for the same table)."""
        key = (constraint_set, constraint_set.motion_rows)
        kept = getattr(self, "_table", None)
        if kept is None or kept[0][0] is not key[0] or kept[0][1] is not key[1]:
            kept = self._table = (key, motion_table(constraint_set))
        return kept[1]

    def fixed_advance(self, run: dict, table, offsets, uf, audit, grid: tuple, k: int,
                      pause: int) -> tuple:
        """Turns of ``Integrator._advance_fixed``'s loop in C (``mbd_fixed_advance``) from
        grid step k (``grid``: t0, step, steps, end) until one ends at or past ``pause``:
        ``run`` with tol, max_iter, divergence and roundoff (the energy check's), q, qd, f
        and ``estimate`` (``Estimate``'s fields); the drivers' motion ``table``, the
        constraints' ``offsets`` and the held force inputs ``uf`` as ``arm_fixed_steps``
        takes them; ``audit`` the energy check's 13 values, or None. The run's arrays are
        kept from call to call for the same table. Returns (status, k, the turn's last
        step, q, q', f, ``Estimate``'s fields, the audit's values)."""
        kept = getattr(self, "_advance", None)
        if kept is None or kept[0] is not table:
            state = np.zeros(AUDIT_SIZE)
            r, _, arrays = self._fixed_struct(dict(y=np.zeros(2 * self.n),
                                                   f=np.zeros(2 * self.n),
                                                   estimate={}), table, offsets, uf,
                                              (state, np.zeros(2, dtype=np.int64)))
            r.audit = state.ctypes.data
            function = self.library.mbd_fixed_advance
            function.argtypes = [_P, _P, _D, _D, _I, _D, _I, _P, _P]
            kept = self._advance = (table, r, arrays, function, ctypes.addressof(r))
        _, r, arrays, function, address = kept
        n, nf = self.n, self.nf
        arrays[3][:] = offsets
        if nf:
            arrays[4][:] = np.tile(uf, 4)
        y, state, counts = arrays[5], arrays[7], arrays[8]
        y[:n], y[n:2 * n], y[2 * n:4 * n] = run["q"], run["qd"], run["f"]
        state[:] = audit if audit is not None else 0.0
        estimate = Estimate(**run["estimate"])
        r.est, r.tol, r.max_iter = ctypes.addressof(estimate), run["tol"], run["max_iter"]
        r.divergence, r.roundoff = run["divergence"], run["roundoff"]
        counts[:] = k
        t0, step, steps, end = grid
        status = function(self.address, address, t0, step, steps, end, pause,
                          counts.ctypes.data, counts.ctypes.data + 8)
        return (status, int(counts[0]), int(counts[1]), y[:n].copy(), y[n:2 * n].copy(),
                y[2 * n:4 * n].copy(), estimate_values(estimate), state)

    def fixed_taken(self):
        """What the wrapper did since arming or the last call: ((steps taken, t reached, y,
        f, ``Estimate``'s fields, the energy check's state, restarts after a set, the force
        inputs the last step held, the sampled drivers' states) or None without steps, and
        [(value reference, value)] of the inputs set since its last step). The run stays
        where the wrapper points until armed anew; the estimate's count of checks starts
        again."""
        r = self.fixed
        if r is None:
            return None, []
        a, nf = self._fixed_arrays, max(self.nf, 1)
        forces, vrs, slots, flags = a[4], a[9], a[10], a[11]
        pending = [(int(vr), float(forces[3 * nf + slot])) for vr, slot, flag in
                   zip(vrs, slots, flags) if flag]
        flags[:] = 0
        if r.steps == 0:
            return None, pending
        n2, y, estimate, audit = 2 * self.n, a[5], a[-1], a[13]
        steps, restarts, r.steps, r.restarts = int(r.steps), int(r.restarts), 0, 0
        values = estimate_values(estimate)
        estimate.checks = 0
        return (steps, float(r.t_now), y[:n2].copy(), y[n2:2 * n2].copy(), values,
                audit[:AUDIT_SIZE].copy(), restarts, forces[:self.nf].copy(),
                a[-2][:r.ndrv * DRV_SIZE].copy()), pending
