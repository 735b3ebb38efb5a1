"""fmi2Get*/fmi2Set* for every type: value-reference, type, state and value checks.

Rule for a call that names several variables (stated once, applied to every type):
every valid entry is returned (get) or applied (set), each invalid one is skipped and
named in the log, and the call returns the worst status of its entries:

* unknown value reference, a reference of another type, a variable that may not be
  set in this state (outputs, calculated parameters, constants, a fixed parameter after
  fmi2ExitInitializationMode), a value of the wrong kind: fmi2Error (the instance then
  enters the Error state, like every fmi2Error);
* a non-finite Real value for an input or parameter: fmi2Discard, the value is not
  applied and the previous one is kept, so the master can send a finite value and go
  on (FMI 2.0 section 2.1.3: a value "outside of its domain" is what fmi2Discard is for).

A skipped get entry comes back as NaN, 0, false or "".
"""

from __future__ import annotations

import math

from . import status
from .machine import State
from .variables import FMI3_EMPTY, FMI3_TYPES, INT32_MAX, INT32_MIN, Variable


def _with_fmi3_names(table: dict, other) -> dict:
    """``table`` (by FMI 2.0 type name) also under FMI 3.0's names; ``other`` for the FMI
    3.0 types the runtime has no variables of (never used: every reference of them fails)."""
    return {**table, **{alias: table[t] for alias, t in FMI3_TYPES.items()},
            **{t: other for t in FMI3_EMPTY}}


# Placeholder returned for a get entry that was skipped.
SKIPPED = _with_fmi3_names({"Real": math.nan, "Integer": 0, "Boolean": False, "String": b""},
                           None)
# Causalities the host never sets, as messages name them.
NOT_SETTABLE = {"output": "an output", "calculatedParameter": "a calculated parameter",
                "local": "a local variable", "independent": "the independent variable"}


def settable_problem(v: Variable, state: str) -> str | None:
    """Why ``v`` cannot be set in ``state`` (FMI 2.0 section 4.2.4, table notes), or None."""
    if v.variability == "constant":
        return f'"{v.name}" is a constant and cannot be set'
    if v.causality in NOT_SETTABLE:
        return f'"{v.name}" is {NOT_SETTABLE[v.causality]} and cannot be set'
    if state == State.STEP_COMPLETE and v.causality == "parameter" and v.variability == "fixed":
        return (f'parameter "{v.name}" is fixed: it can be set only before '
                "fmi2ExitInitializationMode")
    if state == State.INITIALIZATION_MODE and v.initial == "approx":
        return f'"{v.name}" has initial="approx" and can be set only before fmi2EnterInitializationMode'
    return None


def _int32(value) -> int:
    value = int(value)
    if not INT32_MIN <= value <= INT32_MAX:
        raise OverflowError(f"{value} does not fit in a 32-bit fmi2Integer")
    return value


def _utf8(value) -> bytes:
    return str(value).encode("utf-8")


# A value as the C wrapper copies it into the caller's array, per FMI type.
TO_C = _with_fmi3_names({"Real": float, "Integer": _int32, "Boolean": bool, "String": _utf8},
                        float)


def _from_utf8(value) -> str:
    return bytes(value).decode("utf-8")


# The host's value as held in ``Slave.values``, per FMI type. The wrapper passes fmi2Real
# as float, fmi2Integer and fmi2Boolean as int, fmi2String as bytes (without the NUL).
FROM_C = _with_fmi3_names({"Real": float, "Integer": int, "Boolean": bool,
                          "String": _from_utf8}, float)


def get_values(slave, type_name: str, vrs) -> tuple[int, tuple]:
    """The values of ``vrs``; see the module docstring for the mixed-call rule."""
    table, values, log = slave.variables, slave.values, slave._fmi_log
    by_vr, convert = table.by_type[type_name], TO_C[type_name]
    code, out = status.OK, []
    for vr in vrs:
        v = by_vr.get(vr)
        if v is None:
            reason = table.lookup(type_name, vr)[1]
        else:
            try:
                out.append(convert(values[v.name]))
                continue
            except (TypeError, ValueError, OverflowError) as exc:
                reason = f'"{v.name}" holds {values[v.name]!r}, not a {type_name}: {exc}'
        log.status(status.ERROR, f"fmi2Get{type_name}: {reason}")
        code = status.ERROR
        out.append(SKIPPED[type_name])
    return code, tuple(out)


def fast_get(slave, type_name: str, vrs) -> tuple | None:
    """All values when every entry is valid (the usual case, in one pass), else None."""
    by_vr, convert, values = slave.variables.by_type[type_name], TO_C[type_name], slave.values
    try:
        return tuple([convert(values[by_vr[vr].name]) for vr in vrs])
    except (KeyError, TypeError, ValueError, OverflowError):
        return None


def settable_names(table, state: str, type_name: str) -> dict[int, str]:
    """Value reference -> name of the variables of ``type_name`` settable in ``state``."""
    key = (state, type_name)
    if key not in table.cache:
        table.cache[key] = {vr: v.name for vr, v in table.by_type[type_name].items()
                            if settable_problem(v, state) is None}
    return table.cache[key]


def fast_set(slave, type_name: str, vrs, new_values) -> bool:
    """Apply every value and return True when all are valid (the usual case); else
    change nothing and return False, so that ``set_values`` names each problem."""
    table = slave.variables
    names = table.cache.get((slave._fmi_state, type_name))
    if names is None:
        names = settable_names(table, slave._fmi_state, type_name)
    try:
        if type_name in ("Real", "Float64") and not all(map(math.isfinite, new_values)):
            return False
        convert = FROM_C[type_name]
        pairs = [(names[vr], convert(x)) for vr, x in zip(vrs, new_values)]
    except (KeyError, TypeError, ValueError):
        return False
    slave.values.update(pairs)
    slave.set_since_step.update(pairs)
    return True


def set_values(slave, type_name: str, vrs, new_values) -> int:
    """Apply ``new_values`` to ``vrs``; see the module docstring for the mixed-call rule."""
    table, values, log, state = slave.variables, slave.values, slave._fmi_log, slave._fmi_state
    code = status.OK
    for vr, raw in zip(vrs, new_values):
        v, reason = table.lookup(type_name, vr)
        worst = status.ERROR
        if v is not None:
            reason = settable_problem(v, state)
        if reason is None:
            try:
                value = FROM_C[type_name](raw)
            except (TypeError, ValueError) as exc:
                value, reason = None, f'"{v.name}": {exc}'
            if reason is None and v.type == "Real" and not math.isfinite(value):
                reason, worst = f'"{v.name}" = {value} is not finite; value not applied', status.DISCARD
        if reason is None:
            values[v.name] = slave.set_since_step[v.name] = value
            continue
        log.status(worst, f"fmi2Set{type_name}: {reason}")
        code = max(code, worst)
    return code
