"""Paper-mode data of seed 000 (Zhao et al., EOC 2020): the paper's linear network, synthetic
measurements y_i = C_i x + v_i and the estimator, as one seeded, vectorized Monte Carlo (pure numpy).

The paper's section 2: 4 nodes, n = 3, A = I3, C_i = I3, known input B = [0.5 0.5 0.5] m/s (motion
along x = y = z), W = diag(0.02, 0.05, 0.03), V = diag(0.03, 0.04, 0.02) m^2, x(0) = [10 10 10] m,
M(0) = diag(0.19, 0.09, 0.08) m^2; its selection sets T1-T3 and weight sets P1-P3 (T_SETS, P_SETS). No
physics: for the physics-in-the-loop measurements run the
scenario `bandwidth`. Used by `testbed reproduce bandwidth` (paper mode) and the tests.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from estimators import bandwidth as bw

N, n = 4, 3  # nodes, state dimension (position, m)
W_PAPER = np.diag([0.02, 0.05, 0.03])  # process noise, m^2 (per step or per second: see paper_model)
V_PAPER = np.diag([0.03, 0.04, 0.02])  # measurement noise of one y_i, m^2
M0_PAPER = np.diag([0.19, 0.09, 0.08])  # initial error covariance M_i(0), m^2
X0_PAPER = np.array([10.0, 10.0, 10.0])  # x(0), m
VEL_PAPER = np.array([0.5, 0.5, 0.5])  # known input B, m/s


def paper_model(dt: float, w_rate: bool) -> bw.NetworkModel:
    """The paper's model for one reading: W per step (w_rate False) or W*dt (rate); B = v*dt."""
    W = W_PAPER * dt if w_rate else W_PAPER
    return bw.NetworkModel.create(A=np.eye(n), B=VEL_PAPER * dt, C=np.eye(n), W=W, V=V_PAPER, N=N)


@dataclass(frozen=True, kw_only=True, slots=True)
class SimResult:
    """Monte Carlo of the network. truth: (R, K+1, n); xhat: (R, K+1, N, n); M: (K+1, N, n, n)
    without faults (the same in every run), (R, K+1, N, n, n) with faults (it follows the realised
    losses); comm: delivered components per link per step (mean over runs)."""

    truth: np.ndarray
    xhat: np.ndarray
    M: np.ndarray
    comm: bw.CommLog

    @property
    def errors(self) -> np.ndarray:
        """e_i(k) = x(k) - xhat_i(k) (eq. 10): (R, K+1, N, n)."""
        return self.truth[:, :, None, :] - self.xhat


def simulate(model: bw.NetworkModel, net: bw.FusionNetwork, *, mu0: np.ndarray, Sigma0: np.ndarray, K: int,
             runs: int, rng: np.random.Generator, M0: np.ndarray | None = None,
             faults: bw.LinkFaults | None = None, x0_random: bool = True) -> SimResult:
    """Seeded Monte Carlo of truth, synthetic measurements y = C x + v, and the estimator.

    x(0) ~ N(mu0, Sigma0) (x0_random) or x(0) = mu0; every node starts at xhat_i(0) = mu0 with
    M_i(0) = M0 (default Sigma0). Runs are vectorized. K steps give K+1 instants.
    """
    N, n = model.N, model.n
    mu0 = np.asarray(mu0, float)
    Sigma0 = np.asarray(Sigma0, float)
    M0 = Sigma0 if M0 is None else np.asarray(M0, float)
    x = np.broadcast_to(mu0, (runs, n)).copy()
    if x0_random:
        x = x + rng.standard_normal((runs, n)) @ np.linalg.cholesky(Sigma0).T
    Wc = np.linalg.cholesky(model.W) if np.all(np.linalg.eigvalsh(model.W) > 0) else None
    Vc = [np.linalg.cholesky(V) for V in model.V]
    state = bw.FusionState(xhat=np.broadcast_to(mu0, (runs, N, n)).copy(),
                        M=np.broadcast_to(np.broadcast_to(M0, (N, n, n)), (runs, N, n, n)).copy())
    xs, xh, Ms, comps = [x], [state.xhat], [state.M], []
    for k in range(K):
        S, P = net.at(k)
        Se = faults.effective(S, k, rng, runs) if faults is not None else np.broadcast_to(S, (runs,) + S.shape)
        y = [x @ C.T + rng.standard_normal((runs, C.shape[0])) @ Vc[j].T for j, C in enumerate(model.C)]
        state, _ = bw.fusion_step(model, state, y, Se, P)
        w = (rng.standard_normal((runs, n)) @ Wc.T) if Wc is not None else \
            rng.multivariate_normal(np.zeros(n), model.W, size=runs)
        x = x @ model.A.T + model.B + w
        xs.append(x)
        xh.append(state.xhat)
        Ms.append(state.M)
        comps.append(bw.link_components(Se).mean(0))
    budget = None if net.budget is None else np.asarray(net.budget)
    comm = bw.CommLog(components=np.stack(comps) if comps else np.zeros((0, N, N)), budget=budget)
    Mh = np.stack(Ms, 1) if faults is not None else np.stack([m[0] for m in Ms])
    return SimResult(truth=np.stack(xs, 1), xhat=np.stack(xh, 1), M=Mh, comm=comm)


def _sel(T21, T31, T41, T32, T42, T43) -> np.ndarray:
    """Masks (N, N, n) from the paper's listing (T_ji for j > i, 1-based; T_ij = T_ji)."""
    S = np.zeros((N, N, n))
    for i in range(N):
        S[i, i] = 1.0
    for (j, i), d in {(2, 1): T21, (3, 1): T31, (4, 1): T41, (3, 2): T32, (4, 2): T42, (4, 3): T43}.items():
        S[j - 1, i - 1] = S[i - 1, j - 1] = d
    return S


# Section 2: T1, T2, T3 (diagonals), each listed entry transcribed; the symmetric ones follow eq. 5.
T_SETS = {
    "T1": _sel(T21=[0, 1, 0], T31=[1, 1, 0], T41=[0, 1, 1], T32=[1, 1, 0], T42=[0, 1, 1], T43=[0, 1, 0]),
    "T2": _sel(T21=[1, 0, 0], T31=[1, 0, 1], T41=[1, 0, 1], T32=[1, 0, 1], T42=[1, 0, 1], T43=[0, 0, 1]),
    "T3": _sel(T21=[1, 0, 0], T31=[0, 1, 1], T41=[1, 1, 0], T32=[0, 1, 1], T42=[1, 0, 1], T43=[1, 0, 0]),
}
# P[i, j] = p_ij (1-based in the paper). All three are symmetric, so the index order is moot.
P_SETS = {
    "P1": np.full((N, N), 0.25),
    "P2": np.array([[0.45, 0.15, 0.15, 0.25],
                    [0.15, 0.45, 0.25, 0.15],
                    [0.15, 0.25, 0.45, 0.15],
                    [0.25, 0.15, 0.15, 0.45]]),
    "P3": np.array([[0.65, 0.15, 0.15, 0.05],
                    [0.15, 0.65, 0.05, 0.15],
                    [0.15, 0.05, 0.65, 0.15],
                    [0.05, 0.15, 0.15, 0.65]]),
}
