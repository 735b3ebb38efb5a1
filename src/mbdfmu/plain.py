"""Run states as plain data: trees of None, bool, int, float, str, lists, dicts and numpy
arrays, which can be copied cheaply and serialized without executing anything (the FMU's
state format stores nothing else).

An object that is part of a run's state (a counter set, the energy audit, a Newton
iteration matrix, an input signal) is a ``Plain`` subclass: it gives its fields with
``to_plain()`` and is rebuilt by ``from_plain``; ``encode`` tags it with its class name,
``decode`` looks the name up among the registered classes (never imports anything).
"""

from __future__ import annotations

import numpy as np

TYPE_KEY = "__plain__"
_REGISTRY: dict[str, type] = {}


class Plain:
    """Base of objects that are saved in run states. Subclasses list their attributes in
    ``plain_fields`` (or override ``to_plain``/``from_plain``)."""

    plain_fields: tuple[str, ...] = ()
    # Fields are numbers, strings or arrays that are replaced, never changed in place: a
    # shallow copy is a snapshot (``Integrator.rollback_point``).
    flat_fields = False

    def __init_subclass__(cls, **kwargs):
        super().__init_subclass__(**kwargs)
        _REGISTRY[cls.__name__] = cls

    def to_plain(self) -> dict:
        return {name: encode(getattr(self, name)) for name in self.plain_fields}

    @classmethod
    def from_plain(cls, data: dict):
        obj = cls.__new__(cls)
        for name in cls.plain_fields:
            setattr(obj, name, decode(data[name]))
        return obj


def encode(value):
    """A plain copy of ``value`` (arrays copied, ``Plain`` objects tagged with their class)."""
    if value is None or isinstance(value, (bool, int, float, str)):
        return value
    if isinstance(value, np.ndarray):
        return value.copy()
    if isinstance(value, np.generic):
        return value.item()
    if isinstance(value, Plain):
        return {TYPE_KEY: type(value).__name__, "fields": value.to_plain()}
    if isinstance(value, (list, tuple)):
        return [encode(v) for v in value]
    if isinstance(value, dict):
        return {str(k): encode(v) for k, v in value.items()}
    raise TypeError(f"{type(value).__name__} is not part of a plain run state")


def decode(value):
    """The objects of an ``encode``d tree, rebuilt; unknown class names are an error."""
    if isinstance(value, np.ndarray):
        return value.copy()
    if isinstance(value, list):
        return [decode(v) for v in value]
    if isinstance(value, dict):
        if TYPE_KEY in value:
            cls = _REGISTRY.get(value[TYPE_KEY])
            if cls is None:
                raise ValueError(f"unknown state object {value[TYPE_KEY]!r}")
            return cls.from_plain(value["fields"])
        return {k: decode(v) for k, v in value.items()}
    return value
