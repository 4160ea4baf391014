"""GNSS sky visibility: a seeded constellation, ray casts towards it, and the DOP of what is seen.

Constellation (stream "constellation", docs/sensors.md "GNSS sky"): S satellites, each a unit
direction u_s(t) in the world ENU frame (satellites are far: the direction is the same for every
vehicle). At t = 0 the elevation el_s is drawn with sin(el) uniform on [sin(mask), 1] (uniform
over the sky above the mask) and the azimuth az_s (from north towards east) uniform on
[0, 2 pi); each satellite then moves along a great circle at the angular rate w (rate_deg_s):

    u_s(t) = cos(w t) u_s(0) + sin(w t) v_s,   v_s = cos(h_s) e_az + sin(h_s) e_el,  h_s ~ U[0, 2 pi)

with e_az, e_el the unit tangents of increasing azimuth and elevation at u_s(0). A satellite is
used only while its elevation is above the mask.

Visibility: a ray from the antenna towards u_s, ray_length long, through the geoms of `groups`,
ignoring the vehicle's own body; a hit means the satellite is not used.

DOP (the standard geometry of a pseudorange fix): rows G_s = [-u_s^T, 1] of the visible
satellites, Q = (G^T G)^-1 (4 x 4: east, north, up, clock); HDOP = sqrt(Q_ee + Q_nn),
VDOP = sqrt(Q_uu), PDOP = sqrt(Q_ee + Q_nn + Q_uu). Fewer than min_satellites visible, or a
degenerate geometry (G^T G not positive definite), is no fix (DOPs inf).
"""
from __future__ import annotations

import numpy as np

from testbed.sensors.config import SkyConfig
from testbed.sim.world import Physics

# Smallest eigenvalue of G^T G (dimensionless) below which a geometry counts as degenerate.
DEGENERATE = 1e-9


class Constellation:
    """Directions of the satellites over time (module docstring). rng: stream "constellation"."""

    def __init__(self, cfg: SkyConfig, rng: np.random.Generator):
        S = cfg.satellites
        mask = np.radians(cfg.elevation_mask_deg)
        el = np.arcsin(rng.uniform(np.sin(mask), 1.0, S))
        az = rng.uniform(0.0, 2 * np.pi, S)
        h = rng.uniform(0.0, 2 * np.pi, S)
        ce, se, ca, sa = np.cos(el), np.sin(el), np.cos(az), np.sin(az)
        self.u0 = np.stack([ce * sa, ce * ca, se], axis=1)  # (S, 3) ENU
        e_az = np.stack([ca, -sa, np.zeros(S)], axis=1)
        e_el = np.stack([-se * sa, -se * ca, ce], axis=1)
        self.v = np.cos(h)[:, None] * e_az + np.sin(h)[:, None] * e_el
        self.rate = np.radians(cfg.rate_deg_s)  # rad/s
        self.sin_mask = np.sin(mask)

    def directions(self, t: float) -> np.ndarray:
        """(S, 3) unit directions towards the satellites at time t (s), world ENU."""
        a = self.rate * t
        return np.cos(a) * self.u0 + np.sin(a) * self.v

    def above_mask(self, u: np.ndarray) -> np.ndarray:
        """(S,) bool: elevation above the mask, u (S, 3) from `directions`."""
        return u[:, 2] > self.sin_mask


def dop(u: np.ndarray, visible: np.ndarray, min_satellites: int = 4) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """HDOP, VDOP, PDOP (V,) of each vehicle's visible set (module docstring).

    u: (S, 3) unit directions to the satellites (ENU); visible: (V, S) bool. inf where fewer than
    min_satellites are visible or the geometry is degenerate.
    """
    G = np.concatenate([-u, np.ones((len(u), 1))], axis=1)  # (S, 4)
    outer = G[:, :, None] * G[:, None, :]  # (S, 4, 4)
    A = np.einsum("vs,sab->vab", visible.astype(float), outer)  # (V, 4, 4) G^T G of each visible set
    ok = (visible.sum(axis=1) >= min_satellites)
    ok[ok] = np.linalg.eigvalsh(A[ok])[:, 0] > DEGENERATE
    q = np.full((len(visible), 3), np.inf)
    if ok.any():
        # diag of (G^T G)^-1 = squared column norms of L^-1 (A = L L^T)
        L = np.linalg.cholesky(A[ok])
        Linv = np.linalg.solve(L, np.broadcast_to(np.eye(4), L.shape))
        q[ok] = (Linv ** 2).sum(axis=1)[:, :3]
    return np.sqrt(q[:, 0] + q[:, 1]), np.sqrt(q[:, 2]), np.sqrt(q.sum(axis=1))


class Sky:
    """Which satellites each antenna sees, and the DOP of the visible set.

    bodies: (V,) body id of each receiver's vehicle (its own geoms never block).
    """

    def __init__(self, cfg: SkyConfig, physics: Physics, rng: np.random.Generator, bodies: np.ndarray):
        self.cfg = cfg
        self.constellation = Constellation(cfg, rng)
        self.groups = np.array([1 if g in cfg.groups else 0 for g in range(6)], dtype=np.uint8)
        self.blockers = physics.ray_targets(self.groups)
        self.bodies = np.asarray(bodies, dtype=int)

    def visible(self, physics: Physics, t: float, p: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Directions u (S, 3) ENU at t (s) and visibility (V, S) bool from antennas p (V, 3) m world."""
        u = self.constellation.directions(t)
        up = np.flatnonzero(self.constellation.above_mask(u))
        V, S = len(p), len(u)
        src = np.repeat(np.arange(V), len(up))
        sat = np.tile(up, V)
        ends = p[src] + self.cfg.ray_length * u[sat]
        # rays only where a blocking geom's bounding box meets the segment (the rest are clear)
        cast = np.flatnonzero(physics.segments_may_hit(self.blockers, p[src], ends, self.bodies[src][:, None]))
        blocked = np.zeros(len(src), dtype=bool)
        if len(cast):
            dist, _ = physics.rays(p, src[cast], ends[cast], self.groups, self.bodies)
            blocked[cast] = np.isfinite(dist)
        vis = np.zeros((V, S), dtype=bool)
        vis[src, sat] = ~blocked
        return u, vis
