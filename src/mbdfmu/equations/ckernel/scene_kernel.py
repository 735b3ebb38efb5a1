"""The C kernel built for one scene: its structure (the ``Model``'s counts and index
tables) as compile-time constants, and as straight-line code for its sparsity pattern the
band factor of S = Psi_q M^-1 Psi_q^T, the products with Psi_q and Psi_q^T and the
merge of the Jacobian's terms into its entries (docs/performance.md, "The kernel built for
one scene").

The same ``kernel.c`` compiled with ``-DMBD_SCENE``: every loop over the scene's bodies,
rows and Jacobian entries has a constant trip count and constant indices, which the
compiler unrolls and folds. The factor and its substitutions do the generic loops'
operations in their order, less those on entries the pattern keeps at zero (x - u 0 = x),
and each product or merged entry sums its terms in the loop's order from +0, so a
specialised kernel returns the generic kernel's doubles, bit for bit
(tests/test_ckernel_scene.py). Masses, geometry and forces stay the Model's values: a
scene's parameters remain settable.

``scene_header(eq)`` writes the header (None where the straight-line code would be too
long to pay: a large mechanism runs the generic kernel), ``compile_scene_kernel(eq)``
compiles it (``build.compile_kernel``, cached by content). A library compiled here is
used by ``ckernel.use_scene_library``: each ``Kernel`` whose Model has its structure
(``mbd_structure_check``) takes it, any other (a contact mode's) the generic library.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from .build import compile_kernel
from .model import _FIELDS, model_arrays

# Straight-line statements of S's assembly, factor and substitutions above which a scene
# keeps the generic kernel: the code (and its compile time) grows with the square of the
# band, the gain does not.
MAX_STATEMENTS = 3000


# The Model's index tables (kernel.c: its `const I *` fields), empty ones included.
INDEX_TABLES = ("c_rows c_bi c_bj l_rows l_bi l_bj a_rows a_bi a_bj merge keep rows cols "
                "pair_a pair_b band_index perm f_int joint_rows reaction_entries joint_bj "
                "frame_body reaction_joints joint_plan coupler_rows driver_rows s_int").split()


def structure(arrays: dict) -> list[tuple[str, object]]:
    """The Model's integer fields in its order (``model_arrays``' values): (name, count)
    and (name, int64 array)."""
    fields = []
    for field in _FIELDS:
        name = field.strip("*%")
        if field[0] not in "*%" and name in arrays:
            fields.append((name, int(arrays[name])))
        elif name in INDEX_TABLES:
            fields.append((name, np.asarray(arrays[name], dtype=np.int64).ravel()))
    return fields


def _constants(fields) -> list[str]:
    lines, checks = [], []
    for name, value in fields:
        if isinstance(value, int):
            lines.append(f"#define SC_{name} ((I){value})")
            checks.append(f"M->{name} == {value}")
        else:
            items = ", ".join(str(int(x)) for x in value) or "0"    # never of size 0
            lines.append(f"static const I SC_{name}[] = {{{items}}};")
            if value.size:
                checks.append(f"sc_same(M->{name}, SC_{name}, {value.size})")
    lines += ["", "static int sc_same(const I *a, const I *b, I k) {",
              "    for (I i = 0; i < k; i++) if (a[i] != b[i]) return 0;",
              "    return 1;", "}", "",
              "static int sc_structure_is(const Model *M) {",
              "    return " + "\n        && ".join(checks) + ";", "}"]
    return lines


def _band_code(m: int, kd: int, band_index, pair_a, pair_b) -> list[str] | None:
    """sc_assemble, sc_factor and sc_substitute (solve.h's schur_band, band_cholesky_inv
    and band_substitute_inv for this pattern), or None past MAX_STATEMENTS."""
    at = lambda i, j: (i - j) * m + j                     # noqa: E731 - S[i, j], i >= j
    terms: dict[int, list[str]] = {}
    for p, (e, a, b) in enumerate(zip(band_index, pair_a, pair_b)):
        terms.setdefault(int(e), []).append(f"v[{a}] * v[{b}] * pm[{p}]")
    nonzero = {(j + d, j) for d, j in (divmod(int(e), m) for e in band_index)}
    assemble = [f"    L[{e}] = " + " + ".join(["0.0"] + terms.get(e, [])) + ";"
                for e in range((kd + 1) * m)]   # 0.0 first: the generic sum starts at +0
    factor = []
    for j in range(m):
        factor.append(f"    d = L[{j}]; if (!(d > 0.0)) return 0; hi = d > hi ? d : hi; "
                      "lo = d < lo ? d : lo; inv = 1.0 / d;")
        for i in range(j + 1, min(j + kd + 1, m)):
            if (i, j) not in nonzero:
                continue
            factor.append(f"    u = L[{at(i, j)}] * inv;")
            for k in range(j + 1, i + 1):
                if (k, j) in nonzero:
                    factor.append(f"    L[{at(i, k)}] -= u * L[{at(k, j)}];")
                    nonzero.add((i, k))
        factor.append(f"    L[{j}] = inv;")
    substitute = []
    for i in range(m):
        substitute.append(f"    z = y[{i}] * L[{i}]; y[{i}] = z;")
        substitute += [f"    y[{k}] -= L[{at(k, i)}] * z;"
                       for k in range(i + 1, min(i + kd + 1, m)) if (k, i) in nonzero]
    for i in range(m - 1, 0, -1):
        substitute.append(f"    z = y[{i}];")
        substitute += [f"    y[{k}] -= (L[{k}] * L[{at(i, k)}]) * z;"
                       for k in range(max(i - kd, 0), i) if (i, k) in nonzero]
    if len(assemble) + len(factor) + len(substitute) > MAX_STATEMENTS:
        return None
    return ["static inline void sc_assemble(const double *restrict v, const double *restrict pm,",
            "                               double *restrict L) {", *assemble, "}", "",
            "static inline int sc_factor(double *restrict L, double *dmin, double *dmax) {",
            "    double lo = INFINITY, hi = 0.0, d, inv, u;", *factor,
            "    *dmin = sqrt(lo);", "    *dmax = sqrt(hi);", "    return 1;", "}", "",
            "static inline void sc_substitute(const double *restrict L, double *restrict y) {",
            "    double z;", *substitute, "}"]


def _product_code(n: int, m: int, rows, cols) -> list[str]:
    """sc_jac_mul and sc_jac_t_mul (kernel.c's jac_mul, jac_t_mul): Psi_q x and Psi_q^T y
    on this pattern as one sum per result, its terms in the loop's order from +0 (the same
    doubles), each result kept in a register instead of stored and read back per entry."""
    by_row: dict[int, list[str]] = {}
    by_col: dict[int, list[str]] = {}
    for k, (r, c) in enumerate(zip(rows, cols)):
        by_row.setdefault(int(r), []).append(f"v[{k}] * x[{c}]")
        by_col.setdefault(int(c), []).append(f"v[{k}] * y[{r}]")
    mul = [f"    out[{r}] = " + " + ".join(["0.0"] + by_row.get(r, [])) + ";" for r in range(m)]
    t_mul = [f"    out[{c}] = " + " + ".join(["0.0"] + by_col.get(c, [])) + ";"
             for c in range(n)]
    return ["static inline void sc_jac_mul(const double *v, const double *x, double *out) {",
            *mul, "}", "",
            "static inline void sc_jac_t_mul(const double *v, const double *y, double *out) {",
            *t_mul, "}"]


def _merge_code(size: int, merge, keep) -> list[str]:
    """sc_merged (kernel.c's merged): the raw Jacobian terms summed into Psi_q's entries
    (the loop's order from +0; a copy where no two terms share an entry) and its kept
    values gathered, as straight-line code."""
    if merge.size == size:
        data = [f"    data[{i}] = raw[{i}];" for i in range(size)]
    else:
        parts: dict[int, list[str]] = {}
        for k, e in enumerate(merge):
            parts.setdefault(int(e), []).append(f"raw[{k}]")
        data = [f"    data[{i}] = " + " + ".join(["0.0"] + parts.get(i, [])) + ";"
                for i in range(size)]
    gather = [f"    values[{k}] = data[{int(e)}];" for k, e in enumerate(keep)]
    return ["static inline void sc_merged(const double *raw, double *data, double *values) {",
            *data, *gather, "}"]


def scene_header(eq) -> str | None:
    """The header of the kernel built for ``eq``'s structure (``Equations``), or None when
    its straight-line code would pass MAX_STATEMENTS."""
    arrays = model_arrays(eq)
    fields = structure(arrays)
    code = _band_code(int(arrays["m"]), int(arrays["kd"]), *(
        np.asarray(arrays[k], dtype=np.int64) for k in ("band_index", "pair_a", "pair_b")))
    if code is None:
        return None
    code += ["", *_product_code(int(arrays["n"]), int(arrays["m"]), *(
        np.asarray(arrays[k], dtype=np.int64) for k in ("rows", "cols")))]
    code += ["", *_merge_code(int(arrays["size"]), *(
        np.asarray(arrays[k], dtype=np.int64) for k in ("merge", "keep")))]
    title = f"/* The kernel built for scene {eq.scene.name!r} (scene_kernel.py writes it). */"
    return "\n".join([title, *_constants(fields), "", *code, ""])


def compile_scene_kernel(eq, folder=None) -> Path | None:
    """The kernel compiled for ``eq``'s structure (into ``folder``, default the cache;
    compiled once per content), or None where ``scene_header`` gives none.
    ``build.KernelBuildError`` where it cannot be compiled."""
    header = scene_header(eq)
    return None if header is None else compile_kernel(folder, scene_header=header)
