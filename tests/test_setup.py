"""What ``Simulation()`` sets up, held to independent computations: the Jacobian pattern's
plan against numpy's and scipy's public routines on every shipped scene, the C kernel's
model against the arrays it was built from, and the scene argument of the Python API."""

from __future__ import annotations

import ctypes
from pathlib import Path

import numpy as np
import pytest
import scipy.sparse
from scipy.sparse.csgraph import reverse_cuthill_mckee

import mbdfmu
from mbdfmu.equations import ckernel, sparsity
from mbdfmu.equations.dynamics import Equations
from mbdfmu.equations.sparsity import _first_use
from mbdfmu.errors import InputError
from mbdfmu.model.variables import outputs

SCENES = sorted(p.name for p in (Path(__file__).parent.parent / "scenes").glob("*.toml"))
CRANE = Path(__file__).parent.parent / "scenarios" / "hydraulic_crane" / "crane.toml"


def _equations(scenes_dir, name, kernel="numpy"):
    path = CRANE if name == "crane" else scenes_dir / name
    return Equations(mbdfmu.load_scene(path), kernel=kernel)


@pytest.mark.parametrize("name", SCENES + ["crane"])
def test_pattern_plan_matches_numpy_and_scipy(scenes_dir, name):
    eq = _equations(scenes_dir, name)
    p, c = eq.pattern, eq.constraint_set
    # S = J M^-1 J^T's pattern from a dense product, ordered by scipy's public function
    J = (eq.pattern.dense(np.arange(1.0, p.size + 1.0)) != 0).astype(float)
    S = scipy.sparse.csr_matrix(J @ J.T)
    if eq.m:
        np.testing.assert_array_equal(p.perm, reverse_cuthill_mckee(S, symmetric_mode=True))
        # and the public function's path, for a scipy without the routine where it is now
        public = _without_private_rcm(lambda: _equations(scenes_dir, name).pattern.perm)
        np.testing.assert_array_equal(public, p.perm)
        # and a scipy whose private routine kept its name but changed its call
        changed = _without_private_rcm(lambda: _equations(scenes_dir, name).pattern.perm,
                                       _private_rcm_with_another_call)
        np.testing.assert_array_equal(changed, p.perm)
    # the reaction blocks: each (row, column) looked up in the pattern's entries by a dict
    where = {int(f): k for k, f in enumerate(p.flat_with_ground)}
    flat = c.joint_rows[:, :, None] * (eq.n + 3) + 3 * c.joint_bj[:, None, None] + np.arange(3)
    expected = [where.get(int(f), p.size) for f in flat.ravel()]
    np.testing.assert_array_equal(eq._reaction_entries.ravel(), expected)


def _private_rcm_with_another_call(*args):
    raise TypeError(f"_reverse_cuthill_mckee() takes 4 positional arguments ({len(args)} given)")


def _without_private_rcm(build, replacement=None):
    kept = sparsity._reverse_cuthill_mckee
    sparsity._reverse_cuthill_mckee = replacement
    try:
        return build()
    finally:
        sparsity._reverse_cuthill_mckee = kept


@pytest.mark.parametrize("size, values", [(0, 1), (1, 1), (7, 3), (60, 20), (2000, 300)])
def test_entries_numbered_by_first_use_as_numpy_unique(size, values):
    flat = np.random.default_rng(size).integers(0, values, size)
    first, merge = _first_use(flat)
    distinct, index, inverse = np.unique(flat, return_index=True, return_inverse=True)
    order = np.argsort(index)
    np.testing.assert_array_equal(first, index[order])
    np.testing.assert_array_equal(merge, np.argsort(order)[inverse.ravel()])
    np.testing.assert_array_equal(flat[first][merge], flat)


@pytest.mark.skipif(not ckernel.available(), reason="no C kernel here")
@pytest.mark.parametrize("name", ["n_four_bar_2.toml", "slider_crank.toml", "crane"])
def test_kernel_model_points_at_the_equations_arrays(scenes_dir, name):
    eq = _equations(scenes_dir, name, kernel="c")
    arrays, model = ckernel.model_arrays(eq), eq.ckernel.model
    for field, kind in ckernel.Model._fields_:
        if field in ("work", "memo", "slide_f", "rank_tol"):
            continue
        given = np.asarray(arrays[field])
        if kind is not ckernel._P:
            assert getattr(model, field) == given, field
            continue
        if given.size == 0:
            continue
        ctype = ctypes.c_int64 if given.dtype.kind in "iu" else ctypes.c_double
        read = np.ctypeslib.as_array((ctype * given.size).from_address(getattr(model, field)))
        np.testing.assert_array_equal(read, given.ravel(), err_msg=field)


def test_simulation_takes_a_scene_path_as_simulate_does(scenes_dir):
    path = scenes_dir / "slider_crank.toml"
    sims = [mbdfmu.Simulation(s, method="dop853p") for s in
            (mbdfmu.load_scene(path), str(path), path, "slider_crank")]
    for sim in sims:
        sim.advance(0.05)
    for sim in sims[1:]:
        np.testing.assert_array_equal(sim.q, sims[0].q)
        np.testing.assert_array_equal(sim.output_vector(), sims[0].output_vector())


class _BytesPath:
    """A path-like object whose path is bytes (os.fspath gives b"...")."""

    def __fspath__(self):
        return b"scenes/pendulum.toml"


@pytest.mark.parametrize("bad", [42, None, {"bodies": []}, np.zeros((2, 2)), _BytesPath()])
def test_simulation_names_a_scene_of_the_wrong_kind_in_one_line(bad):
    with pytest.raises(InputError) as info:
        mbdfmu.Simulation(bad)
    message = str(info.value)
    assert "\n" not in message and message.startswith("scene must be a Scene")
    kind = "bytes" if isinstance(bad, _BytesPath) else type(bad).__name__
    assert message.endswith(f"got a {kind}")


def test_missing_scene_file_is_the_scene_error_of_load_scene(tmp_path):
    with pytest.raises(mbdfmu.SceneError, match="no_such_scene"):
        mbdfmu.Simulation(str(tmp_path / "no_such_scene.toml"))


def test_output_table_read_when_asked_is_the_variable_table(scenes_dir):
    scene = mbdfmu.load_scene(scenes_dir / "slider_crank.toml")
    sim = mbdfmu.Simulation(scene)
    variables = outputs(scene)
    assert sim.output_names == [v.name for v in variables]
    assert sim.units == {v.name: v.unit for v in variables}
    assert len(sim.output_names) == sim.output_vector().size
