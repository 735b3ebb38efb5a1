"""Charts and animations of results (matplotlib, no screen needed).

Figures are made with ``matplotlib.figure.Figure`` and drawn by the Agg canvas directly:
nothing here touches pyplot or the process-wide backend, so importing this module changes
nothing for a notebook or a host that uses matplotlib itself.
"""

from __future__ import annotations

import fnmatch
from pathlib import Path

import numpy as np

from .errors import InputError
from .model.scene import GROUND, CouplerJoint, PointForce, RollingJoint, Scene, SpringDamper
from .result import Result

# Frames in an animation at most; longer results are subsampled.
MAX_FRAMES = 150


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


def plot_result(result: Result, variables: list[str] | None, path: str | Path,
                title: str = "") -> Path:
    """One subplot per unit, every selected variable against time; saved as PNG."""
    names = select(result, variables)
    units = [result.units.get(n, "") for n in names]
    groups = list(dict.fromkeys(units))
    fig = figure(figsize=(8, 2.6 * len(groups) + 0.6))
    axes = fig.subplots(len(groups), 1, sharex=True, squeeze=False)
    for ax, unit in zip(axes[:, 0], groups):
        for n, u in zip(names, units):
            if u == unit:
                ax.plot(result.time, result[n], label=n)
        ax.set_ylabel(unit or "value")
        ax.grid(True, alpha=0.3)
        ax.legend(loc="best", fontsize="small", ncol=2)
    axes[-1, 0].set_xlabel("time (s)")
    if title:
        axes[0, 0].set_title(title)
    fig.tight_layout()
    path = Path(path)
    fig.savefig(path, dpi=110)
    return path


def body_outlines(scene: Scene) -> dict[str, np.ndarray]:
    """Each body's drawing points in its own frame: its centre, joint and force points."""
    points: dict[str, list] = {b.name: [(0.0, 0.0)] for b in scene.bodies}
    points[GROUND] = []
    for j in scene.joints:
        if isinstance(j, CouplerJoint):          # joins coordinates, not points
            continue
        points[j.body_i].append(j.point_i)
        # a rolling disc: a spoke to its rim, so that its rotation shows
        points[j.body_j].append((j.radius, 0.0) if isinstance(j, RollingJoint) else j.point_j)
    for f in scene.forces:
        if isinstance(f, PointForce):
            points[f.body].append(f.point)
        elif isinstance(f, SpringDamper):
            points[f.body_i].append(f.point_i)
            points[f.body_j].append(f.point_j)
    return {k: np.array(v, dtype=float).reshape(-1, 2) for k, v in points.items()}


def _world(points: np.ndarray, x: float, y: float, phi: float) -> np.ndarray:
    c, s = np.cos(phi), np.sin(phi)
    return np.column_stack((x + c * points[:, 0] - s * points[:, 1],
                            y + s * points[:, 0] + c * points[:, 1]))


def animate(scene: Scene, result: Result, path: str | Path, fps: int = 25) -> Path:
    """A GIF of the mechanism: each body drawn as lines from its centre to its points."""
    names = [b.name for b in scene.bodies]
    for n in names:
        for k in ("x", "y", "phi"):
            if f"{n}.{k}" not in result:
                raise InputError(f'the result has no "{n}.{k}": it is not a run of this scene')
    outlines = body_outlines(scene)
    frames = np.unique(np.linspace(0, len(result.time) - 1, min(MAX_FRAMES, len(result.time))).astype(int))
    poses = {n: np.column_stack([result[f"{n}.{k}"] for k in ("x", "y", "phi")]) for n in names}
    allpts = np.vstack([_world(outlines[n], *poses[n][i]) for n in names for i in frames]
                       + [outlines[GROUND]])
    lo, hi = allpts.min(axis=0), allpts.max(axis=0)
    pad = 0.1 * max(hi - lo) + 1e-3
    fig = figure(figsize=(5, 5), dpi=80)
    ax = fig.subplots()
    ax.set_xlim(lo[0] - pad, hi[0] + pad)
    ax.set_ylim(lo[1] - pad, hi[1] + pad)
    ax.set_aspect("equal")
    ax.grid(True, alpha=0.3)
    ax.set_title(scene.name)
    if len(outlines[GROUND]):
        g = outlines[GROUND]
        ax.plot(g[:, 0], g[:, 1], "k^", markersize=9)
    lines = {n: ax.plot([], [], "-o", lw=3, markersize=4)[0] for n in names}
    springs = [(f, ax.plot([], [], "--", color="gray")[0]) for f in scene.forces
               if isinstance(f, SpringDamper)]
    label = ax.text(0.02, 0.95, "", transform=ax.transAxes)

    def point(body, local, i):
        if body == GROUND:
            return np.asarray(local, dtype=float)
        return _world(np.array([local], dtype=float), *poses[body][i])[0]

    def draw(i):
        for n in names:
            w = _world(outlines[n], *poses[n][i])
            centre = w[0]
            xs, ys = [], []
            for p in w[1:] if len(w) > 1 else w:
                xs += [centre[0], p[0], np.nan]
                ys += [centre[1], p[1], np.nan]
            lines[n].set_data(xs, ys)
        for f, line in springs:
            a, b = point(f.body_i, f.point_i, i), point(f.body_j, f.point_j, i)
            line.set_data([a[0], b[0]], [a[1], b[1]])
        label.set_text(f"t = {result.time[i]:.4f} s")

    return save_gif(fig, draw, frames, path, fps)


def save_gif(fig, draw, frames, path: str | Path, fps: int) -> Path:
    """Draw each frame with ``draw(i)`` and save them as a looping GIF.

    Frames are rendered here and quantized with Pillow's fast octree: matplotlib's
    PillowWriter spends ~50 ms a frame in the default quantizer."""
    from PIL import Image

    images = []
    for i in frames:
        draw(i)
        fig.canvas.draw()
        rgba = Image.frombuffer("RGBA", fig.canvas.get_width_height(),
                                fig.canvas.buffer_rgba(), "raw", "RGBA", 0, 1)
        images.append(rgba.convert("RGB").quantize(colors=64, method=Image.Quantize.FASTOCTREE))
    path = Path(path)
    images[0].save(path, save_all=True, append_images=images[1:], loop=0,
                   duration=int(1000 / fps))
    return path
