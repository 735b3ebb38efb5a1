"""The dense output of an adaptive method's last step in the C kernel (dense.h): the
projected state at a time inside it (``ProjectedRK._output_at``), and the FMU's
communication steps that only read it, taken by the FMU's wrapper without Python
(``fmu_build/runtime/real_cache.py`` FastSteps).

``DenseReads`` is a mixin of ``Kernel``: it uses the kernel's ``dense`` (a ``DenseRead``),
``buf``, ``n``, ``nout``, ``address`` and its bound ``_dense_state``.
"""

from __future__ import annotations

import ctypes

import numpy as np

from .fixed import table_arrays

_P, _I = ctypes.c_void_p, ctypes.c_int64
ST_OK = 0           # kernel.c's ST_OK (ckernel.OK)


class DenseRead(ctypes.Structure):
    """dense.h's ``DenseRead``: one step's dense output, and what an FMU's step that only
    reads it needs (the wrapper calls ``mbd_dense_step`` with it)."""

    _fields_ = [(name, ctypes.c_double) for name in
                ("t_now", "t_old", "h", "time_tol", "tol")] + \
        [("max_iter", _I), ("kind", _I), ("rows", _I), ("coef", _P), ("y_old", _P),
         ("motion", _P), ("uf", _P), ("nout", _I), ("npub", _I), ("pub_dst", _P),
         ("pub_src", _P), ("V", _P), ("nmotion", _I), ("mrow", _P), ("mkind", _P),
         ("mcoef", _P), ("offsets", _P), ("mbuf", _P)]


# dense.h's interpolants (DENSE_*): dense_output.py's rk45 and dop853.
DENSE_KINDS = {"rk45": 1, "dop853": 2}


class DenseReads:
    """The dense-output calls of ``Kernel`` (see the module docstring)."""

    def load_dense(self, interpolant: str, step, motion, uf, tol: float, max_iter: int) -> None:
        """Put ``step`` (a ``DenseStep`` with the coefficients of ``interpolant``, a key of
        DENSE_KINDS), the inputs held over it and the projection's tolerance into
        ``self.dense`` (dense.h's DenseRead), for ``dense_state`` and an FMU's steps."""
        d = self.dense
        coef = np.ascontiguousarray(step.coefficients, dtype=float)
        y_old = np.ascontiguousarray(step.y_old, dtype=float)
        held = np.concatenate([np.ravel(c) for c in motion])
        forces = np.array(uf if uf is not None and len(uf) else [0.0], dtype=float)
        self._dense_arrays = (coef, y_old, held, forces)       # what d points at
        d.t_old, d.h, d.tol, d.max_iter = step.t_old, step.h, tol, max_iter
        d.kind = DENSE_KINDS[interpolant]
        d.rows = coef.shape[1] if d.kind == DENSE_KINDS["rk45"] else coef.shape[0]
        d.coef, d.y_old, d.motion, d.uf = (a.ctypes.data for a in self._dense_arrays)

    def dense_state(self, t: float):
        """(q, q') at t inside the step ``load_dense`` put there, projected; None where
        the numpy path must do it."""
        b, n = self.buf, self.n
        if self._dense_state(self.address, ctypes.addressof(self.dense), t, b.p_y) != ST_OK:
            return None
        return b.y[:n].copy(), b.y[n:].copy()

    def arm_dense_steps(self, t_now: float, time_tol: float, pub_dst, pub_src,
                        motions=None) -> tuple:
        """Let an FMU's wrapper take communication steps from t_now inside the step
        ``load_dense`` put there (``mbd_dense_step``), writing value ``pub_src[k]`` of
        (outputs, q, q', q'') into ``values[pub_dst[k]]``: (the address of
        ``mbd_dense_step``, of the kernel's model, of its DenseRead), as the wrapper's
        FastSteps block takes them. ``dense.t_now`` is then the time the steps reached.
        ``motions``: in a scene with drivers, (their motion table, ``fixed.motion_table``;
        the constraints' offsets), evaluated at each point read."""
        d = self.dense
        if motions is None:
            d.nmotion = 0
        else:
            buffer = np.zeros(3 * max(self.m, 1))
            self._dense_motions = (table_arrays(d, *motions), buffer)    # what d points at
            d.mbuf = buffer.ctypes.data
        if self._publish is None or self._publish[0] is not pub_dst:
            dst, src = (np.ascontiguousarray(a, dtype=np.int64) for a in (pub_dst, pub_src))
            self._publish = (pub_dst, dst, src)
            d.pub_dst, d.pub_src, d.npub = dst.ctypes.data, src.ctypes.data, dst.size
        d.t_now, d.time_tol, d.nout = t_now, time_tol, self.nout
        function = ctypes.cast(self.library.mbd_dense_step, ctypes.c_void_p).value
        return function, self.address, ctypes.addressof(d)
