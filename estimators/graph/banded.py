"""Banded Cholesky of a sparse SPD normal matrix after a reverse Cuthill-McKee ordering.

A factor graph's normal matrix N (k, k) has the sparsity of its variable graph. Reverse
Cuthill-McKee (Cuthill, McKee 1969; George 1971) renumbers the unknowns so that every nonzero lies
within a band |r - c| <= w; the Cholesky factor P N P^T = L L^T then lives in that band (no fill
outside it) and LAPACK's banded Cholesky (pbtrf) factors it in ~k w^2 flops with dense kernels. For
the swarms of seed 001 (UAVs within ranging distance of each other in a box) w grows like k^(2/3);
at 1000 UAVs (k = 3000) the factorization takes tens of milliseconds where SuperLU's supernodal LU
took most of a second. The ordering depends only on the sparsity pattern: `band_order` caches it
per pattern, so the iterations of a solve (and epochs with the same links) compute it once.

`selected_inverse_diag` gives the diagonal blocks of N^-1 from the banded factor by the Takahashi
recurrence (Takahashi, Fagan, Chen 1973) restricted to the band, block column by block column.
Never imports mujoco, testbed or gtsam.
"""
from __future__ import annotations

from collections import OrderedDict
from dataclasses import dataclass
from hashlib import blake2b

import numpy as np
from scipy import linalg, sparse
from scipy.sparse.csgraph import reverse_cuthill_mckee

__all__ = ["BandOrder", "BandedFactor", "band_order", "factor_banded", "selected_inverse_diag"]

#: orderings kept (one per sparsity pattern)
_CACHE_SIZE = 8
_cache: OrderedDict[bytes, "BandOrder"] = OrderedDict()
#: columns per block of the selected inversion (dense kernels on (w + b) x b panels)
_PANEL = 48


@dataclass(frozen=True, slots=True)
class BandOrder:
    """perm: (k,) new position -> unknown (P N P^T = N[perm][:, perm]); width: half bandwidth w of
    the permuted matrix (nonzeros at |r - c| <= w)."""

    perm: np.ndarray
    width: int


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


def _pattern_key(N: sparse.csc_matrix) -> bytes:
    h = blake2b(digest_size=16)
    h.update(np.asarray(N.shape, np.int64).tobytes())
    h.update(np.ascontiguousarray(N.indptr, np.int64).tobytes())
    h.update(np.ascontiguousarray(N.indices, np.int64).tobytes())
    return h.digest()


def band_order(N) -> BandOrder:
    """Reverse Cuthill-McKee ordering of the symmetric pattern of N (k, k) and its half bandwidth,
    cached per pattern (explicit zeros count as nonzeros)."""
    N = sparse.csc_matrix(N)
    N.sort_indices()
    key = _pattern_key(N)
    hit = _cache.get(key)
    if hit is not None:
        _cache.move_to_end(key)
        return hit
    pattern = sparse.csr_matrix((np.ones(N.nnz), N.indices, N.indptr), shape=N.shape)
    perm = np.asarray(reverse_cuthill_mckee(pattern, symmetric_mode=True), dtype=np.int64)
    inv = np.empty_like(perm)
    inv[perm] = np.arange(perm.size)
    coo = pattern.tocoo()
    width = int(np.abs(inv[coo.row] - inv[coo.col]).max(initial=0))
    order = BandOrder(perm, width)
    _cache[key] = order
    if len(_cache) > _CACHE_SIZE:
        _cache.popitem(last=False)
    return order


def factor_banded(N, order: BandOrder | None = None) -> BandedFactor | None:
    """Banded Cholesky of the SPD N (k, k) in the ordering `order` (default: band_order(N));
    None if N is not positive definite."""
    N = sparse.csc_matrix(N)
    order = band_order(N) if order is None else order
    inv = np.empty_like(order.perm)
    inv[order.perm] = np.arange(order.perm.size)
    coo = N.tocoo()
    r, c = inv[coo.row], inv[coo.col]
    low = r >= c
    cb = np.zeros((order.width + 1, N.shape[0]))
    cb[r[low] - c[low], c[low]] = coo.data[low]
    try:
        cb = linalg.cholesky_banded(cb, lower=True, check_finite=False)
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
