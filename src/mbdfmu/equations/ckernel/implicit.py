"""Steps of the implicit index-3 methods in the C kernel (implicit.h): genalpha's and
ali3p's attempts with newton.py's iteration on the banded Schur complement, whole runs of
their fixed steps and of their controlled steps (implicit_run.h), and the kept iteration
matrix's solve.

``ImplicitCalls`` is a mixin of ``Kernel``: it uses the kernel's ``n``, ``m``, ``nf``,
``buf``, ``address``, ``library`` and ``_arrays``.
"""

from __future__ import annotations

import ctypes
import functools
import itertools

import numpy as np

from .fixed import Estimate, estimate_values, table_arrays

_P, _I, _D = ctypes.c_void_p, ctypes.c_int64, ctypes.c_double
# Doubles of room for the energy audit's state in a run's buffers (c_steps.AUDIT_FIELDS: 13)
AUDIT_ROOM = 16
METHODS = {"genalpha": 0, "ali3p": 1}
# implicit.h's NF_* reasons of a failed Newton iteration
NEWTON_REASONS = {1: "non-finite residual", 2: "non-finite iteration matrix",
                  3: "non-finite Newton increment", 4: "Newton diverges"}


class Implicit(ctypes.Structure):
    """implicit.h's ``Implicit``: a method's settings, newton.py's constants, counters."""

    _fields_ = [(name, _I) for name in ("method", "jacobian_full", "count_multipliers",
                                        "max_iter")] + \
        [(name, _D) for name in ("am", "af", "beta", "gamma", "penalty_base", "alpha", "atol",
                                 "length_scale", "roundoff", "atol_max", "tol_floor", "t_ref",
                                 "noise_max", "near_indicator", "near_floor", "t_near", "slow_rate",
                                 "diverging_rate", "singular_pivot", "dense_below", "h_fine")] + \
        [("periodic", _P), ("blocks", _I), ("nbp", _I), ("fd_step", _D), ("bp_a", _P),
         ("bp_b", _P), ("bp_band", _P), ("bp_w", _P)] + \
        [(name, _I) for name in ("nnewton", "njev", "nlu", "nprojections", "reason")] + \
        [(name, _D) for name in ("last_size", "last_residual", "last_tol")] + \
        [("dense", _I), ("fd", _I)]


class ImpRun(ctypes.Structure):
    """implicit_run.h's ``ImpRun``: a run of controlled steps, its counters, its buffers."""

    _fields_ = [(name, _D) for name in ("t", "t_target", "h", "max_step", "share_tol",
                                        "safety", "max_growth", "max_cut", "keep_growth")] + \
        [(name, _I) for name in ("max_work", "rejections", "nsteps", "nrejected", "stepped")] + \
        [("divergence", _D), ("roundoff", _D)] + \
        [(name, _P) for name in ("y", "x", "motion", "uf", "audit", "work")] + \
        [("nmotion", _I), ("mrow", _P), ("mkind", _P), ("mcoef", _P), ("offsets", _P)]


class ImpFast(ctypes.Structure):
    """implicit_run.h's ``ImpFast``: an FMU's communication steps of a run of controlled steps."""

    _fields_ = [("run", ImpRun), ("p", _P), ("kept", _P), ("nkept", _I), ("naudit", _I),
                ("t_now", _D), ("time_tol", _D), ("max_work", _I), ("save", _P), ("y2", _P),
                ("steps", _I), ("nsteps", _I), ("nrejected", _I), ("restarts", _I),
                ("nout", _I), ("npub", _I), ("pub_dst", _P), ("pub_src", _P), ("V", _P),
                ("nvr", _I), ("vrs", _P), ("slots", _P), ("set", _P), ("changed", _I),
                ("uf_step", _P), ("tol", _D), ("max_iter", _I),
                ("fixed", _I), ("h_max", _D), ("slack", _D), ("same_step", _D), ("est", _P),
                ("check", _P)]


def fill_fast(f: ImpFast, settings: dict) -> Estimate:
    """ImpFast's scalar ``settings`` into f, the rest into its ImpRun; the stated accuracy's
    ``estimate`` (a fixed step's) into a new ``Estimate`` that f points at, returned."""
    for name in ("t_now", "time_tol", "max_work", "tol", "max_iter", "fixed", "h_max",
                 "slack", "same_step"):
        setattr(f, name, settings.pop(name, 0))
    estimate = Estimate()
    for name, value in settings.pop("estimate", {}).items():
        setattr(estimate, name, value)
    f.est = ctypes.addressof(estimate)
    for name, value in settings.items():
        setattr(f.run, name, value)
    return estimate


def declare_implicit(lib) -> None:
    """The argument and return types of implicit.h's entry points (once per library)."""
    signatures = {"mbd_implicit_kept_size": ([_P], _I),
                  "mbd_implicit_dense_kept_size": ([_P], _I),
                  "mbd_implicit_solve": ([_P] * 5, ctypes.c_int),
                  "mbd_implicit_attempt": ([_P, _P, _P, _P, _D, _P, _P, _P], ctypes.c_int),
                  "mbd_implicit_steps": ([_P, _P, _P, _P, _D, _I, _P, _P, _I, _P, _D, _D,
                                          _P, _P], ctypes.c_int),
                  "mbd_implicit_run": ([_P] * 4, ctypes.c_int),
                  "mbd_implicit_fast_step": ([_P, _P, _D, _D, _P], ctypes.c_int),
                  "mbd_implicit_set": ([_P, _P, ctypes.c_size_t, _P, _P], ctypes.c_int)}
    for name, (argtypes, restype) in signatures.items():
        function = getattr(lib, name)
        function.argtypes, function.restype = argtypes, restype


class ImplicitCalls:
    """The implicit methods' calls of ``Kernel`` (see the module docstring)."""

    def _bind_implicit(self, lib) -> None:
        self._imp = lib          # its functions' types: declare_implicit, at loading

    @functools.cached_property
    def _imp_arrays(self) -> tuple:
        """(y, x, rhs, out, their addresses): made at the first implicit call, as most
        kernels never make one. One allocation, four parts."""
        n, m = self.n, self.m
        sizes = (5 * n + max(m, 1), 4 * n + max(m, 1), n + max(m, 1), n + max(m, 1))
        block = np.zeros(sum(sizes))
        starts = tuple(itertools.accumulate(sizes, initial=0))
        base = block.ctypes.data
        return (*(block[a:b] for a, b in zip(starts[:-1], starts[1:])),
                tuple(base + 8 * a for a in starts[:-1]))

    imp_y = property(lambda self: self._imp_arrays[0])
    imp_x = property(lambda self: self._imp_arrays[1])
    imp_rhs = property(lambda self: self._imp_arrays[2])
    imp_out = property(lambda self: self._imp_arrays[3])
    _imp_p = property(lambda self: self._imp_arrays[4])

    def implicit_settings(self, method: str, periodic, pattern=None, **values) -> Implicit:
        """An ``Implicit`` for ``method`` (a key of METHODS) with ``values`` by field name;
        with Psi_q's ``pattern`` (sparsity.JacobianPattern) K in 3 x 3 blocks per body."""
        p = Implicit()
        mask = np.ascontiguousarray(periodic, dtype=float)
        self._arrays.append(mask)
        p.method, p.periodic = METHODS[method], mask.ctypes.data
        for name, value in values.items():
            setattr(p, name, value)
        if pattern is not None:
            arrays = [np.ascontiguousarray(a, dtype=np.int64) for a in body_pairs(pattern)]
            self._arrays += arrays
            p.blocks, p.nbp = 1, arrays[0].size
            p.bp_a, p.bp_b, p.bp_band, p.bp_w = (a.ctypes.data for a in arrays)
        return p

    def kept_matrix(self, dense: bool = False) -> np.ndarray:
        """A fresh kept iteration matrix for implicit.h (not valid yet); ``dense``: with
        room for implicit_dense.h's LU."""
        size = self._imp.mbd_implicit_dense_kept_size if dense else self._imp.mbd_implicit_kept_size
        return np.zeros(size(self.address))

    def _load_state(self, qw, turns, qd, qdd, a, lam) -> None:
        n, y = self.n, self.imp_y
        y[:n], y[n:2 * n], y[2 * n:3 * n], y[3 * n:4 * n], y[4 * n:5 * n] = qw, turns, qd, qdd, a
        y[5 * n:5 * n + self.m] = lam

    def implicit_attempt(self, p: Implicit, kept, state, h, motion, uf):
        """One attempt over h from ``state`` = (q wrapped, turns, q', q'', a, lam) with the
        inputs at its end: (status, x = (dq, q', q'', a, lam) as views of one copy)."""
        self._load_state(*state)
        b, m = self.buf, self.m
        b.motion[:m], b.motion[m:2 * m], b.motion[2 * m:] = motion
        if uf is not None and self.nf:
            b.uf[:self.nf] = uf
        py, px = self._imp_p[:2]
        status = self._imp.mbd_implicit_attempt(self.address, ctypes.byref(p), kept.ctypes.data,
                                                py, h, b.p_motion, b.p_uf, px)
        return status, self._split(self.imp_x.copy())

    def _state_of(self, y):
        """A copy of y (5n + m) as the state ``implicit_attempt`` takes: (q wrapped, turns,
        q', q'', a, lam)."""
        n, y = self.n, y[:5 * self.n + self.m].copy()
        return y[:n], y[n:2 * n], y[2 * n:3 * n], y[3 * n:4 * n], y[4 * n:5 * n], y[5 * n:]

    def _run_buffers(self, r: ImpRun, uf_copies: int) -> tuple:
        """One array for an ImpRun's motion (3m), audit state (AUDIT_ROOM), work (3 (n +
        m)) and ``uf_copies`` rows of force inputs, r pointed at it: (the array, where the
        audit and the inputs start)."""
        n, m, nf = self.n, self.m, max(self.nf, 1)
        audit_at, uf_at = 3 * m, 3 * m + AUDIT_ROOM + 3 * (n + m)
        buffers = np.zeros(uf_at + uf_copies * nf)
        base = buffers.ctypes.data
        r.motion, r.work, r.uf = base, base + 8 * (audit_at + AUDIT_ROOM), base + 8 * uf_at
        return buffers, audit_at, uf_at

    def _split(self, x):
        n = self.n
        return x[:n], x[n:2 * n], x[2 * n:3 * n], x[3 * n:4 * n], x[4 * n:4 * n + self.m]

    def implicit_steps(self, p: Implicit, kept, state, h, count, audit, divergence, roundoff):
        """``count`` fixed steps with the inputs in ``buf.motions`` / ``buf.ufs`` (row k:
        the end of step k): (status, steps done, the new state as ``implicit_attempt``
        takes it)."""
        self._load_state(*state)
        b = self.buf
        b.audit[:] = audit
        status = self._imp.mbd_implicit_steps(
            self.address, ctypes.byref(p), kept.ctypes.data, self.imp_y.ctypes.data, h, count,
            b.p_motions, b.p_ufs, self.nf, b.p_audit, divergence, roundoff,
            self.imp_x.ctypes.data, b.p_done)
        return status, int(b.done[0]), self._state_of(self.imp_y)

    def implicit_run(self, p: Implicit, kept, state, settings: dict, motion, audit=None,
                     table=None) -> tuple:
        """Controlled steps from ``state`` (as ``implicit_attempt``) in one call of
        ``mbd_implicit_run``: ``settings`` are ImpRun's scalar fields by name, ``motion``
        the constraints' (c, c', c'') at every step's end, or, with ``table`` (the drivers'
        ``motion_table`` and the constraints' offsets), evaluated there; ``audit`` the energy
        audit's state or None. Returns (status, the ImpRun with its counters, the new state,
        the audit's state after it)."""
        m = self.m
        if "_imp_run" not in self.__dict__:
            r = ImpRun()
            r.y, r.x = self.imp_y.ctypes.data, self.imp_x.ctypes.data
            self._imp_run = (r, self._run_buffers(r, 1)[0])   # no force inputs in Python's runs
        r, buffers = self._imp_run
        self._load_state(*state)
        for name, value in settings.items():
            setattr(r, name, value)
        buffers[:3 * m] = np.concatenate(motion)
        r.nmotion = 0
        if table is not None:      # the arrays the run points at, kept with it
            self._imp_table = table_arrays(r, *table)
        audit_now = buffers[3 * m:3 * m + AUDIT_ROOM]
        r.audit = None if audit is None else audit_now.ctypes.data
        if audit is not None:
            audit_now[:len(audit)] = audit
        status = self._imp.mbd_implicit_run(self.address, ctypes.byref(p), kept.ctypes.data,
                                            ctypes.byref(r))
        return (status, r, self._state_of(self.imp_y),
                audit_now[:len(audit) if audit is not None else 0].copy())

    imp_fast: ImpFast | None = None

    def arm_implicit_steps(self, p: Implicit, kept, state, settings: dict, motion, uf,
                           audit, table, inputs, pub_dst, pub_src) -> tuple:
        """Let an FMU's wrapper take the coming communication steps as runs of controlled
        steps (``mbd_implicit_fast_step``) from ``state`` (as ``implicit_attempt``) at
        ``settings["t_now"]``, with the method's settings ``p`` (its counters add up until
        ``implicit_taken``) and its kept matrix ``kept`` (shared: the steps update it),
        ImpRun's scalar ``settings`` and ImpFast's (t_now, time_tol, max_work; tol,
        max_iter: the restart's projection), the motion and ``table`` as
        ``implicit_run``, the held force inputs ``uf``, the energy audit's state or None,
        ``inputs`` (value references and places in uf of the force inputs fmi2SetReal may
        set here: ``mbd_implicit_set``; none with an audit), publishing as
        ``DenseReads.arm_dense_steps`` does. A method at a fixed step gives its grid
        (``settings``' fixed, h_max, slack, same_step) and its stated accuracy's
        ``estimate`` (``Estimate``'s fields). Returns (the addresses of
        ``mbd_implicit_fast_step``, of the model, of the ImpFast, of ``mbd_implicit_set``
        or 0)."""
        n, m, nf = self.n, self.m, max(self.nf, 1)
        f = self.imp_fast = ImpFast()
        r = f.run
        ny, naudit = 5 * n + max(m, 1), 0 if audit is None else len(audit)
        y = np.zeros(2 * ny + 4 * n + max(m, 1))       # y, x (its first 4n + m), y2
        y[:ny] = np.concatenate((*state[:5], state[5], np.zeros(ny - 5 * n - m)))
        buffers, audit_at, uf_at = self._run_buffers(r, 2)     # uf, then the last step's
        buffers[:3 * m] = np.concatenate(motion)
        if audit is not None:
            buffers[audit_at:audit_at + naudit] = audit
        buffers[uf_at:uf_at + self.nf] = buffers[uf_at + nf:uf_at + nf + self.nf] = uf
        vrs, slots = (np.ascontiguousarray(a, dtype=np.int64) for a in inputs)
        flags = np.zeros(max(vrs.size, 1), dtype=np.int64)
        dst, src = (np.ascontiguousarray(a, dtype=np.int64) for a in (pub_dst, pub_src))
        save, check = np.zeros(ny + kept.size + 16), np.zeros(ny + kept.size + 2 * n)
        f.check = check.ctypes.data
        self._imp_fast_arrays = dict(y=y, buffers=buffers, dst=dst, src=src, save=save,
                                     check=check, kept=kept, p=p, vrs=vrs, slots=slots, set=flags,
                                     uf_at=uf_at, table=table_arrays(r, *table)
                                     if table is not None else None)
        if table is None:
            r.nmotion = 0
        self._imp_fast_arrays["estimate"] = fill_fast(f, settings)
        base = buffers.ctypes.data
        r.y, r.x, f.y2 = y.ctypes.data, y.ctypes.data + 8 * ny, y.ctypes.data + 16 * ny
        r.audit = None if audit is None else base + 8 * audit_at
        f.p, f.kept, f.nkept, f.naudit = ctypes.addressof(p), kept.ctypes.data, kept.size, naudit
        f.save, f.pub_dst, f.pub_src = save.ctypes.data, dst.ctypes.data, src.ctypes.data
        f.nout, f.npub, f.V = self.nout, dst.size, self._dense_scratch.ctypes.data
        f.nvr, f.vrs, f.slots, f.set = vrs.size, vrs.ctypes.data, slots.ctypes.data, \
            flags.ctypes.data
        f.uf_step = base + 8 * (uf_at + nf)
        step = ctypes.cast(self._imp.mbd_implicit_fast_step, ctypes.c_void_p).value
        setter = ctypes.cast(self._imp.mbd_implicit_set, ctypes.c_void_p).value
        return step, self.address, ctypes.addressof(f), setter if vrs.size else 0

    def implicit_taken(self) -> tuple[dict | None, list]:
        """What the wrapper's runs did since arming or the last call: (None without steps,
        else the state: t, the state as ``implicit_attempt`` takes it, h, the audit's
        state, the counters of accepted and rejected steps and of restarts, the force
        inputs the last step held; and [(value reference, value)] of the inputs set since
        its last step). The counts start again."""
        f = self.imp_fast
        if f is None:
            return None, []
        a, m, nf = self._imp_fast_arrays, self.m, max(self.nf, 1)
        uf_at = a["uf_at"]
        pending = [(int(vr), float(a["buffers"][uf_at + slot])) for vr, slot, flag in
                   zip(a["vrs"], a["slots"], a["set"]) if flag]
        a["set"][:] = 0
        if f.steps == 0:
            return None, pending
        audit = a["buffers"][3 * m:3 * m + f.naudit].copy()
        estimate = a["estimate"]
        taken = dict(t=float(f.t_now), h=float(f.run.h), audit=audit, nsteps=int(f.nsteps),
                     estimate=estimate_values(estimate) if f.fixed else None,
                     nrejected=int(f.nrejected), restarts=int(f.restarts),
                     uf=a["buffers"][uf_at + nf:uf_at + nf + self.nf].copy(),
                     state=self._state_of(a["y"]))
        f.steps = f.nsteps = f.nrejected = f.restarts = 0
        return taken, pending

    def implicit_solve(self, p: Implicit, kept, rhs) -> np.ndarray | None:
        """S^-1 rhs (n + m) with the kept iteration matrix; None when it is not valid."""
        size = self.n + self.m
        self.imp_rhs[:size] = rhs
        if self._imp.mbd_implicit_solve(self.address, ctypes.byref(p), kept.ctypes.data,
                                        *self._imp_p[2:]) != 0:
            return None
        return self.imp_out[:size].copy()


def body_pairs(pattern) -> tuple:
    """Every pair (a, b) of Psi_q's kept entries in one body's columns whose rows fall in
    the lower band (position of a's row >= b's, rows in the band's order): (a, b, band
    index, index of K^-1's entry 9 body + 3 c_a + c_b). Rows that share a body share its
    angle column, so the band of J M^-1 J^T holds them."""
    rows, cols, m = np.asarray(pattern.rows), np.asarray(pattern.cols), pattern.m
    position = np.empty(m, dtype=np.int64)
    position[np.asarray(pattern.perm)] = np.arange(m)
    out = ([], [], [], [])
    for body in np.unique(cols // 3):
        entries = np.flatnonzero(cols // 3 == body)
        a, b = (x.ravel() for x in np.meshgrid(entries, entries, indexing="ij"))
        i, j = position[rows[a]], position[rows[b]]
        lower = i >= j
        a, b, i, j = a[lower], b[lower], i[lower], j[lower]
        if np.any(i - j > pattern.kd):
            raise ValueError("rows sharing a body outside the band")
        for k, values in enumerate((a, b, (i - j) * m + j, 9 * body + 3 * (cols[a] % 3) + cols[b] % 3)):
            out[k].append(values)
    return tuple(np.concatenate(x) if x else np.zeros(0, np.int64) for x in out)
