"""Animations of a run: each body drawn as a shape, on axes in metres, with a legend.

Shapes come from what is attached to a body: a bar between its two joint points, a plate
through three or more, a bar from its one joint point to a disc at its centre of mass (a
pendulum bob), a block on a translational joint (oriented along the sliding axis). The
ground shows pivots where joints fix bodies to it and the line of each guide; springs are
zigzags between their points. (This scene format has no rolling joint, so no discs for
rolling.) Frames are rendered with the Agg canvas and saved as a GIF with Pillow.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from .errors import InputError
from .model.scene import (GROUND, CouplerJoint, PointForce, RollingJoint, Scene, SpringDamper,
                          TranslationalJoint)
from .plotting import figure
from .result import Result

# Frames in an animation at most; longer results are subsampled.
MAX_FRAMES = 150
# Shape sizes relative to the size of the drawing.
BAR_WIDTH_PT = 6
DISC = 0.025
BLOCK = (0.12, 0.06)
SPRING_COILS, SPRING_WIDTH = 8, 0.015


def world(points: np.ndarray, x: float, y: float, phi: float) -> np.ndarray:
    c, s = np.cos(phi), np.sin(phi)
    return np.column_stack((x + c * points[:, 0] - s * points[:, 1],
                            y + s * points[:, 0] + c * points[:, 1]))


def attachments(scene: Scene) -> dict[str, np.ndarray]:
    """Each body's joint, spring and force points in its own frame (ground: ground frame)."""
    points: dict[str, list] = {b.name: [] for b in scene.bodies}
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
    return {k: np.unique(np.array(v, dtype=float).reshape(-1, 2), axis=0)
            for k, v in points.items()}


def _hull(points: np.ndarray) -> np.ndarray:
    """Convex hull (counter-clockwise) of 2-D points, by the monotone chain."""
    pts = sorted(map(tuple, points))

    def half(seq):
        out = []
        for p in seq:
            while len(out) >= 2 and np.cross(np.subtract(out[-1], out[-2]),
                                             np.subtract(p, out[-2])) <= 0:
                out.pop()
            out.append(p)
        return out[:-1]
    return np.array(half(pts) + half(pts[::-1]))


def _block_axis(scene: Scene, body: str, poses: dict) -> float | None:
    """The sliding axis of a body on a guide (body_j of a translational joint) in its own
    frame (rad; fixed, since the joint locks the relative rotation); None: no guide."""
    for j in scene.joints:
        if isinstance(j, TranslationalJoint) and body == j.body_j:
            phi_i = poses[j.body_i][0, 2] if j.body_i != GROUND else 0.0
            return float(phi_i + np.arctan2(j.axis_i[1], j.axis_i[0]) - poses[body][0, 2])
    return None


def _disc_radius(scene: Scene, body: str) -> float | None:
    """The radius of a body that rolls (body_j of a rolling joint), else None."""
    return next((j.radius for j in scene.joints
                 if isinstance(j, RollingJoint) and j.body_j == body), None)


class BodyShape:
    """The artists of one body and how they move with its pose."""

    def __init__(self, ax, name: str, local: np.ndarray, colour, size: float, axis=None,
                 radius: float | None = None):
        self.local, self.kind = local, "bar"
        if radius is not None:       # a rolling disc: its rim, and a spoke (``local``)
            self.local, self.kind = np.vstack(([[0.0, 0.0]], local)), "disc"
        elif axis is not None:
            L, H = BLOCK[0] * size, BLOCK[1] * size
            c, s = np.cos(axis), np.sin(axis)
            corners = np.array([[-L, -H], [L, -H], [L, H], [-L, H]]) / 2
            self.local, self.kind = corners @ np.array([[c, s], [-s, c]]), "block"
        elif len(local) >= 3:
            self.local, self.kind = _hull(local), "plate"
        elif len(local) == 1:
            self.local = np.vstack((local, [[0.0, 0.0]]))
        elif len(local) == 0:
            self.local = np.zeros((1, 2))
        self.disc = None
        from matplotlib.patches import Circle, Polygon
        if self.kind == "disc":
            self.disc = ax.add_patch(Circle((0, 0), radius, facecolor=colour, edgecolor="k",
                                            alpha=0.75, label=name, zorder=2))
            self.patch = ax.plot([], [], "-", lw=1.5, color="k", zorder=3)[0]
        elif self.kind in ("block", "plate"):
            self.patch = ax.add_patch(Polygon(self.local, closed=True, facecolor=colour,
                                              edgecolor="k", alpha=0.75, label=name))
        else:
            self.patch = ax.plot([], [], "-", lw=BAR_WIDTH_PT, color=colour,
                                 solid_capstyle="round", label=name, alpha=0.85)[0]
            if len(local) <= 1:     # a bob: a disc at the centre of mass
                self.disc = ax.add_patch(Circle((0, 0), DISC * size, facecolor=colour,
                                                edgecolor="k", zorder=3))
        self.pins = ax.plot([], [], "o", color="white", markeredgecolor="k", markersize=4,
                            zorder=4)[0]

    @property
    def artists(self) -> list:
        return [a for a in (self.patch, self.disc, self.pins) if a is not None]

    def update(self, pose) -> None:
        shape = world(self.local, *pose)
        if self.kind in ("block", "plate"):
            self.patch.set_xy(shape)
        else:
            self.patch.set_data(shape[:, 0], shape[:, 1])
        if self.disc is not None:
            self.disc.center = (pose[0], pose[1])
        pins = shape if self.kind == "bar" else world(np.zeros((1, 2)), *pose)
        self.pins.set_data(pins[:, 0], pins[:, 1])


def zigzag(a: np.ndarray, b: np.ndarray, width: float) -> np.ndarray:
    """Points of a spring's zigzag from a to b."""
    d = b - a
    length = max(float(np.hypot(*d)), 1e-12)
    t = np.concatenate(([0.0, 0.1], np.linspace(0.1, 0.9, 2 * SPRING_COILS + 1)[1:-1], [0.9, 1.0]))
    side = np.zeros_like(t)
    side[2:-2] = width * np.where(np.arange(len(t) - 4) % 2 == 0, 1.0, -1.0)
    normal = np.array([-d[1], d[0]]) / length
    return a + np.outer(t, d) + np.outer(side, normal)


def _ground(ax, scene: Scene, size: float) -> None:
    """Pivots where joints fix bodies to the ground, and the line of each guide."""
    pointed = [j for j in scene.joints if not isinstance(j, (CouplerJoint, RollingJoint))]
    for j in scene.joints:           # the line a disc rolls on, when it is the ground's
        if isinstance(j, RollingJoint) and j.body_i == GROUND:
            p, u = np.asarray(j.point_i), np.asarray(j.axis_i) / np.hypot(*j.axis_i)
            ends = np.array([p - 10 * size * u, p + 10 * size * u])
            ax.plot(ends[:, 0], ends[:, 1], "-", color="0.5", lw=1.5, zorder=0,
                    label="rolling line")
    pivots = [j.point_i for j in pointed if j.body_i == GROUND] + \
             [j.point_j for j in pointed if j.body_j == GROUND]
    for j in scene.joints:
        if isinstance(j, TranslationalJoint) and GROUND in (j.body_i, j.body_j):
            p = np.asarray(j.point_i if j.body_i == GROUND else j.point_j)
            u = np.asarray(j.axis_i) / np.hypot(*j.axis_i)
            ends = np.array([p - 10 * size * u, p + 10 * size * u])
            ax.plot(ends[:, 0], ends[:, 1], "-", color="0.5", lw=1.5, zorder=0, label="guide")
    if pivots:
        pts = np.array(pivots, dtype=float)
        ax.plot(pts[:, 0], pts[:, 1], "k^", markersize=10, zorder=5, label="ground pivot")


def _rod(body, local: np.ndarray) -> np.ndarray:
    """A body hung from one point whose inertia is that of a uniform rod through its
    centre (at least half of m (2 |s|)^2 / 12) is drawn as that rod, not as a bob."""
    if len(local) == 1:
        arm = float(np.hypot(*local[0]))
        if arm > 0 and body.inertia >= 0.5 * body.mass * (2 * arm) ** 2 / 12:
            return np.vstack((local, -local))
    return local


def _frames_and_poses(scene: Scene, result: Result):
    names = [b.name for b in scene.bodies]
    for n in names:
        for k in ("x", "y", "phi"):
            if f"{n}.{k}" not in result:
                raise InputError(f'the result has no "{n}.{k}": it is not a run of this scene')
    count = min(MAX_FRAMES, len(result.time))
    frames = np.unique(np.linspace(0, len(result.time) - 1, count).astype(int))
    poses = {n: np.column_stack([result[f"{n}.{k}"] for k in ("x", "y", "phi")]) for n in names}
    return frames, poses


def _limits(ax, scene, outlines, poses, frames) -> float:
    pts = [world(outlines[n], *poses[n][i]) for n in poses for i in frames if len(outlines[n])]
    pts += [poses[n][frames, :2] for n in poses] + [outlines[GROUND]]
    allpts = np.vstack([p for p in pts if len(p)])
    lo, hi = allpts.min(axis=0), allpts.max(axis=0)
    size = max(float(np.max(hi - lo)), 1e-3)
    pad = 0.12 * size
    ax.set_xlim(lo[0] - pad, hi[0] + pad)
    ax.set_ylim(lo[1] - pad, hi[1] + pad)
    return size


def animate(scene: Scene, result: Result, path: str | Path, fps: int = 25,
            progress=None) -> Path:
    """A GIF of the mechanism through a run; ``progress(done, total)`` after each frame."""
    frames, poses = _frames_and_poses(scene, result)
    outlines = attachments(scene)
    fig = figure(figsize=(6, 5.4), dpi=80)
    ax = fig.subplots()
    ax.set_aspect("equal")
    size = _limits(ax, scene, outlines, poses, frames)
    ax.grid(True, alpha=0.3)
    ax.set_xlabel("x (m)")
    ax.set_ylabel("y (m)")
    ax.set_title(scene.name)
    _ground(ax, scene, size)
    shapes = {b.name: BodyShape(ax, b.name, _rod(b, outlines[b.name]), f"C{k % 10}", size,
                                _block_axis(scene, b.name, poses), _disc_radius(scene, b.name))
              for k, b in enumerate(scene.bodies)}
    springs = [(f, ax.plot([], [], "-", color="0.3", lw=1, label="spring" if k == 0 else None)[0])
               for k, f in enumerate(f for f in scene.forces if isinstance(f, SpringDamper))]
    ax.legend(loc="upper right", fontsize="x-small", framealpha=0.8)
    label = ax.text(0.02, 0.95, "", transform=ax.transAxes)

    def point(body, local, i):
        if body == GROUND:
            return np.asarray(local, dtype=float)
        return world(np.array([local], dtype=float), *poses[body][i])[0]

    def draw(i):
        for name, shape in shapes.items():
            shape.update(poses[name][i])
        for f, line in springs:
            z = zigzag(point(f.body_i, f.point_i, i), point(f.body_j, f.point_j, i),
                       SPRING_WIDTH * size)
            line.set_data(z[:, 0], z[:, 1])
        label.set_text(f"t = {result.time[i]:.4f} s")

    moving = [a for shape in shapes.values() for a in shape.artists]
    moving += [line for _, line in springs] + [label]
    return save_gif(fig, draw, frames, path, fps, progress, moving)


def save_gif(fig, draw, frames, path: str | Path, fps: int, progress=None,
             moving: list | None = None) -> Path:
    """Draw each frame with ``draw(i)`` and save them as a looping GIF.

    With ``moving`` (the artists ``draw`` changes) the rest (axes, ticks, legend, ground) is
    rendered once and each frame draws only those on top of it (blitting). Frames are
    quantized with Pillow's fast octree: matplotlib's PillowWriter spends most of each frame
    in Pillow's default quantizer."""
    from PIL import Image

    canvas = fig.canvas
    background = None
    if moving:
        for artist in moving:
            artist.set_animated(True)
        canvas.draw()
        background = canvas.copy_from_bbox(fig.bbox)
    images = []
    for k, i in enumerate(frames):
        draw(i)
        if background is None:
            canvas.draw()
        else:
            canvas.restore_region(background)
            for artist in moving:
                artist.axes.draw_artist(artist)
        rgba = Image.frombuffer("RGBA", canvas.get_width_height(), canvas.buffer_rgba(),
                                "raw", "RGBA", 0, 1)
        images.append(rgba.convert("RGB").quantize(colors=64, method=Image.Quantize.FASTOCTREE))
        if progress is not None:
            progress(k + 1, len(frames))
    path = Path(path)
    images[0].save(path, save_all=True, append_images=images[1:], loop=0,
                   duration=int(1000 / fps))
    return path
