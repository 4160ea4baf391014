"""Banded Cholesky of a sparse SPD normal matrix after a reverse Cuthill-McKee ordering.

A factor graph's normal matrix N (k, k) has the sparsity of its variable graph. Reverse
Cuthill-McKee (Cuthill, McKee 1969; George 1971) renumbers the unknowns so that every nonzero lies
within a band |r - c| <= w; the Cholesky factor P N P^T = L L^T then lives in that band (no fill
outside it) and LAPACK's banded Cholesky (pbtrf) factors it in ~k w^2 flops with dense kernels. For
the swarms of seed 001 (UAVs within ranging distance of each other in a box) w grows like k^(2/3);
at 1000 UAVs (k = 3000, w = 563) one factorization took 60-90 ms on a loaded 2-core machine where
SuperLU's supernodal LU took 450-700 ms. The ordering depends only on the sparsity pattern: `band_order` caches it
per pattern, so the iterations of a solve (and epochs with the same links) compute it once.

`selected_inverse_diag` gives the diagonal blocks of N^-1 from the banded factor by the Takahashi
recurrence (Takahashi, Fagan, Chen 1973) restricted to the band, block column by block column.
Never imports mujoco, testbed or gtsam.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import linalg, sparse
from scipy.sparse.csgraph import reverse_cuthill_mckee

__all__ = ["BandOrder", "BandedFactor", "band_order", "factor_banded", "selected_inverse_diag"]

#: orderings kept (one per sparsity pattern)
_CACHE_SIZE = 8
_cache: list[tuple[np.ndarray, np.ndarray, "BandOrder"]] = []  # (indptr, indices, order), newest last
#: columns per block of the selected inversion (dense kernels on (w + b) x b panels)
_PANEL = 48


@dataclass(frozen=True, slots=True)
class BandOrder:
    """perm: (k,) new position -> unknown (P N P^T = N[perm][:, perm]); width: half bandwidth w of
    the permuted matrix (nonzeros at |r - c| <= w); lower: (nnz,) bool, the entries of the
    pattern's CSC data (sorted indices) that land on or below the diagonal after permuting;
    scatter: their flat indices in the (w + 1, k) banded storage."""

    perm: np.ndarray
    width: int
    lower: np.ndarray
    scatter: np.ndarray


@dataclass(frozen=True, slots=True)
class BandedFactor:
    """L of P N P^T = L L^T in LAPACK lower banded storage cb (w + 1, k): cb[r - c, c] = L[r, c]."""

    order: BandOrder
    cb: np.ndarray

    def pivots(self) -> np.ndarray:
        """Squared diagonal of L, (k,) in the unknowns' original order (the LDL^T pivots)."""
        d = np.empty(self.cb.shape[1])
        d[self.order.perm] = self.cb[0] ** 2
        return d

    def solve(self, g: np.ndarray) -> np.ndarray:
        """N^-1 g for g (k,) or (k, r)."""
        perm = self.order.perm
        x = linalg.cho_solve_banded((self.cb, True), np.asarray(g, float)[perm], check_finite=False)
        out = np.empty_like(x)
        out[perm] = x
        return out


def _canonical(N) -> sparse.csc_matrix:
    """N as CSC with sorted indices (the data order the cached scatter indices refer to)."""
    N = sparse.csc_matrix(N)
    if not N.has_sorted_indices:
        N = N.sorted_indices()
    return N


def band_order(N) -> BandOrder:
    """Reverse Cuthill-McKee ordering of the symmetric pattern of N (k, k), its half bandwidth and
    the scatter of N's entries into banded storage, cached per pattern (explicit zeros count as
    nonzeros; a pattern is recognised by comparing its index arrays, not by a hash)."""
    N = _canonical(N)
    for k, (indptr, indices, hit) in enumerate(_cache):
        if indptr.shape == N.indptr.shape and indices.shape == N.indices.shape and \
                np.array_equal(indptr, N.indptr) and np.array_equal(indices, N.indices):
            _cache.append(_cache.pop(k))
            return hit
    pattern = sparse.csr_matrix((np.ones(N.nnz), N.indices, N.indptr), shape=N.shape)
    perm = np.asarray(reverse_cuthill_mckee(pattern, symmetric_mode=True), dtype=np.int64)
    inv = np.empty_like(perm)
    inv[perm] = np.arange(perm.size)
    # entries of the CSC data in order: row indices[p], column c for indptr[c] <= p < indptr[c + 1]
    r = inv[N.indices]
    c = inv[np.repeat(np.arange(N.shape[1]), np.diff(N.indptr))]
    width = int(np.abs(r - c).max(initial=0))
    lower = r >= c
    # LAPACK lower banded storage: cb[r - c, c] = L[r, c], flat index (r - c) k + c
    scatter = (r[lower] - c[lower]) * N.shape[0] + c[lower]
    order = BandOrder(perm, width, lower, scatter)
    _cache.append((N.indptr.copy(), N.indices.copy(), order))
    del _cache[:-_CACHE_SIZE]
    return order


def factor_banded(N) -> BandedFactor | None:
    """Banded Cholesky of the SPD N (k, k) in the ordering band_order(N); None if N is not positive
    definite."""
    N = _canonical(N)
    order = band_order(N)
    cb = np.zeros((order.width + 1, N.shape[0]))
    cb.flat[order.scatter] = N.data[order.lower]
    try:
        cb = linalg.cholesky_banded(cb, lower=True, check_finite=False, overwrite_ab=True)
    except linalg.LinAlgError:
        return None
    return BandedFactor(order, cb)


def selected_inverse_diag(fac: BandedFactor, block: int = 3) -> np.ndarray:
    """Diagonal (block x block) blocks of N^-1, (k / block, block, block), unknowns in their
    original order (unknowns b*i .. b*i + b - 1 form block i).

    Z = N^-1 in the permuted order satisfies Z L = L^-T (upper triangular). For a panel of columns
    J and the band rows S below it (S = J_end .. J_end + w - 1):
        Z_SJ = -Z_SS L_SJ L_JJ^-1,   Z_JJ = (L_JJ^-T - Z_SJ^T L_SJ) L_JJ^-1,
    panels from the last to the first; only Z within the band is formed (Z_SS lies in it), and
    every diagonal block of N^-1 lies in it because N's diagonal blocks do. Work ~ k w^2; memory: a
    dense (k, k) array (72 MB at k = 3000).
    """
    cb = fac.cb
    w, k = cb.shape[0] - 1, cb.shape[1]
    Z = np.zeros((k, k))  # only the band is formed; dense storage keeps the panels contiguous
    for c1 in range(k, 0, -_PANEL):
        c0 = max(0, c1 - _PANEL)
        nb = c1 - c0
        s1 = min(k, c1 + w)
        # L_JJ (nb, nb) and L_SJ (s1 - c1, nb) from the banded storage
        rows = np.arange(c0, s1)[:, None]
        cols = np.arange(c0, c1)[None, :]
        off = rows - cols
        Lpanel = np.where((off >= 0) & (off <= w), cb[np.clip(off, 0, w), cols], 0.0)
        LJJ, LSJ = Lpanel[:nb], Lpanel[nb:]
        M = linalg.solve_triangular(LJJ, np.eye(nb), lower=True, trans="T")  # L_JJ^-T
        if s1 > c1:
            # Z_SJ = -Z_SS L_SJ L_JJ^-1
            ZSJ = -linalg.solve_triangular(LJJ, (Z[c1:s1, c1:s1] @ LSJ).T, lower=True, trans="T").T
            Z[c1:s1, c0:c1] = ZSJ
            Z[c0:c1, c1:s1] = ZSJ.T
            M = M - ZSJ.T @ LSJ
        # Z_JJ = (L_JJ^-T - Z_SJ^T L_SJ) L_JJ^-1
        ZJJ = linalg.solve_triangular(LJJ, M.T, lower=True, trans="T").T
        Z[c0:c1, c0:c1] = 0.5 * (ZJJ + ZJJ.T)
    # diagonal blocks in the original order: unknown v sits at position inv[v]
    perm = fac.order.perm
    inv = np.empty_like(perm)
    inv[perm] = np.arange(k)
    pos = inv.reshape(-1, block)  # (n, block)
    return Z[pos[:, :, None], pos[:, None, :]]
