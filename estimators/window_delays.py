"""The centralized window's antenna delays as consider parameters (docs/estimators.md, "The window's
antenna delays").

Every UWB device (a vehicle's tag, an anchor) adds its antenna delay b_d (m of range, constant
over the run, b ~ N(0, sigma_b^2 I), `estimators.sensor_models`) to every range it takes part in:
a range from device a to device c is z = h(x) + b_a + b_c + e, e white. The window weighs its
ranges by the white part only and does not estimate b; its estimate then moves with b by the
sensitivity J = dx/db, and the covariance of its error is

    P = S^-1 + sigma_b^2 J J^T                                            (eq. wd. 1)

S the window's information (Gauss-Newton) at its solution. A window of epochs 0..K-1 and its prior
N(m0, Lambda0^-1) on epoch 0 solves S x = g with g holding Lambda0 m0 and every range's
H_l^T w_l z_l, so

    J = S^-1 G,   G_k = sum over epoch k's ranges of H_l^T w_l B_l  (+ Lambda0 J0 at k = 0)  (eq. wd. 2)

B_l (1, D) the ones of the range's two devices, w_l its weight (the Huber IRLS weight / sigma^2),
H_l its row (u on the position of one end, -u on the other's, u the unit vector between them;
an anchor is known), J0 = dm0/db the sensitivity of the prior's mean. Marginalizing epoch 0 leaves
on epoch 1 the prior with information Lambda1 = K11 - K10 A^-1 K01 (A = epoch 0's information with
the motion factor's block K00) and the sensitivity

    J1 = -Lambda1^-1 K10 A^-1 (Lambda0 J0 + G_0 ranges)                   (eq. wd. 3)

(the Schur complement of eq. wd. 2). The delays are constant over the run, so the window and its
prior, which add up the epochs, cannot average them out: taken as white (2 sigma_b^2 per range),
the window's position ANEES was 4-8 on 3 dof on coop-denied (docs/denied.md, "The window's
antenna delays").

Shapes: n vehicles, s = 6 n states per epoch (centralized, estimators.window), D devices. Units
m. Never imports mujoco or testbed.
"""
from __future__ import annotations

import numpy as np
from scipy import linalg

from estimators.graph.factors import range_terms
from estimators.graph.losses import huber_weight

__all__ = ["delay_gradient", "newest_sensitivity", "marginal_sensitivity"]


def delay_gradient(P: np.ndarray, ep, devices: int, huber: float | None) -> np.ndarray:
    """G of one epoch's ranges (eq. wd. 2 without the prior), (6 n, D): the right-hand side
    H^T W B the delays move. P (n, 3) m the vehicles' positions the window is linearized at; ep an
    estimators.window.Epoch (tag device of vehicle i: i; anchor devices `ep.anchor_device`);
    devices D; huber the range loss threshold (sigmas) or None. Position rows only (velocities:
    zero)."""
    n = P.shape[0]
    G = np.zeros((n, 6, devices))
    if ep.edges.size:
        i, j = ep.edges[:, 0], ep.edges[:, 1]
        dist, u = range_terms(P[i], P[j])
        w = huber_weight((ep.ranges - dist) / ep.range_sigma, huber) / ep.range_sigma ** 2
        for end, sign in ((i, 1.0), (j, -1.0)):
            for dev in (i, j):
                np.add.at(G, (end, slice(0, 3), dev), sign * w[:, None] * u)
    if ep.anchor_vehicle.size:
        if ep.anchor_device is None:
            raise ValueError(f"epoch t = {ep.t:g} s: anchor ranges without anchor_device: the antenna-delay model needs each anchor's device")
        i = ep.anchor_vehicle
        dist, u = range_terms(P[i], ep.anchor_pos)
        w = huber_weight((ep.anchor_range - dist) / ep.anchor_sigma, huber) / ep.anchor_sigma ** 2
        for dev in (i, ep.anchor_device):
            np.add.at(G, (i, slice(0, 3), dev), w[:, None] * u)
    return G.reshape(6 * n, devices)


def newest_sensitivity(D: np.ndarray, U: np.ndarray, G: np.ndarray) -> np.ndarray:
    """J of the newest epoch (eq. wd. 2), (s, D): the last block of H^-1 G for the
    block-tridiagonal window information H (diagonal blocks D (K, s, s), off-diagonal U (K-1, s, s),
    estimators.window's system of one agent) and G (K, s, D), by forward block elimination (the
    newest block needs no back substitution)."""
    S, Y = D[0], G[0]
    for k in range(1, D.shape[0]):
        W = linalg.cho_solve(linalg.cho_factor(S, check_finite=False), np.concatenate([U[k - 1], Y], axis=1),
                             check_finite=False)
        Wu, Wy = W[:, :U.shape[2]], W[:, U.shape[2]:]
        S = D[k] - U[k - 1].T @ Wu
        Y = G[k] - U[k - 1].T @ Wy
    return linalg.cho_solve(linalg.cho_factor(S, check_finite=False), Y, check_finite=False)


def marginal_sensitivity(info: np.ndarray, AiB: np.ndarray, G0: np.ndarray) -> np.ndarray:
    """J1 of the prior left by marginalizing epoch 0 (eq. wd. 3), (s, D): info (s, s) its
    information Lambda1, AiB (s, s) A^-1 K01, G0 (s, D) epoch 0's Lambda0 J0 plus its ranges'
    delay_gradient."""
    return -np.linalg.solve(info, AiB.T @ G0)
