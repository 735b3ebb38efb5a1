"""Test scenes of the new joints, made with their own kinematics.

A scene with every new joint on a moving, rotated body, made with its own kinematics.

``mechanisms_text()`` is the TOML of a beam pinned to the ground carrying: a disc rolling on
a line of the beam that is offset and tilted (rolling on a moving body), a hanger whose pin
runs in a tilted slot of the beam, two wheels on the beam coupled by a crossed belt (a coupler
whose two joints share the beam: repeated Jacobian entries) and a rack sliding along a tilted
track of the beam, geared to the first wheel (revolute to translational coupler). Positions
are computed here with math only, so that every joint starts closed. ``two_sliders()``
couples two translational joints (two line terms in one row).
"""

from __future__ import annotations

import math

BEAM_ANGLE = 0.1
LINE = dict(point=(0.3, 0.05), axis=(1.0, 0.1), radius=0.2, s=0.5)
SLOT = dict(point=(-0.5, -0.1), axis=(0.3, 1.0), pin=(0.2, 0.1), s=0.4, angle=-1.0)
TRACK = dict(point=(0.0, -0.2), axis=(1.0, 0.2), point_j=(0.1, 0.05), s=0.3, angle=0.05)
BELT_RATIO, RACK_RATIO = 2.0, -0.1


def _rot(phi, v):
    c, s = math.cos(phi), math.sin(phi)
    return (c * v[0] - s * v[1], s * v[0] + c * v[1])


def _add(*vs):
    return (sum(v[0] for v in vs), sum(v[1] for v in vs))


def _scale(k, v):
    return (k * v[0], k * v[1])


def _unit(v):
    n = math.hypot(*v)
    return (v[0] / n, v[1] / n)


def _on_line(beam, spec):
    """The beam point s along the line through spec's point along its axis (ground frame)."""
    return _add(beam, _rot(BEAM_ANGLE, spec["point"]),
                _scale(spec["s"], _rot(BEAM_ANGLE, _unit(spec["axis"]))))


def positions() -> dict[str, tuple[tuple[float, float], float]]:
    """Each body's centre and angle."""
    beam = _rot(BEAM_ANGLE, (1.0, 0.0))                 # pinned at its end (-1, 0) to the origin
    u = _unit(LINE["axis"])
    disc = _add(_on_line(beam, LINE), _scale(LINE["radius"], _rot(BEAM_ANGLE, (-u[1], u[0]))))
    pin = _on_line(beam, SLOT)
    hanger = _add(pin, _scale(-1.0, _rot(SLOT["angle"], SLOT["pin"])))
    rack_angle = BEAM_ANGLE + TRACK["angle"]
    rack = _add(_on_line(beam, TRACK), _scale(-1.0, _rot(rack_angle, TRACK["point_j"])))
    return {"beam": (beam, BEAM_ANGLE), "disc": (disc, 0.4), "hanger": (hanger, SLOT["angle"]),
            "wheel1": (_add(beam, _rot(BEAM_ANGLE, (0.5, 0.0))), 0.3),
            "wheel2": (_add(beam, _rot(BEAM_ANGLE, (-0.5, 0.0))), -0.2),
            "rack": (rack, rack_angle)}


MASSES = {"beam": (2.0, 0.7), "disc": (0.5, 0.01), "hanger": (0.8, 0.05),
          "wheel1": (0.3, 0.004), "wheel2": (0.3, 0.004), "rack": (0.4, 0.01)}


def _v(v) -> str:
    """A TOML value: a 2-vector, a string or a number."""
    if isinstance(v, tuple):
        return f"[{v[0]!r}, {v[1]!r}]"
    return f'"{v}"' if isinstance(v, str) else repr(v)


def mechanisms():
    """The scene read by mbdfmu (the text above is made without it)."""
    import tomllib

    from mbdfmu.model import scene_from_dict

    return scene_from_dict(tomllib.loads(mechanisms_text()), source="<mechanisms>")


def mechanisms_text() -> str:
    parts = ['name = "Mechanisms"', 'description = "Every new joint on a moving beam"',
             "gravity = [0.0, -9.81]"]
    for name, ((x, y), angle) in positions().items():
        m, J = MASSES[name]
        parts.append(f'[[body]]\nname = "{name}"\nmass = {m}\ninertia = {J}\n'
                     f"position = {_v((x, y))}\nangle = {angle!r}")
    joints = [
        dict(name="pivot", type="revolute", body_i="ground", point_i=(0.0, 0.0), body_j="beam",
             point_j=(-1.0, 0.0)),
        dict(name="contact", type="rolling", body_i="beam", point_i=LINE["point"],
             axis_i=LINE["axis"], body_j="disc", radius=LINE["radius"]),
        dict(name="slot", type="slot", body_i="beam", point_i=SLOT["point"], axis_i=SLOT["axis"],
             body_j="hanger", point_j=SLOT["pin"]),
        dict(name="w1", type="revolute", body_i="beam", point_i=(0.5, 0.0), body_j="wheel1"),
        dict(name="w2", type="revolute", body_i="beam", point_i=(-0.5, 0.0), body_j="wheel2"),
        dict(name="belt", type="coupler", joint_i="w1", joint_j="w2", ratio=BELT_RATIO),
        dict(name="track", type="translational", body_i="beam", point_i=TRACK["point"],
             axis_i=TRACK["axis"], body_j="rack", point_j=TRACK["point_j"]),
        dict(name="gear", type="coupler", joint_i="w1", joint_j="track", ratio=RACK_RATIO),
    ]
    for j in joints:
        parts.append("\n".join(["[[joint]]"] + [f"{k} = {_v(v)}" for k, v in j.items()]))
    return "\n\n".join(parts) + "\n"


TWO_SLIDERS = """
name = "TwoSliders"
gravity = [0.0, -9.81]
[[body]]
name = "a"
mass = 1.0
inertia = 0.1
position = [0.0, 0.0]
[[body]]
name = "b"
mass = 3.0
inertia = 0.1
position = [-0.17551651237807456, 0.9041148922791594]   # point_j at (0, 1)
angle = 0.5
[[joint]]
name = "ga"
type = "translational"
body_i = "ground"
axis_i = [1.0, 0.0]
body_j = "a"
[[joint]]
name = "gb"
type = "translational"
body_i = "ground"
point_i = [0.0, 1.0]
axis_i = [1.0, 1.0]
body_j = "b"
point_j = [0.2, 0.0]
[[joint]]
name = "lever"
type = "coupler"
joint_i = "ga"
joint_j = "gb"
ratio = -2.0
[[force]]
name = "push"
type = "force"
body = "a"
value = [4.0, 0.0]
"""


def two_sliders():
    """Slider a on ground x, slider b on a 45 degree ground guide moving -2 times a's slide
    (a lever), a pushed by 4 N."""
    import tomllib

    from mbdfmu.model import scene_from_dict

    return scene_from_dict(tomllib.loads(TWO_SLIDERS), source="<two sliders>")


BUILT = {"mechanisms": mechanisms, "two_sliders": two_sliders}
