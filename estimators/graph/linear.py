"""Sparse symmetric positive (semi-)definite solves with an observability (gauge) check.

The normal matrix N = A^T A of a factor graph is singular exactly when some direction of the
variables changes no residual (a gauge freedom: no prior and too few fixed nodes, a node without
factors, collinear ranges only, ...). A Cholesky-type factorization P N P^T = L D L^T exposes it
as a pivot D_i that is zero, or zero to round-off relative to N_ii. `factor_spd` factors N (dense
LAPACK Cholesky for small systems; above `DENSE_LIMIT` unknowns a banded Cholesky after a reverse
Cuthill-McKee ordering (estimators.graph.banded) when the band is narrow, i.e. half-bandwidth below
k * BAND_FRACTION, else SuperLU with a symmetric fill-reducing ordering and no pivoting) and reports
the smallest relative pivot min_i D_i / N_ii; `observable` is that ratio above `GAUGE_RATIO`.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import linalg, sparse
from scipy.sparse import linalg as splinalg

from estimators.graph.banded import BandOrder, band_order, factor_banded

__all__ = ["BAND_FRACTION", "DENSE_LIMIT", "GAUGE_RATIO", "GaugeWarning", "SpdFactor", "factor_spd", "narrow_band"]

#: below this many unknowns the dense Cholesky beats the sparse factorization
DENSE_LIMIT = 600
#: the banded Cholesky is used when the half-bandwidth w after RCM is below this fraction of k
#: (its ~k w^2 flops are then below 3/16 of a dense factorization's k^3 / 3)
BAND_FRACTION = 0.25
#: a relative pivot D_i / N_ii below this is a zero pivot (an unobservable direction)
GAUGE_RATIO = 1e-10


class GaugeWarning(UserWarning):
    """The problem is unobservable (gauge freedom): the estimate is one of many optima."""


@dataclass(frozen=True, slots=True)
class SpdFactor:
    """A factored normal matrix N (k, k).

    ok: the factorization ran to the end with positive pivots; min_pivot_ratio: min_i D_i / N_ii
    (0 if a pivot was not positive); observable: ok and min_pivot_ratio > GAUGE_RATIO.
    """

    ok: bool
    min_pivot_ratio: float
    _solve: object

    @property
    def observable(self) -> bool:
        return self.ok and self.min_pivot_ratio > GAUGE_RATIO

    def solve(self, g: np.ndarray) -> np.ndarray:
        """N^-1 g for g (k,) or (k, r); only when ok."""
        if not self.ok:
            raise np.linalg.LinAlgError("SpdFactor.solve: the matrix is not positive definite")
        return self._solve(g)


def factor_spd(N) -> SpdFactor:
    """Factor a symmetric PSD matrix N (k, k), dense array or scipy sparse; never raises on a
    singular or indefinite N (ok=False instead)."""
    k = N.shape[0]
    if k == 0:
        return SpdFactor(True, np.inf, lambda g: np.asarray(g, float))
    diag = np.asarray(N.diagonal(), dtype=float)
    if not np.all(np.isfinite(diag)) or np.any(diag <= 0):
        return SpdFactor(False, 0.0, None)
    if k <= DENSE_LIMIT:
        Nd = N.toarray() if sparse.issparse(N) else np.asarray(N, float)
        c, info = linalg.lapack.dpotrf(Nd, lower=False)
        if info != 0:
            return SpdFactor(False, 0.0, None)
        ratio = float(np.min(np.diag(c) ** 2 / diag))
        return SpdFactor(True, ratio, lambda g: linalg.cho_solve((c, False), g))
    Ns = sparse.csc_matrix(N)
    order = narrow_band(Ns)
    if order is not None:
        fac = factor_banded(Ns)
        if fac is None:
            return SpdFactor(False, 0.0, None)
        return SpdFactor(True, float(np.min(fac.pivots() / diag)), fac.solve)
    try:
        lu = splinalg.splu(Ns, permc_spec="MMD_AT_PLUS_A", diag_pivot_thresh=0.0,
                           options={"SymmetricMode": True})
    except RuntimeError:  # exactly singular
        return SpdFactor(False, 0.0, None)
    piv = lu.U.diagonal()
    if not np.array_equal(lu.perm_r, lu.perm_c) or not np.all(np.isfinite(piv)) or np.any(piv <= 0):
        return SpdFactor(False, 0.0, None)
    # U = D L^T in the permuted order: pivot of column c is U[c, c], variable perm_c^-1(c)
    ratio = float(np.min(piv[lu.perm_c] / diag))
    return SpdFactor(True, ratio, lu.solve)


def narrow_band(N: sparse.spmatrix) -> BandOrder | None:
    """The RCM ordering of N (k, k) if the banded Cholesky suits N (half-bandwidth below
    BAND_FRACTION k), else None."""
    order = band_order(N)
    return order if order.width < BAND_FRACTION * N.shape[0] else None
