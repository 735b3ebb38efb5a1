"""An FMU's communication steps past the end of the step its wrapper reads, taken in C
(``equations/ckernel/dense_run.h``), seen from the integrator: the settings they start
from (``dense_run``) and the state to take over after them (``adopt_dense_run``).

The wrapper reads an embedded pair's dense output inside a step without Python
(``ckernel/dense.h``); a read past the step's end needed Python's next step and its
interpolant. The C run takes those steps with ``prk_run``'s decisions and builds the
interpolant with the function ``DOP853P._interpolant`` or ``RK45P._interpolant`` calls, so
the values it serves are Python's bit for bit.
"""

from __future__ import annotations

import numpy as np

from . import c_steps
from .singular_zone import gaps
from .dense_output import DenseStep
from .projected_rk import (DOP853P, ENERGY_JUMP_LIMIT, ENERGY_MIN_GAIN, MAX_FACTOR, MIN_FACTOR,
                           RK45P, SAFETY)
from .tableaux import DOP853_A_EXTRA, DOP853_D

# rk45p's interpolant needs no extra stages (dense_run.h reads D as its P)
NO_EXTRA = np.zeros(1)


def dense_run(rk, limit, stiff_limit: float | None) -> tuple | None:
    """The arguments of ``Kernel.arm_dense_run`` after (y, f, motion, uf) are added by the
    caller, for rk's coming steps past the step the wrapper reads, or None when they must
    go through Python: another method than dop853p or rk45p, a watch after each step that
    is not auto's at rest (``stiff_limit`` None), no interpolant loaded, a short CPU limit."""
    eq = rk.equations
    if type(rk) not in (DOP853P, RK45P) or stiff_limit is None or eq.ckernel is None or \
            eq.m == 0 or rk.dense is None or rk.dense.coefficients is None:
        return None
    max_work = c_steps.wrapper_steps(limit)
    if max_work is None:
        return None
    settings = c_steps.run_settings(rk, (SAFETY, MIN_FACTOR, MAX_FACTOR),
                                    (ENERGY_MIN_GAIN, ENERGY_JUMP_LIMIT), max_work)
    settings["run"]["stiff_limit"] = stiff_limit
    # the run checks the doStep's CPU limit itself (PrkPy.cpu_limit), as Python's loop does
    cpu_limit = limit.max_cpu if limit is not None and limit.max_cpu is not None else 0.0
    settings.update(t_target=rk.t, dense=1, rejections=0, cpu_limit=cpu_limit)
    audit = c_steps.audit_state(rk.audit) if rk.audit is not None else None
    dense = (DOP853_A_EXTRA, DOP853_D) if type(rk) is DOP853P else (NO_EXTRA, rk.P)
    return (settings, c_steps.tableau(rk), gaps(rk.C[:rk.n_stages]), audit, *dense)


def adopt_dense_run(rk, state: dict) -> None:
    """The state, counters, audit and last step (with its interpolant) after the wrapper's
    dense run (``Kernel.dense_run_taken``), as ``_advance_adaptive`` with ``prk_run``
    leaves them."""
    c_steps.adopt_pair_state(rk, state)
    rk.energy_rejected = state["energy_rejected"]
    rk.dense = DenseStep(state["t_old"], state["h_old"], state["y_old"], state["y_end"],
                         state["K_old"])
    rk.dense.coefficients = state["coefficients"]
    # rk.out stays the output the run was armed at (before the new step): the caller's
    # advance to the wrapper's time then reads it from the new step's dense output
    if rk.audit is not None:
        c_steps.audit_back(rk.audit, state["audit"])
