"""Sparse symmetric positive (semi-)definite solves with an observability (gauge) check.

The normal matrix N = A^T A of a factor graph is singular exactly when some direction of the
variables changes no residual (a gauge freedom: no prior and too few fixed nodes, a node without
factors, collinear ranges only, ...). A Cholesky-type factorization P N P^T = L D L^T exposes it
as a pivot D_i that is zero, or zero to round-off relative to N_ii. `factor_spd` factors N (dense
LAPACK Cholesky for small systems; above `DENSE_LIMIT` unknowns a banded Cholesky after a reverse
Cuthill-McKee ordering (estimators.graph.banded) when the band is narrow, i.e. half-bandwidth below
k * BAND_FRACTION, else SuperLU with a symmetric fill-reducing ordering and no pivoting) and reports
the smallest relative pivot min_i D_i / N_ii; `observable` is that ratio above `GAUGE_RATIO`.
The normal equations N delta = g that the iteration of estimators.graph.lm solves, damped or not:
`SparseNormal` (one problem, sparse N, factored by `factor_spd`) and `DenseNormals` (a batch of
independent small problems, N (E, k, k), batched Cholesky). The seed 001 solvers' covariances:
`dense_covariance` ((A^T A)^-1 by potrf/potri) and `marginal_blocks` (the 3x3 diagonal blocks of
N^-1 by a selected inverse, for large swarms). The sliding window's block-tridiagonal solve:
`solve_block_tridiagonal`, and its normal equations for the iteration, `BlockTridiagonalNormals`.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import linalg, sparse
from scipy.sparse import linalg as splinalg

from estimators.graph.banded import BandOrder, band_order, factor_banded, selected_inverse_diag

__all__ = ["BAND_FRACTION", "DENSE_LIMIT", "GAUGE_RATIO", "GaugeWarning", "SpdFactor", "factor_spd", "narrow_band",
           "SparseNormal", "DenseNormals", "dense_covariance", "marginal_blocks", "solve_block_tridiagonal",
           "BlockTridiagonalNormals"]

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


class SparseNormal:
    """The normal equations N delta = g of one problem (a batch of E = 1 for estimators.graph.lm):
    N (k, k) scipy sparse (or dense), symmetric PSD; g (1, k). Seed 001 eq. 16: N = A^T A, g = A^T b
    for the whitened Jacobian A and error b (`from_whitened`)."""

    __slots__ = ("N", "g")

    def __init__(self, N, g: np.ndarray):
        self.N = N
        self.g = np.asarray(g, float).reshape(1, -1)

    @classmethod
    def from_whitened(cls, A, b: np.ndarray) -> "SparseNormal":
        """N = A^T A, g = A^T b from A (rows, k) sparse and b (rows,)."""
        return cls((A.T @ A).tocsc(), A.T @ b)

    def diagonal(self) -> np.ndarray:
        """diag(N), (1, k)."""
        return np.asarray(self.N.diagonal(), float)[None]

    def solve(self, shift: np.ndarray | None) -> tuple[np.ndarray, np.ndarray]:
        """(delta (1, k), ok (1,)): (N + diag(shift)) delta = g, shift (1, k) or None (undamped);
        ok False (delta zero) when that matrix is not positive definite (`factor_spd`)."""
        M = self.N if shift is None else self.N + sparse.diags(shift[0])
        fac = factor_spd(M)
        if not fac.ok:
            return np.zeros_like(self.g), np.zeros(1, bool)
        return fac.solve(self.g[0])[None], np.ones(1, bool)

    def quad(self, delta: np.ndarray) -> np.ndarray:
        """delta^T N delta, (1,), for delta (1, k)."""
        return np.array([float(delta[0] @ (self.N @ delta[0]))])

    def where(self, mask: np.ndarray, other: "SparseNormal") -> "SparseNormal":
        """self if mask[0] else other."""
        return self if mask[0] else other


class DenseNormals:
    """The normal equations of E independent problems of k unknowns each: N (E, k, k) symmetric
    PSD, g (E, k) (e.g. the epochs of estimators.graph.batch, the nodes of a distributed round)."""

    __slots__ = ("N", "g")

    def __init__(self, N: np.ndarray, g: np.ndarray):
        self.N, self.g = N, g

    def diagonal(self) -> np.ndarray:
        """diag(N) per problem, (E, k)."""
        return np.diagonal(self.N, axis1=1, axis2=2)

    def solve(self, shift: np.ndarray | None) -> tuple[np.ndarray, np.ndarray]:
        """(delta (E, k), ok (E,)): (N + diag(shift)) delta = g per problem, shift (E, k) or None.
        One batched Cholesky; if one matrix is numerically indefinite, each is factored on its own
        (`factor_spd`) and a failed one gets ok False and delta zero."""
        A = self.N if shift is None else self.N + shift[:, :, None] * np.eye(self.N.shape[1])
        try:
            L = np.linalg.cholesky(A)
        except np.linalg.LinAlgError:
            out, ok = np.zeros_like(self.g), np.zeros(self.g.shape[0], bool)
            for i in range(A.shape[0]):
                fac = factor_spd(A[i])
                if fac.ok:
                    out[i], ok[i] = fac.solve(self.g[i]), True
            return out, ok
        y = np.linalg.solve(L, self.g[..., None])
        return np.linalg.solve(np.swapaxes(L, 1, 2), y)[..., 0], np.ones(self.g.shape[0], bool)

    def quad(self, delta: np.ndarray) -> np.ndarray:
        """delta^T N delta per problem, (E,), for delta (E, k)."""
        return np.einsum("ei,eij,ej->e", delta, self.N, delta)

    def inverse(self) -> np.ndarray:
        """N^-1 per problem (E, k, k) (a covariance), L^-T L^-1 from the Cholesky factor N = L L^T.
        Raises numpy.linalg.LinAlgError where an N is not positive definite."""
        Li = np.linalg.inv(np.linalg.cholesky(self.N))
        return np.einsum("nba,nbc->nac", Li, Li)

    def where(self, mask: np.ndarray, other: "DenseNormals") -> "DenseNormals":
        """Per problem: self where mask (E,) else other."""
        return DenseNormals(np.where(mask[:, None, None], self.N, other.N), np.where(mask[:, None], self.g, other.g))

    def take(self, idx: np.ndarray) -> "DenseNormals":
        """The problems idx (index or mask)."""
        return DenseNormals(self.N[idx], self.g[idx])

    def put(self, idx: np.ndarray, part: "DenseNormals") -> None:
        """Write part into the problems idx."""
        self.N[idx], self.g[idx] = part.N, part.g


def dense_covariance(A: sparse.csr_matrix) -> np.ndarray:
    """(A^T A)^-1 (k, k) of a whitened Jacobian A (rows, k): dense Cholesky factor and its inverse
    (LAPACK potrf/potri). Raises LinAlgError when A^T A is not positive definite."""
    N = (A.T @ A).toarray()
    c, info = linalg.lapack.dpotrf(N, lower=False)
    if info != 0:
        raise np.linalg.LinAlgError(f"dense_covariance: A^T A not positive definite (potrf info {info})")
    inv, info = linalg.lapack.dpotri(c, lower=False)
    if info != 0:
        raise np.linalg.LinAlgError(f"dense_covariance: potri failed (info {info})")
    # seed 001 eq. 19 on the whole graph: Sigma = (R^T R)^-1 = (A^T A)^-1; potri fills the upper triangle
    return np.triu(inv) + np.triu(inv, 1).T


def marginal_blocks(N: sparse.csc_matrix, n: int) -> np.ndarray:
    """Diagonal 3x3 blocks of N^-1 (n, 3, 3) (m^2 for positions) of a sparse SPD N (3n, 3n), without
    the full inverse.

    A narrow band after reverse Cuthill-McKee: the banded Cholesky and its selected inverse
    (estimators.graph.banded). Otherwise:
    selected inverse (Takahashi, Fagan, Chen 1973) on a sparse LDL^T factor, supernode by supernode:
    SuperLU with a symmetric fill-reducing ordering and no pivoting gives P N P^T = L D L^T (L unit
    lower, U = D L^T). Z = N^-1 satisfies Z L = L^-T D^-1 (upper triangular), so for a supernode of
    columns J with the rows S below it (struct of L):
        Z_SJ = -Z_SS L_SJ L_JJ^-1,   Z_JJ = (L_JJ^-T D_J^-1 - Z_SJ^T L_SJ) L_JJ^-1,
    from the last supernode to the first; only entries on the (chordal) pattern of L are computed,
    and that pattern holds every 3x3 block of N's diagonal. Work ~ sum over supernodes of |S|^2 |J|.
    The working array is dense (3n)^2 (72 MB at n = 1000); the flops are the sparse ones.
    Falls back to the dense inverse if SuperLU permuted rows and columns differently.
    """
    nv = N.shape[0]
    order = narrow_band(N)
    if order is not None:
        fac = factor_banded(N)
        if fac is None:
            raise np.linalg.LinAlgError("marginal_blocks: N is not positive definite")
        return selected_inverse_diag(fac)
    lu = splinalg.splu(N, permc_spec="MMD_AT_PLUS_A", diag_pivot_thresh=0.0, options={"SymmetricMode": True})
    if not np.array_equal(lu.perm_r, lu.perm_c):
        full = linalg.cho_solve(linalg.cho_factor(N.toarray()), np.eye(nv))
        idx = np.arange(n)
        return full.reshape(n, 3, n, 3)[idx, :, idx, :]
    L = lu.L.tocsc()
    L.sort_indices()
    d = lu.U.diagonal()
    ip, ix = L.indptr, L.indices
    starts = [0]
    for i in range(nv - 1):  # column i + 1 continues i's supernode if struct(i) \ {i} == struct(i + 1)
        a, b = ix[ip[i] + 1: ip[i + 1]], ix[ip[i + 1]: ip[i + 2]]
        if not (a.size == b.size and np.array_equal(a, b)):
            starts.append(i + 1)
    starts.append(nv)
    Z = np.zeros((nv, nv))
    for k in range(len(starts) - 2, -1, -1):
        c0, c1 = starts[k], starts[k + 1]
        rows = ix[ip[c0]: ip[c0 + 1]]
        S = rows[rows >= c1]
        blk = L[:, c0:c1]
        LJJ = blk[c0:c1].toarray()
        # L_JJ^-T D_J^-1
        M = linalg.solve_triangular(LJJ, np.diag(1.0 / d[c0:c1]), lower=True, trans="T", unit_diagonal=True)
        if S.size:
            LSJ = blk[S].toarray()
            # Z_SJ = -Z_SS L_SJ L_JJ^-1
            ZSJ = -linalg.solve_triangular(LJJ, (Z[np.ix_(S, S)] @ LSJ).T, lower=True, trans="T", unit_diagonal=True).T
            Z[np.ix_(S, np.arange(c0, c1))] = ZSJ
            Z[np.ix_(np.arange(c0, c1), S)] = ZSJ.T
            M = M - ZSJ.T @ LSJ
        # Z_JJ = (L_JJ^-T D_J^-1 - Z_SJ^T L_SJ) L_JJ^-1
        ZJJ = linalg.solve_triangular(LJJ, M.T, lower=True, trans="T", unit_diagonal=True).T
        Z[c0:c1, c0:c1] = 0.5 * (ZJJ + ZJJ.T)
    idx = lu.perm_c.reshape(n, 3)  # position of variable v in the factored order: perm_c[v]
    return Z[idx[:, :, None], idx[:, None, :]]


class _Spd:
    """A batch of SPD matrices (B, s, s) factored once: Cholesky (scipy) for one large matrix,
    numpy's batched LU for many small ones (a per-vehicle 6 x 6 block)."""

    def __init__(self, S: np.ndarray):
        self.one = S.shape[0] == 1
        self.f = linalg.cho_factor(S[0], check_finite=False) if self.one else S

    def solve(self, Y: np.ndarray) -> np.ndarray:
        """S^-1 Y for Y (B, s) or (B, s, r)."""
        if self.one:
            return linalg.cho_solve(self.f, Y[0], check_finite=False)[None]
        return np.linalg.solve(self.f, Y[..., None])[..., 0] if Y.ndim == 2 else np.linalg.solve(self.f, Y)


def solve_block_tridiagonal(D: np.ndarray, U: np.ndarray, R: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Solve the block-tridiagonal SPD system H delta = R (a chain of epochs linked by motion
    factors: the sliding window, estimators.window), batched over B agents, by forward block
    elimination and back substitution.

    D (B, K, s, s) diagonal blocks, U (B, K-1, s, s) blocks H[k, k+1], R (B, K, s).
    Returns delta (B, K, s) and S (B, s, s): the last Schur complement, the information of the
    newest epoch's marginal (its inverse is that epoch's covariance)."""
    K = D.shape[1]
    S, Y = D[:, 0], [R[:, 0]]
    F = [_Spd(S)]
    for k in range(1, K):
        Wk = F[-1].solve(U[:, k - 1])  # S_{k-1}^{-1} U_{k-1}
        S = D[:, k] - np.swapaxes(U[:, k - 1], 1, 2) @ Wk
        Y.append(R[:, k] - np.einsum("bij,bi->bj", Wk, Y[-1]))
        F.append(_Spd(S))
    delta = [F[-1].solve(Y[-1])]
    for k in range(K - 2, -1, -1):
        delta.append(F[k].solve(Y[k] - np.einsum("bij,bj->bi", U[:, k], delta[-1])))
    return np.stack(delta[::-1], axis=1), S


class BlockTridiagonalNormals:
    """The normal equations H delta = g of B independent chains of K epochs of s unknowns each
    (the agents of the sliding window, estimators.window), for estimators.graph.lm: H block-
    tridiagonal in time with diagonal blocks D (B, K, s, s) and blocks H[k, k+1] U (B, K-1, s, s);
    g (B, K s), the right-hand sides R (B, K, s) flattened epoch-major. A solve also leaves S
    (B, s, s), the newest epoch's information of the matrix it solved (`solve_block_tridiagonal`;
    None before any solve)."""

    __slots__ = ("D", "U", "g", "S")

    def __init__(self, D: np.ndarray, U: np.ndarray, R: np.ndarray):
        self.D, self.U, self.g, self.S = D, U, R.reshape(R.shape[0], -1), None

    def diagonal(self) -> np.ndarray:
        """diag(H) per chain, (B, K s)."""
        return np.diagonal(self.D, axis1=2, axis2=3).reshape(self.g.shape)

    def solve(self, shift: np.ndarray | None) -> tuple[np.ndarray, np.ndarray]:
        """(delta (B, K s), ok (B,) all True): (H + diag(shift)) delta = g, shift (B, K s) or None.
        A singular block raises numpy.linalg.LinAlgError (as `solve_block_tridiagonal`)."""
        B, K, s = self.D.shape[:3]
        D = self.D if shift is None else self.D + shift.reshape(B, K, s)[..., None] * np.eye(s)
        delta, self.S = solve_block_tridiagonal(D, self.U, self.g.reshape(B, K, s))
        return delta.reshape(B, -1), np.ones(B, bool)

    def quad(self, delta: np.ndarray) -> np.ndarray:
        """delta^T H delta per chain, (B,), for delta (B, K s)."""
        d = delta.reshape(self.D.shape[:3])
        return (np.einsum("bki,bkij,bkj->b", d, self.D, d)
                + 2.0 * np.einsum("bki,bkij,bkj->b", d[:, :-1], self.U, d[:, 1:]))

    def where(self, mask: np.ndarray, other: "BlockTridiagonalNormals") -> "BlockTridiagonalNormals":
        """Per chain: self where mask (B,) else other (S not carried)."""
        if mask.all() or not mask.any():
            return self if mask.all() else other
        return BlockTridiagonalNormals(np.where(mask[:, None, None, None], self.D, other.D),
                                       np.where(mask[:, None, None, None], self.U, other.U),
                                       np.where(mask[:, None], self.g, other.g))
