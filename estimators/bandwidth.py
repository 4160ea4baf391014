"""Bandwidth-limited distributed fusion estimator (seed 000: Zhao, Liu, Zhao, Gao, EOC 2020).

Model (paper eqs. 1-3, with the known input of eq. 22):

    x(k+1) = A x(k) + B + w(k),      w ~ N(0, W)         x: (n,), B: (n,) known input per step
    y_i(k) = C_i x(k) + v_i(k),      v_i ~ N(0, V_i)     y_i: (m_i,), i = 0..N-1

Every node is a fusion node. Per step k:

1. node j forms its intermediate estimate (eq. 4, with the input B)
       lambda_j = A xhat_j + B + L_j (y_j - C_j xhat_j);
2. node j sends node i only the components selected by the diagonal 0/1 matrix T_ji;
3. node i compensates the missing components with its own one-step prediction (eq. 6)
       lambda^c_ji = T_ji lambda_j + (I - T_ji)(A xhat_i + B);
4. node i fuses (eq. 7)  xhat_i(k+1) = sum_j p_ij lambda^c_ji.

The known input B must enter both one-step predictions (eq. 4 and eq. 6); with it in only one of
them the compensated components are biased by B.

Conventions (all arrays are numpy float64; nodes are indexed 0..N-1 in code and numbered 1..N,
as in the paper, in every error message and report):

* selection masks ``S``: (..., N, N, n) array of 0/1, ``S[..., j, i, :]`` is the diagonal of
  T_ji, the components that node j sends to node i. ``S[j, j] = 1`` (T_jj = I). Full selection
  matrices (..., N, N, n, n) are accepted by :func:`as_masks` and checked to be diagonal 0/1.
* weights ``P``: (..., N, N), ``P[..., i, j] = p_ij``, the weight node i gives to lambda^c_ji;
  rows sum to 1.
* links: (N, N) bool, symmetric, ``links[i, j]`` True if i and j can talk (diagonal True).
* budget: (N,) int, t_i = sum_{j != i} t_ji, components node i receives per step (eq. 5 text).
* the state, W, M are in the state's units (metres and m^2 in the paper's scenario); B is the
  displacement per step (velocity * dt).

Gains and bound (section 1.2): L_i = A M_i C_i^T (C_i M_i C_i^T + V_i/2)^-1 (eq. 18) and the
recursion of M_i (eq. 19) with M_i(0) = Sigma_i(0); M_i(k) >= Sigma_i(k), the true error
covariance, so J_bar = sum_k sum_i tr M_i(k) (eq. 16) bounds the cost J (eq. 12 / 14).

Eq. 11 of the paper has a typo: the measurement-noise term must carry T_ji (only transmitted
components contain node j's noise), i.e. - T_ji L_j v_j, not - (I - T_ji) L_j v_j; eq. 15 is
written with T_ji and is right. :func:`transition_matrices` implements the corrected eq. 11.

Notes on the bound (measured on the paper's setup, see testbed/reproduce/bandwidth_paper.py):
the factor 2 of eq. 15 makes the compensation term 2 sum_{j: c not sent} p_ij A M_i A^T. When, for
some node and component, the weights of the neighbours that do not send it add up to more than
1/2, M grows geometrically (ratio up to 2 (1 - p_ii)) while the true covariance stays bounded:
with P1 (all 0.25) and the paper's T1 or T2 some node receives a component from nobody and the
bound grows as 1.5^k (1e88 after 500 steps). The gains of eq. 18 then tend to A C^+ (L -> I for
C = I): the node uses its raw measurement. M stays a valid upper bound; it is just very loose.
For long horizons it can overflow float64 (at ratio 2, after about 1000 steps).

Besides the paper's bound this module gives the *exact* error covariance of the linear network
(:func:`exact_covariance`, joint over nodes) for the same gains, so the bound and a Monte Carlo
can both be checked against a number with no sampling error.

Pure numpy/scipy: never imports mujoco or testbed.
"""
from __future__ import annotations

import itertools
from dataclasses import dataclass, field
from typing import Callable, Mapping, Sequence

import numpy as np
from scipy.linalg import cho_factor, cho_solve

from estimators.core import Gaussian
from estimators.geometry import DegenerateGeometryError, require_span

BYTES_PER_COMPONENT = 8  # float64


def _sym(M: np.ndarray) -> np.ndarray:
    """Batched (M + M^T)/2 over the last two axes (core.symmetrize transposes all axes)."""
    return 0.5 * (M + np.swapaxes(M, -1, -2))


# --------------------------------------------------------------------------------------------
# Model
# --------------------------------------------------------------------------------------------
@dataclass(frozen=True, kw_only=True, slots=True)
class NetworkModel:
    """Linear network model of eqs. 1-3 with a known input (eq. 22).

    A: (n, n) transition per step; B: (n,) known input per step (state units per step);
    C: tuple of N arrays (m_i, n); W: (n, n) process noise covariance per step;
    V: tuple of N arrays (m_i, m_i) measurement noise covariances.
    """

    A: np.ndarray
    B: np.ndarray
    C: tuple[np.ndarray, ...]
    W: np.ndarray
    V: tuple[np.ndarray, ...]

    @staticmethod
    def create(*, A, B, C, W, V, N: int | None = None) -> "NetworkModel":
        """Build and check a model. C and V may be one array (shared by all N nodes) or a list."""
        A = np.atleast_2d(np.asarray(A, float))
        n = A.shape[0]
        B = np.zeros(n) if B is None else np.asarray(B, float).reshape(n)
        W = np.atleast_2d(np.asarray(W, float))
        Cs = [np.atleast_2d(np.asarray(c, float)) for c in C] if isinstance(C, (list, tuple)) else None
        Vs = [np.atleast_2d(np.asarray(v, float)) for v in V] if isinstance(V, (list, tuple)) else None
        if N is None:
            N = len(Cs) if Cs is not None else (len(Vs) if Vs is not None else None)
        if N is None:
            raise ValueError("NetworkModel: give N or per-node lists C, V")
        if Cs is None:
            Cs = [np.atleast_2d(np.asarray(C, float))] * N
        if Vs is None:
            Vs = [np.atleast_2d(np.asarray(V, float))] * N
        if A.shape != (n, n) or W.shape != (n, n):
            raise ValueError(f"NetworkModel: A {A.shape} and W {W.shape} must be ({n}, {n})")
        if len(Cs) != N or len(Vs) != N:
            raise ValueError(f"NetworkModel: {len(Cs)} C and {len(Vs)} V for N = {N} nodes")
        for i, (c, v) in enumerate(zip(Cs, Vs)):
            if c.shape[1] != n or v.shape != (c.shape[0], c.shape[0]):
                raise ValueError(f"NetworkModel: node {i + 1}: C {c.shape} / V {v.shape} do not fit n = {n}")
            if not np.allclose(v, v.T) or np.linalg.eigvalsh(v).min() <= 0:
                raise ValueError(f"NetworkModel: node {i + 1}: V must be symmetric positive definite")
        if not np.allclose(W, W.T) or np.linalg.eigvalsh(W).min() < 0:
            raise ValueError("NetworkModel: W must be symmetric positive semidefinite")
        return NetworkModel(A=A, B=B, C=tuple(Cs), W=W, V=tuple(Vs))

    @property
    def N(self) -> int:
        return len(self.C)

    @property
    def n(self) -> int:
        return self.A.shape[0]


# --------------------------------------------------------------------------------------------
# Selection matrices, weights: conversion and validation
# --------------------------------------------------------------------------------------------
def as_masks(T: np.ndarray) -> np.ndarray:
    """Selection matrices (..., N, N, n, n) or masks (..., N, N, n) -> masks (..., N, N, n) of 0/1.

    Raises ValueError naming the pair (numbered from 1) if a T_ji is not diagonal 0/1.
    """
    T = np.asarray(T, float)
    if T.ndim >= 4 and T.shape[-1] == T.shape[-2] and T.shape[-3] == T.shape[-4]:
        d = np.diagonal(T, axis1=-2, axis2=-1)
        off = T - d[..., None] * np.eye(T.shape[-1])
        bad = np.argwhere(np.abs(off).reshape(*off.shape[:-2], -1).max(-1) > 0)
        if bad.size:
            j, i = bad[0][-2:]
            raise ValueError(f"T[{j + 1},{i + 1}] is not diagonal")
        T = d
    bad = np.argwhere(~np.isin(T, (0.0, 1.0)).all(-1))
    if bad.size:
        j, i = bad[0][-2:]
        raise ValueError(f"T[{j + 1},{i + 1}] has a diagonal entry that is not 0 or 1")
    return T


def masks_to_matrices(S: np.ndarray) -> np.ndarray:
    """Masks (..., N, N, n) -> diagonal selection matrices (..., N, N, n, n)."""
    return S[..., None] * np.eye(S.shape[-1])


def validate_network(S: np.ndarray, P: np.ndarray, *, links: np.ndarray | None = None,
                     budget: Sequence[int] | np.ndarray | None = None, exact_budget: bool = True,
                     where: str = "") -> None:
    """Check one step's selection masks S (N, N, n) and weights P (N, N) (conventions above).

    Rules (paper, section 1.1): T_ji diagonal 0/1; T_ii = I; T_ji = T_ij (eq. 5); no component on a
    missing link; sum_{j != i} t_ji = t_i (or <= t_i when exact_budget is False); p_ij >= 0,
    sum_j p_ij = 1 (eq. 7); p_ij = 0 where there is no link. Raises ValueError with one line
    naming the node or the pair (numbered from 1).
    """
    S = as_masks(S)
    P = np.asarray(P, float)
    N, _, n = S.shape
    sfx = f" {where}" if where else ""
    if P.shape != (N, N):
        raise ValueError(f"P has shape {P.shape}, expected ({N}, {N}){sfx}")
    links = np.ones((N, N), bool) if links is None else np.asarray(links, bool)
    for i in range(N):
        if not np.all(S[i, i] == 1):
            raise ValueError(f"T[{i + 1},{i + 1}] != I{sfx}")
        for j in range(i + 1, N):
            if not np.array_equal(S[i, j], S[j, i]):
                raise ValueError(f"T[{i + 1},{j + 1}] != T[{j + 1},{i + 1}]{sfx}")
            if not links[i, j] and S[j, i].any():
                raise ValueError(f"T[{j + 1},{i + 1}] selects components but nodes {j + 1} and {i + 1} "
                                 f"have no link{sfx}")
    if budget is not None:
        t = S.sum(-1)  # t[j, i] = t_ji
        for i in range(N):
            got = int(t[:, i].sum() - t[i, i])
            ti = int(np.asarray(budget)[i])
            if got > ti or (exact_budget and got != ti):
                parts = ", ".join(f"T[{j + 1},{i + 1}]:{int(t[j, i])}" for j in range(N) if j != i)
                raise ValueError(f"budget of node {i + 1}: receives {got} components ({parts}) "
                                 f"{'>' if got > ti else '!='} t_{i + 1} = {ti}{sfx}")
    for i in range(N):
        for j in range(N):
            if P[i, j] < 0:
                raise ValueError(f"p[{i + 1},{j + 1}] = {P[i, j]:g} < 0{sfx}")
            if P[i, j] > 0 and not links[i, j]:
                raise ValueError(f"p[{i + 1},{j + 1}] = {P[i, j]:g} > 0 but nodes {i + 1} and {j + 1} "
                                 f"have no link{sfx}")
        if abs(P[i].sum() - 1.0) > 1e-9:
            raise ValueError(f"weights of node {i + 1} sum to {P[i].sum():.12g}, not 1 "
                             f"(p[{i + 1},1..{N}]){sfx}")


Schedule = np.ndarray | Callable[[int], np.ndarray]


def _at(schedule: Schedule, k: int, const_ndim: int) -> np.ndarray:
    """A value of a schedule at step k: constant array, per-step array (K, ...), or callable."""
    if callable(schedule):
        return np.asarray(schedule(k), float)
    a = np.asarray(schedule, float)
    return a if a.ndim == const_ndim else a[k]


@dataclass(frozen=True, kw_only=True, slots=True)
class FusionNetwork:
    """Communication design: selections T, weights P, links and budgets.

    select: masks (N, N, n) or matrices (N, N, n, n) constant; or per step (K, N, N, n[, n]); or a
        callable k -> masks/matrices. S[j, i] is T_ji (j sends to i).
    weights: (N, N) constant, (K, N, N) per step, or a callable k -> (N, N); P[i, j] = p_ij.
    links: (N, N) bool, default all linked. budget: (N,) t_i or None (no budget check).
    Constant and per-step arrays are validated on construction; callables at every step used.
    """

    select: Schedule
    weights: Schedule
    links: np.ndarray | None = None
    budget: np.ndarray | None = None
    exact_budget: bool = True

    def __post_init__(self) -> None:
        if not callable(self.select):
            object.__setattr__(self, "select", as_masks(self.select))
        if not callable(self.weights):
            object.__setattr__(self, "weights", np.asarray(self.weights, float))
        if not callable(self.select) and not callable(self.weights):
            S, P = self.select, self.weights
            K = max(S.shape[0] if S.ndim == 4 else 1, P.shape[0] if P.ndim == 3 else 1)
            for k in range(K):
                self._check(S if S.ndim == 3 else S[k], P if P.ndim == 2 else P[k], k, K > 1)

    def _check(self, S, P, k, per_step) -> None:
        validate_network(S, P, links=self.links, budget=self.budget, exact_budget=self.exact_budget,
                         where=f"(step {k})" if per_step else "")

    def at(self, k: int) -> tuple[np.ndarray, np.ndarray]:
        """Masks (N, N, n) and weights (N, N) of step k (validated if they come from a callable)."""
        S = as_masks(_at(self.select, k, 3)) if callable(self.select) else _at(self.select, k, 3)
        P = _at(self.weights, k, 2)
        if callable(self.select) or callable(self.weights):
            self._check(S, P, k, True)
        return S, P


# --------------------------------------------------------------------------------------------
# Gains, bound recursion, exact covariance
# --------------------------------------------------------------------------------------------
def gains(model: NetworkModel, M: np.ndarray) -> list[np.ndarray]:
    """Suboptimal gains of eq. 18 for every node.

    M: (..., N, n, n) bound matrices. Returns a list of N arrays (..., n, m_i).
    """
    A = model.A
    out = []
    for i, (C, V) in enumerate(zip(model.C, model.V)):
        Mi = M[..., i, :, :]
        S = _sym(C @ Mi @ C.T + 0.5 * V)
        PxzT = C @ Mi @ A.T  # (..., m, n) = (A M C^T)^T
        # eq. 18: L_i = A M_i C_i^T (C_i M_i C_i^T + V_i/2)^-1   (solve, no inverse)
        out.append(np.swapaxes(np.linalg.solve(S, PxzT), -1, -2))
    return out


def bound_step(model: NetworkModel, M: np.ndarray, S: np.ndarray, P: np.ndarray,
               L: list[np.ndarray] | None = None) -> np.ndarray:
    """One step of the bound recursion. M: (..., N, n, n); S: (..., N, N, n); P: (..., N, N).

    With L = None the gains are those of eq. 18 and the result is eq. 19. Eq. 19 is evaluated in
    the form of eq. 15, 2 p_ij T [(A - L C) M_j (A - L C)^T + L (V/2) L^T] T, which is algebraically
    identical at the eq. 18 gain but stays positive semidefinite when M is large (eq. 19's
    subtraction cancels catastrophically once M_j >> V_j, which happens: see the module docstring).
    With a given L (list of (..., n, m_i)) it is eq. 15 for that gain.
    """
    A = model.A
    L = gains(model, M) if L is None else L
    Q = np.empty_like(M)
    for j, (C, V) in enumerate(zip(model.C, model.V)):
        Lj = L[j]
        F = A - Lj @ C
        Q[..., j, :, :] = F @ M[..., j, :, :] @ np.swapaxes(F, -1, -2) + Lj @ (0.5 * V) @ np.swapaxes(Lj, -1, -2)
    R = A @ M @ A.T  # (..., N, n, n): A M_i A^T
    O = S[..., :, None] * S[..., None, :]  # (..., j, i, n, n): T_ji (.) T_ji
    Sb = 1.0 - S
    Ob = Sb[..., :, None] * Sb[..., None, :]  # Tbar_ji (.) Tbar_ji
    # eq. 15 / 19: M_i(k+1) = sum_j 2 p_ij [T_ji Q_j T_ji + Tbar_ji A M_i A^T Tbar_ji] + W
    Mn = 2.0 * np.einsum("...ij,...jiab,...jab->...iab", P, O, Q)
    Mn = Mn + 2.0 * np.einsum("...ij,...jiab->...iab", P, Ob) * R
    return _sym(Mn + model.W)


def bound_step_eq19(model: NetworkModel, M: np.ndarray, S: np.ndarray, P: np.ndarray) -> np.ndarray:
    """Eq. 19 literally (with its subtraction), unbatched: M (N, n, n), S (N, N, n), P (N, N).

    For tests; use :func:`bound_step` in practice (same value, numerically safe).
    """
    A, N = model.A, model.N
    Mn = np.zeros_like(M)
    for i in range(N):
        for j in range(N):
            T, Tb = np.diag(S[j, i]), np.diag(1.0 - S[j, i])
            C, V = model.C[j], model.V[j]
            G = A @ M[j] @ C.T @ np.linalg.solve(C @ M[j] @ C.T + 0.5 * V, C @ M[j] @ A.T)
            # eq. 19
            Mn[i] += P[i, j] * (2 * T @ A @ M[j] @ A.T @ T + 2 * Tb @ A @ M[i] @ A.T @ Tb - 2 * T @ G @ T)
        Mn[i] += model.W
    return Mn


def bound_recursion(model: NetworkModel, net: FusionNetwork, M0: np.ndarray, K: int
                    ) -> tuple[np.ndarray, list[list[np.ndarray]]]:
    """M_i(k) for k = 0..K (eqs. 18-19) and the gains L_i(k) for k = 0..K-1.

    M0: (n, n) shared or (N, n, n). Returns M (K+1, N, n, n) and gains[k][i] (n, m_i).
    """
    N, n = model.N, model.n
    M = np.broadcast_to(np.asarray(M0, float), (N, n, n)).copy()
    Ms, Ls = [M], []
    for k in range(K):
        S, P = net.at(k)
        L = gains(model, M)
        M = bound_step(model, M, S, P, L)
        Ms.append(M)
        Ls.append(L)
    return np.stack(Ms), Ls


def j_bound(M: np.ndarray, cumulative: bool = False) -> np.ndarray | float:
    """Eq. 16: J_bar = sum_k sum_i tr M_i(k). M: (..., K+1, N, n, n).

    Returns (...) or, cumulative, (..., K+1): J_bar up to each k.
    """
    tr = np.trace(M, axis1=-2, axis2=-1).sum(-1)
    return np.cumsum(tr, -1) if cumulative else tr.sum(-1)


def j_cost(errors: np.ndarray, cumulative: bool = False) -> np.ndarray | float:
    """Eq. 12: J = sum_k sum_i E||e_i(k)||^2, estimated over runs.

    errors: (R, K+1, N, n), e = x - xhat. Returns the run mean (scalar or (K+1,) cumulative).
    """
    per = (errors ** 2).sum(axis=(-1, -2))  # (R, K+1)
    per = per.mean(0)
    return np.cumsum(per) if cumulative else float(per.sum())


def transition_matrices(model: NetworkModel, S: np.ndarray, P: np.ndarray, L: list[np.ndarray]
                        ) -> tuple[np.ndarray, np.ndarray]:
    """Joint error dynamics E(k+1) = F E(k) + G v(k) + (1 (x) I) w(k) of the stacked node errors.

    From eq. 11 with the corrected noise term (T_ji, not I - T_ji):
    e_i(k+1) = sum_j p_ij [T_ji (A - L_j C_j) e_j - T_ji L_j v_j + Tbar_ji A e_i] + w.
    S: (..., N, N, n); P: (..., N, N); L: list of (..., n, m_i).
    Returns F (..., N n, N n) and G (..., N n, sum m_i).
    """
    A, N, n = model.A, model.N, model.n
    ms = [C.shape[0] for C in model.C]
    off = np.concatenate([[0], np.cumsum(ms)])
    batch = np.broadcast_shapes(S.shape[:-3], P.shape[:-2], *[l.shape[:-2] for l in L])
    F = np.zeros(batch + (N * n, N * n))
    G = np.zeros(batch + (N * n, off[-1]))
    for i in range(N):
        # eq. 11: sum_j p_ij Tbar_ji A e_i
        Abar = np.einsum("...j,...ja->...a", P[..., i, :], 1.0 - S[..., :, i, :])[..., :, None] * A
        F[..., i * n:(i + 1) * n, i * n:(i + 1) * n] += Abar
        for j in range(N):
            TL = S[..., j, i, :, None] * L[j]  # T_ji L_j
            pij = P[..., i, j, None, None]
            # eq. 11: p_ij T_ji (A - L_j C_j) e_j   (the Tbar_ji A e_i term is Abar above)
            F[..., i * n:(i + 1) * n, j * n:(j + 1) * n] += pij * (S[..., j, i, :, None] * A - TL @ model.C[j])
            # eq. 11 corrected: - p_ij T_ji L_j v_j (the paper prints I - T_ji here, a typo; eq. 15 is right)
            G[..., i * n:(i + 1) * n, off[j]:off[j + 1]] = -pij * TL
    return F, G


def exact_covariance(model: NetworkModel, net: FusionNetwork, Sigma0: np.ndarray, K: int,
                     gains_seq: list[list[np.ndarray]]) -> np.ndarray:
    """Exact joint error covariance of all nodes (eq. 13 without the bounding steps).

    Sigma0: (n, n) covariance of x(0) - mu0 when every node starts at xhat_i(0) = mu0 (all node
    errors equal at k = 0), or a joint (N n, N n). gains_seq: from :func:`bound_recursion`.
    Returns (K+1, N n, N n); node i's Sigma_i(k) is the diagonal block i.
    """
    N, n = model.N, model.n
    Sigma0 = np.asarray(Sigma0, float)
    P0 = np.kron(np.ones((N, N)), Sigma0) if Sigma0.shape == (n, n) else Sigma0
    Vb = _block_diag(model.V)
    Wj = np.kron(np.ones((N, N)), model.W)
    out = [P0]
    Pk = P0
    for k in range(K):
        S, P = net.at(k)
        F, G = transition_matrices(model, S, P, gains_seq[k])
        Pk = _sym(F @ Pk @ F.T + G @ Vb @ G.T + Wj)
        out.append(Pk)
    return np.stack(out)


def node_blocks(joint: np.ndarray, N: int) -> np.ndarray:
    """Diagonal blocks (..., N n, N n) -> (..., N, n, n)."""
    n = joint.shape[-1] // N
    return np.stack([joint[..., i * n:(i + 1) * n, i * n:(i + 1) * n] for i in range(N)], axis=-3)


def _block_diag(mats: Sequence[np.ndarray]) -> np.ndarray:
    sizes = [m.shape[0] for m in mats]
    out = np.zeros((sum(sizes), sum(sizes)))
    o = 0
    for m, s in zip(mats, sizes):
        out[o:o + s, o:o + s] = m
        o += s
    return out


# --------------------------------------------------------------------------------------------
# Filter step, faults, communication accounting, simulation
# --------------------------------------------------------------------------------------------
@dataclass(frozen=True, kw_only=True, slots=True)
class NodeMeasurements:
    """The measurements of all N nodes at one step (what `FusionFilter.update` takes).

    y: N arrays (..., m_i), node i's measurement; V: N arrays (..., m_i, m_i), its noise
    covariance; available: (..., N) bool or None (all): a node without a measurement (see
    :func:`fusion_step`).
    """

    y: tuple
    V: tuple
    available: np.ndarray | None = None


@dataclass(frozen=True, kw_only=True, slots=True)
class FusionState:
    """State of all nodes at step k. xhat: (..., N, n) estimates; M: (..., N, n, n) bounds.

    pending: the step's measurements stored by `FusionFilter.update`, applied by its predict.
    As a belief of the estimator interface, mean = xhat and cov = M (an upper bound of the error
    covariance, not a calibrated one).
    """

    xhat: np.ndarray
    M: np.ndarray
    k: int = 0
    pending: NodeMeasurements | None = None

    @property
    def mean(self) -> np.ndarray:
        return self.xhat

    @property
    def cov(self) -> np.ndarray:
        return self.M

    def beliefs(self) -> list[Gaussian]:
        """Per-node Gaussian(xhat_i, M_i) (unbatched state only). M_i is an upper bound of the
        error covariance, so this belief is conservative, not a calibrated covariance."""
        return [Gaussian(self.xhat[i].copy(), self.M[i].copy()) for i in range(self.xhat.shape[0])]


def fusion_step(model: NetworkModel, state: FusionState, y: Sequence[np.ndarray], S: np.ndarray,
                P: np.ndarray, available: np.ndarray | None = None) -> tuple[FusionState, np.ndarray]:
    """One step of the estimator for all nodes: eqs. 18, 4, 6, 7 and 19.

    state: xhat (..., N, n), M (..., N, n, n); y: list of N measurements (..., m_i) of step k;
    S: effective masks (..., N, N, n) of what actually arrived (nominal T with dropped components
    zeroed); P: (..., N, N). available: (..., N) bool or None (all): a node without a measurement
    this step (e.g. a lost range) uses L_j = 0, so lambda_j = A xhat_j + B, and its bound is eq. 15
    with L_j = 0 (Q_j = A M_j A^T); its y entry is ignored (may be NaN).
    Returns the new state and lambda (..., N, n).
    """
    A, B = model.A, model.B
    L = gains(model, state.M)  # eq. 18
    if available is not None:
        av = np.asarray(available, bool)
        L = [Lj * av[..., j, None, None] for j, Lj in enumerate(L)]
        y = [np.where(av[..., j, None], y[j], 0.0) for j in range(len(y))]
    pred = state.xhat @ A.T + B  # A xhat_i + B, (..., N, n)
    lam = np.empty_like(state.xhat)
    for j, C in enumerate(model.C):
        innov = y[j] - state.xhat[..., j, :] @ C.T
        # eq. 4 (with the known input B): lambda_j = A xhat_j + B + L_j (y_j - C_j xhat_j)
        lam[..., j, :] = pred[..., j, :] + np.einsum("...am,...m->...a", L[j], innov)
    # eq. 6 + eq. 7: xhat_i(k+1) = sum_j p_ij [T_ji lambda_j + (I - T_ji)(A xhat_i + B)]
    x_new = np.einsum("...ij,...jia,...ja->...ia", P, S, lam)
    x_new = x_new + np.einsum("...ij,...jia->...ia", P, 1.0 - S) * pred
    M_new = bound_step(model, state.M, S, P, L)  # eq. 19 (see bound_step); eq. 15 where L_j = 0
    return FusionState(xhat=x_new, M=M_new, k=state.k + 1), lam


@dataclass(frozen=True, kw_only=True, slots=True)
class FusionFilter:
    """The estimator of eqs. 4-7 and 18-19 on the estimator interface (core.Filter; run by
    core.drive). Beliefs are FusionState (all nodes, optionally batched over runs).

    The paper's estimator is in one-step-predictor form: the gain of eq. 18 is a predictor gain
    (L = A M C^T (...)^-1), so a node's measurement at step k enters only through xhat(k+1). So
    update(state, NodeMeasurements) stores the step's measurements (the estimate at k is not
    changed: there is no filtered estimate at k in this method), and predict(state, dt, u)
    applies them with the exchange and fusion of :func:`fusion_step`, giving xhat(k+1) and
    M(k+1). u = (S, P): the masks (..., N, N, n) of what actually arrived this step and the
    weights (..., N, N). dt is the model's fixed step (A, B, W are per step) and is not used.
    A, B, C, W as in :class:`NetworkModel`; V comes with the measurements.
    """

    A: np.ndarray
    B: np.ndarray
    C: tuple
    W: np.ndarray

    def update(self, state: FusionState, measurement: NodeMeasurements) -> FusionState:
        return FusionState(xhat=state.xhat, M=state.M, k=state.k, pending=measurement)

    def predict(self, state: FusionState, dt: float, u: tuple[np.ndarray, np.ndarray]) -> FusionState:
        meas = state.pending
        if meas is None:
            raise ValueError("FusionFilter.predict: no measurements for this step (update first: the "
                             "estimator is in one-step-predictor form)")
        S, P = u
        model = NetworkModel(A=self.A, B=self.B, C=self.C, W=self.W, V=tuple(meas.V))
        # eqs. 18, 4, 6, 7, 19
        new, _ = fusion_step(model, state, list(meas.y), S, P, available=meas.available)
        return new


@dataclass(frozen=True, kw_only=True, slots=True)
class LinkFaults:
    """Communication faults.

    drop_prob: probability that the message of a directed link j -> i (j != i) is lost in a step,
        scalar or (N, N) with entry [j, i]; all its components are lost together.
    failed: {node index (0-based): first step k at which it stops sending}; its own estimate
        continues, it still receives.
    A lost component falls back to compensation at the receiver: for that step the effective
    T_ji has a 0 there, so eq. 6 fills it with the receiver's own prediction A xhat_i + B. The
    receiver knows what arrived, so M is propagated with the same effective T (the bound then
    holds conditionally on the realised loss pattern; computing it needs the neighbours' M_j,
    which the paper also assumes known).
    """

    drop_prob: float | np.ndarray = 0.0
    failed: Mapping[int, int] = field(default_factory=dict)

    def effective(self, S: np.ndarray, k: int, rng: np.random.Generator | None, runs: int) -> np.ndarray:
        """Masks of what arrives at step k: (runs, N, N, n) from nominal S (N, N, n)."""
        N = S.shape[0]
        Se = np.broadcast_to(S, (runs,) + S.shape).copy()
        q = np.broadcast_to(np.asarray(self.drop_prob, float), (N, N))
        off = ~np.eye(N, dtype=bool)
        if np.any(q[off] > 0):
            if rng is None:
                raise ValueError("LinkFaults: message drops need a numpy Generator")
            lost = (rng.random((runs, N, N)) < q) & off
            Se[lost] = 0.0
        for node, k0 in self.failed.items():
            if k >= k0:
                keep = Se[:, node, node].copy()
                Se[:, node, :, :] = 0.0
                Se[:, node, node] = keep
        return Se


@dataclass(frozen=True, kw_only=True, slots=True)
class CommLog:
    """Communication per step. components[k, j, i]: components node j sent to node i in step k
    (j != i; diagonal 0), as actually delivered (effective masks, averaged over runs when batched);
    bytes = 8 * components (float64). budget: (N,) t_i or None."""

    components: np.ndarray
    budget: np.ndarray | None

    @property
    def bytes(self) -> np.ndarray:
        return BYTES_PER_COMPONENT * self.components

    @property
    def received(self) -> np.ndarray:
        """(K, N) components received by each node per step."""
        return self.components.sum(1)

    @property
    def sent(self) -> np.ndarray:
        """(K, N) components sent by each node per step."""
        return self.components.sum(2)

    def within_budget(self) -> bool:
        """True if no node ever received more than its budget t_i."""
        return self.budget is None or bool(np.all(self.received <= np.asarray(self.budget) + 1e-12))


def link_components(S: np.ndarray) -> np.ndarray:
    """Components per directed link from masks (..., N, N, n): (..., N, N), diagonal zeroed."""
    t = S.sum(-1)
    N = t.shape[-1]
    return t * (1 - np.eye(N))


def uwb_pseudo_measurement(ranges: np.ndarray, anchors: np.ndarray, range_sigma: float
                           ) -> tuple[np.ndarray, np.ndarray]:
    """Linear position pseudo-measurement from ranges to one anchor group (paper eqs. 21-23).

    ranges: (..., m) measured ranges r_k (m) to the anchors a_1..a_m; anchors: (m, 3) known
    positions (m, world ENU), the last one a_m is the reference; m >= 4 and the differences
    a_k - a_m must span 3-D. range_sigma: 1 sigma of each range (m, white, independent).
    Degenerate geometry is refused, never answered with an arbitrary number: fewer than 4
    anchors, anchors on one plane (or line), or a ranges array whose last axis is not m raise
    geometry.DegenerateGeometryError (a ValueError) naming the cause (estimators.geometry).

    r_k^2 = |p|^2 - 2 a_k.p + |a_k|^2; subtracting the reference's equation removes |p|^2:
        2 (a_k - a_m)^T p = |a_k|^2 - |a_m|^2 - r_k^2 + r_m^2,   k = 1..m-1   (eqs. 21-22)
    i.e. H p = z; p = (H^T H)^-1 H^T z (H invertible for m = 4), so y = p with C = I3 (eq. 23).
    Noise by linear error propagation: dz = G dr with G = [-2 diag(r_1..r_{m-1}) | 2 r_m 1], so
    cov(y) = sigma^2 H^+ G G^T H^+T, evaluated at the *measured* ranges (never the true ones). The
    second-order terms -dr_k^2 + dr_m^2 have zero mean, so y is unbiased to second order.
    Returns y (..., 3) (m, world) and V (..., 3, 3) (m^2).
    """
    a = np.asarray(anchors, float)
    r = np.asarray(ranges, float)
    m = a.shape[0]
    if r.shape[-1:] != (m,):
        raise DegenerateGeometryError(f"uwb_pseudo_measurement: {r.shape[-1] if r.ndim else 0} ranges "
                                      f"for {m} anchors")
    # eqs. 21-22 need 4 anchors spanning 3-D: coplanar ones leave H^T H singular (to round-off)
    require_span(a, 3, "uwb_pseudo_measurement: anchors")
    H = 2.0 * (a[:-1] - a[-1])  # (m-1, 3)
    # eq. 22: z_k = |a_k|^2 - |a_m|^2 - r_k^2 + r_m^2
    z = (a[:-1] ** 2).sum(-1) - (a[-1] ** 2).sum() - r[..., :-1] ** 2 + r[..., -1:] ** 2
    # H^+ = (H^T H)^-1 H^T by Cholesky (H^T H is SPD when the anchor differences span 3-D)
    Hp = cho_solve(cho_factor(H.T @ H), H.T)  # (3, m-1)
    # eq. 23: y = H^+ z = p (C = I3)
    y = z @ Hp.T
    G = np.zeros(r.shape[:-1] + (m - 1, m))
    idx = np.arange(m - 1)
    G[..., idx, idx] = -2.0 * r[..., :-1]
    G[..., :, -1] = 2.0 * r[..., -1:]
    HG = Hp @ G  # (..., 3, m)
    V = range_sigma ** 2 * HG @ np.swapaxes(HG, -1, -2)
    return y, _sym(V)


def comm_accounting(net: FusionNetwork, K: int) -> CommLog:
    """Nominal communication (no faults) over K steps: components and bytes per link vs budget."""
    comps = np.stack([link_components(net.at(k)[0]) for k in range(K)])
    return CommLog(components=comps, budget=None if net.budget is None else np.asarray(net.budget))


# --------------------------------------------------------------------------------------------
# Selection search
# --------------------------------------------------------------------------------------------
@dataclass(frozen=True, kw_only=True, slots=True)
class SearchResult:
    """Outcome of :func:`search_selection`.

    best: masks (N, N, n) of the best set; best_J: its objective; count: number of admissible sets
    (exact when enumerated, None for the heuristic); method: "exhaustive" or "local-search";
    objective: "bound" (eq. 16) or "exact" (eq. 14 from the exact covariance); all_J: objective of
    every enumerated set (exhaustive only), candidates: (count, N, N, n) masks (exhaustive only).
    """

    best: np.ndarray
    best_J: float
    count: int | None
    method: str
    objective: str
    all_J: np.ndarray | None = None
    candidates: np.ndarray | None = None


def _combos(n: int, t: int) -> list[tuple[float, ...]]:
    out = []
    for idx in itertools.combinations(range(n), t):
        v = [0.0] * n
        for a in idx:
            v[a] = 1.0
        out.append(tuple(v))
    return out


def _edge_list(links: np.ndarray) -> list[tuple[int, int]]:
    N = links.shape[0]
    return [(i, j) for i in range(N) for j in range(i + 1, N) if links[i, j]]


def _t_assignments(N: int, edges: list[tuple[int, int]], budget: np.ndarray, t_range: tuple[int, int],
                   exact: bool, limit: int | None = None, order_rng: np.random.Generator | None = None):
    """Yield admissible per-edge component counts (tuple over edges), by backtracking with
    node-budget pruning; in random order of values if order_rng is given."""
    lo, hi = t_range
    inc = [[e for e, (a, b) in enumerate(edges) if node in (a, b)] for node in range(N)]
    rem_edges = [len(x) for x in inc]
    load = [0] * N
    cur: list[int] = []
    count = 0

    def rec(e: int):
        nonlocal count
        if limit is not None and count >= limit:
            return
        if e == len(edges):
            if all((load[v] == budget[v]) if exact else (load[v] <= budget[v]) for v in range(N)):
                count += 1
                yield tuple(cur)
            return
        a, b = edges[e]
        vals = list(range(lo, hi + 1))
        if order_rng is not None:
            order_rng.shuffle(vals)
        for t in vals:
            ok = True
            for v in (a, b):
                after = load[v] + t
                r = rem_edges[v] - 1
                if after + r * lo > budget[v] or (exact and after + r * hi < budget[v]):
                    ok = False
            if not ok:
                continue
            load[a] += t; load[b] += t; rem_edges[a] -= 1; rem_edges[b] -= 1
            cur.append(t)
            yield from rec(e + 1)
            cur.pop()
            load[a] -= t; load[b] -= t; rem_edges[a] += 1; rem_edges[b] += 1

    yield from rec(0)


def _assemble(N: int, n: int, edges, pats) -> np.ndarray:
    S = np.zeros((N, N, n))
    for i in range(N):
        S[i, i] = 1.0
    for (a, b), p in zip(edges, pats):
        S[a, b] = p
        S[b, a] = p
    return S


def enumerate_selections(N: int, n: int, budget: Sequence[int], *, t_range: tuple[int, int] | None = None,
                         links: np.ndarray | None = None, exact_budget: bool = True,
                         max_sets: int | None = None) -> tuple[np.ndarray | None, int]:
    """All admissible symmetric selection sets: masks (count, N, N, n) and count.

    Admissible: T_ji = T_ij, T_ii = I, t_ji in t_range (default 1..n) on every link, the node
    budgets of :func:`validate_network`. If more than max_sets exist, returns (None, max_sets + 1).
    """
    links = np.ones((N, N), bool) if links is None else np.asarray(links, bool)
    t_range = (1, n) if t_range is None else t_range
    edges = _edge_list(links)
    budget = np.asarray(budget, int)
    by_t = {t: _combos(n, t) for t in range(t_range[0], t_range[1] + 1)}
    out, count = [], 0
    for ts in _t_assignments(N, edges, budget, t_range, exact_budget):
        for pats in itertools.product(*[by_t[t] for t in ts]):
            count += 1
            if max_sets is not None and count > max_sets:
                return None, count
            out.append(_assemble(N, n, edges, [np.array(p) for p in pats]))
    return (np.stack(out) if out else np.zeros((0, N, N, n))), count


def selection_objective(model: NetworkModel, candidates: np.ndarray, P: np.ndarray, M0: np.ndarray, K: int,
                        *, objective: str = "bound", Sigma0: np.ndarray | None = None,
                        chunk: int = 512) -> np.ndarray:
    """Objective of constant selection sets over a horizon of K steps, vectorized over sets.

    candidates: (S, N, N, n) masks; P: (N, N). "bound": J_bar of eq. 16 (sum over k = 0..K);
    "exact": J of eq. 14 from the exact covariance, with Sigma0 (default M0) shared by all nodes.
    Returns (S,).
    """
    N, n = model.N, model.n
    out = np.empty(candidates.shape[0])
    Sigma0 = np.asarray(M0 if Sigma0 is None else Sigma0, float)
    Vb = _block_diag(model.V)
    Wj = np.kron(np.ones((N, N)), model.W)
    for s0 in range(0, candidates.shape[0], chunk):
        Sc = candidates[s0:s0 + chunk]
        b = Sc.shape[0]
        M = np.broadcast_to(np.broadcast_to(np.asarray(M0, float), (N, n, n)), (b, N, n, n)).copy()
        J = np.trace(M, axis1=-2, axis2=-1).sum(-1)
        Pj = np.broadcast_to(np.kron(np.ones((N, N)), Sigma0), (b, N * n, N * n)).copy()
        if objective == "exact":
            J = np.trace(Pj, axis1=-2, axis2=-1).copy()
        for k in range(K):
            L = gains(model, M)
            if objective == "exact":
                F, G = transition_matrices(model, Sc, P, L)
                Pj = _sym(F @ Pj @ np.swapaxes(F, -1, -2) + G @ Vb @ np.swapaxes(G, -1, -2) + Wj)
                J = J + np.trace(Pj, axis1=-2, axis2=-1)
            M = bound_step(model, M, Sc, P, L)
            if objective == "bound":
                J = J + np.trace(M, axis1=-2, axis2=-1).sum(-1)
        out[s0:s0 + b] = J
    return out


def search_selection(model: NetworkModel, P: np.ndarray, M0: np.ndarray, K: int, budget: Sequence[int], *,
                     t_range: tuple[int, int] | None = None, links: np.ndarray | None = None,
                     objective: str = "bound", max_enumerate: int = 200_000, restarts: int = 8,
                     rng: np.random.Generator | None = None, Sigma0: np.ndarray | None = None) -> SearchResult:
    """Best constant symmetric selection set for weights P under per-node budgets.

    Exhaustive when the admissible sets number at most max_enumerate (the paper's case: N = 4,
    n = 3, t_ji in 1..3, t_i = 5 gives 2430 sets). Otherwise a heuristic local search:
    start from `restarts` random admissible sets (backtracking with shuffled values), then
    steepest descent over the neighbourhood made of (a) every other choice of components on one
    link with the same count t_ji, and (b) every move of one component count around a 4-cycle
    a-b-c-d (t_ab+1, t_bc-1, t_cd+1, t_da-1, which keeps every budget), with every choice of the
    added/removed components; stop at a local minimum. No optimality guarantee.
    """
    N, n = model.N, model.n
    links_b = np.ones((N, N), bool) if links is None else np.asarray(links, bool)
    t_range = (1, n) if t_range is None else t_range
    budget = np.asarray(budget, int)
    cands, count = enumerate_selections(N, n, budget, t_range=t_range, links=links_b, max_sets=max_enumerate)
    if cands is not None:
        if count == 0:
            raise ValueError("no admissible selection set for these budgets")
        J = selection_objective(model, cands, P, M0, K, objective=objective, Sigma0=Sigma0)
        b = int(np.argmin(J))
        return SearchResult(best=cands[b], best_J=float(J[b]), count=count, method="exhaustive",
                            objective=objective, all_J=J, candidates=cands)
    rng = np.random.default_rng(0) if rng is None else rng
    edges = _edge_list(links_b)
    eidx = {e: k for k, e in enumerate(edges)}
    f = lambda c: selection_objective(model, c, P, M0, K, objective=objective, Sigma0=Sigma0)
    best, best_J = None, np.inf
    for _ in range(restarts):
        ts = next(_t_assignments(N, edges, budget, t_range, True, order_rng=rng), None)
        if ts is None:
            raise ValueError("no admissible selection set for these budgets")
        pats = [np.zeros(n) for _ in ts]
        for p, t in zip(pats, ts):
            p[rng.choice(n, t, replace=False)] = 1.0
        cur = _assemble(N, n, edges, pats)
        cur_J = float(f(cur[None])[0])
        while True:
            nb = _neighbours(cur, edges, eidx, t_range)
            if not nb:
                break
            Jn = f(np.stack(nb))
            b = int(np.argmin(Jn))
            if Jn[b] >= cur_J - 1e-12 * abs(cur_J):
                break
            cur, cur_J = nb[b], float(Jn[b])
        if cur_J < best_J:
            best, best_J = cur, cur_J
    return SearchResult(best=best, best_J=best_J, count=None, method="local-search", objective=objective)


def _neighbours(S: np.ndarray, edges, eidx, t_range) -> list[np.ndarray]:
    n = S.shape[-1]
    out = []
    # (a) same count, other components on one link
    for (a, b) in edges:
        t = int(S[a, b].sum())
        for p in _combos(n, t):
            p = np.array(p)
            if not np.array_equal(p, S[a, b]):
                c = S.copy(); c[a, b] = p; c[b, a] = p
                out.append(c)
    # (b) move one unit around a 4-cycle a-b-c-d-a: +ab, -bc, +cd, -da
    N = S.shape[0]
    lo, hi = t_range
    for a, b, c, d in itertools.permutations(range(N), 4):
        es = [(a, b), (b, c), (c, d), (d, a)]
        key = [tuple(sorted(e)) for e in es]
        if any(k not in eidx for k in key) or len(set(key)) < 4:
            continue
        sign = [1, -1, 1, -1]
        if any(not lo <= S[e].sum() + s <= hi for e, s in zip(es, sign)):
            continue
        choices = []
        for e, s in zip(es, sign):
            cur = S[e]
            idx = np.flatnonzero(cur == (0 if s > 0 else 1))
            choices.append([(e, i, s) for i in idx])
        for combo in itertools.product(*choices):
            c = S.copy()
            for (u, v), i, s in combo:
                c[u, v, i] = c[v, u, i] = 1.0 if s > 0 else 0.0
            out.append(c)
    return out
