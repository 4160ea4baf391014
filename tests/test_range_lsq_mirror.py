"""estimators.range_lsq.mirror_fit (docs/replay.md, "The mirror check"): with every known point in one
plane a little above the tags, the ranges fit the pose and its reflection alike: the epoch is
flagged and its covariance holds the other minimum within one sigma; with known points off one
plane the mirrored start finds nothing the gate admits, and the fit is returned as it was."""
from __future__ import annotations

import numpy as np

from estimators.range_lsq import fit_ranges, mirror_fit

ARMS = np.array([[0.3, 0.0, 0.0], [-0.15, 0.26, 0.0], [-0.15, -0.26, 0.0]])  # m, a level tag triangle
SIGMA = 0.02  # m


def _epoch(anchors: np.ndarray, seed: int):
    """One epoch of every tag ranging every anchor: the body at (1, 2, 0), level; (arms, known, ranges, sigma)."""
    rng = np.random.default_rng(seed)
    p = np.array([1.0, 2.0, 0.0])
    arms = np.repeat(ARMS, len(anchors), axis=0)
    known = np.tile(anchors, (len(ARMS), 1))
    r = np.linalg.norm(p + arms - known, axis=1) + SIGMA * rng.standard_normal(len(arms))
    return arms, known, r, np.full(len(r), SIGMA)


def _square(z: np.ndarray) -> np.ndarray:
    """Eight anchors (8, 3) m on a 10 m square, at heights z (8,)."""
    xy = np.array([[-5, -5], [0, -5], [5, -5], [5, 0], [5, 5], [0, 5], [-5, 5], [-5, 0]], float)
    return np.column_stack([xy, z])


def test_anchors_in_one_plane_above_the_tags_flag_the_epoch_with_both_minima_in_its_covariance():
    arms, known, r, s = _epoch(_square(np.full(8, 0.08)), 1)
    fit = fit_ranges(arms, known, r, s, np.array([1.0, 2.0, 0.0]), np.eye(3))
    assert fit.converged and fit.observable
    out, flagged = mirror_fit(fit, arms, known, r, s)
    assert flagged
    other = fit_ranges(arms, known, r, s, fit.p + [0.0, 0.0, 2 * (0.08 - fit.p[2])], fit.R)
    assert abs(other.p[2] - fit.p[2]) > 0.1  # two minima, one on either side of the anchors' plane
    d = other.p - out.p
    assert d @ np.linalg.solve(out.cov[:3, :3], d) <= 1.0 + 1e-9
    assert d @ np.linalg.solve(fit.cov[:3, :3], d) > 1.0  # the plain covariance did not hold it


def test_anchors_off_one_plane_leave_the_fit_as_it_was():
    arms, known, r, s = _epoch(_square(np.array([0.0, 3.0, 0.5, 2.5, 0.2, 3.5, 1.0, 2.0])), 2)
    fit = fit_ranges(arms, known, r, s, np.array([1.0, 2.0, 0.0]), np.eye(3))
    out, flagged = mirror_fit(fit, arms, known, r, s)
    assert not flagged and np.allclose(out.p, fit.p, atol=1e-6) and np.allclose(out.cov, fit.cov, rtol=1e-6)
