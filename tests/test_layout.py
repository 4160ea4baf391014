"""estimators.layout and the window's mirror images (estimators.window, `mirrors`).

- the shape from one epoch's ranges (8 of 153 pairs unranged, one range 3 m long) has every
  distance within a metre of the true one (a folded vehicle is 3-7 m off), and placed on fixes of
  3 m vertical sigma it is never the mirror image and is as far off vertically as a rigid fit to
  18 fixes: the start the centralized window and the distributed start exchange use;
- a vehicle started at its mirror image through the plane of its neighbours stays there without
  the mirror test and is brought back with it, centralized and distributed; a whole swarm
  started upside down is turned back by the centralized window's group test.
"""
from __future__ import annotations

import numpy as np
import pytest

from estimators import layout
from estimators import window as sw


def street_swarm() -> np.ndarray:
    """(18, 3) m: coop-denied's formation, 6 rows of 3 across the street, rows 6 m apart, the
    middle vehicle of each row 4 m above the outer ones."""
    rows = np.arange(6) * -6.0
    return np.array([[x, y, 7.0 + (4.0 if y == 0.0 else 0.0) + (1.0 if r % 2 else 0.0)]
                     for r, x in enumerate(rows) for y in (-5.0, 0.0, 5.0)])


OUT = 3.0


def ranged(truth: np.ndarray, rng: np.random.Generator, missing: int = 8, sigma: float = 0.1):
    """Every pair ranged but `missing` random ones, noise sigma, the first range 3 m long
    (an outlier). Returns edges (m, 2), ranges (m,), range_sigma (m,)."""
    n = len(truth)
    pairs = np.array([(i, j) for i in range(n) for j in range(i + 1, n)])
    pairs = np.delete(pairs, rng.choice(len(pairs), missing, replace=False), axis=0)
    d = np.linalg.norm(truth[pairs[:, 0]] - truth[pairs[:, 1]], axis=1) + rng.normal(0, sigma, len(pairs))
    d[0] += OUT
    return pairs, d, np.full(len(pairs), sigma)


def distances(P: np.ndarray) -> np.ndarray:
    return np.linalg.norm(P[:, None] - P[None], axis=2)


def test_shape_from_ranges_and_placement():
    """Over 20 draws: the shape matches every pair to within a metre (a fold is 3-7 m off) but the
    outlier's, which moves less than half its error; placed on fixes of 3 m vertical sigma it
    is never the mirror image, and its vertical error is that of a rigid fit to 18 fixes
    (translation and two tilts: about sigma sqrt(3 / 18) = 0.41 sigma RMS), not a fix's."""
    truth = street_swarm()
    n = len(truth)
    sigma = np.tile([1.5, 1.5, 3.0], (n, 1))
    none = np.zeros(0, np.int64), np.zeros((0, 3)), np.zeros(0), np.zeros(0)
    ratios = []
    for seed in range(20):
        rng = np.random.default_rng(seed)
        edges, d, s = ranged(truth, rng)
        Y = layout.shape_from_ranges(n, edges, d, s)
        error = np.abs(distances(Y) - distances(truth))
        a, b = edges[0]  # the 3 m outlier: pulls its own pair less than half way, the rest not
        assert error[a, b] < 0.5 * OUT
        error[a, b] = error[b, a] = 0.0
        assert error.max() < 1.0  # 0.1 m ranges; a fold: 3-7 m
        fix = truth + rng.normal(0, sigma)
        start = layout.start_positions(fix, sigma, edges, d, s, *none)
        # not the mirror image: the rigid fit of the start onto the truth is a rotation
        A, B = start - start.mean(0), truth - truth.mean(0)
        assert np.linalg.det(np.linalg.svd(A.T @ B)[0] @ np.linalg.svd(A.T @ B)[2]) > 0
        ratios.append(np.sqrt(np.mean((start[:, 2] - truth[:, 2]) ** 2) / np.mean((fix[:, 2] - truth[:, 2]) ** 2)))
    assert np.mean(ratios) < 0.6
    # not enough to lay out: three vehicles; vehicles not connected by ranges
    assert layout.shape_from_ranges(3, edges[:2], d[:2], s[:2]) is None
    assert layout.shape_from_ranges(n, edges[:5], d[:5], s[:5]) is None


def _epochs(truth: np.ndarray, sigma: np.ndarray, count: int, seed: int) -> list[sw.Epoch]:
    """count epochs 0.2 s apart of a hovering swarm: every pair ranged (0.1 m), fixes of sigma."""
    rng = np.random.default_rng(seed)
    n = len(truth)
    edges = np.array([(i, j) for i in range(n) for j in range(i + 1, n)])
    out = []
    for k in range(count):
        d = np.linalg.norm(truth[edges[:, 0]] - truth[edges[:, 1]], axis=1) + rng.normal(0, 0.1, len(edges))
        out.append(sw.Epoch(t=0.2 * k, fix=truth + rng.normal(0, sigma), fix_sigma=sigma, edges=edges, ranges=d,
                            range_sigma=np.full(len(edges), 0.1), anchor_vehicle=np.zeros(0, np.int64),
                            anchor_pos=np.zeros((0, 3)), anchor_range=np.zeros(0), anchor_sigma=np.zeros(0)))
    return out


def _reflect(P: np.ndarray, points: np.ndarray) -> np.ndarray:
    """P (3,) reflected through the best plane of points (m, 3)."""
    c = points.mean(axis=0)
    nu = np.linalg.svd(points - c)[2][-1]
    return P - 2.0 * ((P - c) @ nu) * nu


# four vehicles in a level square with precise fixes (0.3 m), a fifth 3 m above its middle with a
# street's fix (3 m vertical sigma): ranges cannot tell it from 3 m below
SQUARE = np.array([[0.0, 0.0, 8.0], [6.0, 0.0, 8.0], [0.0, 6.0, 8.0], [6.0, 6.0, 8.0], [3.0, 3.0, 11.0]])
SIGMA = np.array([[0.3, 0.3, 0.3]] * 4 + [[1.5, 1.5, 3.0]])


@pytest.mark.parametrize("solver", ["centralized", "distributed"])
def test_a_vehicle_started_at_its_mirror_image_is_brought_back(monkeypatch, solver):
    start = SQUARE.copy()
    start[4] = _reflect(SQUARE[4], SQUARE[:4])  # 5 m high
    monkeypatch.setattr(layout, "start_positions", lambda *a: start)
    monkeypatch.setattr(sw.Distributed, "_start", lambda self, ep, transport: (start, 0, 0))
    errors, mirrored = {}, {}
    for mirrors in (False, True):
        s = sw.Centralized(5, window=5, q=1.0) if solver == "centralized" else sw.Distributed(5, window=5, q=1.0)
        s.mirrors = mirrors
        est = [s.add(ep) for ep in _epochs(SQUARE, SIGMA, 15, seed=11)]
        errors[mirrors] = abs(est[-1].pos[4, 2] - SQUARE[4, 2])
        mirrored[mirrors] = sum(e.mirrored for e in est)
    assert errors[False] > 4.0 and mirrored[False] == 0  # stays on the wrong side: 6 m off
    assert errors[True] < 1.0 and mirrored[True] >= 1


def test_a_swarm_started_upside_down_is_turned_back(monkeypatch):
    truth = street_swarm()[:9]  # three rows: the middle vehicles 4 m above the outer ones
    c = truth.mean(axis=0)
    start = truth * [1.0, 1.0, -1.0] + [0.0, 0.0, 2.0 * c[2]]  # every vehicle through the mean height
    monkeypatch.setattr(layout, "start_positions", lambda *a: start)
    sigma = np.tile([1.5, 1.5, 3.0], (9, 1))
    errors, mirrored = {}, {}
    for mirrors in (False, True):
        s = sw.Centralized(9, window=5, q=1.0)
        s.mirrors = mirrors
        est = [s.add(ep) for ep in _epochs(truth, sigma, 10, seed=5)]
        errors[mirrors] = float(np.abs(est[-1].pos[:, 2] - truth[:, 2]).max())
        mirrored[mirrors] = sum(e.mirrored for e in est)
    assert errors[False] > 2.0 and mirrored[False] == 0
    assert errors[True] < 1.0 and mirrored[True] >= 9
