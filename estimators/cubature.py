"""Cubature rules for Gaussian-weighted integrals (seed 004).

A rule approximates E[g(x)], x ~ N(0, I_n), by sum_i w_i g(xi_i). For a Gaussian N(m, P) with
P = S S^T the points are m + S xi_i (paper eq. 18 and 23). Points are returned as *unit* points
(the N(0, I) rule): the caller applies the mean and the square root.

    third_degree_rule(n)  2n points, exact for every monomial of degree <= 3
                          (spherical-radial rule, Arasaratnam & Haykin 2009).
    fifth_degree_rule(n)  2n^2 + 1 points, exact for every monomial of degree <= 5
                          (Jia, Xin & Cheng 2013; weights of the seed's eq. 22).

Both rules are symmetric under x -> -x with equal weights, so every odd moment is zero, as for the
Gaussian. The fifth-degree rule has NEGATIVE axis weights (4 - n) / (2 (n + 2)^2) for n > 4:
a covariance computed with it from a nonlinear map may be indefinite; sigma_filters.ensure_spd
handles that.
"""
from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache

import numpy as np


@dataclass(frozen=True, slots=True, eq=False)
class CubatureRule:
    """A cubature rule for N(0, I_n).

    points: (n, L) unit points xi_i (dimensionless, in units of standard deviations);
    weights: (L,) weights summing to 1; degree: highest total monomial degree integrated exactly.
    """

    points: np.ndarray
    weights: np.ndarray
    degree: int

    @property
    def dim(self) -> int:
        """State dimension n."""
        return int(self.points.shape[0])

    @property
    def size(self) -> int:
        """Number of points L."""
        return int(self.points.shape[1])


def _frozen(a: np.ndarray) -> np.ndarray:
    a.setflags(write=False)
    return a


@lru_cache(maxsize=64)
def third_degree_rule(n: int) -> CubatureRule:
    """Third-degree spherical-radial rule (Arasaratnam & Haykin 2009): 2n points.

    Points +/- sqrt(n) e_k, k = 1..n, each with weight 1 / (2n). Returns unit points (n, 2n).
    """
    if n < 1:
        raise ValueError(f"third_degree_rule: n must be >= 1, got {n}")
    eye = np.eye(n)
    points = np.sqrt(n) * np.hstack([eye, -eye])
    weights = np.full(2 * n, 1.0 / (2 * n))
    return CubatureRule(_frozen(points), _frozen(weights), 3)


@lru_cache(maxsize=64)
def fifth_degree_rule(n: int) -> CubatureRule:
    """Fifth-degree rule of Jia, Xin & Cheng (2013): 2n^2 + 1 points, weights of eq. 22.

    Order of the points (as the index ranges of eq. 22):
      0                      the centre, weight 2 / (n + 2);
      1 .. 2n(n-1)           sqrt(n + 2) (s_k e_k + s_l e_l) / sqrt(2), k < l, s = +/-1,
                             weight 1 / (n + 2)^2;
      2n(n-1)+1 .. 2n^2      +/- sqrt(n + 2) e_k, weight (4 - n) / (2 (n + 2)^2)  (< 0 for n > 4).
    Returns unit points (n, 2n^2 + 1).
    """
    if n < 1:
        raise ValueError(f"fifth_degree_rule: n must be >= 1, got {n}")
    k, l = np.triu_indices(n, 1)                      # the n(n-1)/2 pairs k < l
    n_pairs = k.size
    sign_k = np.array([1.0, 1.0, -1.0, -1.0])
    sign_l = np.array([1.0, -1.0, 1.0, -1.0])
    cols = np.arange(4 * n_pairs).reshape(n_pairs, 4)  # four sign patterns per pair
    pairs = np.zeros((n, 4 * n_pairs))
    pairs[k[:, None], cols] = sign_k[None, :]
    pairs[l[:, None], cols] = sign_l[None, :]
    pairs *= np.sqrt((n + 2) / 2.0)
    eye = np.eye(n)
    axes = np.sqrt(n + 2.0) * np.hstack([eye, -eye])
    points = np.hstack([np.zeros((n, 1)), pairs, axes])
    # eq. 22
    weights = np.concatenate([
        [2.0 / (n + 2)],
        np.full(4 * n_pairs, 1.0 / (n + 2) ** 2),
        np.full(2 * n, (4.0 - n) / (2.0 * (n + 2) ** 2)),
    ])
    return CubatureRule(_frozen(points), _frozen(weights), 5)
