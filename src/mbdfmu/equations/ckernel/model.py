"""kernel.c's ``Model`` of one scene's ``Equations``: its fields and the arrays behind them
(``model_arrays``: index tables, forces, output plan, sliding friction), packed into two
blocks whose addresses the struct holds (``_packed``)."""

from __future__ import annotations

import ctypes
import functools
import math
from typing import NamedTuple

import numpy as np

from ...model.scene import PointForce, RevoluteJoint, RotationalSpringDamper, SpringDamper, Torque
from ..sparsity import RANK_TOLERANCE

FORCE_CODES = {PointForce: 0, Torque: 1, SpringDamper: 2, RotationalSpringDamper: 3}
# Per sliding joint (friction.h's SL_*): revolute or not, body_i, body_j (-1: the ground),
# its place among the joints with reactions; point_i, point_j, unit axis, direction,
# coulomb, coefficient, radius, frame_angle.
SLIDE_INTS, SLIDE_REALS = 4, 11
SLIDE_DIRECTION, SLIDE_COULOMB = 6, 7       # their places in the reals

# Minimum-norm solves (projections, error estimates) in C as sparsity.py's, else the numpy
# path's. Never eq. 14's: at an ill-conditioned S it takes the null-space form (singular.py,
# nullspace.h), whose q'' stays right next to a singular configuration; a cut-off's not.
MIN_NORM_IN_C = True

_P, _I = ctypes.c_void_p, ctypes.c_int64
_FIELDS = (
    "nb n m nf kc *c_rows *c_bi *c_bj *c_si *c_sj kl *l_rows *l_bi *l_bj *l_si *l_sj *l_u "
    "*l_w ka *a_rows *a_bi *a_bj *a_w nconst *constants nraw *merge size nkeep *keep *rows "
    "*cols npairs *pair_a *pair_b *pair_minv *band_index *perm kd *mass *minv *gravity "
    "%rank_tol *f_const nforce *f_int *f_real nr *joint_rows *reaction_entries *joint_bj "
    "*frame_body *reaction_joints *frame_angle *frame_point nj nplan *joint_plan ncoupler "
    "*coupler_rows ndriver *driver_rows banded min_norm psi_only nslide *s_int *s_real *slide_f "
    "*work *memo").split()


# Model's array fields (work, memo and slide_f: set by Kernel) and its counts
_POINTERS = [f[1:] for f in _FIELDS if f[0] == "*" and f not in ("*work", "*memo", "*slide_f")]
_COUNTS = [f for f in _FIELDS if f[0] not in "*%"]


class Model(ctypes.Structure):
    """kernel.c's ``Model``: counts (int64), pointers, one double (``%``)."""

    _fields_ = [(f.strip("*%"), _P if f[0] == "*" else ctypes.c_double if f[0] == "%" else _I)
                for f in _FIELDS]


def _ints(a) -> np.ndarray:
    return np.ascontiguousarray(a, dtype=np.int64).ravel()


def _floats(a) -> np.ndarray:
    return np.ascontiguousarray(a, dtype=np.float64).ravel()


def force_table(applied) -> tuple[np.ndarray, np.ndarray]:
    """The forces that depend on the state or inputs (``AppliedForces.state_forces``) as
    kernel.c reads them: (type, body_i, body_j, input slot or -1) and eight reals each."""
    ints, reals = [], []
    slots = {name: s.start for name, s in applied.layout.forces.items()}
    index = applied.index
    for f in applied.state_forces:
        real = np.zeros(8)
        if isinstance(f, PointForce):
            b = index[f.body]
            ints.append((0, b, b, slots[f.name] if f.input else -1))
            real[:4] = (*f.point, *((0.0, 0.0) if f.input else f.value))
        elif isinstance(f, Torque):
            b = index[f.body]
            ints.append((1, b, b, slots[f.name]))
        elif isinstance(f, SpringDamper):
            ints.append((2, index[f.body_i], index[f.body_j],
                         slots[f.name] if f.actuator_input else -1))
            real[:7] = (*f.point_i, *f.point_j, f.stiffness, f.damping, f.rest_length)
        else:
            joint = applied.scene.joint(f.joint)
            ints.append((3, index[joint.body_i], index[joint.body_j], -1))
            real[:3] = (f.stiffness, f.damping, f.rest_angle)
        reals.append(real)
    return _ints(np.array(ints, dtype=np.int64).reshape(-1, 4)), _floats(np.array(reals).reshape(-1, 8))


def model_arrays(eq) -> dict:
    """Every array and count of ``Model`` for the ``Equations`` eq."""
    c, p = eq.constraint_set, eq.pattern
    co, li, an = c.coincidence, c.line, c.angle
    f_int, f_real = force_table(eq.applied)
    a = dict(nb=eq.nb, n=eq.n, m=eq.m, nf=eq.layout.size,
             kc=co.n, c_rows=co.rows, c_bi=co.bi, c_bj=co.bj, c_si=co.si, c_sj=co.sj,
             kl=li.n, l_rows=li.rows, l_bi=li.bi, l_bj=li.bj, l_si=li.si, l_sj=li.sj,
             l_u=li.u, l_w=li.w, ka=an.n, a_rows=an.rows, a_bi=an.bi, a_bj=an.bj, a_w=an.w,
             nconst=c._constants.size, constants=c._constants, nraw=p.merge.size,
             merge=p.merge, size=p.size, nkeep=p.keep.size, keep=p.keep, rows=p.rows,
             cols=p.cols, npairs=p.pair_a.size, pair_a=p.pair_a, pair_b=p.pair_b,
             pair_minv=p.pair_minv, band_index=p.band_index, perm=p.perm, kd=p.kd,
             mass=eq.mass, minv=eq.minv, gravity=eq.applied.gravity,
             f_const=eq.applied.constant, nforce=f_int.size // 4, f_int=f_int, f_real=f_real,
             nr=len(c.joint_rows), joint_rows=c.joint_rows,
             reaction_entries=eq._reaction_entries, joint_bj=c.joint_bj,
             frame_body=c.frame_body, reaction_joints=c.reaction_joints,
             frame_angle=c.frame_angle, frame_point=c.frame_point, nj=len(eq.scene.joints),
             nplan=eq._joint_outputs.size, joint_plan=eq._joint_outputs,
             ncoupler=c.coupler_rows.size, coupler_rows=c.coupler_rows,
             ndriver=c.driver_rows.size, driver_rows=c.driver_rows,
             banded=int(p.banded), min_norm=int(MIN_NORM_IN_C),
             psi_only=int(eq.has_events))
    a["nslide"], a["s_int"], a["s_real"] = friction_table(eq)
    return a


def joint_table(eq, k: int, direction: float = 0.0) -> tuple[tuple, tuple]:
    """Joint ``k`` of eq's scene as friction.h reads it: (SLIDE_INTS ints, SLIDE_REALS
    reals), its friction 0 where it has none; ``direction`` that of a sliding joint."""
    joint = eq.scene.joints[k]
    index = {b.name: i for i, b in enumerate(eq.scene.bodies)}
    reaction = [int(j) for j in eq.constraint_set.reaction_joints].index(k)
    revolute = isinstance(joint, RevoluteJoint)
    u = (0.0, 0.0) if revolute else tuple(v / math.hypot(*joint.axis_i) for v in joint.axis_i)
    f = joint.friction
    coulomb, coefficient, radius = (0.0, 0.0, 0.0) if f is None else (
        f.coulomb, f.coefficient, f.radius if revolute else 0.0)
    return ((int(revolute), index.get(joint.body_i, -1), index.get(joint.body_j, -1), reaction),
            (*joint.point_i, *joint.point_j, *u, float(direction), coulomb, coefficient, radius,
             0.0 if revolute else joint.frame_angle))


def friction_table(eq) -> tuple[int, np.ndarray, np.ndarray]:
    """The sliding joints of a contact mode (``Equations.sliding``) as friction.h reads
    them: (count, SLIDE_INTS ints, SLIDE_REALS reals)."""
    rows = [joint_table(eq, k, d) for k, d in eq.sliding.items()]
    if not rows:
        return 0, _NO_INTS, _NO_REALS
    return (len(rows), _ints(np.array([r[0] for r in rows], dtype=np.int64).reshape(
        -1, SLIDE_INTS)), _floats(np.array([r[1] for r in rows], dtype=float).reshape(
            -1, SLIDE_REALS)))


_NO_INTS, _NO_REALS = np.zeros(0, dtype=np.int64), np.zeros(0)

# events.h's kinds of event function: a stop's distance, a held coordinate's effort, a
# sticking joint's bound minus its effort, a sliding joint's rate
EV_DISTANCE, EV_HELD, EV_STICK, EV_RATE = range(4)


def event_table(eq, events: list[tuple]) -> tuple[np.ndarray, np.ndarray]:
    """Event functions as events.h reads them: (ints, reals) from ``events``, each (kind,
    joint index, held row or -1, limit, sign)."""
    ints, reals = [], []
    for kind, k, row, limit, sign in events:
        joint_ints, joint_reals = joint_table(eq, k)
        ints.append((kind, row, *joint_ints))
        reals.append((*joint_reals, limit, sign))
    return _ints(np.array(ints, dtype=np.int64)), _floats(np.array(reals, dtype=float))


def watch_events(run, events) -> tuple | None:
    """Point ``run`` (a ctypes struct with events.h's ``EventWatch`` fields: nevent, ev_int,
    ev_real, ev_g) at the event functions ``events`` ((ints, reals, their values now):
    ``ContactModes.c_events``), or at none (None). Returns the arrays it points at, which
    must live as long as it does: ints, reals and the values, with room for the next."""
    if events is None:
        run.nevent = 0
        return None
    ints, reals, values = events
    ne = len(values)
    arrays = (np.ascontiguousarray(ints, dtype=np.int64),
              np.ascontiguousarray(reals, dtype=float), np.zeros(2 * ne))
    arrays[2][:ne] = values
    run.nevent = ne
    run.ev_int, run.ev_real, run.ev_g = (a.ctypes.data for a in arrays)
    return arrays


def _packed(arrays: dict) -> tuple[dict, list]:
    """``Model``'s fields from ``model_arrays``: counts as they are, each array copied into
    one int64 or one float64 block (as ``_ints`` / ``_floats`` would give it) and given by
    its address there; and the two blocks, which must live as long as the model."""
    values = {name: arrays[name] for name in _COUNTS}
    integer, real = [], []
    for name in _POINTERS:
        a = np.asarray(arrays[name])
        (integer if a.dtype.kind in "iu" else real).append((name, a))
    blocks = []
    for part, dtype in ((integer, np.int64), (real, np.float64)):
        # one element more: never of size 0
        block = np.concatenate([a for _, a in part] + [np.zeros(1, dtype)], axis=None,
                               dtype=dtype)
        address = block.ctypes.data
        for name, a in part:
            values[name] = address
            address += 8 * a.size
        blocks.append(block)
    return values, blocks


class SharedModel(NamedTuple):
    """What every Kernel of one structure reads and none writes: the ``Model`` filled in
    (but for its work space), the blocks its pointers point into, and the counts Kernel
    sizes its buffers by."""

    template: Model
    blocks: tuple
    pair_cols: np.ndarray       # each pair's column (the weights of ``partition``)
    nout: int
    nslide: int
    s_real: np.ndarray


def shared_model(eq) -> SharedModel:
    """``SharedModel`` of the ``Equations`` eq: laid out once, kept on eq, and shared by its
    copies (``dynamics.for_another_run``), whose structure it is."""
    shared = eq.__dict__.get("_shared_model")
    if shared is None:
        arrays = model_arrays(eq)
        values, blocks = _packed(arrays)
        springs = sum(isinstance(f, SpringDamper) for f in eq.scene.forces)
        shared = eq._shared_model = SharedModel(
            Model(rank_tol=RANK_TOLERANCE, **values), tuple(blocks),
            np.asarray(arrays["cols"])[np.asarray(arrays["pair_a"])],
            6 * eq.nb + arrays["nplan"] + arrays["ndriver"] + 3 * springs + 4,
            arrays["nslide"], arrays["s_real"])
    return shared


@functools.lru_cache(maxsize=64)
def _layout(shapes: tuple) -> tuple:
    """For ``shapes`` ((name, shape), ...) laid end to end: (doubles in all, the flat parts
    (name, start, stop), the others (name, start, stop, shape), the addresses' names and
    offsets in bytes (p_<name>, offset))."""
    flat, shaped, offsets, start = [], [], [], 0
    for name, shape in shapes:
        stop = start + math.prod(shape)
        if len(shape) == 1:
            flat.append((name, start, stop))
        else:
            shaped.append((name, start, stop, shape))
        offsets.append(("p_" + name, 8 * start))
        start = stop
    return start, tuple(flat), tuple(shaped), tuple(offsets)


class Carved:
    """One zeroed block of doubles (``block``) cut into named parts, ``shapes`` ((name,
    shape), ...): each part is ``<name>`` (a view of that shape) and its address
    ``p_<name>``. One allocation and one address asked of numpy, the layout worked out
    once per shapes: a run's buffers are made for every Simulation."""

    def __init__(self, shapes: tuple):
        total, flat, shaped, offsets = _layout(shapes)
        self.block = block = np.zeros(total)
        base = block.ctypes.data
        fields = {name: block[a:b] for name, a, b in flat}
        fields.update((name, block[a:b].reshape(shape)) for name, a, b, shape in shaped)
        fields.update((name, base + offset) for name, offset in offsets)
        self.__dict__.update(fields)
