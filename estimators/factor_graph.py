"""Factor-graph cooperative navigation of a UAV swarm at one epoch (seed 001: GNSS + UWB ranges).

Variables: the 3-D positions p_i (ENU, metres, local frame of the scenario origin) of all n UAVs
at one epoch, stacked as x = [p_0; p_1; ...; p_{n-1}] (3n,).
Factors (seed 001, docs/papers.md):
- GNSS factor per UAV i: z_i = p_i + n_i, n_i ~ N(0, Sigma_i) (Sigma_i: (3, 3) m^2, diagonal
  (s_h^2, s_h^2, s_v^2) for SPP 1.5/3.0 m or RTK 0.02/0.03 m, any SPD matrix accepted);
- range factor per pair (i, j) within ranging distance: d_ij = |p_i - p_j| + e, e ~ N(0, sigma_d^2)
  (sigma_d = 0.10 m by default, per link).

Conventions chosen here (see also the report of the seed):
- UWB clock scale factor (20 ppm): NOT modelled as a state. Over a <= 100 m link it is a bias of
  at most 20e-6 * 100 m = 2 mm, i.e. a variance (2e-3)^2 = 4e-6 m^2 against sigma_d^2 = 1e-2 m^2
  (0.04 %): it is absorbed into the range noise. A user who wants it can pass a per-link
  `range_sigma` (m,) = sqrt(sigma_d^2 + (ppm * d)^2); errors shared by the links of one radio
  (per-device clock offsets, antenna delays) go into `range_cov`, the joint (m, m) covariance of
  the ranges, which the centralized least-squares solver whitens with its Cholesky factor.
- Linearization follows the paper's notation (eqs. 13-16): at the current x0 each factor k gives
  the whitened Jacobian A_k = Sigma_k^{-1/2} dh_k/dx and the whitened prediction error
  b_k = Sigma_k^{-1/2} (z_k - h_k(x0)); the step Delta solves min |A Delta - b|^2, i.e. the normal
  equations A^T A Delta = A^T b.
- Robust option: Huber loss on the whitened range residuals r (IRLS weight w = min(1, delta/|r|)),
  threshold delta = 1.345 (in units of the range sigma: 0.1345 m for sigma_d = 0.10 m), the
  classical choice with 95 % efficiency under Gaussian noise.
- Distributed scheme (the paper's message iteration, section 2.3.2): each UAV's local graph has its
  own GNSS factor, the range factors to its neighbours and the neighbours' last received
  broadcasts (position (3,) + covariance (3, 3)) as priors on local neighbour variables. One
  Gauss-Newton step is taken on the local graph linearized at (own estimate, neighbours'
  broadcasts); only the UAV's own 3-D block of the step and of the covariance is kept (eq. 19).
  By the Schur complement this is *exactly* the same as keeping the neighbours fixed at their
  broadcast positions and inflating each range variance to sigma_d^2 + u^T Sigma_j u (u: unit
  vector from j to i). The vectorized solver uses that closed form; `local_step_qr` is the
  literal QR form of the paper and the tests check that the two agree.
- Messages: one broadcast per transmitting UAV per round = position (3 float64) + the 6 unique
  entries of the covariance (6 float64) = 72 bytes of payload (headers not counted). A broadcast is
  one message regardless of how many neighbours hear it; successful receptions are counted
  separately as `deliveries`. Round 0 is the broadcast of the GNSS fix and GNSS covariance.
- Faults: every receiver keeps a table of the last message received from each neighbour.
  A silent node (stops broadcasting from a given round on) or a lost message leaves the previous
  entry in place (`max_age=None`: keep the last message) or, with `max_age=k`, the entry is dropped
  once it is older than k rounds, and with it the range factor to that neighbour (a range to a
  neighbour of unknown position carries no information about one's own position).

Built from the graph library (estimators.graph): its factors (graph.factors: range and GNSS
measurement functions, whitening, the inflated range variance), robust losses (graph.losses), its
iterations (graph.lm: the Gauss-Newton / Levenberg-Marquardt iteration of every centralized solve,
least squares, Newton-Huber or the general graph, and the round iteration of the distributed
scheme) and the linear algebra (graph.linear). This module never imports mujoco, testbed or gtsam.
"""
from __future__ import annotations

import warnings
from dataclasses import dataclass, field

import numpy as np
from scipy import linalg, sparse

from estimators.core import symmetrize
from estimators.graph.factors import (
    gnss_h, gnss_jacobian, inflated_range_variance, range_h, range_jacobian, range_terms, sqrt_information,
)
from estimators.graph.linear import DENSE_LIMIT, DenseNormals, GaugeWarning, SparseNormal, dense_covariance, factor_spd, marginal_blocks
from estimators.graph import lm
from estimators.graph.lm import Report, minimize
from estimators.graph.losses import HUBER_DELTA, Loss, huber_rho, huber_weight, loss_rho, loss_weight
from estimators.transport import Transport

__all__ = [
    "CoopProblem",
    "CentralizedResult",
    "DistributedResult",
    "GaugeWarning",
    "Loss",
    "HUBER_DELTA",
    "MESSAGE_BYTES",
    "gnss_h",
    "gnss_jacobian",
    "range_h",
    "range_jacobian",
    "huber_weight",
    "huber_rho",
    "whitened_system",
    "cost",
    "solve_centralized",
    "local_step_qr",
    "solve_distributed",
    "neighbours",
]

#: Payload of one broadcast: position (3) + unique covariance entries (6), float64.
MESSAGE_BYTES = (3 + 6) * 8
#: Levenberg term (m^-2) of the local step of a node without a prior (distributed solver).
LOCAL_DAMPING = 1e-9
#: Broadcast variance (m^2) of a node that has neither a prior nor an estimate yet.
NO_INFO_VAR = 1e9


# ----------------------------------------------------------------------------------------------
# Problem
# ----------------------------------------------------------------------------------------------
@dataclass(frozen=True, slots=True)
class CoopProblem:
    """The measurements of one epoch.

    gnss_pos: (n, 3) GNSS fixes z_i, metres, ENU.
    gnss_cov: (n, 3, 3) GNSS covariances Sigma_i, m^2, SPD.
    edges: (m, 2) int, UAV index pairs (i, j), i != j, each unordered pair at most once.
    ranges: (m,) measured UWB distances d_ij, metres.
    range_sigma: (m,) range standard deviations sigma_d, metres (a scalar is broadcast).
    prior: (n,) bool or None (all True): node i has the GNSS factor (gnss_pos[i], gnss_cov[i]);
        for a node without it gnss_pos[i] is only the default initial guess and gnss_cov[i] is
        ignored (any value).
    fixed: (n,) bool or None (all False): node i is known (an anchor, a robot with a known
        position) and held at gnss_pos[i]; it is not a variable, its prior is ignored.
    range_cov: (m, m) m^2 joint covariance of the range errors or None (independent ranges,
        diag(range_sigma^2)). Errors shared by the links of one radio (a per-device antenna delay
        or clock offset) correlate ranges of the same epoch; its diagonal must be range_sigma^2.
        Used by the least-squares path of solve_centralized (whitening by its Cholesky factor);
        the distributed scheme treats ranges as independent (range_sigma), and robust losses,
        fixed nodes and missing priors refuse it (ValueError; also if it is not positive definite).
        Dense: O(m^3) once per problem, O(m^2) per whitening, meant for one epoch of seed 001 (tens
        to hundreds of links); a swarm of thousands of links would carry the per-device terms as
        nuisance variables instead (not implemented).
    range_chol: (m, m) m, computed (not an argument): the lower Cholesky factor L of range_cov =
        L L^T, factored once here rather than at every cost evaluation of the solver; None if
        range_cov is None.
    """

    gnss_pos: np.ndarray
    gnss_cov: np.ndarray
    edges: np.ndarray
    ranges: np.ndarray
    range_sigma: np.ndarray
    prior: np.ndarray | None = None
    fixed: np.ndarray | None = None
    range_cov: np.ndarray | None = None
    range_chol: np.ndarray | None = field(default=None, init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        z = np.asarray(self.gnss_pos, dtype=float)
        n = z.shape[0]
        cov = np.asarray(self.gnss_cov, dtype=float)
        e = np.asarray(self.edges, dtype=np.int64).reshape(-1, 2)
        d = np.asarray(self.ranges, dtype=float).reshape(-1)
        s = np.broadcast_to(np.asarray(self.range_sigma, dtype=float), d.shape).copy()
        if z.ndim != 2 or z.shape[1] != 3:
            raise ValueError(f"CoopProblem: gnss_pos must be (n, 3), got {z.shape}")
        if cov.shape != (n, 3, 3):
            raise ValueError(f"CoopProblem: gnss_cov must be ({n}, 3, 3), got {cov.shape}")
        if e.shape[0] != d.shape[0]:
            raise ValueError(f"CoopProblem: {e.shape[0]} edges but {d.shape[0]} ranges")
        if e.size and (e.min() < 0 or e.max() >= n or np.any(e[:, 0] == e[:, 1])):
            raise ValueError("CoopProblem: edge indices out of range or self-loops")
        if np.any(s <= 0):
            raise ValueError("CoopProblem: range_sigma must be positive")
        prior = np.ones(n, bool) if self.prior is None else np.asarray(self.prior, dtype=bool).reshape(-1)
        fixed = np.zeros(n, bool) if self.fixed is None else np.asarray(self.fixed, dtype=bool).reshape(-1)
        if prior.shape != (n,) or fixed.shape != (n,):
            raise ValueError(f"CoopProblem: prior and fixed must be ({n},) bool, got {prior.shape}, {fixed.shape}")
        if not (prior | fixed).all():
            # the covariance of a node without a prior is never used: make it harmless
            cov = cov.copy()
            cov[~(prior | fixed)] = np.eye(3)
        object.__setattr__(self, "prior", prior)
        object.__setattr__(self, "fixed", fixed)
        object.__setattr__(self, "gnss_pos", z)
        object.__setattr__(self, "gnss_cov", cov)
        object.__setattr__(self, "edges", e)
        object.__setattr__(self, "ranges", d)
        object.__setattr__(self, "range_sigma", s)
        if self.range_cov is not None:
            C = np.asarray(self.range_cov, dtype=float)
            if C.shape != (d.size, d.size) or not np.allclose(C, C.T, rtol=0.0, atol=1e-15):
                raise ValueError(f"CoopProblem: range_cov must be a symmetric ({d.size}, {d.size}) matrix, got {C.shape}")
            if not np.allclose(np.sqrt(np.diagonal(C)), s, rtol=1e-9, atol=0.0):
                raise ValueError("CoopProblem: the diagonal of range_cov must be range_sigma^2")
            object.__setattr__(self, "range_cov", C)
            try:
                object.__setattr__(self, "range_chol", np.linalg.cholesky(C))
            except np.linalg.LinAlgError:
                raise ValueError("CoopProblem: range_cov is not positive definite") from None

    @property
    def n(self) -> int:
        """Number of UAVs."""
        return self.gnss_pos.shape[0]

    @property
    def m(self) -> int:
        """Number of range factors."""
        return self.edges.shape[0]

    @property
    def is_plain(self) -> bool:
        """Every node has its prior and none is fixed (the seed 001 problem)."""
        return bool(self.prior.all() and not self.fixed.any())


def _range_residuals(problem: CoopProblem, X: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Whitened range residuals r (m,) and unit vectors u_k (m, 3): r_k = (d_k - |p_i - p_j|)/sigma_k,
    or with range_cov = L L^T, r = L^{-1} (d - |p_i - p_j|) (correlated ranges)."""
    i, j = problem.edges[:, 0], problem.edges[:, 1]
    h, u = range_terms(X[i], X[j])
    res = problem.ranges - h
    if problem.range_cov is None:
        return res / problem.range_sigma, u
    return linalg.solve_triangular(problem.range_chol, res, lower=True), u


#: factor types of the seed 001 graph, the keys of a `losses` mapping
FACTOR_TYPES = ("gnss", "range")


def _check_losses(losses) -> dict:
    """{factor type: Loss} from a mapping with keys in FACTOR_TYPES (missing: least squares)."""
    losses = dict(losses or {})
    bad = set(losses) - set(FACTOR_TYPES)
    if bad:
        raise ValueError(f"losses: unknown factor types {sorted(bad)}; known: {FACTOR_TYPES}")
    for k, v in losses.items():
        if not isinstance(v, Loss):
            raise ValueError(f"losses[{k!r}] must be a Loss, got {v!r}")
    return losses


def _robust_terms(problem: CoopProblem, X: np.ndarray, losses: dict):
    """Whitened residuals of the general graph at X (n, 3), with their IRLS weights.

    Returns (pri (p,) nodes with a prior that are free, W (p, 3, 3) their sqrt information,
    bg (p, 3) whitened GNSS residuals, wg (p,) their weights, r (m,) whitened range residuals,
    u (m, 3) unit vectors j -> i, wr (m,) their weights).
    """
    if problem.range_cov is not None:
        raise ValueError("CoopProblem: range_cov (correlated ranges) needs the plain least-squares path "
                         "(every node with a prior, none fixed, no robust loss, method 'gn')")
    pri = np.flatnonzero(problem.prior & ~problem.fixed)
    W = sqrt_information(problem.gnss_cov[pri])
    bg = np.einsum("nab,nb->na", W, problem.gnss_pos[pri] - X[pri])
    wg = loss_weight(losses.get("gnss"), np.linalg.norm(bg, axis=1))
    r, u = _range_residuals(problem, X)
    wr = loss_weight(losses.get("range"), r)
    return pri, W, bg, wg, r, u, wr


def _general_cost(problem: CoopProblem, X: np.ndarray, losses: dict) -> float:
    """Robust objective sum rho(|b_k|) over the GNSS factors of free nodes and the ranges."""
    pri, W, bg, _, r, _, _ = _robust_terms(problem, X, losses)
    return float(np.sum(loss_rho(losses.get("gnss"), np.linalg.norm(bg, axis=1)))
                 + np.sum(loss_rho(losses.get("range"), r)))


def _general_system(problem: CoopProblem, X: np.ndarray, losses: dict) -> tuple[sparse.csr_matrix, np.ndarray]:
    """IRLS-weighted whitened system of the general graph: A ((3p + m) x 3f) over the f free nodes
    (column block of free node i: its rank among the free nodes), b (3p + m,). Rows of a factor are
    scaled by sqrt(w) (see estimators.graph.losses); columns of fixed nodes are dropped."""
    m = problem.m
    col = np.cumsum(~problem.fixed) - 1  # block column of each free node
    nf = int((~problem.fixed).sum())
    pri, W, bg, wg, r, u, wr = _robust_terms(problem, X, losses)
    sg, sr = np.sqrt(wg), np.sqrt(wr)
    p = pri.size
    # eq. 13-14: whitening, A_k = Sigma_k^{-1/2} H_k, b_k = Sigma_k^{-1/2} (z_k - h_k(x0)), times sqrt(w_k)
    rows_g = np.repeat(np.arange(3 * p).reshape(p, 3), 3, axis=1).reshape(-1)
    cols_g = np.tile((3 * col[pri])[:, None, None] + np.arange(3), (1, 3, 1)).reshape(-1)
    vals_g = (sg[:, None, None] * W).reshape(-1)
    coef = (sr / problem.range_sigma)[:, None] * u
    i, j = problem.edges[:, 0], problem.edges[:, 1]
    rows_r = np.repeat(3 * p + np.arange(m), 3)
    keep_i, keep_j = np.repeat(~problem.fixed[i], 3), np.repeat(~problem.fixed[j], 3)
    cols_i = (3 * col[i][:, None] + np.arange(3)).reshape(-1)
    cols_j = (3 * col[j][:, None] + np.arange(3)).reshape(-1)
    rows = np.concatenate([rows_g, rows_r[keep_i], rows_r[keep_j]])
    cols = np.concatenate([cols_g, cols_i[keep_i], cols_j[keep_j]])
    vals = np.concatenate([vals_g, coef.reshape(-1)[keep_i], -coef.reshape(-1)[keep_j]])
    A = sparse.csr_matrix((vals, (rows, cols)), shape=(3 * p + m, 3 * nf))
    b = np.concatenate([(sg[:, None] * bg).reshape(-1), sr * r])
    return A, b


def cost(problem: CoopProblem, X: np.ndarray, huber: float | None = None, *, losses=None) -> float:
    """Objective 1/2 sum |b_k|^2 (Huber on the range terms if huber is a threshold). X: (n, 3) m.

    With `losses` ({factor type: Loss}, see FACTOR_TYPES) or a problem with fixed nodes or missing
    priors: the robust objective of the general graph, sum of rho(|b_k|) over its factors.
    """
    if losses is not None or not problem.is_plain:
        if huber is not None:
            raise ValueError("cost: give either huber or losses")
        return _general_cost(problem, X, _check_losses(losses))
    W = sqrt_information(problem.gnss_cov)
    bg = np.einsum("nab,nb->na", W, problem.gnss_pos - X)
    r, _ = _range_residuals(problem, X)
    return float(0.5 * np.sum(bg * bg) + np.sum(huber_rho(r, huber)))


def whitened_system(
    problem: CoopProblem, X: np.ndarray, huber: float | None = None
) -> tuple[sparse.csr_matrix, np.ndarray]:
    """Stacked whitened Jacobian A ((3n + m) x 3n, sparse) and error b ((3n + m),) at X (n, 3).

    Rows 0..3n-1: GNSS factors, A block W_i at column block i, b = W_i (z_i - p_i).
    Rows 3n..3n+m-1: range factors, A row (u/sigma at block i, -u/sigma at block j), b = r_k;
    with `huber`, range rows and errors are scaled by sqrt(w_k) (IRLS). With range_cov = L L^T the
    range rows are L^{-1} J (J: the unwhitened rows (u, -u)) and b = L^{-1} (d - h) (no huber).
    """
    n, m = problem.n, problem.m
    W = sqrt_information(problem.gnss_cov)
    # eq. 13-14: whitening, A_k = Sigma_k^{-1/2} H_k, b_k = Sigma_k^{-1/2} (z_k - h_k(x0))
    bg = np.einsum("nab,nb->na", W, problem.gnss_pos - X).reshape(-1)
    rows_g = np.repeat(np.arange(3 * n).reshape(n, 3), 3, axis=1).reshape(-1)
    cols_g = np.tile(np.arange(3 * n).reshape(n, 1, 3), (1, 3, 1)).reshape(-1)
    vals_g = W.reshape(-1)
    r, u = _range_residuals(problem, X)
    correlated = problem.range_cov is not None
    if correlated and huber is not None:
        raise ValueError("whitened_system: huber needs independent ranges (range_cov None)")
    sw = np.sqrt(huber_weight(r, huber))
    coef = u if correlated else (sw / problem.range_sigma)[:, None] * u  # (m, 3)
    i, j = problem.edges[:, 0], problem.edges[:, 1]
    rows_r = np.repeat(3 * n + np.arange(m), 6)
    cols_r = np.concatenate([3 * i[:, None] + np.arange(3), 3 * j[:, None] + np.arange(3)], axis=1).reshape(-1)
    vals_r = np.concatenate([coef, -coef], axis=1).reshape(-1)
    A = sparse.csr_matrix(
        (np.concatenate([vals_g, vals_r]), (np.concatenate([rows_g, rows_r]), np.concatenate([cols_g, cols_r]))),
        shape=(3 * n + m, 3 * n),
    )
    if correlated:  # range rows L^{-1} J: dense (m, 3n), the links of one radio share information
        A_r = linalg.solve_triangular(problem.range_chol, A[3 * n:].toarray(), lower=True)
        A = sparse.vstack([A[:3 * n], sparse.csr_matrix(A_r)], format="csr")
    b = np.concatenate([bg, sw * r])
    return A, b


# ----------------------------------------------------------------------------------------------
# Centralized Gauss-Newton
# ----------------------------------------------------------------------------------------------
@dataclass(frozen=True, slots=True)
class CentralizedResult:
    """Centralized MAP solution.

    positions: (n, 3) metres ENU; cov: (n, 3, 3) marginal covariances m^2 (None if not asked);
    cov_full: (3n, 3n) joint covariance (A^T A)^-1 or None; cost: final objective; iterations:
    accepted Gauss-Newton steps (Levenberg-Marquardt: linear solves, rejected ones included);
    converged: stopped on the step/cost tolerances (never on a cost increase, never on the
    iteration cap); history: objective after each accepted iteration (first entry: initial cost);
    observable: the normal matrix at the solution has no zero pivot (no gauge freedom; when False
    a GaugeWarning was issued and cov, cov_full are NaN); method: "gn" or "lm"; report: the
    estimators.graph.lm Report of the iteration (with huber: of its Huber-cost phase).
    Fixed nodes keep their given position and a zero covariance.
    """

    positions: np.ndarray
    cov: np.ndarray | None
    cov_full: np.ndarray | None
    cost: float
    iterations: int
    converged: bool
    history: tuple[float, ...]
    observable: bool = True
    method: str = "gn"
    report: Report | None = None


def _newton_huber(problem: CoopProblem, X: np.ndarray, huber: float) -> SparseNormal:
    """Gauss-Newton normal equations of the Huber cost itself at X (n, 3): gradient from the clipped
    residual psi(r) = clip(r, -delta, delta), curvature 1 on the quadratic branch and 0 on the
    linear branch (rho'' = 0): N = A^T C A, g = A^T [b_gnss; psi(r)], C = diag(1 (GNSS rows), 1{|r| <= delta});
    the GNSS factors keep N positive definite, so its step is a descent direction of the Huber cost."""
    A, b = whitened_system(problem, X, None)
    ng = 3 * problem.n
    r = b[ng:]
    rhs = np.concatenate([b[:ng], np.clip(r, -huber, huber)])
    curv = np.concatenate([np.ones(ng), (np.abs(r) <= huber).astype(float)])
    # eq. 16 with the Huber curvature: (A^T C A) Delta = A^T psi
    return SparseNormal((A.T @ (sparse.diags(curv) @ A)).tocsc(), A.T @ rhs)


def solve_centralized(
    problem: CoopProblem,
    x0: np.ndarray | None = None,
    *,
    huber: float | None = None,
    max_iter: int = 100,
    step_tol: float = 1e-10,
    cost_tol: float = 0.0,
    max_halvings: int = 30,
    covariance: str = "marginal",
    method: str = "gn",
    losses=None,
    lm_lambda: float = 1e-4,
) -> CentralizedResult:
    """Gauss-Newton on the stacked whitened system (eqs. 13-16) with backtracking step control,
    by the iteration of the graph library (estimators.graph.lm, method "gn").

    method: "gn" (Gauss-Newton with step halving, the default of seed 001) or "lm"
    (Levenberg-Marquardt, see `_solve_general`; lm_lambda: initial damping relative to diag(N)).
    losses: {factor type: Loss} (FACTOR_TYPES: "gnss", "range"), robust losses as IRLS weights;
    exclusive with huber (the Newton-Huber path below). A problem with fixed nodes or nodes
    without a prior, `losses` or method "lm" take the general path `_solve_general`.
    max_iter: the iteration cap; reaching it is a result (converged=False), never an exception.
    Least squares needs at most 17 iterations on the coop-fg epochs of seed 1; the Newton-Huber
    phase converges linearly, as slowly as 0.76 per iteration when an outlying range sits next to
    an SPP UAV (its neglected curvature delta * d2|p_i - p_j|/dp2 is comparable to the GNSS
    information): 91 iterations measured on tests' nlos_epoch(1).

    problem: the epoch; x0: (n, 3) initial positions, metres (default: the GNSS fixes);
    huber: Huber threshold on whitened range residuals (e.g. HUBER_DELTA) or None for least squares;
    step_tol: stop when the largest component of an accepted Gauss-Newton step (the full step,
    before any halving: it estimates the distance to the optimum) is below it (metres). Gauss-Newton
    converges only linearly here (nonzero range residuals; measured contraction 0.035 per iteration,
    at most 0.15, on the coop-fg epochs), so the optimum is then ~0.15 step_tol away or closer;
    cost_tol: if > 0, also stop when the relative cost decrease of an accepted step is below it.
    Off by default: the cost's evaluation scatters by ~3e-14 relative (round-off of
    d - |p_i - p_j|), so it cannot order iterates closer than ~5e-7 m along the weakest direction;
    a cost test stopped at up to 5e-7 m from the optimum on coop-fg epochs;
    covariance: "marginal" (n,3,3 blocks; dense inverse up to 3n = 600 unknowns, above that the
    sparse selected inverse `marginal_blocks`), "full" (also the (3n,3n) matrix) or "none".
    A step that raises the cost beyond its round-off (estimators.graph.lm.ROUNDOFF, relative) is
    halved (up to max_halvings); if no halving lowers it the solver stops with converged=False
    unless the step was already below step_tol. A step whose predicted decrease (g^T Delta / 2)
    is below ROUNDOFF of the cost is taken whole whatever the evaluated cost does (the cost cannot
    judge it), so `history` may rise by round-off there.
    With huber: least-squares solve first, then Gauss-Newton steps on the Huber cost (zero
    curvature on the linear branch, `_newton_huber`). The covariance then uses the IRLS weights
    at the solution (the usual approximation). `history` holds the Huber-cost phase only.
    """
    if covariance not in ("marginal", "full", "none"):
        raise ValueError(f"solve_centralized: covariance must be marginal, full or none, got {covariance!r}")
    if method not in ("gn", "lm"):
        raise ValueError(f"solve_centralized: method must be 'gn' or 'lm', got {method!r}")
    if huber is not None and losses is not None:
        raise ValueError("solve_centralized: give either huber (Newton-Huber on ranges) or losses (IRLS)")
    if method == "lm" or losses is not None or not problem.is_plain:
        if huber is not None:
            losses = {"range": Loss(kind="huber", scale=huber)}
        return _solve_general(problem, x0, method=method, losses=_check_losses(losses), max_iter=max_iter,
                              step_tol=step_tol, cost_tol=cost_tol, max_halvings=max_halvings,
                              covariance=covariance, lm_lambda=lm_lambda)
    X = np.array(problem.gnss_pos if x0 is None else x0, dtype=float)
    if huber is not None:
        # start the robust solve from the least-squares optimum: there only the outlying ranges
        # sit on the linear branch of the Huber loss and the Newton-Huber steps are well posed
        X = solve_centralized(problem, X, max_iter=max_iter, step_tol=step_tol, cost_tol=cost_tol,
                              max_halvings=max_halvings, covariance="none").positions
    # eq. 15-16: Delta = argmin |A Delta - b|^2  <=>  A^T A Delta = A^T b (estimators.graph.lm, GN)
    system = (lambda X: whitened_system(problem, X)) if huber is None else (lambda X: _newton_huber(problem, X, huber))
    res = minimize(X, lambda X: cost(problem, X, huber), system, lambda X, d: X + d.reshape(-1, 3), method="gn",
                   max_iter=max_iter, step_tol=step_tol, cost_tol=cost_tol, max_halvings=max_halvings)
    X = res.x
    cov = cov_full = None
    if covariance != "none":
        A, _ = whitened_system(problem, X, huber)
        n = problem.n
        if covariance == "full" or 3 * n <= DENSE_LIMIT:
            full = dense_covariance(A)
            idx = np.arange(n)
            cov = full.reshape(n, 3, n, 3)[idx, :, idx, :]
            cov_full = full if covariance == "full" else None
        else:
            cov = marginal_blocks((A.T @ A).tocsc(), n)
    return CentralizedResult(X, cov, cov_full, res.cost, res.iterations, res.converged, res.history, report=res.report)


def _solve_general(problem: CoopProblem, x0, *, method: str, losses: dict, max_iter: int, step_tol: float,
                   cost_tol: float, max_halvings: int, covariance: str, lm_lambda: float) -> CentralizedResult:
    """Gauss-Newton or Levenberg-Marquardt (estimators.graph.lm) on the general graph: fixed
    nodes, optional priors, robust losses as IRLS weights re-evaluated at every iterate. The
    gauge check factors the undamped N at the solution (estimators.graph.linear)."""
    n = problem.n
    free = ~problem.fixed
    X0 = np.array(problem.gnss_pos if x0 is None else x0, dtype=float)
    X0[problem.fixed] = problem.gnss_pos[problem.fixed]

    def retract(X, delta):
        X = X.copy()
        X[free] += delta.reshape(-1, 3)
        return X

    res = minimize(X0, lambda X: _general_cost(problem, X, losses), lambda X: _general_system(problem, X, losses),
                   retract, method=method, max_iter=max_iter, step_tol=step_tol, cost_tol=cost_tol,
                   max_halvings=max_halvings, lm_lambda=lm_lambda)
    X, N = res.x, res.N
    fac = factor_spd(N)
    observable = fac.observable
    if not observable:
        warnings.warn(f"solve_centralized: the problem is unobservable (gauge freedom; smallest relative "
                      f"pivot {fac.min_pivot_ratio:.1e}): the estimate is one of many optima", GaugeWarning,
                      stacklevel=3)
    cov = cov_full = None
    if covariance != "none":
        nf = int(free.sum())
        cov = np.zeros((n, 3, 3))
        full_free = None
        if not observable:
            cov[free] = np.nan
            full_free = np.full((3 * nf, 3 * nf), np.nan)
        elif covariance == "full" or 3 * nf <= DENSE_LIMIT:
            full_free = fac.solve(np.eye(3 * nf))
            full_free = 0.5 * (full_free + full_free.T)
            idx = np.arange(nf)
            cov[free] = full_free.reshape(nf, 3, nf, 3)[idx, :, idx, :]
        else:
            cov[free] = marginal_blocks(N, nf)
        if covariance == "full":
            sel = np.flatnonzero(np.repeat(free, 3))
            cov_full = np.zeros((3 * n, 3 * n))
            cov_full[np.ix_(sel, sel)] = full_free
    return CentralizedResult(X, cov, cov_full, res.cost, res.iterations, res.converged, res.history, observable, method,
                             res.report)


# ----------------------------------------------------------------------------------------------
# Distributed message iteration
# ----------------------------------------------------------------------------------------------
def neighbours(problem: CoopProblem, i: int) -> tuple[np.ndarray, np.ndarray]:
    """Neighbours of UAV i in the range graph: (indices (k,), edge indices (k,))."""
    e = problem.edges
    k = np.flatnonzero((e[:, 0] == i) | (e[:, 1] == i))
    other = np.where(e[k, 0] == i, e[k, 1], e[k, 0])
    return other, k


def local_step_qr(
    x_i: np.ndarray,
    z_i: np.ndarray,
    gnss_cov_i: np.ndarray,
    nbr_pos: np.ndarray,
    nbr_cov: np.ndarray,
    ranges: np.ndarray,
    range_sigma: np.ndarray,
) -> tuple[np.ndarray, np.ndarray]:
    """One Gauss-Newton step of UAV i's local graph, the paper's literal form (eqs. 17-19).

    x_i: (3,) current own position (linearization point), z_i: (3,) own GNSS fix, gnss_cov_i (3, 3);
    nbr_pos: (k, 3) neighbours' broadcast positions, nbr_cov: (k, 3, 3) their broadcast covariances
    (priors on the local neighbour variables, linearized at the broadcasts);
    ranges, range_sigma: (k,) metres.
    Local state X_i = [p_i, p_1..p_k] (3 + 3k); whitened A_i ((3 + 3k + k) x (3 + 3k)) is QR
    factored. Returns (own step (3,), own covariance (3, 3)): the p_i blocks of the step and of
    (R^T R)^-1.
    """
    k = nbr_pos.shape[0]
    nv = 3 + 3 * k
    A = np.zeros((3 + 3 * k + k, nv))
    b = np.zeros(3 + 3 * k + k)
    Wg = sqrt_information(gnss_cov_i)
    A[:3, :3] = Wg
    b[:3] = Wg @ (z_i - x_i)
    if k:
        Wn = sqrt_information(nbr_cov)
        for a in range(k):
            A[3 + 3 * a: 6 + 3 * a, 3 + 3 * a: 6 + 3 * a] = Wn[a]  # prior residual is 0 at the broadcast
        h, u = range_terms(x_i, nbr_pos)
        r = (ranges - h) / range_sigma
        rows = 3 + 3 * k + np.arange(k)
        A[rows, 0:3] = u / range_sigma[:, None]
        for a in range(k):
            A[rows[a], 3 + 3 * a: 6 + 3 * a] = -u[a] / range_sigma[a]
        b[rows] = r
    # eq. 18: A_i = Q R; Delta = R^-1 Q^T b_i
    Q, R = np.linalg.qr(A, mode="reduced")
    delta = linalg.solve_triangular(R, Q.T @ b)
    # eq. 19: Sigma = (R^T R)^-1 = R^-1 R^-T; keep the rows/columns of p_i
    Rinv = linalg.solve_triangular(R, np.eye(nv))
    Sigma = Rinv[:3] @ Rinv[:3].T
    return delta[:3], symmetrize(Sigma)


@dataclass(frozen=True, slots=True)
class DistributedResult:
    """Result of the distributed scheme.

    positions: (n, 3) metres ENU; cov: (n, 3, 3) the covariances each UAV computed (eq. 19), m^2;
    rounds: optimization rounds run; converged: every position change of the last round below tol;
    messages: broadcasts sent (one per transmitting UAV per round, round 0 = GNSS broadcast);
    bytes_sent: messages * MESSAGE_BYTES; deliveries: successful receptions (directed links);
    max_step: (rounds,) largest position change |Delta_i| of each round, metres;
    positions_history: (rounds + 1, n, 3) positions after each round (entry 0: GNSS);
    report: the estimators.graph.lm Report of the round iteration (None: no rounds were iterated).
    """

    positions: np.ndarray
    cov: np.ndarray
    rounds: int
    converged: bool
    messages: int
    bytes_sent: int
    deliveries: int
    max_step: np.ndarray
    positions_history: np.ndarray = field(repr=False)
    report: Report | None = None


def solve_distributed(
    problem: CoopProblem,
    *,
    mode: str = "iterate",
    neighbour_model: str = "prior",
    max_rounds: int = 100,
    tol: float = 1e-4,
    huber: float | None = None,
    silent_from: dict[int, int] | None = None,
    loss_prob: float = 0.0,
    rng: np.random.Generator | None = None,
    max_age: int | None = None,
    local_solver: str = "schur",
    damping: float = 1.0,
    x0: np.ndarray | None = None,
    cov0: np.ndarray | None = None,
    transport: Transport | None = None,
) -> DistributedResult:
    """The paper's distributed message iteration (section 2.3.2, Table 1), synchronous rounds.

    mode: "gnss" (no cooperation, no messages), "single" (one optimization: GNSS broadcast, one
    local step, no iteration) or "iterate" (repeat broadcast + local step until every position
    change is below `tol` metres, at most `max_rounds` rounds).
    neighbour_model: "prior" (the paper: neighbours' broadcasts are priors with their broadcast
    covariances; equivalently fixed neighbours with range variance sigma_d^2 + u^T Sigma_j u) or
    "fixed" (neighbours fixed at their broadcasts, range variance sigma_d^2: block-Jacobi
    Gauss-Newton whose fixed point is exactly the centralized optimum; its covariance ignores the
    neighbours' uncertainty).
    huber: Huber threshold on the range residual whitened by its (inflated) sigma, or None.
    silent_from: {uav: round} - the UAV stops broadcasting from that round on (0 = never sends);
    it keeps receiving and computing.
    loss_prob: probability that one directed delivery is lost, drawn with `rng` (required if > 0).
    transport: the channel of the broadcasts (estimators.transport.Transport; None = ideal): each
    round, the directed messages still alive after silence and loss_prob go through
    transport.deliver(round, src, dst, MESSAGE_BYTES), and only those it delivers are used.
    max_age: receivers drop a neighbour's message (and the range factor) once it is older than
    max_age rounds; None keeps the last message forever.
    local_solver: "schur" (vectorized closed form) or "qr" (per-UAV literal QR, eqs. 17-19; only
    with neighbour_model="prior" and no Huber).
    damping: fraction in (0, 1] of the local Gauss-Newton step applied (1 = the paper). Undamped
    "fixed" iterations can oscillate and diverge on this nonlinear problem (measured: 1 of 3
    seeded 18-UAV epochs); 0.5 removes the oscillating modes of the Jacobi iteration.
    x0, cov0: warm start, (n, 3) m and (n, 3, 3) m^2 (e.g. the previous epoch's estimates moved by
    the motion model): the first linearization point and the round-0 broadcast instead of the
    GNSS fix and its covariance (cov0 None: the GNSS covariance, or NO_INFO_VAR I for a node
    without a prior). The GNSS factors stay at the fixes.
    Fixed nodes (problem.fixed) broadcast their known position with a zero covariance and never
    move. A node without a prior has no GNSS factor; its local step gets a Levenberg term
    LOCAL_DAMPING I (m^-2) so that it is defined with fewer than three neighbours (the step is
    then zero along the unobserved directions and the covariance ~ 1/LOCAL_DAMPING there).
    """
    if mode not in ("gnss", "single", "iterate"):
        raise ValueError(f"solve_distributed: unknown mode {mode!r}")
    if neighbour_model not in ("prior", "fixed"):
        raise ValueError(f"solve_distributed: unknown neighbour_model {neighbour_model!r}")
    if local_solver not in ("schur", "qr"):
        raise ValueError(f"solve_distributed: unknown local_solver {local_solver!r}")
    if local_solver == "qr" and (neighbour_model != "prior" or huber is not None):
        raise ValueError("solve_distributed: local_solver='qr' supports only neighbour_model='prior' without Huber")
    if not 0.0 < damping <= 1.0:
        raise ValueError(f"solve_distributed: damping must be in (0, 1], got {damping}")
    if loss_prob > 0.0 and rng is None:
        raise ValueError("solve_distributed: loss_prob > 0 needs an rng (numpy Generator)")
    if local_solver == "qr" and not problem.is_plain:
        raise ValueError("solve_distributed: local_solver='qr' needs every node with a prior and none fixed")
    n, m = problem.n, problem.m
    z, Sg = problem.gnss_pos, problem.gnss_cov
    info_g = np.linalg.inv(Sg)
    X = z.copy() if x0 is None else np.array(x0, dtype=float).reshape(n, 3)
    P = Sg.copy() if cov0 is None else np.array(cov0, dtype=float).reshape(n, 3, 3)
    plain = problem.is_plain
    if not plain:
        no_prior = ~problem.prior & ~problem.fixed
        info_g[no_prior] = LOCAL_DAMPING * np.eye(3)
        if cov0 is None:
            P[no_prior] = NO_INFO_VAR * np.eye(3)
        X[problem.fixed] = z[problem.fixed]
        P[problem.fixed] = 0.0
    if mode == "gnss":
        return DistributedResult(X, P, 0, True, 0, 0, 0, np.zeros(0), X[None].copy())

    # directed links: receiver dst uses the message of src and the range of edge eid
    src = np.concatenate([problem.edges[:, 0], problem.edges[:, 1]])
    dst = np.concatenate([problem.edges[:, 1], problem.edges[:, 0]])
    eid = np.concatenate([np.arange(m), np.arange(m)])
    d = problem.ranges[eid]
    sig2 = problem.range_sigma[eid] ** 2
    tab_pos = np.zeros((2 * m, 3))
    tab_cov = np.zeros((2 * m, 3, 3))
    tab_age = np.full(2 * m, np.iinfo(np.int64).max // 2)  # never received
    silent_round = np.full(n, np.iinfo(np.int64).max)
    for uav, r0 in (silent_from or {}).items():
        silent_round[int(uav)] = int(r0)
    messages = deliveries = 0

    def one_round(rnd: int, X: np.ndarray) -> np.ndarray:
        """Round rnd: every UAV broadcasts, then takes its local Gauss-Newton step; P is updated."""
        nonlocal P, tab_age, messages, deliveries
        # --- broadcast of (position, covariance): round 0 sends the GNSS fix and covariance
        sending = silent_round > rnd
        messages += int(sending.sum())
        ok = sending[src]
        if loss_prob > 0.0:
            ok &= rng.random(2 * m) >= loss_prob
        if transport is not None:
            alive = np.flatnonzero(ok)
            ok[alive] = transport.deliver(rnd, src[alive], dst[alive], MESSAGE_BYTES)
        deliveries += int(ok.sum())
        tab_pos[ok] = X[src[ok]]
        tab_cov[ok] = P[src[ok]]
        tab_age = np.where(ok, 0, tab_age + 1)
        valid = tab_age < np.iinfo(np.int64).max // 4 if max_age is None else tab_age <= max_age

        # --- local Gauss-Newton step of every UAV on its own position
        if local_solver == "qr":
            dX = np.zeros((n, 3))
            P_new = np.empty((n, 3, 3))
            for i in range(n):
                sel = np.flatnonzero(valid & (dst == i))
                dX[i], P_new[i] = local_step_qr(
                    X[i], z[i], Sg[i], tab_pos[sel], tab_cov[sel], d[sel], np.sqrt(sig2[sel])
                )
        else:
            v = np.flatnonzero(valid)
            h, u = range_terms(X[dst[v]], tab_pos[v])
            res = d[v] - h
            if neighbour_model == "prior":
                # Schur complement of the neighbour prior: var = sigma_d^2 + u^T Sigma_j u
                s2 = inflated_range_variance(sig2[v], u, tab_cov[v])
            else:
                s2 = sig2[v]
            w = huber_weight(res / np.sqrt(s2), huber) / s2
            Lam = info_g.copy()
            g = np.einsum("nab,nb->na", info_g, z - X)
            if not plain:
                g[no_prior] = 0.0  # Levenberg term: damping only, no pull towards gnss_pos
                Lam[problem.fixed] = np.eye(3)  # fixed nodes do not solve (their step is zeroed)
            # eq. 16 (local): (A_i^T A_i) Delta_i = A_i^T b_i, accumulated factor by factor
            np.add.at(Lam, dst[v], w[:, None, None] * u[:, :, None] * u[:, None, :])
            np.add.at(g, dst[v], (w * res)[:, None] * u)
            local = DenseNormals(Lam, g)
            dX = local.solve(None)[0]
            # eq. 19: Sigma_i = (R^T R)^-1 = (A_i^T A_i)^-1 restricted to p_i (raises if not positive definite)
            P_new = local.inverse()
        dX = damping * dX
        if not plain:
            dX[problem.fixed] = 0.0
            P_new[problem.fixed] = 0.0
        P = 0.5 * (P_new + np.swapaxes(P_new, 1, 2))
        return X + dX

    # the round iteration of the graph library: stops on tol, max_rounds or a diverged step
    X, hist, report = lm.iterate_rounds(X, one_round, max_rounds=1 if mode == "single" else max_rounds,
                                     tol=tol if mode == "iterate" else None)
    rounds, converged = int(report.iterations[0]), bool(report.converged[0]) or mode == "single"
    return DistributedResult(X, P, rounds, converged, messages, messages * MESSAGE_BYTES, deliveries,
                             np.asarray(report.trace), hist, report)
