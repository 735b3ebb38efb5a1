"""An FMU's communication steps of an embedded pair that land on the communication point,
taken by its wrapper without Python (adaptive.h), with the force inputs the master sets
before each step taken by the wrapper too (``mbd_prk_set``); armed by the slave after a
Python step, read back when it catches up (``fmu_build/runtime/real_cache.py``
FastSteps).

``PrkSteps`` is a mixin of ``Kernel``: it uses the kernel's ``n``, ``m``, ``nf``, ``nout``,
``address``, ``library`` and ``_dense_scratch`` (the published values' buffer, shared with
the other fast steps: one kind is armed at a time).
"""

from __future__ import annotations

import ctypes
import functools

import numpy as np

from .dense import ST_OK
from .fixed import AUDIT_SIZE, DRV_SIZE, sampled_arrays, table_arrays
from .model import Carved, watch_events

_P, _I, _D = ctypes.c_void_p, ctypes.c_int64, ctypes.c_double


class PrkRun(ctypes.Structure):
    """adaptive.h's ``PrkRun``."""

    _fields_ = [("t_now", _D), ("time_tol", _D), ("h", _D), ("max_step", _D), ("ns", _I),
                ("A", _P), ("B", _P), ("E", _P), ("E3", _P), ("exponent", _D), ("safety", _D),
                ("min_factor", _D), ("max_factor", _D), ("beta", _D), ("err_old", _D),
                ("rtol", _D), ("atol", _D), ("tol", _D), ("max_iter", _I), ("indicator", _D),
                ("landing", _I), ("max_work", _I), ("motion", _P), ("motions", _P),
                ("ufs", _P), ("uf", _P), ("nvr", _I), ("vrs", _P), ("slots", _P), ("set", _P),
                ("changed", _I), ("uf_step", _P), ("y", _P), ("f", _P), ("y1", _P),
                ("f1", _P), ("K", _P), ("y_new", _P), ("f_new", _P), ("steps", _I),
                ("nsteps", _I), ("nrejected", _I), ("naccel", _I), ("nprojections", _I),
                ("nout", _I), ("npub", _I), ("pub_dst", _P), ("pub_src", _P), ("V", _P),
                ("stiff_limit", _D), ("kept", _P), ("nevent", _I), ("ev_int", _P),
                ("ev_real", _P), ("ev_g", _P), ("nmotion", _I), ("mrow", _P), ("mkind", _P),
                ("mcoef", _P), ("offsets", _P), ("fractions", _P), ("ndrv", _I),
                ("dslot", _I), ("dmot", _P), ("drv", _P), ("reinit_tol", _D),
                ("reinit_iter", _I), ("skip_end", _I)]


# How ``mbd_prk_run`` stopped (adaptive.h RUN_*).
RUN_DONE, RUN_PYTHON, RUN_WORK, RUN_ENERGY, RUN_FAILED = range(5)
# What the slave reads back: the counters, then the state's fields.
COUNTERS = ("nsteps", "nrejected", "naccel", "nprojections")


class PrkSteps:
    """The embedded pairs' fast steps of ``Kernel`` (see the module docstring)."""

    prk: PrkRun | None = None

    def start(self, q, qd, motion, uf):
        """(q'', the singularity indicator at q): ``accelerations`` and
        ``singularity_indicator`` in one call (a run's start), or None for the numpy path's
        case."""
        b = self.buf
        self._load(q, qd, motion, uf)
        if self._start(self.address, b.p_q, b.p_qd, b.p_motion, b.p_uf, b.p_qdd, b.p_lam,
                       b.p_err) != ST_OK:
            return None
        return b.qdd.copy(), float(b.err[0])

    def initial_step(self, y, f, motion, uf, tolerances: tuple, max_step: float,
                     order: int) -> float | None:
        """``starting_step.initial_step`` from y with y' = f, the inputs (motion: (c, c', c'');
        uf) held: its step (the same double), or None for the numpy path's case.
        ``tolerances``: (local factor, rtol, atol)."""
        b = self.buf
        b.y[:], b.f[:] = y, f
        self._load_inputs(motion, uf)
        if self._initial_step(self.address, b.p_y, b.p_f, b.p_motion, b.p_uf, *tolerances,
                              max_step, order, b.p_err) != ST_OK:
            return None
        return float(b.err[0])

    def arm_prk_steps(self, run: dict, tableau, inputs, pub_dst, pub_src,
                      events=None, motions=None) -> tuple:
        """Let an FMU's wrapper take an embedded pair's communication steps
        (``mbd_prk_fast_step``) from the state in ``run`` (PrkRun's scalar fields, and y, f,
        motion: (c, c', c'') and uf: the held force inputs), with ``tableau`` (ns and the
        addresses of A, B, E, E3: ``Kernel.tableau``) and ``inputs`` (value references and
        places in uf of the inputs fmi2SetReal may set here), publishing as
        ``DenseReads.arm_dense_steps`` does; in a scene with end stops or friction,
        ``events`` are the contact mode's event functions the steps watch
        (``ContactModes.c_events``). ``motions``: in a scene with drivers, (their motion
        table: ``fixed.motion_table``; the constraints' offsets; the stages' time fractions
        with 1 appended; the sampled drivers as ``arm_fixed_steps`` takes them, or None),
        and ``inputs`` may then name the sampled drivers' fields as there. Returns (the
        addresses of ``mbd_prk_fast_step``, of the model, of the PrkRun, of
        ``mbd_prk_set``)."""
        r = self.prk = PrkRun()
        n2, ns, nf = 2 * self.n, tableau[0], max(self.nf, 1)
        states = np.zeros(4 * n2)                        # y, f, y1, f1
        states[:n2], states[n2:2 * n2] = run.pop("y"), run.pop("f")
        motion = np.array(run.pop("motion"), dtype=float)
        table, offsets, fractions, drivers = motions if motions is not None else \
            ((0, *np.zeros((3, 1))), np.zeros(1), np.ones(1), None)
        ndrv, sampled = sampled_arrays(r, drivers, table[0])
        step_at = nf + 3 * ndrv                          # uf, the drivers' fields, uf_step
        uf = np.zeros(step_at + nf)
        uf[:self.nf] = uf[step_at:step_at + self.nf] = run.pop("uf")
        vrs, slots = (np.ascontiguousarray(a, dtype=np.int64) for a in inputs)
        known = slots < step_at                          # no room for a driver not armed
        vrs, slots = vrs[known], slots[known]
        dst, src = (np.ascontiguousarray(a, dtype=np.int64) for a in (pub_dst, pub_src))
        size = self.library.mbd_fixed_kept_size
        size.restype, size.argtypes = _I, [_P]
        arrays = dict(motion=motion, motions=np.tile(motion, ns + 1), ufs=np.zeros((ns + 1) * nf),
                      uf=uf, vrs=vrs, slots=slots, set=np.zeros(max(vrs.size, 1), dtype=np.int64),
                      states=states, K=np.zeros((ns + 1) * n2), y_new=np.zeros(n2),
                      f_new=np.zeros(n2), pub_dst=dst, pub_src=src,
                      kept=np.zeros(size(self.address)),           # nothing kept yet
                      table=table_arrays(r, table, offsets),
                      fractions=np.ascontiguousarray(fractions, dtype=float), sampled=sampled)
        arrays["events"] = watch_events(r, events)
        self._prk_arrays = arrays                       # what r points at
        for name, value in run.items():
            setattr(r, name, value)
        r.ns, r.A, r.B, r.E, r.E3 = tableau[0], *(x or 0 for x in tableau[1:5])
        for name in ("motion", "motions", "ufs", "uf", "vrs", "slots", "set", "K", "y_new",
                     "f_new", "pub_dst", "pub_src", "kept", "fractions"):
            setattr(r, name, arrays[name].ctypes.data)
        r.dslot = nf
        r.uf_step = uf.ctypes.data + 8 * step_at
        base = states.ctypes.data
        r.y, r.f, r.y1, r.f1 = base, base + 8 * n2, base + 16 * n2, base + 24 * n2
        r.nvr, r.npub, r.nout = vrs.size, dst.size, self.nout
        r.V = self._dense_scratch.ctypes.data
        step = ctypes.cast(self.library.mbd_prk_fast_step, ctypes.c_void_p).value
        setter = ctypes.cast(self.library.mbd_prk_set, ctypes.c_void_p).value
        return step, self.address, ctypes.addressof(r), setter

    def stiff_h_lambda(self, tableau, K, y, h: float) -> float:
        """Hairer's h |lambda| of an embedded pair's step (``auto_watch.stiffness``) as
        adaptive.h computes it for the wrapper's steps: ``tableau`` from ``Kernel.tableau``,
        K its stages ((ns + 1) rows, the last f at the unprojected end), from y over h."""
        function = self.library.mbd_stiff_h_lambda
        if function.restype is not ctypes.c_double:
            function.argtypes = [_I, _P, _P, _I, _P, _P, _D]
            function.restype = ctypes.c_double
        K = np.ascontiguousarray(K, dtype=float)
        y = np.ascontiguousarray(y, dtype=float)
        return float(function(tableau[0], tableau[1], tableau[2], y.size, K.ctypes.data,
                              y.ctypes.data, h))

    def prk_taken(self):
        """What the wrapper did since arming or the last call: (steps it took, then the
        state for ``c_steps.adopt_prk_run`` or None without steps, and [(value reference,
        value)] of the inputs set since its last step). The counts start again; the run
        stays where the wrapper points until armed anew."""
        r = self.prk
        if r is None:
            return 0, None, []
        a, n2, step_at = self._prk_arrays, 2 * self.n, max(self.nf, 1) + 3 * r.ndrv
        pending = [(int(vr), float(a["uf"][slot])) for vr, slot, flag in
                   zip(a["vrs"], a["slots"], a["set"]) if flag]
        a["set"][:] = 0
        if r.steps == 0:
            return 0, None, pending
        state = dict(t=float(r.t_now), h=float(r.h), err_old=float(r.err_old),
                     indicator=float(r.indicator),
                     landing=bool(r.landing), y=a["states"][:n2].copy(),
                     f=a["states"][n2:2 * n2].copy(),
                     uf=a["uf"][step_at:step_at + self.nf].copy(),
                     counters={k: int(getattr(r, k)) for k in COUNTERS},
                     drivers=a["sampled"][1][:r.ndrv * DRV_SIZE].copy())
        steps = int(r.steps)
        r.steps = r.nsteps = r.nrejected = r.naccel = r.nprojections = 0
        return steps, state, pending


class PrkPy(ctypes.Structure):
    """adaptive.h's ``PrkPy``: a ``PrkRun`` and what Python's step loop adds to it."""

    _fields_ = [("r", PrkRun), ("t", _D), ("t_target", _D), ("dense", _I), ("rejections", _I),
                ("energy_rejected", _D), ("audit", _P), ("step_factor", _D),
                ("min_gain", _D), ("jump_limit", _D), ("divergence", _D), ("roundoff", _D),
                ("t_old", _D), ("h_old", _D), ("y_old", _P), ("y_end", _P), ("K_old", _P),
                ("stepped", _I), ("ngaps", _I), ("gap_mid", _P), ("gap_width", _P),
                ("cpu_limit", _D), ("cpu_start", _D), ("undo", _P), ("coming", _D)]


class PrkRunBuffers(Carved):
    """The arrays a ``PrkPy`` points at, for one tableau: y, f (the state, in place), the
    stage inputs, the trial's stages and results, the last accepted step and the audit;
    ``driven``: with drivers, the motion table's arrays and the stages' time fractions."""

    def __init__(self, n: int, m: int, nf: int, ns: int):
        super().__init__(_run_shapes(n, m, nf, ns))
        self.driven: tuple | None = None


@functools.lru_cache(maxsize=16)
def _run_shapes(n: int, m: int, nf: int, ns: int) -> tuple:
    n2 = 2 * n
    return (("y", (n2,)), ("f", (n2,)), ("y_new", (n2,)), ("f_new", (n2,)), ("y_old", (n2,)),
            ("y_end", (n2,)), ("K", (ns + 1, n2)), ("K_old", (ns + 1, n2)),
            ("motions", (ns + 1, 3 * m)), ("ufs", (ns + 1, max(nf, 1))), ("audit", (AUDIT_SIZE,)))


# The gaps' arrays (singular_zone.gaps) with their count and addresses, by the first
# array's identity: held here, so that identity stays theirs
_GAP_POINTERS: dict = {}


def gap_pointers(gaps) -> tuple:
    """(count, address of the middles, of the widths) of ``gaps``."""
    key = id(gaps[0])
    if key not in _GAP_POINTERS:
        arrays = [np.ascontiguousarray(a, dtype=float) for a in gaps]
        _GAP_POINTERS[key] = (arrays, arrays[0].size, *(a.ctypes.data for a in arrays))
    return _GAP_POINTERS[key][1:]


def point_run(p: PrkPy, b: PrkRunBuffers, tableau, gaps) -> None:
    """Point p at the arrays of b, the pair ``tableau`` (``Kernel.tableau``) and the gaps
    between its nodes (``singular_zone.gaps``)."""
    r = p.r
    r.ns, r.A, r.B, r.E, r.E3 = tableau[0], *(x or 0 for x in tableau[1:5])
    r.y, r.f, r.K, r.y_new, r.f_new = b.p_y, b.p_f, b.p_K, b.p_y_new, b.p_f_new
    r.motions = r.motion = b.p_motions
    r.ufs = b.p_ufs
    p.y_old, p.y_end, p.K_old = b.p_y_old, b.p_y_end, b.p_K_old
    p.ngaps, p.gap_mid, p.gap_width = gap_pointers(gaps)


def prk_run(kernel, tableau, gaps, settings: dict, y, f, motion, audit, motions=None,
            forces=None):
    """Steps of an embedded pair in one call of ``mbd_prk_run`` (adaptive.h) from (y, f) at
    ``settings["t"]``: PrkPy's scalar fields (and PrkRun's, ``settings["run"]``), the
    middles and widths of the gaps between the tableau's nodes (``singular_zone.gaps``), the
    stage inputs ``motion`` ((c, c', c'')), constant unless ``motions`` (the drivers'
    motion table, ``fixed.motion_table``; the constraints' offsets; the stages' time
    fractions with 1 appended) evaluates them at every stage's time, the energy audit's
    state (13 values, updated in place) or None, and the force inputs, held over the run
    (``forces``, nf values; None without). Returns (status, the PrkPy, its buffers):
    the state in buffers.y / .f, the last accepted step in .y_old, .y_end, .K_old."""
    key = tableau[0]
    cache = kernel.__dict__.setdefault("_prk_run", {})
    if key not in cache:
        p = PrkPy()
        b = PrkRunBuffers(kernel.n, kernel.m, kernel.nf, key)
        point_run(p, b, tableau, gaps)
        cache[key] = (p, b, kernel.library.mbd_prk_run)     # types: declared at loading
    p, b, function = cache[key]
    b.y[:], b.f[:], b.motions[:] = y, f, motion
    b.ufs[:] = 0.0 if forces is None else forces       # every stage's row: held
    for name, value in settings.pop("run").items():
        setattr(p.r, name, value)
    for name, value in settings.items():
        setattr(p, name, value)
    p.r.nsteps = p.r.nrejected = p.r.naccel = p.r.nprojections = 0
    p.stepped = 0
    if motions is None:
        p.r.nmotion = 0
    else:
        b.driven = (table_arrays(p.r, *motions[:2]),
                    np.ascontiguousarray(motions[2], dtype=float))
        p.r.fractions = b.driven[1].ctypes.data
    if audit is None:
        p.audit = None
    else:
        b.audit[:] = audit
        p.audit = b.p_audit
    status = function(kernel.address, ctypes.addressof(p))
    return status, p, b
