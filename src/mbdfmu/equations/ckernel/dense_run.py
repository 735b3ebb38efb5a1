"""An FMU's communication step past the end of the adaptive step its wrapper reads
(dense_run.h): the pair's next steps in dense mode, their DOP853 interpolant and the read
at the communication point, all by the wrapper without Python; and the interpolant alone
for Python's own dense output (``DOP853P._interpolant``).

``DenseRuns`` is a mixin of ``Kernel``: it uses the kernel's ``run`` (a ``DenseRun``,
whose first field is the kernel's ``dense``), ``n``, ``m``, ``nf``, ``address`` and
``library``.
"""

from __future__ import annotations

import ctypes

import numpy as np

from .adaptive import PrkPy, PrkRunBuffers, point_run
from .dense import DENSE_KINDS, DenseRead
from .fixed import AUDIT_SIZE, table_arrays
from .model import watch_events

_P, _I = ctypes.c_void_p, ctypes.c_int64
ST_OK = 0                               # kernel.c's ST_OK
DENSE_STAGES, DENSE_ROWS = 16, 7        # dense_run.h: DOP853's stages with the extra three
PAIR_SCALARS, RUN_SCALARS = 13, 4       # adaptive.h's save_pair, dense_run.h's save_run
COUNTERS = ("nsteps", "nrejected", "naccel", "nprojections")


class DenseRun(ctypes.Structure):
    """dense_run.h's ``DenseRun``."""

    _fields_ = [("d", DenseRead), ("p", PrkPy), ("a_extra", _P), ("D", _P), ("motions", _P),
                ("ufs", _P), ("coef", _P * 2), ("which", _I), ("Kx", _P),
                ("ys", _P), ("saved", _P), ("taken", _I), ("horizon", ctypes.c_double),
                ("c_extra", _P)]


class RunBuffers(PrkRunBuffers):
    """The arrays a ``DenseRun`` points at, for a pair of ``ns`` stages: its PrkPy's, and
    the interpolant's."""

    def __init__(self, n: int, m: int, nf: int, ns: int):
        super().__init__(n, m, nf, ns)
        n2 = 2 * n
        self.node_motions, self.node_ufs = np.zeros((3, 3 * m)), np.zeros((3, max(nf, 1)))
        self.coef = np.zeros((2, DENSE_ROWS, n2))
        self.Kx, self.ys = np.zeros((DENSE_STAGES, n2)), np.zeros(n2)
        # the pair's state (save_pair) and the watched event functions' values: where a
        # run puts itself back after a step that changes a sign (PrkPy.undo); with the
        # run's own scalars, the state before a doStep's run (save_run)
        self.pair_base = 4 * n2 + (ns + 1) * n2 + AUDIT_SIZE + PAIR_SCALARS
        self.saved = np.zeros(self.pair_base + RUN_SCALARS)
        self.undo = np.zeros(self.pair_base)
        self.events = None


class DenseRuns:
    """The dense runs of ``Kernel`` (see the module docstring)."""

    run_buffers: RunBuffers | None = None

    def dop853_dense(self, K, y_old, y_end, h: float, a_extra, D, motions, ufs):
        """F (7, 2n) of DOP853's interpolant of the step from y_old over h with stages K
        (13 rows, the last f at the unprojected end y_end): ``mbd_dop853_dense``, with the
        inputs at the three extra nodes (motions: 3 rows of (c, c', c''); ufs: 3 rows of
        force inputs); None where an evaluation fails (the numpy path then says why)."""
        n2 = 2 * self.n
        # F, then the extra stages and a stage's state (scratch): one allocation
        block = np.empty((DENSE_ROWS + DENSE_STAGES + 1) * n2)
        base = block.ctypes.data
        arrays = [np.ascontiguousarray(a, dtype=float) for a in
                  (K, y_old, y_end, a_extra, D, motions, ufs)]
        status = self.library.mbd_dop853_dense(  # its argument types: declared at loading
            self.address, *(a.ctypes.data for a in arrays[:3]), h,
            *(a.ctypes.data for a in arrays[3:]), base, base + 8 * DENSE_ROWS * n2,
            base + 8 * (DENSE_ROWS + DENSE_STAGES) * n2)
        return block[:DENSE_ROWS * n2].reshape(DENSE_ROWS, n2) if status == ST_OK else None

    def rk45_dense(self, K, P):
        """Q (2n, 4) of Dormand-Prince 5(4)'s interpolant from a step's stages K (7 rows,
        the last f at the unprojected end) and its P (7, 4): ``mbd_rk45_dense``, the
        function the wrapper's dense runs call."""
        K, P = (np.ascontiguousarray(a, dtype=float) for a in (K, P))
        n2, rows = K.shape[1], P.shape[1]
        Q = np.zeros((n2, rows))
        self.library.mbd_rk45_dense(n2, K.shape[0], rows, K.ctypes.data, P.ctypes.data,
                                    Q.ctypes.data)
        return Q

    def arm_dense_run(self, settings: dict, tableau, gaps, y, f, motion, uf, audit,
                      a_extra, D, events=None, horizon: float | None = None,
                      motions=None) -> tuple:
        """Let an FMU's wrapper also take the communication steps past the step
        ``load_dense`` put in ``dense`` (armed by ``arm_dense_steps`` first): the pair
        ``tableau`` (``Kernel.tableau``) from (y, f) with ``settings`` (PrkPy's scalar
        fields, PrkRun's in ``settings["run"]``: c_steps.run_settings), the gaps between
        its nodes, the held inputs (motion: (c, c', c''), uf), the energy audit's state
        (13 values) or None, DOP853's dense tableau (a_extra, D; for rk45p, whose
        interpolant ``load_dense`` named, D is its P and a_extra is unused); in a scene
        with end stops or friction, the contact mode's event functions (``events``:
        events.h's ints and reals and their values now, ``ContactModes.c_events``) and the
        event runner's horizon (s, or None). ``motions``: in a scene with drivers, (their
        motion table, ``fixed.motion_table``; the constraints' offsets; the stages' time
        fractions with 1 appended; DOP853's extra nodes), evaluated at every stage's time
        (``arm_dense_steps`` took them for the reads). Returns (the addresses of
        ``mbd_dense_run_step``, of the model, of the DenseRun)."""
        run, ns = self.run, tableau[0]
        b = self.run_buffers
        if b is None or b.K.shape[0] != ns + 1:
            b = self.run_buffers = RunBuffers(self.n, self.m, self.nf, ns)
            point_run(run.p, b, tableau, gaps)
            self._point_interpolant(run, b, a_extra, D)
        b.y[:], b.f[:] = y, f
        b.motions[:], b.node_motions[:] = motion, motion
        b.ufs[:, :self.nf], b.node_ufs[:, :self.nf] = uf, uf
        p = run.p
        for name, value in settings.pop("run").items():
            setattr(p.r, name, value)
        for name, value in settings.items():
            setattr(p, name, value)
        for name in COUNTERS:
            setattr(p.r, name, 0)
        p.stepped, run.taken = 0, 0
        if audit is None:
            p.audit = None
        else:
            b.audit[:] = audit
            p.audit = b.p_audit
        self._watch_events(run, b, events)
        run.horizon = np.nan if horizon is None else horizon
        if motions is None:
            p.r.nmotion = 0
        else:
            table, offsets, fractions, c_extra = motions
            b.driven = (table_arrays(p.r, table, offsets),
                        *(np.ascontiguousarray(a, dtype=float) for a in (fractions, c_extra)))
            p.r.fractions, run.c_extra = b.driven[1].ctypes.data, b.driven[2].ctypes.data
        function = ctypes.cast(self.library.mbd_dense_run_step, ctypes.c_void_p).value
        return function, self.address, ctypes.addressof(run)

    @staticmethod
    def _watch_events(run: DenseRun, b: RunBuffers, events) -> None:
        """Point the run at the event functions it watches (kept in b), or at none."""
        b.events = watch_events(run.p.r, events)
        ne = 0 if events is None else len(events[2])
        if b.saved.size < b.pair_base + ne + RUN_SCALARS:
            b.saved = np.zeros(b.pair_base + ne + RUN_SCALARS)
            b.undo = np.zeros(b.pair_base + ne)
            run.saved = b.saved.ctypes.data
        run.p.undo = b.undo.ctypes.data if ne else None

    def _run_coefficients(self, coef):
        """A run's interpolant as Python keeps it: DOP853's F (7, 2n), or Dormand-Prince
        5(4)'s Q (2n, 4) in the first 8n doubles (dense.h's DENSE_RK45)."""
        if self.run.d.kind == DENSE_KINDS["rk45"]:
            rows = self.run.d.rows
            return coef.ravel()[:2 * self.n * rows].reshape(2 * self.n, rows).copy()
        return coef.copy()

    @staticmethod
    def _point_interpolant(run: DenseRun, b: RunBuffers, a_extra, D) -> None:
        b.tableau = [np.ascontiguousarray(a, dtype=float) for a in (a_extra, D)]
        run.a_extra, run.D = (a.ctypes.data for a in b.tableau)
        run.motions, run.ufs = b.node_motions.ctypes.data, b.node_ufs.ctypes.data
        run.coef[0], run.coef[1] = b.coef[0].ctypes.data, b.coef[1].ctypes.data
        run.Kx, run.ys, run.saved = b.Kx.ctypes.data, b.ys.ctypes.data, b.saved.ctypes.data

    def dense_run_taken(self) -> dict | None:
        """What the wrapper's dense run did since it was armed: None without steps, else the
        state for ``integrators.dense_runs.adopt_dense_run`` (copies), its counters started
        again."""
        run, b = self.run, self.run_buffers
        if b is None or not run.taken:
            return None
        p, r = run.p, run.p.r
        which = int(run.which)
        state = dict(t=float(p.t), h=float(r.h), err_old=float(r.err_old),
                     indicator=float(r.indicator), landing=bool(r.landing),
                     energy_rejected=None if np.isnan(p.energy_rejected) else
                     float(p.energy_rejected), y=b.y.copy(), f=b.f.copy(),
                     t_old=float(p.t_old), h_old=float(p.h_old), y_old=b.y_old.copy(),
                     y_end=b.y_end.copy(), K_old=b.K_old.copy(),
                     coefficients=self._run_coefficients(b.coef[which]),
                     audit=b.audit.copy() if p.audit else None,
                     horizon=None if np.isnan(run.horizon) else float(run.horizon),
                     counters={k: int(getattr(r, k)) for k in COUNTERS})
        run.taken = 0
        for name in COUNTERS:
            setattr(r, name, 0)
        return state
