"""Linear algebra of the constraint Jacobian: its fixed sparsity pattern and eq. (15)'s solves.

Psi_q has the same nonzeros at every configuration (they follow from which bodies each
constraint row touches), so the pattern is worked out once per scene and every evaluation
only fills in the values. Two forms use it:

* small mechanisms get a dense ``ndarray`` Psi_q and a dense Cholesky factorisation of the
  Schur complement ``S = Psi_q M^-1 Psi_q^T`` (LAPACK potrf): at tens of rows nothing is
  faster from Python;
* large ones (``m >= BANDED_MIN_ROWS``) get a ``SparseJacobian``: products by index sums
  (``np.bincount``) and S assembled straight into band storage, in the reverse Cuthill-McKee
  order of its rows, and factorised by banded Cholesky (LAPACK pbtrf). For chain-like
  mechanisms the band is narrow and does not grow with the mechanism, so the cost of a
  solve is linear in the number of bodies instead of cubic.

Both forms support ``J @ x`` and ``J.T @ y``, and ``schur_solve(J, minv, b)`` solves
``S x = b`` with the same rules: Cholesky when S is well conditioned, otherwise (singular
configurations, redundant constraints) the minimum-norm least-squares solution.
"""

from __future__ import annotations

import math

import numpy as np
import scipy.linalg
import scipy.sparse
from scipy.sparse.csgraph import reverse_cuthill_mckee

from ..errors import SolverError

try:    # the ordering itself, on index arrays: what reverse_cuthill_mckee calls once it has
    # built and checked a csr matrix, which costs more than the ordering at tens of rows
    from scipy.sparse.csgraph._reordering import _reverse_cuthill_mckee
except ImportError:         # a scipy that moved it: the public function
    _reverse_cuthill_mckee = None

# Constraint rows from which the sparse banded form is used (below it dense wins).
BANDED_MIN_ROWS = 60
# Relative size of the smallest singular value kept in minimum-norm solves.
RANK_TOLERANCE = 1e-10
# Iterated Tikhonov steps of the banded minimum-norm solve: each multiplies the error of a
# component with eigenvalue s by eps / (s + eps), so three leave well-kept ones exact.
TIKHONOV_STEPS = 3

_potrf, _potrs = scipy.linalg.lapack.dpotrf, scipy.linalg.lapack.dpotrs
_pbtrf, _pbtrs = scipy.linalg.lapack.dpbtrf, scipy.linalg.lapack.dpbtrs


def _well_conditioned(diag: np.ndarray) -> bool:
    """Cholesky's diagonal says S is far enough from singular to trust the factorisation."""
    diag = np.abs(diag)
    return diag.min() > math.sqrt(RANK_TOLERANCE) * diag.max()


def solve_spd(S: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Solve S x = b for symmetric positive semi-definite dense S.

    Cholesky when S is well conditioned; otherwise the minimum-norm least-squares solution.
    """
    return solve_spd_checked(S, b)[0]


def solve_spd_checked(S: np.ndarray, b: np.ndarray) -> tuple[np.ndarray, bool]:
    """``solve_spd``, and whether Cholesky was used (False: the minimum-norm path)."""
    # LAPACK directly: the scipy wrappers cost more than the factorisation at these sizes.
    factor, info = _potrf(S, lower=False, clean=False)
    if info == 0 and _well_conditioned(np.diag(factor)):
        x, info = _potrs(factor, b, lower=False)
        if info == 0:
            return x, True
    if not np.all(np.isfinite(S)) or not np.all(np.isfinite(b)):
        raise SolverError("non-finite values in the constraint equations")
    x, *_ = scipy.linalg.lstsq(S, b, cond=RANK_TOLERANCE, check_finite=False)
    return x, False


def spd_solver(S: np.ndarray):
    """A solver ``b -> x`` of S x = b for several right-hand sides, with ``solve_spd``'s
    rules: Cholesky once when S is well conditioned, else minimum-norm least squares."""
    factor, info = _potrf(S, lower=False, clean=False)
    if info == 0 and _well_conditioned(np.diag(factor)):
        def cholesky_solve(b):
            x, info = _potrs(factor, b, lower=False)
            return x if info == 0 else solve_spd(S, b)
        return cholesky_solve
    return lambda b: solve_spd(S, b)


def schur_solve(J, minv: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Solve ``(J M^-1 J^T) x = b`` for a dense or sparse J (see the module's rules)."""
    return schur_solve_checked(J, minv, b)[0]


def schur_solve_checked(J, minv: np.ndarray, b: np.ndarray) -> tuple[np.ndarray, bool]:
    """``schur_solve``, and whether S was well conditioned (False: minimum-norm solution)."""
    if isinstance(J, SparseJacobian):
        return J.pattern.schur_solve_checked(J.data, b)
    JMi = J * minv
    return solve_spd_checked(JMi @ J.T, b)


class JacobianPattern:
    """The nonzeros of Psi_q, (rows, cols), fixed for a scene, and what follows from them.

    The constraint kernels fill a vector of term values, one per (row, column) entry of a
    term; where two terms of one row touch one column (a coupler between joints that share
    a body, a rolling joint's line and angle terms) their values add up: ``merged`` sums
    them into ``data``, one value per distinct entry (``merge`` maps each term entry to its
    entry; without repeats ``data`` is the term vector itself). ``rows``/``cols`` index
    ``data``'s entries in moving bodies' columns (``keep``); the ones in columns >= n (the
    virtual ground body) are kept in ``data`` but dropped here. ``banded`` chooses the
    sparse form (see the module docstring).
    """

    def __init__(self, rows, cols, m: int, n: int, minv: np.ndarray, *, banded: bool | None = None):
        rows, cols = np.asarray(rows, dtype=np.intp), np.asarray(cols, dtype=np.intp)
        flat = rows * (n + 3) + cols
        first, self.merge = _first_use(flat)
        self.size = int(first.size)
        self.repeats = self.size < flat.size
        rows, cols = rows[first], cols[first]
        self.flat_with_ground = flat[first]
        self.keep = (cols < n).nonzero()[0]
        self.rows, self.cols = rows[self.keep], cols[self.keep]
        self.m, self.n = m, n
        self.flat = self.rows * n + self.cols
        self.banded = (m >= BANDED_MIN_ROWS) if banded is None else bool(banded)
        self._plan_schur_band(minv)   # the compiled kernel uses it at any size

    def merged(self, terms: np.ndarray) -> np.ndarray:
        """``data`` from the kernels' term values: repeated entries summed."""
        if not self.repeats:
            return terms
        return np.bincount(self.merge, weights=terms, minlength=self.size)

    # ------------------------------------------------------------------ both forms

    def dense(self, data: np.ndarray) -> np.ndarray:
        J = np.zeros((self.m, self.n))
        J.flat[self.flat] = data[self.keep]
        return J

    def dense_with_ground(self, data: np.ndarray) -> np.ndarray:
        """Dense Psi_q with the virtual ground body's three columns last (m, n + 3)."""
        J = np.zeros((self.m, self.n + 3))
        J.flat[self.flat_with_ground] = data
        return J

    def entries(self, rows, cols) -> np.ndarray:
        """Where entries (rows, cols) of the extended Psi_q (ground columns last) are in
        ``data``: indices into ``data`` with one zero appended, so that structural zeros
        read that zero. ``np.append(data, 0.0)[entries(...)]`` gathers a block in O(size)."""
        flat = np.asarray(rows, dtype=np.intp) * (self.n + 3) + np.asarray(cols, dtype=np.intp)
        known = self.flat_with_ground                    # distinct: one match at most
        if known.size == 0:
            return np.zeros(flat.shape, dtype=np.intp)   # all read the appended zero
        order = known.argsort()
        hit = order[np.minimum(known.searchsorted(flat, sorter=order), known.size - 1)]
        return np.where(known[hit] == flat, hit, known.size).astype(np.intp)

    def jacobian(self, data: np.ndarray, sparse: bool):
        """Psi_q from its values: a ``SparseJacobian`` when asked for and banded, else dense."""
        if sparse and self.banded:
            return SparseJacobian(self, data[self.keep])
        return self.dense(data)

    # ------------------------------------------------------------------ banded Schur complement

    def _column_pairs(self):
        """Every pair (a, b) of kept entries in one column: S_ab = sum_k J_ak J_bk / M_k is a
        sum over exactly these pairs, so S can be assembled without forming J."""
        order = self.cols.argsort(kind="stable")
        cols_sorted = self.cols[order]
        starts = _first_of_runs(cols_sorted).nonzero()[0]
        sizes = np.empty_like(starts)           # the runs' lengths (np.diff of an append)
        sizes[:-1], sizes[-1:] = starts[1:], cols_sorted.size
        sizes -= starts
        # each entry of a column pairs with every entry of it, in the order a per-column
        # meshgrid (i outer, j inner) would give, without a Python loop over columns
        group = np.arange(starts.size).repeat(sizes)              # column of each sorted entry
        count = sizes[group]                                       # pairs of each sorted entry
        first = (count.cumsum() - count).repeat(count)             # where its pairs begin
        a = np.arange(cols_sorted.size).repeat(count)
        b = starts[group[a]] + np.arange(a.size) - first
        return order[a], order[b]

    def _plan_schur_band(self, minv: np.ndarray) -> None:
        """Index maps that put S = J M^-1 J^T straight into lower band storage
        ``band[i - j, j] = S[i, j]`` (i >= j; LAPACK's lower form, also the compiled
        kernel's), rows in reverse Cuthill-McKee order, which keeps the band narrow."""
        m = self.m
        pa, pb = self._column_pairs()
        ra, rb = self.rows[pa], self.rows[pb]
        # S's pattern straight in canonical CSR (sorted, no repeats): what coo's tocsr
        # gives, without its checks and conversions
        flat = ra * m + rb
        flat.sort()
        flat = flat[_first_of_runs(flat)]
        indptr = flat.searchsorted(np.arange(m + 1) * m)
        perm = _rcm(flat % m, indptr, m)
        position = np.empty(m, dtype=np.intp)
        position[perm] = np.arange(m)
        i, j = position[ra], position[rb]
        lower = i >= j
        pa, pb, i, j = pa[lower], pb[lower], i[lower], j[lower]
        self.kd = int((i - j).max()) if i.size else 0
        self.pair_a, self.pair_b = pa, pb
        self.pair_minv = minv[self.cols[pa]]
        self.band_index = (i - j) * m + j                # into a C-ordered (kd + 1, m) array
        self.band_size = (self.kd + 1) * m
        self.perm = perm

    def schur_band(self, values: np.ndarray) -> np.ndarray:
        """S = J M^-1 J^T in lower band storage (kd + 1, m), rows in ``self.perm`` order."""
        weights = values[self.pair_a] * values[self.pair_b] * self.pair_minv
        return np.bincount(self.band_index, weights=weights,
                           minlength=self.band_size).reshape(self.kd + 1, self.m)

    def schur_solve(self, values: np.ndarray, b: np.ndarray) -> np.ndarray:
        """Solve (J M^-1 J^T) x = b by banded Cholesky; minimum-norm when S is near singular.

        M is the mass matrix the pattern was planned with (a scene's is fixed)."""
        return self.schur_solve_checked(values, b)[0]

    def schur_solve_checked(self, values: np.ndarray, b: np.ndarray) -> tuple[np.ndarray, bool]:
        """``schur_solve``, and whether Cholesky was used (False: the minimum-norm path)."""
        band = self.schur_band(values)
        bp = b[self.perm]
        factor, info = _pbtrf(band, lower=1)
        if info == 0 and _well_conditioned(factor[0]):
            xp, info = _pbtrs(factor, bp, lower=1)
            if info == 0:
                return self._unpermute(xp), True
        if not np.all(np.isfinite(values)) or not np.all(np.isfinite(b)):
            raise SolverError("non-finite values in the constraint equations")
        return self._unpermute(self._min_norm(band, bp)), False

    def _min_norm(self, band: np.ndarray, bp: np.ndarray) -> np.ndarray:
        """Minimum-norm least-squares solution by iterated Tikhonov regularisation.

        x_k+1 = x_k + (S + eps I)^-1 (b - S x_k) from x_0 = 0 never leaves the range of S and
        converges there to the least-squares solution; eps at RANK_TOLERANCE times the
        largest diagonal plays the part of lstsq's cut-off, in banded cost.
        """
        eps = RANK_TOLERANCE * float(np.abs(band[0]).max() or 1.0)
        shifted = band.copy()
        shifted[0] += eps
        factor, info = _pbtrf(shifted, lower=1)
        if info != 0:
            raise SolverError("the constraint equations could not be solved (Schur complement "
                              "not positive semi-definite)")
        x = np.zeros_like(bp)
        for _ in range(TIKHONOV_STEPS):
            dx, _ = _pbtrs(factor, bp - _band_matvec(band, x), lower=1)
            x += dx
        return x

    def _unpermute(self, xp: np.ndarray) -> np.ndarray:
        x = np.empty_like(xp)
        x[self.perm] = xp
        return x


def _first_of_runs(values: np.ndarray) -> np.ndarray:
    """Mask of the entries of a sorted array that differ from the one before."""
    new = np.empty(values.size, dtype=bool)
    new[:1] = True
    np.not_equal(values[1:], values[:-1], out=new[1:])
    return new


def _first_use(flat: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The distinct values of ``flat`` in order of first use: where each first occurs, and
    each entry's number among them (np.unique's index and inverse, renumbered)."""
    order = flat.argsort(kind="stable")              # stable: a value's first entry leads
    new = _first_of_runs(flat[order])
    first = order[new]                               # in value order
    by_use = first.argsort()
    position = np.empty(by_use.size, dtype=np.intp)
    position[by_use] = np.arange(by_use.size)
    merge = np.empty(flat.size, dtype=np.intp)
    merge[order] = position[new.cumsum() - 1]
    return first[by_use], merge


def _rcm(indices: np.ndarray, indptr: np.ndarray, m: int) -> np.ndarray:
    """scipy's reverse Cuthill-McKee order of the symmetric pattern (csr ``indices``,
    ``indptr``, canonical) of an m x m matrix."""
    if m == 0:
        return np.zeros(0, np.intp)                  # no constraints: nothing to order
    if _reverse_cuthill_mckee is not None:
        try:
            return _reverse_cuthill_mckee(indices.astype(np.int32), indptr.astype(np.int32),
                                          m).astype(np.intp)
        except (TypeError, ValueError):  # a scipy whose private routine changed its call
            pass
    graph = scipy.sparse.csr_matrix((np.ones(indices.size), indices, indptr), shape=(m, m))
    return reverse_cuthill_mckee(graph, symmetric_mode=True).astype(np.intp)


def _band_matvec(band: np.ndarray, x: np.ndarray) -> np.ndarray:
    """S x for symmetric S in lower band storage (kd + 1, m): band[d, j] = S[j + d, j]."""
    m = x.size
    y = band[0] * x
    for d in range(1, band.shape[0]):
        diag = band[d, :m - d]
        y[d:] += diag * x[:m - d]
        y[:m - d] += diag * x[d:]
    return y


class SparseJacobian:
    """Psi_q of a large mechanism as values on its ``JacobianPattern``: ``J @ x``, ``J.T @ y``."""

    __slots__ = ("pattern", "data")

    def __init__(self, pattern: JacobianPattern, data: np.ndarray):
        self.pattern, self.data = pattern, data

    @property
    def shape(self):
        return self.pattern.m, self.pattern.n

    def __matmul__(self, x: np.ndarray) -> np.ndarray:
        p = self.pattern
        return np.bincount(p.rows, weights=self.data * x[p.cols], minlength=p.m)

    @property
    def T(self):
        return _Transposed(self)

    def toarray(self) -> np.ndarray:
        J = np.zeros(self.shape)
        J.flat[self.pattern.flat] = self.data
        return J


class _Transposed:
    __slots__ = ("J",)

    def __init__(self, J: SparseJacobian):
        self.J = J

    def __matmul__(self, y: np.ndarray) -> np.ndarray:
        p = self.J.pattern
        return np.bincount(p.cols, weights=self.J.data * y[p.rows], minlength=p.n)
