"""A start from the first ranges and heights: the ranges of a short window, stacked as one epoch.

A filter with no position fix (no GNSS, no initial pose) starts from ranges to known points
(anchors) and heights gathered over the last `span` seconds (docs/replay.md, "Sparse ranging";
docs/estimators.md, "Flights: sparse ranging without GNSS"). Sparse ranging gives one range at a
time, so no single epoch determines a position; the window's ranges are taken together as one
epoch at the time t of the fix, each range of age a = t - t_k with its sigma grown to

    sigma_k(t) = hypot(sigma_k, v_sigma a)                                      (eq. S1)

(the body moved by v a since, v ~ N(0, v_sigma^2 I) per axis, which changes the range by u^T v a
~ N(0, (v_sigma a)^2)); the latest height likewise. The stacked epoch goes to
estimators.ranging.initial_belief (a multilateration fix per antenna, or a rigid pose fix).

Units: seconds, metres, m/s; known points in the world frame N. Pure numpy; never imports testbed.
"""
from __future__ import annotations

import numpy as np

from estimators.geometry import DegenerateGeometryError
from estimators.ranging import RangingEpoch, initial_belief


PRUNE_EVERY = 64  # epochs between two prunings of a window (a range costs an append)


def grown_sigma(sigma, v_sigma: float, age):
    """Eq. S1: sigma (m, scalar or (k,)) of a range or height of age (s, scalar or (k,)) taken as
    one at the fix's time, the body moving at v_sigma (m/s, per axis) since: hypot(sigma, v_sigma age)."""
    # eq. S1
    return np.hypot(sigma, v_sigma * age)


class StartWindow:
    """The ranges and heights of one body over the last `span` s (s; 0: one epoch), v_sigma (m/s)
    its velocity prior per axis (eq. S1)."""

    def __init__(self, span: float, v_sigma: float):
        self.span, self.v_sigma = float(span), float(v_sigma)
        # (t, antenna (k,) int, known (k, 3) m, ranges (k,) m, sigma (k,) m, height (z m, sigma m, weights (n,)) | None)
        self.epochs: list[tuple] = []

    def add(self, t: float, antenna, known, ranges, sigma, height: tuple | None = None) -> None:
        """The epoch at t (s, not before the last): ranges (k,) m of sigma (k,) m between follower
        antennas antenna (k,) and known points known (k, 3) m, and a height (z m, sigma m, the
        antennas' weights (n,)) or None. Epochs older than t - span are dropped (every PRUNE_EVERY
        epochs, and before `ranges` and `epoch` read the window)."""
        self.epochs.append((t, np.asarray(antenna, int).reshape(-1), np.asarray(known, float).reshape(-1, 3),
                            np.asarray(ranges, float).reshape(-1), np.asarray(sigma, float).reshape(-1), height))
        if len(self.epochs) % PRUNE_EVERY == 0:
            self._prune()

    def _prune(self) -> None:
        if self.epochs:
            t = self.epochs[-1][0]
            self.epochs = [e for e in self.epochs if e[0] >= t - self.span - 1e-9]

    def ranges(self) -> int:
        """The number of ranges in the window."""
        self._prune()
        return sum(e[3].size for e in self.epochs)

    def epoch(self, t: float, height: tuple | None = None) -> RangingEpoch:
        """The window's ranges and its latest height (or height = (t_h s, (z, sigma, weights)) given)
        as one epoch at t (s, the window's last epoch), sigmas grown by eq. S1."""
        self._prune()
        tk = np.concatenate([np.full(e[3].size, e[0]) for e in self.epochs]) if self.epochs else np.zeros(0)
        antenna, ranges, sigma = (np.concatenate([e[k] for e in self.epochs]) if self.epochs else np.zeros(0)
                                  for k in (1, 3, 4))
        known = np.concatenate([e[2] for e in self.epochs]) if self.epochs else np.zeros((0, 3))
        heights = [(e[0], e[5]) for e in self.epochs if e[5] is not None]
        hk, h = height if height is not None else heights[-1] if heights else (t, None)
        return RangingEpoch(
            antenna=antenna.astype(int), known_pos=known, ranges=ranges,
            sigma_range=grown_sigma(sigma, self.v_sigma, t - tk),
            height=None if h is None else h[0],
            sigma_height=1.0 if h is None else float(grown_sigma(h[1], self.v_sigma, t - hk)),
            height_weights=None if h is None else h[2])

    def clear(self) -> None:
        self.epochs = []


class BodyStarts:
    """The range start of each body of a swarm's IMU filters (one point, the body origin, per body):
    a StartWindow each (span s, v_sigma m/s). A range from a tag at lever arm l (3,) m body frame,
    or a height of a site at l, is taken at the body origin with its sigma grown to

        sigma' = hypot(sigma, |l|)                                                  (eq. S2)

    (the attitude is not known before the start: the site lies within |l| of the origin)."""

    def __init__(self, span: float, v_sigma: float):
        self.span, self.v_sigma = float(span), float(v_sigma)
        self.windows: dict = {}
        self.heights: dict = {}  # body: (t s, z m, sigma m) of its latest height

    def _window(self, body) -> StartWindow:
        if body not in self.windows:
            self.windows[body] = StartWindow(self.span, self.v_sigma)
        return self.windows[body]

    def range(self, body, t: float, anchor: np.ndarray, r: float, sigma: float, lever: np.ndarray) -> None:
        """A range r (m, sigma m) at t (s) from body's tag at lever (3,) m to a known point anchor (3,) m world."""
        self._window(body).add(t, [0], [anchor], [r], [np.hypot(sigma, np.linalg.norm(lever))])  # eq. S2

    def height(self, body, t: float, z: float, sigma: float, lever: np.ndarray) -> None:
        """A height z (m world up, sigma m) at t (s) of body's site at lever (3,) m (the latest
        is the one used, StartWindow.epoch)."""
        self.heights[body] = (t, float(z), float(np.hypot(sigma, np.linalg.norm(lever))))  # eq. S2

    def fix(self, body, t: float) -> tuple[np.ndarray, np.ndarray] | None:
        """(position (3,) m world, covariance (3, 3) m^2) of body's origin at t (s) from its window's
        ranges and latest height (estimators.ranging.initial_belief, one antenna), or None while they do
        not determine it (fewer than three ranges, a mirror image the height cannot tell)."""
        w = self.windows.get(body)
        if w is None or w.ranges() < 3:
            return None
        h = self.heights.get(body)
        latest = (h[0], (h[1], h[2], np.ones(1))) if h is not None and h[0] >= t - self.span - 1e-9 else None
        try:
            b = initial_belief(w.epoch(t, latest), 1)
        except DegenerateGeometryError:
            return None
        if not np.all(np.isfinite(b.mean[:3])):
            return None
        return b.mean[:3], b.cov[:3, :3]
