"""Degenerate geometry, made explicit: the rank of a set of points and the error raised when a
position cannot be determined.

A least-squares position from ranges (multilateration, the linearized pseudo-measurement of
seed 000, the initial fix of a ranging filter) is determined only if the known points span
enough dimensions: four or more points not on one plane for a 3-D position from ranges alone;
three not on one line when the plane's mirror ambiguity is resolved otherwise (a height aid).
On degenerate geometry the normal equations are singular, and a Cholesky factorization of them
either fails or, worse, succeeds on round-off and returns an arbitrary position hundreds of
metres away (581 m for four coplanar anchors, measured). The functions here detect it from the
singular values, with a relative tolerance well above round-off, and say so.

Pure numpy; never imports mujoco or testbed.
"""
from __future__ import annotations

import numpy as np

#: singular values below RANK_RTOL * the largest count as zero (numerical rank). 1e-8: the
#: normal matrix A^T A then has a condition number up to 1e16, the limit of double precision.
RANK_RTOL = 1e-8


class DegenerateGeometryError(ValueError):
    """The known points (anchors, antennas) or the ranges given cannot determine the position
    asked for: too few ranges, or points on one plane / line / coincident. The message names
    what is missing; `rank` is the numerical rank found (or -1 when too few points were given)."""

    def __init__(self, message: str, rank: int = -1) -> None:
        super().__init__(message)
        self.rank = rank


def numerical_rank(A: np.ndarray, rtol: float = RANK_RTOL) -> tuple[int, np.ndarray]:
    """Numerical rank of A (m, k) and its singular values (min(m, k),), descending.

    A singular value counts if it exceeds rtol times the largest (and is positive).
    """
    s = np.linalg.svd(np.asarray(A, float), compute_uv=False)
    if s.size == 0 or not np.isfinite(s).all() or s[0] <= 0.0:
        return 0, s
    return int(np.count_nonzero(s > rtol * s[0])), s


def spanned_dimension(points: np.ndarray, rtol: float = RANK_RTOL) -> int:
    """Dimension of the affine hull of points (k, 3): 0 coincident, 1 a line, 2 a plane, 3 space."""
    P = np.asarray(points, float)
    if P.shape[0] < 2:
        return 0
    return numerical_rank(P[1:] - P[0], rtol)[0]


def require_span(points: np.ndarray, dimension: int, what: str, rtol: float = RANK_RTOL) -> None:
    """Raise DegenerateGeometryError unless points (k, 3) span `dimension` (1, 2 or 3) dimensions.

    what: how the message names the points, e.g. "anchors of group 2".
    """
    P = np.asarray(points, float)
    need = dimension + 1
    if P.shape[0] < need:
        raise DegenerateGeometryError(f"{what}: {P.shape[0]} points given, at least {need} needed")
    dim = spanned_dimension(P, rtol)
    if dim < dimension:
        shape = ("coincident points", "points on one line", "points on one plane")[dim]
        raise DegenerateGeometryError(
            f"{what}: {shape} (they span {dim} dimension(s), {dimension} needed)", rank=dim)
