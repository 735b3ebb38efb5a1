"""Simulation results: time first, every variable by name, the raw arrays, CSV in and out."""

from __future__ import annotations

import csv
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from .errors import InputError


@dataclass
class Result:
    """A run's output at each output time.

    ``result["crank.phi"]`` is one variable over time; ``names`` lists them (CSV order);
    ``q``, ``qd``, ``qdd`` (nt, n) and ``lam`` (nt, m) are the raw coordinates, velocities,
    accelerations and Lagrange multipliers; ``units`` maps names to units.
    """

    time: np.ndarray
    names: list[str]
    values: np.ndarray
    q: np.ndarray | None = None
    qd: np.ndarray | None = None
    qdd: np.ndarray | None = None
    lam: np.ndarray | None = None
    units: dict[str, str] = field(default_factory=dict)
    method: str = ""
    method_reason: str = ""
    stats: dict[str, int] = field(default_factory=dict)
    warnings: list[str] = field(default_factory=list)
    # transitions of end stops and friction: (time s, joint, what happened), in time order
    events: list[tuple[float, str, str]] = field(default_factory=list)
    # auto's changes of method (integrators/auto_watch.py): (time s, from, to, reason)
    switches: list[tuple[float, str, str, str]] = field(default_factory=list)

    def __getitem__(self, name: str) -> np.ndarray:
        if name == "time":
            return self.time
        try:
            return self.values[:, self.names.index(name)]
        except ValueError:
            raise KeyError(f'no variable "{name}" in this result') from None

    def __contains__(self, name: str) -> bool:
        return name == "time" or name in self.names

    def to_csv(self, path: str | Path) -> Path:
        """Write ``time,<variable>,...`` with full precision."""
        path = Path(path)
        data = np.column_stack((self.time, self.values))
        np.savetxt(path, data, delimiter=",", header=",".join(["time"] + self.names),
                   comments="", fmt="%.17g")
        return path


def read_csv(path: str | Path) -> Result:
    """Read a CSV written by ``Result.to_csv``, by fmpy (quoted names) or any table with a
    ``time`` column first."""
    path = Path(path)
    try:
        with open(path, encoding="utf-8", newline="") as fh:
            header = next(csv.reader(fh), [])
        data = np.loadtxt(path, delimiter=",", skiprows=1, ndmin=2)
    except (OSError, ValueError) as exc:
        raise InputError(f"{path}: cannot read as CSV: {exc}") from None
    if not header or header[0].strip() != "time":
        raise InputError(f'{path}: the first column must be "time"')
    if data.shape[1] != len(header):
        raise InputError(f"{path}: {len(header)} names in the header but {data.shape[1]} columns")
    return Result(time=data[:, 0], names=[h.strip() for h in header[1:]], values=data[:, 1:])
