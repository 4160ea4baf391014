"""A swarm's positions from one epoch's ranges and GNSS fixes, without a starting guess: the start
of the centralized window (estimators.window), where Gauss-Newton from the raw fixes folds.

Why: started at the GNSS fixes (3-8 m of vertical sigma in coop-denied's street, single fixes
4-11 m off), Gauss-Newton on the ranges settles in the nearest configuration that fits them,
which can be the swarm folded: part of it reflected through the plane of the rest, every range
fitted. From there no step lowers the cost; flown on it, the folded vehicles climb to correct an
error they do not have (coop-denied seed 23: the upper layer estimated 5-6 m low at the first
epoch, 120 m at 4 s).

Method (the standard one for a start from ranges alone):
1. the distance matrix of the vehicles: each ranged pair's mean range, an unranged pair the
   shortest path through the ranged ones (an overestimate: a start only);
2. classical multidimensional scaling: B = -1/2 J D^2 J (J = I - 11^T / n, D^2 the squared
   distances), the three largest eigenpairs give the shape Y = V sqrt(Lambda) (n, 3), exact up
   to a rigid motion and a reflection when every pair is ranged without noise;
   Repeated (IMPUTATIONS times) with each unranged pair's distance taken from the last shape;
3. the shape refined on the measured ranges alone (robust least squares, Huber, from step 2):
   the path lengths of unranged pairs are too long, and 8 of 153 pairs missing distorted the
   classical shape by up to 11 m on coop-denied seed 27's first epoch;
4. folds undone: the refined shape can still hold a vehicle reflected through the plane of its
   neighbours, a local minimum whose ranges to the rest are metres off (on the test's swarm of
   coop-denied's shape with 8 pairs unranged: 5 of 60 draws, 3.0-7.4 m); each vehicle in turn is
   reflected back and the shape refitted, kept when its cost is lower, until no reflection helps;
5. placed on the GNSS fixes: the rigid motion of Y, and of its mirror image, that fits the fixes
   (each axis on its own sigma) and the anchor ranges in least squares, started from the Kabsch
   fit (every axis weighted alike, by the fix's 1 / mean sigma^2: a start only; kept as the
   answer, it tilted coop-denied seed 27's swarm by 11 m over its length, the vertical fixes
   being the noisiest); of the two the one that costs less: ranges among the vehicles cannot
   tell a shape from its mirror image.

Never imports mujoco or testbed.
"""
from __future__ import annotations

import numpy as np
from scipy import optimize, sparse
from scipy.sparse import csgraph
from scipy.spatial.transform import Rotation

from estimators.graph.losses import HUBER_DELTA

__all__ = ["mirror_plane", "shape_from_ranges", "place_on_fixes", "start_positions"]

IMPUTATIONS = 20  # classical scaling rounds, each unranged pair's distance taken from the last shape
HUBER = HUBER_DELTA  # the shape's range loss: Huber at 1.345 sigma (the window's; 1 % of UWB ranges are metres off)


def mirror_plane(points: np.ndarray, mask: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """The reflection through the plane that fits points (..., m, 3) m best (least squares: through
    their mean, normal to their direction of least extent, the eigenvector of the smallest
    eigenvalue of their scatter matrix): its point c (..., 3) m and matrix H = I - 2 nu nu^T
    (..., 3, 3); a point p reflects to c + H (p - c). mask (..., m) bool: the points to fit (None:
    all; batches of sets of different sizes, padded)."""
    w = np.ones(points.shape[:-1]) if mask is None else mask.astype(float)
    c = np.einsum("...m,...mi->...i", w, points) / np.maximum(w.sum(axis=-1), 1.0)[..., None]
    d = (points - c[..., None, :]) * np.sqrt(w)[..., None]
    nu = np.linalg.eigh(np.swapaxes(d, -1, -2) @ d)[1][..., :, 0]
    return c, np.eye(3) - 2.0 * nu[..., :, None] * nu[..., None, :]


def shape_from_ranges(n: int, edges: np.ndarray, ranges: np.ndarray, sigma: np.ndarray) -> np.ndarray | None:
    """(n, 3) m the vehicles' positions up to a rigid motion and a reflection, from ranges
    (m,) m with 1-sigma sigma (m,) m between the vehicle pairs edges (m, 2) (steps 1-4 of the
    module docstring); None when the ranged pairs do not connect all n >= 4 vehicles."""
    if n < 4 or not len(edges):
        return None
    i, j = np.asarray(edges, np.int64).T
    total = np.zeros((n, n))
    count = np.zeros((n, n))
    np.add.at(total, (i, j), ranges)
    np.add.at(count, (i, j), 1.0)
    total, count = total + total.T, count + count.T
    mean = np.where(count > 0, total / np.maximum(count, 1.0), 0.0)
    D = csgraph.shortest_path(sparse.csr_matrix(mean), directed=False)
    if not np.isfinite(D).all():
        return None
    J = np.eye(n) - 1.0 / n
    unranged = count == 0
    for _ in range(IMPUTATIONS):
        w, V = np.linalg.eigh(-0.5 * J @ (D ** 2) @ J)
        Y = V[:, -3:] * np.sqrt(np.maximum(w[-3:], 0.0))
        D = np.where(unranged, np.linalg.norm(Y[:, None] - Y[None], axis=2), D)  # the shape's own distances

    m = len(i)

    def residuals(x: np.ndarray) -> np.ndarray:
        X = x.reshape(n, 3)
        return (np.linalg.norm(X[i] - X[j], axis=1) - ranges) / sigma

    def jacobian(x: np.ndarray) -> np.ndarray:
        X = x.reshape(n, 3)
        diff = X[i] - X[j]
        u = diff / (np.maximum(np.linalg.norm(diff, axis=1), 1e-9) * sigma)[:, None]
        out = np.zeros((m, n, 3))
        out[np.arange(m), i] = u
        out[np.arange(m), j] = -u
        return out.reshape(m, 3 * n)

    def fit(Y: np.ndarray) -> tuple[np.ndarray, float]:
        # the measured ranges alone (an unranged pair's path length is only an upper bound)
        r = optimize.least_squares(residuals, Y.ravel(), jac=jacobian, loss="huber", f_scale=HUBER)
        return r.x.reshape(n, 3), float(r.cost)

    Y, cost = fit(Y)
    # step 4: a vehicle folded through the plane of its neighbours, reflected back and refitted
    neighbours = [np.unique(np.concatenate([j[i == v], i[j == v]])) for v in range(n)]
    improved = True
    while improved:
        improved = False
        for v, nb in enumerate(neighbours):
            if len(nb) < 3:
                continue
            c, H = mirror_plane(Y[nb])
            Z = Y.copy()
            Z[v] = c + H @ (Y[v] - c)
            Z, new = fit(Z)
            if new < cost * (1.0 - 1e-6):
                Y, cost, improved = Z, new, True
    return Y


def _rigid(Y: np.ndarray, X: np.ndarray, w: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The rotation R (3, 3) and translation t (3,) that move Y (m, 3) onto X (m, 3) in weighted
    least squares, weights w (m,) (Kabsch): X ~ Y R^T + t."""
    yc, xc = w @ Y / w.sum(), w @ X / w.sum()
    U, _, Vt = np.linalg.svd(((X - xc) * w[:, None]).T @ (Y - yc))
    R = U @ np.diag([1.0, 1.0, np.sign(np.linalg.det(U @ Vt))]) @ Vt
    return R, xc - yc @ R.T


def place_on_fixes(Y: np.ndarray, fix: np.ndarray, fix_sigma: np.ndarray, anchor_vehicle: np.ndarray,
                   anchor_pos: np.ndarray, anchor_range: np.ndarray, anchor_sigma: np.ndarray) -> np.ndarray | None:
    """(n, 3) m world: the shape Y (n, 3) placed on the GNSS fixes (step 5 of the module
    docstring). fix (n, 3) m world, NaN rows without a fix, fix_sigma (n, 3) m; anchor ranges:
    vehicle (a,), anchor position (a, 3) m, range (a,) m, sigma (a,) m. None with fewer than 3
    fixes."""
    has = ~np.isnan(fix[:, 0])
    if has.sum() < 3:
        return None
    w = 1.0 / np.mean(fix_sigma[has] ** 2, axis=1)

    def residuals(x: np.ndarray, base: np.ndarray, centre: np.ndarray) -> np.ndarray:
        placed = (base - centre) @ Rotation.from_rotvec(x[:3]).as_matrix().T + centre + x[3:]
        r = ((fix[has] - placed[has]) / fix_sigma[has]).ravel()
        if len(anchor_vehicle):
            dist = np.linalg.norm(placed[anchor_vehicle] - anchor_pos, axis=1)
            r = np.concatenate([r, (anchor_range - dist) / anchor_sigma])
        return r

    best, best_cost = None, np.inf
    for mirror in (1.0, -1.0):  # the shape, then its mirror image
        Ym = Y * np.array([1.0, 1.0, mirror])
        R, t = _rigid(Ym[has], fix[has], w)  # a start: every axis weighted alike
        base = Ym @ R.T + t
        centre = base[has].mean(axis=0)
        # the rigid motion in least squares on the fixes' own sigmas and the anchor ranges
        fit = optimize.least_squares(residuals, np.zeros(6), args=(base, centre))
        if fit.cost < best_cost:
            x = fit.x
            best = (base - centre) @ Rotation.from_rotvec(x[:3]).as_matrix().T + centre + x[3:]
            best_cost = fit.cost
    return best


def start_positions(fix: np.ndarray, fix_sigma: np.ndarray, edges: np.ndarray, ranges: np.ndarray,
                    range_sigma: np.ndarray, anchor_vehicle: np.ndarray, anchor_pos: np.ndarray, anchor_range: np.ndarray,
                    anchor_sigma: np.ndarray, shapes: dict | None = None) -> np.ndarray | None:
    """(n, 3) m world: the vehicles' positions from one epoch's ranges and fixes (module
    docstring; arguments as estimators.window.Epoch's); None where the method does not apply
    (ranges not connecting every vehicle, fewer than 3 fixes): start from the fixes then.
    shapes: a dict the caller keeps across calls, of the shapes found (steps 1-4, a function of
    n and the ranges alone): a call with the same n, edges, ranges and sigmas takes its shape
    from there (the same numbers) and only places it on its own fixes (step 5)."""
    key = (len(fix), *(np.ascontiguousarray(a).tobytes() for a in (edges, ranges, range_sigma)))
    if shapes is not None and key in shapes:
        Y = shapes[key]
    else:
        Y = shape_from_ranges(len(fix), edges, ranges, range_sigma)
        if shapes is not None:
            shapes[key] = Y
    if Y is None:
        return None
    return place_on_fixes(Y, fix, fix_sigma, anchor_vehicle, anchor_pos, anchor_range, anchor_sigma)
