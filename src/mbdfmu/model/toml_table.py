"""Typed, located access to TOML tables, shared by the scene and scenario readers.

A model class declares each of its keys once, as a dataclass field made by ``key(kind,
...)``; ``read_fields`` then reads any such class from a table, checking kinds and ranges
and naming the file, the item and the key in every problem.
"""

from __future__ import annotations

import dataclasses
import math
import sys
from pathlib import Path
from typing import Any

from ..errors import Problems, ReadError, suggest

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover - Python 3.10 (FMUs read their scene as JSON and need no TOML)
    try:
        import tomli as tomllib
    except ModuleNotFoundError:
        tomllib = None

REQUIRED = dataclasses.MISSING
KINDS = ("float", "vec2", "floats", "str", "bool", "table")


def key(kind: str, default: Any = REQUIRED, *, positive: bool = False,
        nonnegative: bool = False, nonzero: bool = False, ref: str | None = None,
        required_unless: str | None = None):
    """A dataclass field that is also a scene key of ``kind`` (one of ``KINDS``).

    ``ref`` names what a string refers to ("body", "joint", "revolute joint");
    ``required_unless`` names a bool key: only when it is true may this key be left out
    (and take ``default``).
    """
    assert kind in KINDS, kind
    meta = {"kind": kind, "positive": positive, "nonnegative": nonnegative,
            "nonzero": nonzero, "ref": ref, "required_unless": required_unless}
    if default is REQUIRED:
        return dataclasses.field(metadata=meta)
    if isinstance(default, dict):
        return dataclasses.field(default_factory=lambda: dict(default), metadata=meta)
    return dataclasses.field(default=default, metadata=meta)


def load_toml(path: str | Path, error: type[ReadError]) -> dict:
    """Parse a TOML file; any failure becomes one ``error`` naming the file."""
    path = Path(path)
    if tomllib is None:  # pragma: no cover
        raise error(f"{path.name}: reading TOML needs Python 3.11 or the tomli package")
    try:
        text = path.read_text(encoding="utf-8")
    except OSError as exc:
        raise error(f"{path}: cannot read: {exc.strerror or exc}") from None
    except UnicodeDecodeError as exc:
        raise error(f"{path}: not a text file (UTF-8): {exc.reason} at byte {exc.start}") from None
    try:
        return tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise error(f"{path.name}: invalid TOML: {exc}") from None
    except RecursionError:
        raise error(f"{path.name}: invalid TOML: nested too deeply") from None


class Table:
    """One TOML table being read; remembers which keys were read, collects problems."""

    def __init__(self, data: Any, where: str, problems: Problems):
        self.where, self.problems = where, problems
        self.data = data if isinstance(data, dict) else {}
        if not isinstance(data, dict):
            problems.add(where, "must be a table")
        self.known: set[str] = set()
        self.ok = isinstance(data, dict)

    def fail(self, what: str) -> None:
        self.ok = False
        self.problems.add(self.where, what)

    def get(self, name: str, kind: str, default: Any = REQUIRED, *, positive=False,
            nonnegative=False, nonzero=False):
        """Read ``name`` as ``kind``; ``REQUIRED`` default: a missing key is a problem."""
        self.known.add(name)
        if name not in self.data:
            if default is REQUIRED:
                self.fail(f'missing required key "{name}"')
                return None
            return default
        value, problem = convert(self.data[name], kind)
        if problem is None and kind == "float":
            problem = _range_problem(value, positive, nonnegative)
        if problem is None and nonzero and kind == "vec2" and math.hypot(*value) < 1e-12:
            problem = "has zero length"
        if problem is None and nonzero and kind == "float" and value == 0.0:
            problem = "must not be zero"
        if problem is not None:
            self.fail(f'"{name}" {problem}')
            return None
        return value

    def finish(self) -> None:
        """Every key not read is unknown: a problem, with a suggestion."""
        for name in self.data:
            if name not in self.known:
                self.fail(f'unknown key "{name}"{suggest(name, self.known)}')


def _range_problem(value: float, positive: bool, nonnegative: bool) -> str | None:
    if positive and value <= 0:
        return f"must be positive, got {value:g}"
    if nonnegative and value < 0:
        return f"must not be negative, got {value:g}"
    return None


def convert(value: Any, kind: str) -> tuple[Any, str | None]:
    """(value as ``kind``, None) or (None, what is wrong)."""
    if kind == "float":
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            return None, f"must be a number, got {value!r}"
        if not math.isfinite(value):
            return None, f"must be finite, got {value}"
        return float(value), None
    if kind in ("vec2", "floats"):
        if not isinstance(value, list) or not value or (kind == "vec2" and len(value) != 2):
            shape = "a list of two numbers" if kind == "vec2" else "a non-empty list of numbers"
            return None, f"must be {shape}, got {value!r}"
        out = []
        for v in value:
            if isinstance(v, bool) or not isinstance(v, (int, float)):
                return None, f"must hold numbers, got {v!r}"
            if not math.isfinite(v):
                return None, f"must be finite, got {v}"
            out.append(float(v))
        return tuple(out), None
    if kind == "str":
        return (value, None) if isinstance(value, str) else (None, f"must be a string, got {value!r}")
    if kind == "bool":
        return ((value, None) if isinstance(value, bool)
                else (None, f"must be true or false, got {value!r}"))
    return (value, None) if isinstance(value, dict) else (None, f"must be a table, got {value!r}")


def read_fields(cls, table: Table, values: dict[str, Any] | None = None) -> dict[str, Any]:
    """Every ``key`` field of dataclass ``cls`` read from ``table`` (``values`` given by the
    caller are taken as they are). Fields of kind "table" are left to the caller."""
    out = dict(values or {})
    fields = [f for f in dataclasses.fields(cls) if "kind" in f.metadata and f.name not in out]
    for f in fields:
        meta = f.metadata
        if meta["kind"] == "table":
            continue
        default = f.default
        unless = meta["required_unless"]
        if unless is not None and table.data.get(unless) is not True:
            default = REQUIRED   # the field's default applies only when ``unless`` is true
        out[f.name] = table.get(f.name, meta["kind"], default, positive=meta["positive"],
                                nonnegative=meta["nonnegative"], nonzero=meta["nonzero"])
    return out
