"""Charts of a parameter sweep: one PNG per output, one panel per parameter.

Each panel shows the output's final value (solid) and peak |value| (dashed) against the
parameter; with more than one parameter, one line per combination of the others (at most
``MAX_LINES``, evenly spaced, the ends included). Failed runs are left out of the lines and counted in the
title.
"""

from __future__ import annotations

import re
from pathlib import Path


from .sweep import SweepResult

MAX_LINES = 8


def _groups(rows: list[dict], parameter: str, others: list[str]):
    """{combination of the other parameters: rows in order of ``parameter``}."""
    groups: dict[tuple, list[dict]] = {}
    for r in rows:
        groups.setdefault(tuple(r[o] for o in others), []).append(r)
    for members in groups.values():
        members.sort(key=lambda r: r[parameter])
    return groups


def _panel(ax, result: SweepResult, output: str, parameter: str, unit: str) -> None:
    others = [p for p in result.parameters if p != parameter]
    ok = [r for r in result.rows if r["status"] == "ok"]
    groups = list(_groups(ok, parameter, others).items())
    if len(groups) > MAX_LINES:      # evenly spaced combinations of the others, ends included
        keep = sorted({round(k * (len(groups) - 1) / (MAX_LINES - 1)) for k in range(MAX_LINES)})
        groups = [groups[k] for k in keep]
    for k, (key, members) in enumerate(groups):
        x = [r[parameter] for r in members]
        label = ", ".join(f"{o} = {v:.4g}" for o, v in zip(others, key)) or None
        lines = ax.plot(x, [r[f"{output}.final"] for r in members], "-o", color=f"C{k % 10}",
                        markersize=3, label=label)
        ax.plot(x, [r[f"{output}.peak"] for r in members], "--", color=lines[0].get_color(),
                alpha=0.6)
    ax.set_xlabel(parameter)
    ax.set_ylabel(f"{output} ({unit})" if unit else output)
    ax.grid(True, alpha=0.3)
    if others:
        ax.legend(fontsize="x-small", loc="best")


def draw(result: SweepResult, folder: str | Path, units: dict[str, str]) -> list[Path]:
    """One chart per output in ``folder``; returns their paths."""
    from ..plotting import figure

    folder = Path(folder)
    paths = []
    failed = len(result.failed)
    for output in result.outputs:
        n = len(result.parameters)
        fig = figure(figsize=(5.5 * n, 4.0))
        axes = fig.subplots(1, n, squeeze=False)[0]
        for ax, parameter in zip(axes, result.parameters):
            _panel(ax, result, output, parameter, units.get(output, ""))
        title = f"{output}: final (solid) and peak |value| (dashed)"
        if failed:
            title += f"; {failed} of {len(result.rows)} runs failed (see results.csv)"
        fig.suptitle(title, fontsize="medium")
        fig.tight_layout()
        path = folder / f"{re.sub(r'[^A-Za-z0-9_.-]', '_', output)}.png"
        fig.savefig(path, dpi=90)
        paths.append(path)
    return paths


__all__ = ["draw"]
