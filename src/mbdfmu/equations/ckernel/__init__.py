"""The C kernel: eq. (14), the projections, whole steps of the projected explicit methods
and the output vector, compiled from ``kernel.c`` (a translation of the numpy code of this
layer, function by function: see its header) and called through ctypes.

``Kernel(equations)`` lays a scene's index arrays, forces and output plan out once, in a
C struct of pointers into arrays it keeps, with persistent buffers for arguments and
results, so a call copies a few small vectors and crosses into C once. Steps of genalpha and ali3p: ``implicit.py``. The library comes
from ``use_library(path)`` (an FMU's shipped copy), else ``$MBDFMU_C_KERNEL``, else
``build.compile_kernel()`` (the per-user cache; compiled on first use). The tests hold it
to the numpy kernel (tests/test_ckernel.py).
"""

from __future__ import annotations

import ctypes
import functools
import hashlib
import itertools
import os
from pathlib import Path

import numpy as np

from .dense import DENSE_KINDS, DenseReads  # noqa: F401 (DENSE_KINDS: public here)
from .adaptive import PrkSteps
from .dense_run import DenseRun, DenseRuns
from .fixed import FixedSteps
from .implicit import ImplicitCalls, declare_implicit
from .model import (SLIDE_COULOMB, SLIDE_DIRECTION, SLIDE_REALS, Model, _I, _P,  # noqa: F401
                    Carved, model_arrays, shared_model)  # (model_arrays: public here)

# Return codes of kernel.c (ST_*).
OK, SINGULAR, PROJECTION, NOT_FINITE, SPRING, ENERGY, ERROR_NORM, NEWTON = range(8)
# Stages of the largest tableau a trial step may have (DOP853's 12, plus its last row).
MAX_STAGES = 13
# Times whose inputs one call can take (a run of 64 rk4p steps evaluates 3 times each).
MAX_ROWS = 192
ENV_LIBRARY = "MBDFMU_C_KERNEL"
_D = ctypes.c_double
# kernel.c's entry points called through a Kernel, and their argument types (all return int)
_SIGNATURES = {
    "mbd_accelerations": [_P] * 8, "mbd_outputs": [_P] * 8, "mbd_state_outputs": [_P] * 8,
    "mbd_project_positions": [_P, _P, _P, _D, _I], "mbd_project_velocities": [_P] * 5,
    "mbd_singularity_indicator": [_P] * 4, "mbd_dense_state": [_P, _P, _D, _P],
    "mbd_initial_step": [_P] * 5 + [_D] * 4 + [_I, _P], "mbd_start": [_P] * 8,
    "mbd_rk4p_steps": [_P, _P, _P, _D, _I, _P, _I, _P, _I, _D, _I, _P, _D, _D, _P],
    "mbd_prk_trial": [_P, _I, _P, _P, _P, _P, _D, _P, _P, _P, _P, _D, _D, _D, _I, _P, _P, _P,
                      _P],
    "mbd_mc_trial": [_P, _P, _I, _P, _P, _P, _P, _D, _P, _P, _P, _P, _D, _D, _D, _I, _P, _P,
                     _P, _P],
    "mbd_prk_trial_near": [_P, _I, _P, _P, _P, _P, _D, _P, _P, _P, _P, _D, _D, _D, _I, _P, _P,
                           _P, _P, _D, _P, _I]}

_library_path: str | None = None
_library = None
# Embedded pairs' tableaus as the kernel reads them, by key (Kernel.tableau): the arrays and
# their addresses, alive as long as the process
_TABLEAUS: dict = {}


def use_library(path) -> None:
    """Take the kernel from this compiled file (an FMU's shipped copy)."""
    global _library_path, _library
    _library_path, _library = str(path), None


# Kernels built for one scene (scene_kernel.py), most recent first: a Kernel whose Model has
# the structure one was built for takes it, any other the generic library.
_scene_libraries: list = []


def use_scene_library(path) -> None:
    """Offer this kernel built for one scene (an FMU's shipped copy, or
    ``specialize``'s) to every ``Kernel`` of its structure made from now on (once per
    content: each instance of an FMU offers its extracted copy again)."""
    digest = hashlib.sha256(Path(path).read_bytes()).hexdigest()
    if any(lib.digest == digest for lib in _scene_libraries):
        return
    lib = ctypes.CDLL(str(Path(path)))
    _prepare(lib)
    lib.digest = digest
    _scene_libraries.insert(0, lib)


def specialize(eq) -> Path | None:
    """Compile (once per content) the kernel built for the structure of ``eq`` (an
    ``Equations``) and use it for every Kernel of that structure made from now on; its
    path, or None where the scene is too large for it to pay (scene_kernel.scene_header)."""
    from .scene_kernel import compile_scene_kernel
    path = compile_scene_kernel(eq)
    if path is not None:
        use_scene_library(path)
    return path


def library_for(address: int):
    """The library for the Model at ``address``: a scene's own where one was built for its
    structure, else the generic one."""
    for lib in _scene_libraries:
        if lib.mbd_structure_check(address):
            return lib
    return library()


def _prepare(lib) -> None:
    """Declare the argument and return types of a loaded library's entry points."""
    lib.mbd_work_size.restype, lib.mbd_work_size.argtypes = _I, [_P, _I]
    lib.mbd_memo_size.restype, lib.mbd_memo_size.argtypes = _I, [_P]
    lib.mbd_structure_check.restype, lib.mbd_structure_check.argtypes = _I, [_P]
    _declare(lib, _SIGNATURES, ctypes.c_int)     # once per library, not per Kernel
    _declare(lib, {"mbd_constraints": [_P] * 7,
                   "mbd_rk45_dense": [_I, _I, _I, _P, _P, _P]}, None)
    _declare(lib, {"mbd_dop853_dense": [_P] * 4 + [_D] + [_P] * 7,
                   "mbd_prk_run": [_P, _P]}, ctypes.c_int)
    declare_implicit(lib)


def library():
    """The loaded kernel library (see the module docstring for where it comes from)."""
    global _library
    if _library is None:
        path = _library_path or os.environ.get(ENV_LIBRARY)
        if not path:
            from .build import compile_kernel   # the compiler only when nothing was given
            path = compile_kernel()
        lib = ctypes.CDLL(str(Path(path)))
        _prepare(lib)
        _library = lib
    return _library


def _declare(lib, signatures: dict, restype) -> None:
    """Set the argument types of the library's functions (``{name: argtypes}``)."""
    for name, argtypes in signatures.items():
        function = getattr(lib, name)
        function.argtypes, function.restype = argtypes, restype


def available() -> bool:
    """The kernel can be loaded (or compiled) here."""
    try:
        library()
    except Exception:   # noqa: BLE001 - any reason means: not here
        return False
    return True


class Buffers(Carved):
    """The persistent arrays of one kernel, and their addresses (``p_<name>``): arguments
    and results are copied in and out, so a call passes addresses known beforehand."""

    def __init__(self, n: int, m: int, nf: int, nout: int):
        super().__init__(_buffer_shapes(n, m, nf, nout))
        self.done = self.done.view(np.int64)     # an int64 flag in a double's place
        self._row_shapes = (MAX_ROWS, 3 * m), (MAX_ROWS, max(nf, 1))

    @functools.cached_property
    def _rows(self) -> tuple:
        """(motions, ufs, their addresses): the inputs at each time a run of steps or a trial
        evaluates ((c, c', c'') and the force inputs, one row each), MAX_ROWS rows, nine
        tenths of the buffers: made at the first such call, as a run of the embedded pairs
        has its own (``PrkRunBuffers``) and most kernels never make one."""
        (rows, width), (_, nf) = self._row_shapes
        block = np.zeros(rows * (width + nf))
        base = block.ctypes.data
        return (block[:rows * width].reshape(rows, width), block[rows * width:].reshape(rows, nf),
                base, base + 8 * rows * width)

    motions = property(lambda self: self._rows[0])
    ufs = property(lambda self: self._rows[1])
    p_motions = property(lambda self: self._rows[2])
    p_ufs = property(lambda self: self._rows[3])


@functools.lru_cache(maxsize=16)
def _buffer_shapes(n: int, m: int, nf: int, nout: int) -> tuple:
    return (("q", (n,)), ("qd", (n,)), ("motion", (3 * m,)), ("uf", (max(nf, 1),)),
            ("qdd", (n,)), ("lam", (max(m, 1),)), ("y", (2 * n,)), ("f", (2 * n,)),
            ("y_new", (2 * n,)), ("f_new", (2 * n,)), ("K", (MAX_STAGES * 2 * n,)), ("err", (2,)),
            ("audit", (13,)), ("out", (nout,)), ("done", (1,)))


class Kernel(DenseReads, DenseRuns, FixedSteps, PrkSteps, ImplicitCalls):
    """The C kernel bound to one scene's ``Equations``; every method returns None where
    kernel.c hands the case back to the numpy path (a singular Schur complement, a spring
    of zero length), which then says or does what it always does."""

    def __init__(self, eq):
        self.n, self.m, self.nf = eq.n, eq.m, eq.layout.size
        self._size = eq.pattern.size
        shared = shared_model(eq)
        self._weights = (np.asarray(eq.minv, dtype=float), shared.pair_cols)
        self._partition: tuple | None = None
        self.nout = shared.nout
        self._arrays = list(shared.blocks)      # what the Model points into, and more
        model = Model.from_buffer_copy(shared.template)
        self.model, self.address = model, ctypes.addressof(model)
        lib = library_for(self.address)
        self.scene_built = lib in _scene_libraries    # the kernel built for this structure
        # the dense read (dense.h) heads the dense run (dense_run.h): one address for both
        self.run = DenseRun()
        self.dense, self._dense_arrays, self._publish = self.run.d, (), None
        # the work space, the kept evaluation, the dense reads' scratch and the sliding
        # friction's (friction.h: its last forces first): one allocation
        ns = shared.nslide
        sizes = (lib.mbd_work_size(self.address, MAX_STAGES), lib.mbd_memo_size(self.address),
                 self.nout + 3 * self.n + max(self.m, 1), 3 * ns + self.n + ns * self.n)
        block, ends = np.zeros(sum(sizes)), tuple(itertools.accumulate(sizes, initial=0))
        self.work, self.memo, self._dense_scratch, slide = (
            block[a:b] for a, b in zip(ends, ends[1:]))
        base = block.ctypes.data
        model.work, model.memo, self.dense.V = base, base + 8 * ends[1], base + 8 * ends[2]
        model.slide_f = base + 8 * ends[3]
        # the friction forces the last evaluation converged to (N or N m), first the guess
        # ModeEquations starts from: -direction x coulomb
        self.sliding_forces = slide[:ns]
        if ns:
            reals = np.asarray(shared.s_real).reshape(ns, SLIDE_REALS)
            self.sliding_forces[:] = -reals[:, SLIDE_DIRECTION] * reals[:, SLIDE_COULOMB]
        self.buf = Buffers(self.n, self.m, self.nf, self.nout)
        self.static_rows = 0          # rows of buf.motions holding a driverless scene's block
        self.library = lib
        self._bind(lib)
        self._bind_implicit(lib)

    def _bind(self, lib) -> None:
        # the entry points as attributes (_accelerations, ...), gathered once per library
        # (their argument types: set when it was loaded)
        if not hasattr(lib, "bound"):
            lib.bound = {"_" + name[4:]: getattr(lib, name) for name in _SIGNATURES}
        self.__dict__.update(lib.bound)

    def forget(self) -> None:
        """Drop the kept evaluation (the next accelerations call computes anew)."""
        self.memo[0] = 0.0

    def _load(self, q, qd, motion, uf) -> None:
        b = self.buf
        b.q[:] = q
        b.qd[:] = qd
        self._load_inputs(motion, uf)

    def _load_inputs(self, motion, uf) -> None:
        """The rows' motions (c, c', c'') and the force inputs (None: as they are)."""
        b, m = self.buf, self.m
        b.motion[:m], b.motion[m:2 * m], b.motion[2 * m:] = motion
        if uf is not None:
            b.uf[:self.nf] = uf

    def accelerations(self, q, qd, motion, uf):
        """(q'', lam) of eq. (14); motion: (c, c', c'') of every row; uf: force inputs."""
        b = self.buf
        self._load(q, qd, motion, uf)
        if self._accelerations(self.address, b.p_q, b.p_qd, b.p_motion, b.p_motion + 16 * self.m,
                               b.p_uf, b.p_qdd, b.p_lam) != OK:
            return None
        return b.qdd.copy(), b.lam[:self.m].copy()

    def outputs(self, q, qd, qdd, lam, motion, uf):
        """The vector of ``Equations.output_values`` (a copy)."""
        b = self.buf
        self._load(q, qd, motion, uf)
        b.lam[:self.m] = lam
        if self._outputs(self.address, b.p_q, b.p_qd, b.p_qdd, b.p_lam, b.p_motion, b.p_uf,
                         b.p_out) != OK:
            return None
        return b.out.copy()

    def project(self, q, qd, motion, tol, max_iter):
        """(q, q') projected onto the constraints (positions to ``tol``, then velocities;
        ``projection.project_positions`` / ``project_velocities``), or None when the numpy
        path must do it (no convergence, a singular Schur complement: it says why)."""
        b, m = self.buf, self.m
        self._load(q, qd, motion, None)
        if self._project_positions(self.address, b.p_q, b.p_motion, tol, max_iter) != OK or \
                self._project_velocities(self.address, b.p_q, b.p_qd, b.p_motion,
                                         b.p_motion + 8 * m) != OK:
            return None
        return b.q.copy(), b.qd.copy()

    def project_velocities(self, q, qd, motion):
        """q' projected onto Psi_q q' = nu at q (``projection.project_velocities``), or None
        when the numpy path must do it (a singular Schur complement)."""
        b, m = self.buf, self.m
        self._load(q, qd, motion, None)
        if self._project_velocities(self.address, b.p_q, b.p_qd, b.p_motion,
                                    b.p_motion + 8 * m) != OK:
            return None
        return b.qd.copy()

    def constraint_values(self, q, qd, c):
        """(Psi, Psi_q's merged values, gamma without c'', or None without qd) at (q, q'),
        c the rows' motions: ``ConstraintSet.values`` computed in C (its own arrays: the
        buffers hold what a run or a dense read left)."""
        m = self.m
        q, c = np.ascontiguousarray(q, dtype=float), np.ascontiguousarray(c, dtype=float)
        qd = None if qd is None else np.ascontiguousarray(qd, dtype=float)
        psi, data, gamma = np.empty(max(m, 1)), np.empty(self._size + 1), np.empty(max(m, 1))
        self.library.mbd_constraints(self.address, q.ctypes.data,
                                     None if qd is None else qd.ctypes.data,
                                     c.ctypes.data if m else None, psi.ctypes.data,
                                     data.ctypes.data, gamma.ctypes.data)
        return psi[:m], data[:self._size], None if qd is None else gamma[:m]

    def singularity_indicator(self, q, motion) -> float:
        """``singular.singularity_indicator`` of Psi_q at q (motion: (c, c', c''))."""
        b = self.buf
        self._load(q, b.qd, motion, None)
        self._singularity_indicator(self.address, b.p_q, b.p_motion, b.p_err)
        return float(b.err[0])

    def state_outputs(self, q, qd, motion, uf):
        """(outputs, q'', lam) at (q, q'): the output vector with q'' and lam of eq. (14) at
        that state (those the last step computed when it ended there), in one call. None:
        the numpy path's case."""
        b = self.buf
        self._load(q, qd, motion, uf)
        if self._state_outputs(self.address, b.p_q, b.p_qd, b.p_motion, b.p_uf, b.p_qdd, b.p_lam,
                               b.p_out) != OK:
            return None
        return b.out.copy(), b.qdd.copy(), b.lam[:self.m].copy()

    def rk4p_steps(self, q, qd, qdd, h, steps, tol, max_iter, audit, divergence, roundoff):
        """``steps`` steps of rk4p (``mbd_rk4p_steps``) with the inputs the caller put in
        ``buf.motions`` / ``buf.ufs``: rows 3k .. 3k + 2 at t, t + h/2, t + h of step k;
        audit: the energy check's state (13 values, updated). Returns (q, q', q'', steps
        done, status)."""
        b, n = self.buf, self.n
        b.y[:n], b.y[n:], b.f[:n], b.f[n:] = q, qd, qd, qdd
        b.audit[:] = audit
        status = self._rk4p_steps(self.address, b.p_y, b.p_f, h, steps, b.p_motions, 9 * self.m,
                                  b.p_ufs, 3 * self.nf, tol, max_iter, b.p_audit, divergence,
                                  roundoff, b.p_done)
        return b.y[:n].copy(), b.y[n:].copy(), b.f[n:].copy(), int(b.done[0]), status

    def tableau(self, key, A, B, E, E3) -> tuple:
        """An embedded pair's (stages, addresses of A, B, E, E3): the arrays laid out once
        per ``key`` in the process, for every Kernel (they are read only)."""
        if key not in _TABLEAUS:
            arrays = [None if x is None else np.ascontiguousarray(x, dtype=float)
                      for x in (A, B, E, E3)]
            _TABLEAUS[key] = (arrays, (arrays[1].size, *(None if x is None else x.ctypes.data
                                                         for x in arrays)))
        return _TABLEAUS[key][1]

    def prk_trial_near(self, tableau, h, q, qd, f0, rtol, atol, tol, max_iter, c0,
                       end_rhs=True):
        """``prk_trial`` that also returns the singularity indicator at the step's end
        (before the projection) and, near a singular configuration (c0, the indicator at
        the start, or that one below ``singular_zone.NEAR_ZONE``), estimates the error
        along the constraints (``mbd_prk_trial_near``): (status, err, y_new, f_new, c1).
        ``end_rhs`` False: y' at the unprojected end is not evaluated (0 in its place)."""
        b, n = self.buf, self.n
        b.y[:n], b.y[n:] = q, qd
        b.f[:] = f0
        status = self._prk_trial_near(self.address, *tableau, h, b.p_y, b.p_f, b.p_motions,
                                      b.p_ufs, rtol, atol, tol, max_iter, b.p_y_new, b.p_f_new,
                                      b.p_err, b.p_K, c0, b.p_err + 8, int(end_rhs))
        return status, float(b.err[0]), b.y_new.copy(), b.f_new.copy(), float(b.err[1])

    def prk_trial(self, tableau, h, q, qd, f0, rtol, atol, tol, max_iter):
        """The arithmetic of one step of an embedded pair (``mbd_prk_trial``) with the
        inputs in ``buf.motions`` / ``buf.ufs`` (row s: stage s; row ns: t + h), from
        (q, q') with f0 = y' there; tableau from ``tableau``. Returns (status, err, y_new,
        f_new)."""
        b, n = self.buf, self.n
        b.y[:n], b.y[n:] = q, qd
        b.f[:] = f0
        status = self._prk_trial(self.address, *tableau, h, b.p_y, b.p_f, b.p_motions,
                                 b.p_ufs, rtol, atol, tol, max_iter, b.p_y_new, b.p_f_new,
                                 b.p_err, b.p_K)
        return status, float(b.err[0]), b.y_new.copy(), b.f_new.copy()

    def partition(self, independent: np.ndarray) -> int:
        """The model of minimal coordinates with ``independent`` (bool, n) held: this one
        with zero weight on them in the projections, so that a projection solves for the
        dependent coordinates alone. Kept until the mask changes; returns its address."""
        key = np.asarray(independent, dtype=bool).tobytes()
        if self._partition is None or self._partition[0] != key:
            minv, pair_cols = self._weights
            weights = np.where(np.frombuffer(key, dtype=bool), 0.0, minv)
            pair = np.ascontiguousarray(weights[pair_cols])
            model = Model()
            ctypes.pointer(model)[0] = self.model          # a copy of every field
            model.minv, model.pair_minv = weights.ctypes.data, pair.ctypes.data
            self._partition = (key, model, weights, pair)
        return ctypes.addressof(self._partition[1])

    def mc_trial(self, partition, tableau, h, q, qd, f0, rtol, atol, tol, max_iter):
        """``prk_trial`` in minimal coordinates (``mbd_mc_trial``) with the model of
        ``partition``: (status, err, y_new, f_new)."""
        b, n = self.buf, self.n
        b.y[:n], b.y[n:] = q, qd
        b.f[:] = f0
        status = self._mc_trial(self.address, partition, *tableau, h, b.p_y, b.p_f,
                                b.p_motions, b.p_ufs, rtol, atol, tol, max_iter, b.p_y_new,
                                b.p_f_new, b.p_err, b.p_K)
        return status, float(b.err[0]), b.y_new.copy(), b.f_new.copy()
