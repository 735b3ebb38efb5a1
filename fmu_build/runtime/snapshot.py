"""FMU states: what fmi2GetFMUstate captures and the checks before one is restored.

An ``FmuState`` is the Python object behind an fmi2FMUstate handle. Its ``tree`` holds
only the types ``state_format`` can write, so every state can be serialized:

``{"version": 2, "state": "Step Complete", "time": 0.5, "start_time": 0.0,
"stop_time": 1.0 | None, "tolerance": 1e-6 | None, "dirty": False, "terminate_requested": False,
"values": {variable name: value}, "set_since_step": {variable name: value},
"model": <what Slave.save_state returned>}``
"""

from __future__ import annotations

import math

import numpy as np

from . import state_format, status
from .machine import State, fmi_function
from .status import FmiError
from .variables import VariableTable, value_problem

TREE_VERSION = 2
KEYS = {"version", "state", "time", "start_time", "stop_time", "tolerance", "dirty",
        "terminate_requested", "values", "set_since_step", "model"}
# States a saved state may be in (a state is never taken in the Error state).
RESTORABLE = frozenset(State.ALL) - {State.ERROR}


class FmuState:
    """A captured FMU state, tied to the FMU (GUID) that took it."""

    __slots__ = ("guid", "tree")

    def __init__(self, guid: str, tree: dict):
        self.guid = guid
        self.tree = tree


def copy_tree(tree):
    """A copy of ``tree`` that shares no list, dict or array with it."""
    if isinstance(tree, dict):
        return {k: copy_tree(v) for k, v in tree.items()}
    if isinstance(tree, (list, tuple)):
        return [copy_tree(v) for v in tree]
    if isinstance(tree, np.ndarray):
        return tree.copy()
    return tree


def tree_problem(tree, table: VariableTable) -> str | None:
    """Why ``tree`` (read from bytes) is not a state of this FMU's runtime, or None."""
    if not isinstance(tree, dict) or set(tree) != KEYS:
        got = sorted(tree) if isinstance(tree, dict) else type(tree).__name__
        return f"the state's fields are {got}, expected {sorted(KEYS)}"
    if tree["version"] != TREE_VERSION or tree["state"] not in RESTORABLE:
        return f"state version {tree['version']!r} / machine state {tree['state']!r} is not known"
    for key in ("time", "start_time"):
        if not _finite(tree[key]):
            return f'"{key}" is {tree[key]!r}, not a finite number'
    for key in ("stop_time", "tolerance"):
        if tree[key] is not None and not _finite(tree[key]):
            return f'"{key}" is {tree[key]!r}, not a finite number or None'
    if not all(isinstance(tree[k], bool) for k in ("dirty", "terminate_requested")):
        return '"dirty" and "terminate_requested" must be booleans'
    values = tree["values"]
    if not isinstance(values, dict) or set(values) != set(table.by_name):
        return "the state's variables are not this FMU's variables"
    pending = tree["set_since_step"]
    if not isinstance(pending, dict) or not set(pending) <= set(table.by_name):
        return '"set_since_step" names variables this FMU does not have'
    for name, value in [*values.items(), *pending.items()]:
        problem = value_problem(table.by_name[name], value)
        if problem:
            return f'variable "{name}": {problem}'
    return None


def _finite(x) -> bool:
    return isinstance(x, float) and math.isfinite(x)


class StateProtocol:
    """fmi2Get/Set/Serialize/DeSerializeFMUstate for ``Slave`` (a mixin: it uses the
    slave's ``state``, ``values``, time fields and model hooks)."""

    @fmi_function("fmi2GetFMUstate")
    def fmi2_get_fmu_state(self):
        tree = {"version": TREE_VERSION, "state": self._fmi_state, "time": self._fmi_time,
                "start_time": self.start_time, "stop_time": self.stop_time,
                "tolerance": self.tolerance, "dirty": self._fmi_dirty,
                "terminate_requested": self._fmi_terminate, "values": dict(self.values),
                "set_since_step": dict(self.set_since_step), "model": copy_tree(self.save_state())}
        return status.OK, FmuState(self.guid, tree)

    @fmi_function("fmi2SetFMUstate")
    def fmi2_set_fmu_state(self, state):
        if not isinstance(state, FmuState) or state.guid != self.guid:
            raise FmiError("the state was not taken from an instance of this FMU")
        tree = state.tree
        self.values = dict(tree["values"])
        self.set_since_step = dict(tree["set_since_step"])
        self._fmi_at(tree["time"])
        self.start_time = tree["start_time"]
        self.stop_time, self.tolerance = tree["stop_time"], tree["tolerance"]
        self._fmi_dirty, self._fmi_terminate = tree["dirty"], tree["terminate_requested"]
        self._fmi_state = tree["state"]
        self.restore_state(copy_tree(tree["model"]))   # (sees the restored values and flags)
        self._fmi_stale = self._fmi_calculates
        return status.OK, None

    @fmi_function("fmi2SerializeFMUstate")
    def fmi2_serialize_fmu_state(self, state):
        if not isinstance(state, FmuState) or state.guid != self.guid:
            raise FmiError("the state was not taken from an instance of this FMU")
        try:
            return status.OK, state_format.dumps(state.tree, self.guid)
        except state_format.StateFormatError as exc:
            raise FmiError(f"cannot serialize the state: {exc}") from None

    @fmi_function("fmi2DeSerializeFMUstate")
    def fmi2_deserialize_fmu_state(self, blob: bytes):
        try:
            tree = state_format.loads(blob, self.guid)
        except state_format.StateFormatError as exc:
            raise FmiError(f"refused: {exc}") from None
        problem = tree_problem(tree, self.variables) or self.check_state(tree["model"])
        if problem:
            raise FmiError(f"refused: {problem}")
        return status.OK, FmuState(self.guid, tree)
