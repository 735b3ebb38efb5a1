"""Charts of results (matplotlib, no screen needed); animations are in ``animation.py``.

Figures are made with ``matplotlib.figure.Figure`` and drawn by the Agg canvas directly:
nothing here touches pyplot or the process-wide backend, so importing this module changes
nothing for a notebook or a host that uses matplotlib itself. Only ``show`` (``mbdfmu plot
--show``) opens a window through pyplot, when a display exists.

Units: a result from ``simulate`` carries them; a CSV does not, so they come from the scene
(``scene_units``) or from the variable names through the variable table
(``units_from_names``: ``.x`` is m, ``.omega`` rad/s, ``.Fx`` N, ...). Each unit gets its
own axis; a variable whose unit is unknown gets an axis of its own.
"""

from __future__ import annotations

import fnmatch
import os
import sys
from pathlib import Path

import numpy as np

from .errors import InputError
from .model.scene import Scene
from .model.variables import GLOBAL_OUTPUTS, TABLES, inputs, outputs
from .result import Result


def figure(**kwargs):
    """A figure on the Agg canvas, without pyplot."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(**kwargs)
    FigureCanvasAgg(fig)
    return fig


def select(result: Result, patterns: list[str] | None) -> list[str]:
    """Variable names matching glob patterns (default: every body's x, y and phi)."""
    patterns = patterns or ["*.x", "*.y", "*.phi"]
    names = [n for n in result.names if any(fnmatch.fnmatchcase(n, p) for p in patterns)]
    if not names:
        raise InputError(f"no variable matches {', '.join(patterns)}; "
                         f"available: {', '.join(result.names)}")
    return names


def scene_units(scene: Scene) -> dict[str, str]:
    """Every output's and input's unit, exactly, from the scene."""
    return {v.name: v.unit for v in (*outputs(scene), *inputs(scene))}


def units_from_names(names: list[str]) -> dict[str, str]:
    """Units the variable table gives by name alone: a suffix whose unit is the same for
    every item type (``.x`` m, ``.Fy`` N; not ``.effort``, N or N.m by driver)."""
    by_suffix: dict[str, set] = {}
    for table in TABLES.values():
        for spec in (*table.outputs, *table.inputs):
            by_suffix.setdefault(spec.suffix, set()).add(spec.unit)
    exact = {v.name: v.unit for v in GLOBAL_OUTPUTS}
    out = {}
    for name in names:
        units = by_suffix.get(name.rpartition(".")[2], set())
        if name in exact:
            out[name] = exact[name]
        elif len(units) == 1 and "{" not in next(iter(units)):
            out[name] = next(iter(units))
    return out


def plot_result(result: Result, variables: list[str] | None, path: str | Path | None,
                title: str = "", fig=None) -> Path | None:
    """One subplot per unit (unit in the label), every selected variable against time;
    saved as PNG at ``path``. ``fig``: draw on this figure (a pyplot window) instead."""
    names = select(result, variables)
    known = result.units or units_from_names(names)
    # a variable of unknown unit shares its axis with nobody
    units = [known.get(n) or f"? {n}" for n in names]
    groups = list(dict.fromkeys(units))
    if fig is None:
        fig = figure(figsize=(8, 2.6 * len(groups) + 0.6))
    axes = fig.subplots(len(groups), 1, sharex=True, squeeze=False)
    for ax, unit in zip(axes[:, 0], groups):
        for n, u in zip(names, units):
            if u == unit:
                ax.plot(result.time, result[n], label=n)
        members = [n for n, u in zip(names, units) if u == unit]
        label = ", ".join(members) if len(members) <= 2 else f"{len(members)} variables"
        ax.set_ylabel(f"{label} (unit unknown: plot --scene)" if unit.startswith("? ")
                      else f"{label} ({unit})")
        ax.grid(True, alpha=0.3)
        ax.legend(loc="best", fontsize="small", ncol=2)
    axes[-1, 0].set_xlabel("time (s)")
    if title:
        axes[0, 0].set_title(title)
    fig.tight_layout()
    if path is None:
        return None
    path = Path(path)
    fig.savefig(path, dpi=110)
    return path


def display_problem() -> str | None:
    """Why no window can open here (None: one can)."""
    if sys.platform.startswith("linux") and not (os.environ.get("DISPLAY")
                                                 or os.environ.get("WAYLAND_DISPLAY")):
        return "no display (DISPLAY and WAYLAND_DISPLAY are unset)"
    return None


def show(result: Result, variables: list[str] | None, title: str = "") -> str:
    """Open the chart in a window when a display exists; returns what happened."""
    problem = display_problem()
    if problem is None:
        import matplotlib.pyplot as plt
        if plt.get_backend().lower() in ("agg", "pdf", "svg", "ps", "cairo", "template"):
            problem = f"matplotlib has no window backend here ({plt.get_backend()})"
        else:
            plot_result(result, variables, None, title, fig=plt.figure(figsize=(9, 6)))
            plt.show()
            return "window closed"
    return f"--show: {problem}; the chart is in the PNG only"
