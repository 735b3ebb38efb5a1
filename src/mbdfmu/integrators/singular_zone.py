"""Step planning of the projected Runge-Kutta pairs through singular configurations.

Near a singular configuration (P2's cranks horizontal) the index-1 equations are
ill-conditioned: q'' carries normal components that grow like 1 / sigma (sigma the
smallest singular value of Psi_q), and the position projection of a state close to the
configuration is conditioning-limited. So a step that ends next to the configuration, or a
stage that lands next to it, spoils the run, while a step across it with every stage clear
of it is as accurate as any other. The zone: ``singularity_indicator`` below ZONE (for P2
about 0.014 rad either side of the horizontal). The plan (``plan``):

* steps end before the zone: a step that would end inside it is shortened to end some
  way before it (it comes closer in two steps, the prediction of the crossing improving),
  then at its edge;
* from the edge, one step crosses the whole zone with the configuration in the middle of
  a wide gap between the tableau's nodes (no stage lands near it), the latest gap that
  lets it end beyond the zone; its error estimate counts only the part along the
  constraints, which is what the projection keeps (``ProjectedRK._tangent``);
* when the tolerance does not allow so long a step, the crossing step is shorter, with the
  configuration in a later gap, and ends inside the zone, past the configuration (a step
  from inside the zone towards it is planned the same way); ordinary steps that cross
  instead put stages next to it, are rejected, and end ever closer to it;
* a step that would land on an output time inside the zone (inputs set by a master) is
  planned like any other: the crossing step passes the output time, which then comes from
  its dense output (the inputs beyond it are the current ones; if a master sets others
  at that time, ``Simulation`` restarts from that output);
* a step not planned that ends inside the zone anyway (the crossing was not foreseen) is
  retried to end at the zone's edge (``after_step``).

The indicator falls linearly to zero at the configuration (``singularity_indicator``), so
its rate k, from a probe a little way along q', gives the time of the crossing t* and the
zone's half-width in time, ZONE_MARGIN ZONE / k.
"""

from __future__ import annotations

import functools
import math

import numpy as np

from ..equations.singular import singularity_indicator
from ..plain import Plain

ZONE = 1e-2
# Below this the indicator says a singular configuration is near: the crossing is planned
# and the error estimate counts only its part along the constraints.
NEAR_ZONE = 0.1
# Half-width of the zone in time, relative to ZONE / k.
ZONE_MARGIN = 1.2
# An indicator this small at both ends of a step: Psi_q is rank-deficient throughout
# (redundant constraints), not near a singular configuration.
REDUNDANT = 1e-7
# A crossing step puts the configuration in the middle of a gap between the tableau's
# nodes (step fractions) at least this wide, so that its stages keep at least
# MIN_CLEARANCE from it (in indicator units), and ends at least INNER past it.
MIN_GAP = 0.12
MIN_CLEARANCE = 1e-4
INNER = 1e-3
# The probe that measures the indicator's rate: this fraction of the indicator, in time.
PROBE = 1e-4


class SingularZone(Plain):
    """The planner's state: the indicator at the integrator's time, and whether the step
    being tried is a planned crossing or ends on an output time."""

    plain_fields = ("indicator", "crossing", "landing")
    flat_fields = True

    def __init__(self):
        self.indicator = None
        self.crossing = False
        self.landing = False


def indicator(integrator, t: float, q: np.ndarray) -> float:
    eq = integrator.equations
    if eq.m == 0:
        return math.inf
    if eq.ckernel is not None:
        return eq.ckernel.singularity_indicator(q, eq.motion_values(t, integrator.inputs(t)))
    return singularity_indicator(integrator.constraints(t, q, sparse=True)[1])


def crossing(integrator, c0: float) -> tuple[float, float] | None:
    """(rate k of the indicator, time t* of the configuration) when the mechanism is
    approaching a singular configuration, else None."""
    if not REDUNDANT <= c0 < NEAR_ZONE:
        return None
    speed = float(np.max(np.abs(integrator.qd), initial=0.0))
    if speed == 0.0:
        return None
    eps = PROBE * c0 / speed
    ahead = indicator(integrator, integrator.t + eps, integrator.q + eps * integrator.qd)
    k = (c0 - ahead) / eps
    if not k > 0.0:
        return None
    return k, integrator.t + c0 / k


def gaps(nodes: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Middles and widths of the gaps of at least MIN_GAP between the sorted nodes (and 1),
    read-only: worked out once per tableau (every run of steps in C asks for them)."""
    return _gaps(np.ascontiguousarray(nodes, dtype=float).tobytes())


@functools.lru_cache(maxsize=16)
def _gaps(nodes: bytes) -> tuple[np.ndarray, np.ndarray]:
    c = np.unique(np.append(np.frombuffer(nodes), 1.0))
    wide = np.diff(c) >= MIN_GAP
    middles, widths = (c[:-1] + c[1:])[wide] / 2, np.diff(c)[wide]
    middles.flags.writeable = widths.flags.writeable = False
    return middles, widths


def crossing_step(nodes, d: float, w: float, k: float, limit: float) -> float | None:
    """A step across a configuration at d (zone half-width w, indicator rate k), at most
    ``limit``, with the configuration in the middle of a gap between the nodes: one whose
    stages keep MIN_CLEARANCE from it and that ends INNER past it; the shortest that ends
    beyond the zone, else the longest. Failing that, the clearest step no longer than the
    limit; None if none reaches the configuration."""
    middles, widths = gaps(nodes)
    H = d / middles
    clearance = 0.5 * k * widths * H
    fits = H <= limit
    good = fits & (k * (H - d) >= INNER) & (clearance >= MIN_CLEARANCE)
    if (good & (H >= d + w)).any():
        return float(H[good & (H >= d + w)].min())
    if good.any():
        return float(H[good].max())
    if fits.any():
        return float(H[fits][np.argmax(clearance[fits])])
    return None


def plan(integrator, zone: SingularZone, h: float, landing: bool, proposal: float) -> float:
    """The step to try from integrator.t by the rules of the module docstring: h (the
    controller's ``proposal``, or less to land on an output time), or a step that is
    shorter, or longer than a landing step, to cross a singular configuration."""
    zone.crossing, zone.landing = False, landing
    found = crossing(integrator, zone.indicator)
    if found is None:
        return h
    t0 = integrator.t
    k, t_star = found
    d, w = t_star - t0, ZONE_MARGIN * ZONE / k
    if t0 + h <= t_star - w:
        return h                                  # ends before the zone
    if d > 3.0 * w:
        return d - 2.0 * w                        # towards the zone
    if d > 1.5 * w:
        return d - w                              # to its edge
    H = crossing_step(integrator.C[:integrator.n_stages], d, w, k, proposal)
    if H is None:
        return h
    zone.crossing = True
    return H


def after_step(zone: SingularZone, t0: float, H: float, c0: float, c1: float) -> float | None:
    """None to accept a step from t0 over H (indicator c0 -> c1); a step size to retry with
    when a step not planned to cross ended inside the zone."""
    if zone.crossing or zone.landing:
        return None
    if c1 < ZONE <= c0 and c0 >= REDUNDANT:
        t_star = t0 + H * c0 / (c0 - c1)
        return max((t_star - t0) * (1.0 - ZONE_MARGIN * ZONE / c0), 0.1 * H)
    return None
