"""The seed 003 ranging EKF generalized: any number of antennas, any lever arms, rates optional.

The paper's filter (estimators.phase_model, estimators.phase_ekf) tracks the three antennas of
one follower from the ranges and range rates to M three-antenna masters, nose+wing layout. This
module is the same filter with every one of those numbers free (docs/models.md, "Generalized
ranging EKF"); the paper's configuration is one instance of it (`from_phase_measurement`, tested
to agree to round-off).

Frames and units
----------------
One frame N shared by everything given (world ENU on recorded data; the paper's master body
frame in seed 003), metres and m/s. Bodies are FLU; lever arms are body-frame vectors (m) from
the body origin to each antenna; quaternions wxyz, body to N (as MuJoCo).

State (eq. 13 generalized), x: (6 n,)
    x = [x_1 .. x_n, v_1 .. v_n]: the n >= 1 follower antenna positions (m) then their
    velocities (m/s) in N; `x[:3 n].reshape(n, 3)[j]` is antenna j. The antennas are tracked as
    points (as in the paper): rigidity enters through the process noise (`RangingNoise`) and the
    body pose is fitted to them afterwards (`body_pose`), when the lever arms allow it.
    Optionally followed by m >= 0 range-bias states (m), x: (6 n + m,): `x[6 n + k]` is bias k,
    added to the ranges of the links that name it (RangingEpoch.bias), a random constant or a
    random walk (RangingEkf.bias_walk); m is the state's size minus 6 n, so a caller adds a bias
    state by appending a row and column to its belief (docs/replay.md, "Range bias").

Measurements: one `RangingEpoch` = L links. Link l joins a KNOWN point X_l (an anchor, or an
antenna of a vehicle whose pose is known from any source: `known_points`) to follower antenna
j_l. Rows, in this order: the L ranges (NaN = missing), then, if range rates are given, the L
rates, then, if a height is given, one height row:
    r_l    = |x_{j_l} - X_l|                                              (eq. 5)
             + b_{k_l}  when link l names bias state k_l (docs/replay.md, "Range bias")
    rdot_l = u_l . (v_{j_l} - V_l),   u_l = (x_{j_l} - X_l) / r_l          (eq. 10, relative velocity)
             or, with a rate window W, the mean rate (r(t) - r(t - W)) / W  (eq. 7 as measured)
    h      = sum_j c_j x_j[2]                                              (height of a point of the array)
with the Jacobians of phase_model.measurement_model per link (eq. 27-28 corrected) and c_j on
the z column of antenna j for the height. At least one known point per link; full position of
an antenna needs >= 3 links to it (>= 4 non-coplanar known points, or 3 and the height to
resolve the plane's mirror image, `multilaterate`).

A range whose two ends coincide in the estimate (r = 0) has no direction: that row is skipped
and counted (core.tally skipped_updates); a factorization failure skips the epoch and is
counted; nothing in a filter run raises on a degenerate epoch.

Public API
----------
RangingEpoch, ranging_model(x, n, epoch), transition(dt, n, biases), RangingNoise,
process_noise(dt, n, q, x, bias_walk), RangingEkf(n, q, gate, iterations, bias_walk) (a core.Filter), multilaterate(known, ranges, sigma, height),
initial_belief(...) (prior from a multilateration fix per antenna), known_points(p, q, arms, v, w),
body_pose(belief, lever_arms), from_phase_measurement(PhaseMeasurement).
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import NamedTuple

import numpy as np
from scipy import linalg

from estimators.core import (NO_GATE, Gate, Gaussian, UpdateInfo, kf_predict, linearized_update, symmetrize, tally,
                             white_acceleration_q)
from estimators.geometry import DegenerateGeometryError, numerical_rank, spanned_dimension
from estimators.so3 import quat_exp, quat_to_rotmat, rotmat_to_quat, skew

#: default white-acceleration density per antenna axis, m^2/s^3 (a walking robot; set it per use)
DEFAULT_Q = 1e-2
#: a range below this (m) between a known point and the estimated antenna has no direction
MIN_RANGE_M = 1e-9


# ------------------------------------------------------------------------------------------------
# Measurements
# ------------------------------------------------------------------------------------------------
@dataclass(frozen=True, kw_only=True, slots=True)
class RangingEpoch:
    """One epoch of links between known points and the follower's antennas (module docstring).

    antenna: (L,) int, follower antenna index j_l of each link (0 <= j_l < n);
    known_pos: (L, 3) m, the known end X_l in N; ranges: (L,) m (NaN = missing);
    sigma_range: m, scalar or (L,);
    range_rates: (L,) m/s or None (no rate rows); known_vel: (L, 3) m/s of X_l, None = static;
    sigma_range_rate: m/s, scalar or (L,); rate_window: None (instantaneous rates, eq. 10) or W s,
    scalar or (L,) (mean rate over [t - W, t], eq. 7 as measured);
    height: m, height (z in N) of the point sum_j c_j x_j of the array, or None;
    height_weights: (n,) the c_j (None = 1 / n each: the antennas' centroid); sigma_height: m.
    bias: (L,) int, the bias state k_l added to link l's range (-1: none), or None (no bias).
    offset: (L,) s, link l's time offset c_l (its range at t is the distance at t + c_l:
    r_l = |x_j - X_l| + c_l u_l^T (v_j - V_l), docs/calibration.md cal. 10), or None (all 0);
    V_l from known_vel (None: static).
    """

    antenna: np.ndarray
    known_pos: np.ndarray
    ranges: np.ndarray
    sigma_range: float | np.ndarray = 0.1
    range_rates: np.ndarray | None = None
    known_vel: np.ndarray | None = None
    sigma_range_rate: float | np.ndarray = 0.1
    rate_window: float | np.ndarray | None = None
    height: float | None = None
    height_weights: np.ndarray | None = None
    bias: np.ndarray | None = None
    offset: np.ndarray | None = None
    sigma_height: float = 0.1

    @property
    def n_links(self) -> int:
        return int(np.shape(self.antenna)[0])

    def weights(self, n: int) -> np.ndarray:
        """c (n,) of the height row."""
        return np.full(n, 1.0 / n) if self.height_weights is None else np.asarray(self.height_weights, float)

    def stacked(self) -> tuple[np.ndarray, np.ndarray]:
        """z (m,) and noise variances r_var (m,) in the row order of the module docstring."""
        L = self.n_links
        z = [np.asarray(self.ranges, float).reshape(L)]
        r_var = [np.broadcast_to(np.square(self.sigma_range, dtype=float), (L,))]
        if self.range_rates is not None:
            z.append(np.asarray(self.range_rates, float).reshape(L))
            r_var.append(np.broadcast_to(np.square(self.sigma_range_rate, dtype=float), (L,)))
        if self.height is not None:
            z.append(np.array([self.height], float))
            r_var.append(np.array([self.sigma_height ** 2]))
        return np.concatenate(z), np.concatenate(r_var)

    def row_label(self, row: int) -> tuple[str, int, int]:
        """(kind "range" | "range_rate" | "height", link l (-1 for height), antenna j (-1))."""
        L = self.n_links
        if row < L:
            return "range", int(row), int(self.antenna[row])
        if self.range_rates is not None and row < 2 * L:
            return "range_rate", int(row - L), int(self.antenna[row - L])
        return "height", -1, -1


def ranging_model(x: np.ndarray, n: int, epoch: RangingEpoch) -> tuple[np.ndarray, np.ndarray]:
    """h(x) (m,) and its analytic Jacobian H (m, 6 n + b) for one epoch (module docstring rows).

    x: (6 n + b,) antenna state in N, then b >= 0 bias states (m). Vectorized over links. A link whose range is below MIN_RANGE_M
    gets NaN in h (its direction is undefined; the filter skips such rows).
    """
    x = np.asarray(x, float)
    P, V = x[:3 * n].reshape(n, 3), x[3 * n:6 * n].reshape(n, 3)
    j = np.asarray(epoch.antenna, int)
    L = j.size
    X0 = np.asarray(epoch.known_pos, float).reshape(L, 3)
    d = P[j] - X0
    # eq. 5: r_l = |x_j - X_l|
    r = np.sqrt(np.einsum("lk,lk->l", d, d))
    r = np.where(r < MIN_RANGE_M, np.nan, r)
    u = d / r[:, None]
    has_rate, has_height = epoch.range_rates is not None, epoch.height is not None
    m = L * (2 if has_rate else 1) + int(has_height)
    h = np.empty(m)
    H = np.zeros((m, x.size))
    rows = np.arange(L)
    pos_cols = 3 * j[:, None] + np.arange(3)
    h[:L] = r
    if epoch.bias is not None:
        biased = np.flatnonzero(np.asarray(epoch.bias, int) >= 0)
        col = 6 * n + np.asarray(epoch.bias, int)[biased]
        # docs/replay.md, "Range bias": r_l = |x_j - X_l| + b_k, d r_l / d b_k = 1
        h[biased] += x[col]
        H[biased, col] = 1.0
    # eq. 27: d r / d x_j = u^T
    H[rows[:, None], pos_cols] = u
    if epoch.offset is not None or has_rate:
        V0 = np.zeros((L, 3)) if epoch.known_vel is None else np.asarray(epoch.known_vel, float).reshape(L, 3)
        w = V[j] - V0
        # eq. 10 with the relative velocity; eq. 28 (corrected): d rdot / d x_j = (w - u rdot)^T / r, d rdot / d v_j = u^T
        rdot = np.einsum("lk,lk->l", u, w)
        rdot_x = (w - u * rdot[:, None]) / r[:, None]
    if epoch.offset is not None:
        c = np.asarray(epoch.offset, float).reshape(L)
        # eq. cal. 10 (docs/calibration.md): r_l(t) = |x_j - X_l| + c_l rdot_l, the distance at t + c_l
        h[:L] += c * rdot
        H[rows[:, None], pos_cols] += c[:, None] * rdot_x
        H[rows[:, None], 3 * n + pos_cols] = c[:, None] * u
    if has_rate:
        if epoch.rate_window is None:
            Hp, Hv = rdot_x, u
        else:
            # eq. 7 as measured: (r(t) - r(t - W)) / W with x_j(t - W) = x_j - W v_j (eq. 24)
            W = np.broadcast_to(np.asarray(epoch.rate_window, float), (L,))[:, None]
            d0 = d - W * w
            r0 = np.sqrt(np.einsum("lk,lk->l", d0, d0))
            u0 = d0 / r0[:, None]
            rdot = (r - r0) / W[:, 0]
            Hp, Hv = (u - u0) / W, u0
        h[L:2 * L] = rdot
        H[L + rows[:, None], pos_cols] = Hp
        H[L + rows[:, None], 3 * n + pos_cols] = Hv
    if has_height:
        c = epoch.weights(n)
        h[-1] = c @ P[:, 2]
        H[-1, 3 * np.arange(n) + 2] = c
    return h, H


# ------------------------------------------------------------------------------------------------
# Time update
# ------------------------------------------------------------------------------------------------
def transition(dt: float, n: int, biases: int = 0) -> np.ndarray:
    """Phi (6 n + b, 6 n + b) of the constant-velocity model over dt s (eq. 24 for n antennas),
    the b bias states held."""
    F = np.eye(6 * n + biases)
    F[:3 * n, 3 * n:6 * n] = dt * np.eye(3 * n)
    return F


@dataclass(frozen=True, kw_only=True, slots=True)
class RangingNoise:
    """White-acceleration densities (phase_ekf.ProcessNoise for n antennas).

    antenna: independent per antenna axis (m^2/s^3); translation: common body acceleration per
    axis (m^2/s^3); rotation: body angular acceleration per axis (rad^2/s^3), acting on the lever
    arms rho_j = x_j - centroid of the antennas (the paper's layout uses the wing-tip midpoint).
    """

    antenna: float = DEFAULT_Q
    translation: float = 0.0
    rotation: float = 0.0

    def density(self, x: np.ndarray, n: int) -> np.ndarray:
        """S (3 n, 3 n) = q I + q_t 1 1^T (x) I3 + q_r [rho_i]x [rho_j]x^T at the state x (6 n,)."""
        S = self.antenna * np.eye(3 * n)
        if self.translation:
            S += np.kron(np.full((n, n), self.translation), np.eye(3))
        if self.rotation:
            Pa = np.asarray(x, float)[:3 * n].reshape(n, 3)
            Sk = skew(Pa - Pa.mean(0))
            S += self.rotation * np.einsum("iab,jcb->iajc", Sk, Sk).reshape(3 * n, 3 * n)
        return S


def process_noise(dt: float, n: int, q: RangingNoise, x: np.ndarray, bias_walk: float = 0.0) -> np.ndarray:
    """Q (6 n + b, 6 n + b) = [[dt^3/3 S, dt^2/2 S], [dt^2/2 S, dt S]] with S = q.density(x, n),
    then bias_walk dt I_b for the b = x.size - 6 n bias states (bias_walk m^2/s; 0: constants)."""
    S = q.density(x, n)
    Q = np.kron(white_acceleration_q(dt), S)
    b = np.size(x) - 6 * n
    return linalg.block_diag(Q, bias_walk * dt * np.eye(b)) if b else Q


# ------------------------------------------------------------------------------------------------
# The filter
# ------------------------------------------------------------------------------------------------
@dataclass(frozen=True, kw_only=True, slots=True)
class RangingEkf:
    """The generalized ranging EKF as a core.Filter: predict(belief, dt) and update(belief, epoch).

    n: follower antennas; q: RangingNoise; gate: core.Gate (Baarda w-test over all rows);
    iterations: 1 = EKF, > 1 iterated EKF (as phase_ekf.measurement_update); bias_walk: m^2/s,
    random-walk density of the bias states (0: random constants). No input u.
    """

    n: int
    q: RangingNoise = RangingNoise()
    gate: Gate = Gate()
    iterations: int = 1
    bias_walk: float = 0.0

    def __post_init__(self) -> None:
        if self.n < 1 or self.iterations < 1:
            raise ValueError(f"RangingEkf: n = {self.n} and iterations = {self.iterations} must be >= 1")

    def predict(self, belief: Gaussian, dt: float, u: None = None) -> Gaussian:
        """Time update over dt s (eq. 18, 22-24)."""
        b = belief.mean.size - 6 * self.n
        return kf_predict(belief, transition(dt, self.n, b), process_noise(dt, self.n, self.q, belief.mean, self.bias_walk))

    def update(self, belief: Gaussian, epoch: RangingEpoch) -> Gaussian:
        """Measurement update (eq. 16-22); degenerate rows and epochs are skipped and counted."""
        return self.update_info(belief, epoch)[0]

    def update_info(self, belief: Gaussian, epoch: RangingEpoch) -> tuple[Gaussian, UpdateInfo | None]:
        """`update` with the core.UpdateInfo of the first pass (None if the epoch was skipped)."""
        z, r_var = epoch.stacked()
        hx, H = ranging_model(belief.mean, self.n, epoch)
        valid = np.isfinite(z)
        bad = valid & ~np.isfinite(hx)
        if bad.any():
            tally(skipped_updates=int(bad.sum()))
            valid &= ~bad
            hx, H = np.nan_to_num(hx), np.nan_to_num(H)
        try:
            # eq. 19-21 (core.linearized_update: information-form gain, Joseph form, gate)
            post, info = linearized_update(belief, z, hx, H, r_var, valid, self.gate, labels=epoch.row_label)
            for _ in range(self.iterations - 1):
                xi = post.mean
                hi, Hi = ranging_model(xi, self.n, epoch)
                if not np.isfinite(hi[info.used]).all():
                    break
                post, _ = linearized_update(belief, z, np.nan_to_num(hi) + np.nan_to_num(Hi) @ (belief.mean - xi),
                                            np.nan_to_num(Hi), r_var, info.used, NO_GATE)
        except np.linalg.LinAlgError:
            tally(skipped_updates=1)
            return belief, None
        return post, info


# ------------------------------------------------------------------------------------------------
# Known points from poses of any source
# ------------------------------------------------------------------------------------------------
def known_points(p: np.ndarray, quat: np.ndarray, lever_arms: np.ndarray, v: np.ndarray | None = None,
                 omega: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Positions (k, 3) m and velocities (k, 3) m/s in N of k antennas of a body of known pose.

    p: (3,) body origin, quat: (4,) wxyz body to N, lever_arms: (k, 3) body frame; v: (3,) m/s
    body-origin velocity and omega: (3,) rad/s body-frame angular rate (None = zero):
        X = p + R l,   V = v + R (omega x l)   (eq. 1 and 8 of the paper for any lever arm).
    """
    R = quat_to_rotmat(np.asarray(quat, float))
    arms = np.asarray(lever_arms, float).reshape(-1, 3)
    X = np.asarray(p, float)[None, :] + arms @ R.T
    Vb = np.zeros_like(arms) if omega is None else np.cross(np.asarray(omega, float)[None, :], arms)
    V = Vb @ R.T + (0.0 if v is None else np.asarray(v, float)[None, :])
    return X, V


# ------------------------------------------------------------------------------------------------
# Initial fix from the geometry given
# ------------------------------------------------------------------------------------------------
class Fix(NamedTuple):
    """A multilateration fix: position (3,) m, covariance (3, 3) m^2 (Gauss-Newton information
    at the fix), converged flag, dimension the known points span (2: mirror resolved by height)."""

    position: np.ndarray
    cov: np.ndarray
    converged: bool
    span: int


def _gauss_newton_fix(p, known, ranges, w, height, w_h, iters=50, tol=1e-10):
    """Gauss-Newton on whitened range rows (+ a height row) from p; returns p, info N, converged."""
    for _ in range(iters):
        d = p - known
        r = np.linalg.norm(d, axis=1)
        if np.any(r < MIN_RANGE_M):
            raise DegenerateGeometryError("multilaterate: the fix coincides with a known point")
        J = d / r[:, None] * w[:, None]
        res = (ranges - r) * w
        if height is not None:
            J = np.vstack([J, [0.0, 0.0, w_h]])
            res = np.append(res, (height - p[2]) * w_h)
        N = J.T @ J
        if numerical_rank(N)[0] < 3:
            raise DegenerateGeometryError("multilaterate: the position is not determined by these "
                                          "ranges (singular normal matrix at the fix)", rank=numerical_rank(N)[0])
        step = linalg.cho_solve(linalg.cho_factor(N), J.T @ res)
        p = p + step
        if np.abs(step).max() < tol * max(1.0, np.abs(p).max()):
            return p, N, True
    return p, N, False


def multilaterate(known: np.ndarray, ranges: np.ndarray, sigma: float | np.ndarray,
                  height: float | None = None, sigma_height: float = 0.1) -> Fix:
    """Least-squares position of one point from ranges to known points, with degeneracy explicit.

    known: (k, 3) m; ranges: (k,) m (non-finite entries are dropped); sigma: m, scalar or (k,);
    height: optional z of the point (m), sigma_height its 1 sigma.
    - fewer than 3 ranges, or known points on one line (or coincident): DegenerateGeometryError;
    - known points spanning 3-D (>= 4 ranges): linear start from differences of squared ranges
      (as eqs. 21-22 of seed 000, about the centroid), then Gauss-Newton;
    - known points on one plane: the in-plane part q is linear; the offset s from the plane solves
      s^2 = mean_k (r_k^2 - |q - a_k|^2), two mirror images +-s. The height tells the side: the
      start is q moved along the normal to the aid's height, then Gauss-Newton (with the height
      row). DegenerateGeometryError if there is no height, or if the aid is within 3
      sigma_height of the plane's height at q while s exceeds 3 sigma_height (e.g. a vertical
      plane: the images differ sideways, not in height).
    The height row, when given, is part of the Gauss-Newton and of the covariance.
    """
    K = np.asarray(known, float).reshape(-1, 3)
    r = np.asarray(ranges, float).reshape(-1)
    s = np.broadcast_to(np.asarray(sigma, float), r.shape)
    ok = np.isfinite(r)
    K, r, w = K[ok], r[ok], 1.0 / s[ok]
    if r.size < 3:
        raise DegenerateGeometryError(f"multilaterate: {r.size} ranges, at least 3 needed")
    span = spanned_dimension(K)
    if span < 2:
        raise DegenerateGeometryError(f"multilaterate: the {r.size} known points lie on one "
                                      f"{'line' if span == 1 else 'point'}", rank=span)
    c = K.mean(0)
    A = K - c
    # differences of squared ranges about the centroid: 2 (a_k - c)^T (p - c) = b_k (eqs. 21-22)
    b = (A * A).sum(1) - r ** 2 - ((A * A).sum(1) - r ** 2).mean()
    _, _, Vt = np.linalg.svd(A, full_matrices=True)
    B = Vt[:span]  # (span, 3): directions the known points span
    q = linalg.lstsq(2.0 * A @ B.T, b)[0] @ B
    w_h = None if height is None else 1.0 / sigma_height
    if span == 3:
        p0 = c + q
    else:
        # the offset from the plane is +-s (two mirror images): only the height tells the side
        nrm, base = Vt[2], c + q
        off = np.sqrt(max(float(np.mean(r ** 2 - ((base - K) ** 2).sum(1))), 0.0))
        if height is None:
            raise DegenerateGeometryError("multilaterate: known points on one plane, mirror ambiguity "
                                          "(no height aid)", rank=2)
        t_h = height - base[2]
        if abs(t_h) < 3.0 * sigma_height and off > 3.0 * sigma_height:
            raise DegenerateGeometryError(f"multilaterate: known points on one plane, mirror ambiguity (the "
                                          f"height does not tell the side: {t_h:.3g} m from the plane)", rank=2)
        # start at the aid's height on the side it gives (base itself if the plane is vertical)
        p0 = base + (t_h / nrm[2] if abs(nrm[2]) > 1e-3 else 0.0) * nrm
    p, N, converged = _gauss_newton_fix(p0, K, r, w, height, w_h)
    cov = linalg.cho_solve(linalg.cho_factor(N), np.eye(3))
    return Fix(p, symmetrize(cov), converged, span)


def _height_sigma(epoch: RangingEpoch, n: int, arms: np.ndarray | None) -> float | None:
    """sigma of the height aid as the height of one antenna: hypot(sigma_height, extent), extent =
    max |l_j - sum c_i l_i| (an antenna's height differs from the aided point's by at most that)."""
    if epoch.height is None:
        return None
    extent = 0.0
    if arms is not None:
        extent = float(np.linalg.norm(arms - epoch.weights(n) @ arms, axis=1).max())
    return float(np.hypot(epoch.sigma_height, extent))


def _pose_rows(p, R, arms, j, X0, r, w, c, height, w_h, w_level):
    """Whitened residuals and Jacobian wrt [dp, dtheta] (body-frame) of ranges (+ height, + level
    prior: the body z axis R e_z has zero horizontal components, 1 sigma = 1 / w_level rad)."""
    a = arms @ R.T  # (n, 3) lever arms in N
    d = p + a[j] - X0
    rng = np.linalg.norm(d, axis=1)
    u = d / rng[:, None]
    J = np.concatenate([u, -np.einsum("lk,lkm->lm", u, R @ skew(arms[j]))], axis=1) * w[:, None]
    res = (r - rng) * w
    if height is not None:
        ca = c @ arms
        J = np.vstack([J, w_h * np.concatenate([[0.0, 0.0, 1.0], -(R @ skew(ca))[2]])])
        res = np.append(res, w_h * (height - p[2] - (R @ ca)[2]))
    if w_level is not None:
        # d (R exp([dtheta]x) e_z) = -R [e_z]x dtheta
        J = np.vstack([J, np.concatenate([np.zeros((2, 3)), -w_level * (R @ skew(np.array([0.0, 0.0, 1.0])))[:2]], 1)])
        res = np.append(res, -w_level * R[:2, 2])
    return res, J


def fit_pose_to_ranges(epoch: RangingEpoch, n: int, lever_arms: np.ndarray, yaw_starts: int = 8,
                       iters: int = 50, level_sigma: float | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Rigid 6-DOF fix of the follower from one epoch's ranges (and height): p (3,) m, R (3, 3)
    body to N, cov (6, 6) of [dp, dtheta (body frame)], by Gauss-Newton with step halving on
        min sum_l ((r_l - |p + R l_{j_l} - X_l|) / sigma_l)^2 (+ the height row).
    Start: the aided point sum c_j x_j multilaterated from all links as if they ended there
    (sigma inflated by the array's extent; `multilaterate`, so its degenerate cases raise), then
    yaw_starts level attitudes; the lowest cost wins (the mirror image is refused by the height).
    level_sigma: optional prior that the body is level (rad, on the tilt of its z axis; e.g. a
    ground robot): one epoch of ranges over arrays a few decimetres wide leaves roll and pitch
    poorly determined (tenths of a radian), which no Gaussian prior describes well.
    Raises DegenerateGeometryError if the information matrix at the fix has rank < 6.
    """
    arms = np.asarray(lever_arms, float)
    j, X0 = np.asarray(epoch.antenna, int), np.asarray(epoch.known_pos, float)
    r = np.asarray(epoch.ranges, float)
    w = 1.0 / np.broadcast_to(np.asarray(epoch.sigma_range, float), r.shape)
    ok = np.isfinite(r)
    j, X0, r, w = j[ok], X0[ok], r[ok], w[ok]
    c = epoch.weights(n)
    extent = float(np.linalg.norm(arms - c @ arms, axis=1).max())
    sh = _height_sigma(epoch, n, arms)
    centre = multilaterate(X0, r, np.hypot(1.0 / w, extent), epoch.height,
                           sh if sh is not None else 0.1).position
    w_h = None if epoch.height is None else 1.0 / epoch.sigma_height
    w_level = None if level_sigma is None else 1.0 / level_sigma
    best = None
    for yaw in 2 * np.pi * np.arange(yaw_starts) / yaw_starts:
        R = quat_to_rotmat(np.array([np.cos(yaw / 2), 0.0, 0.0, np.sin(yaw / 2)]))
        p = centre - R @ (c @ arms)
        res, J = _pose_rows(p, R, arms, j, X0, r, w, c, epoch.height, w_h, w_level)
        f = res @ res
        for _ in range(iters):
            step = linalg.lstsq(J, res)[0]
            t = 1.0
            for _ in range(30):
                p_n, R_n = p + t * step[:3], R @ quat_to_rotmat(quat_exp(t * step[3:]))
                res_n, J_n = _pose_rows(p_n, R_n, arms, j, X0, r, w, c, epoch.height, w_h, w_level)
                if res_n @ res_n <= f:
                    break
                t *= 0.5
            else:
                break
            p, R, res, J, f_old, f = p_n, R_n, res_n, J_n, f, res_n @ res_n
            if f_old - f <= 1e-12 * max(f_old, 1.0):
                break
        if best is None or f < best[0]:
            best = (f, p, R, J)
    _, p, R, J = best
    N = J.T @ J
    rank = numerical_rank(N)[0]
    if rank < 6:
        raise DegenerateGeometryError(f"fit_pose_to_ranges: the ranges determine only {rank} of the 6 pose "
                                      f"degrees of freedom", rank=rank)
    return p, R, symmetrize(linalg.cho_solve(linalg.cho_factor(N), np.eye(6)))


def initial_belief(epoch: RangingEpoch, n: int, lever_arms: np.ndarray | None = None,
                   v_mean: np.ndarray | None = None, v_cov: np.ndarray | float = 1.0,
                   shape_sigma: float = 0.01, omega_var: float = 0.01, level_sigma: float | None = None) -> Gaussian:
    """Prior on the (6 n,) state built from one epoch's ranges and the geometry given.

    Rigid (lever_arms (n, 3) given, n >= 3 not on one line): a 6-DOF pose fix from all the
    ranges and the height (`fit_pose_to_ranges`), spread to the antennas as x_j = p + R l_j with
    cov A C A^T + shape_sigma^2 I (A_j = [I3, -R [l_j]x], C the fix's (6, 6) covariance;
    shape_sigma (m): how far the antennas may sit from their nominal lever arms); velocities
    common to the antennas, v_mean (3,) m/s (default 0) with v_cov (3, 3) or a variance per axis
    (m^2/s^2), plus a body rate of variance omega_var (rad^2/s^2) per axis and shape_sigma^2
    (m^2/s^2) per antenna axis: P_v = 1 1^T (x) v_cov + B (omega_var I) B^T + shape_sigma^2 I,
    B_j = -R [l_j]x. level_sigma: the optional level prior of `fit_pose_to_ranges`.
    Otherwise (one or two antennas, or no lever arms): a multilateration fix per antenna
    (`multilaterate`, the height taken with `_height_sigma`), antennas independent, velocity
    prior v_mean, v_cov per antenna.
    Raises DegenerateGeometryError naming what is not determined.
    """
    v_mean = np.zeros(3) if v_mean is None else np.asarray(v_mean, float)
    Pv = np.asarray(v_cov, float) * (np.eye(3) if np.ndim(v_cov) == 0 else 1.0)
    arms = None if lever_arms is None else np.asarray(lever_arms, float).reshape(n, 3)
    if arms is not None and n >= 3 and spanned_dimension(arms) >= 2:
        p, R, C = fit_pose_to_ranges(epoch, n, arms, level_sigma=level_sigma)
        Rl = -R @ skew(arms)  # (n, 3, 3): d x_j / d theta
        A = np.concatenate([np.broadcast_to(np.eye(3), (n, 3, 3)), Rl], axis=2).reshape(3 * n, 6)
        B = Rl.reshape(3 * n, 3)
        shape = shape_sigma ** 2 * np.eye(3 * n)
        P_pos = A @ C @ A.T + shape
        P_vel = np.kron(np.ones((n, n)), Pv) + omega_var * B @ B.T + shape
        mean = np.concatenate([(p + arms @ R.T).reshape(-1), np.tile(v_mean, n)])
        return Gaussian(mean, symmetrize(linalg.block_diag(P_pos, P_vel)))
    j, r, X0 = np.asarray(epoch.antenna, int), np.asarray(epoch.ranges, float), np.asarray(epoch.known_pos, float)
    s = np.broadcast_to(np.asarray(epoch.sigma_range, float), r.shape)
    sh = _height_sigma(epoch, n, arms)
    means, covs = [], []
    for a in range(n):
        sel = j == a
        try:
            fix = multilaterate(X0[sel], r[sel], s[sel], epoch.height, sh if sh is not None else 0.1)
        except DegenerateGeometryError as e:
            raise DegenerateGeometryError(f"antenna {a}: {e}", e.rank) from None
        means.append(fix.position)
        covs.append(fix.cov)
    mean = np.concatenate([np.concatenate(means), np.tile(v_mean, n)])
    return Gaussian(mean, linalg.block_diag(*covs, *([Pv] * n)))


# ------------------------------------------------------------------------------------------------
# Body pose from the antennas (eq. 29-30 for any lever arms)
# ------------------------------------------------------------------------------------------------
class BodyPose(NamedTuple):
    """Follower body state fitted to the antennas: position (3,) m, quaternion (4,) wxyz body to
    N, velocity (3,) m/s of the body origin, omega (3,) rad/s body frame, and cov (12, 12) of
    [position, attitude error (rad, body tangent: log(R_true^T R_est)), velocity, omega]."""

    position: np.ndarray
    quat: np.ndarray
    velocity: np.ndarray
    omega: np.ndarray
    cov: np.ndarray


def fit_pose(P: np.ndarray, lever_arms: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Least-squares rigid fit min sum_j |x_j - p - R l_j|^2 (Kabsch): returns p (3,), R (3, 3).

    P: (n, 3) antenna positions in N; lever_arms: (n, 3) body frame; n >= 3 not on one line.
    """
    arms = np.asarray(lever_arms, float)
    lc, pc = arms.mean(0), P.mean(0)
    U, _, Vt = np.linalg.svd((P - pc).T @ (arms - lc))
    D = np.diag([1.0, 1.0, np.sign(np.linalg.det(U @ Vt))])
    R = U @ D @ Vt
    return pc - R @ lc, R


def pose_sensitivity(R: np.ndarray, lever_arms: np.ndarray) -> np.ndarray:
    """G (6, 3 n): first-order map from antenna position errors to [dp, dtheta] of `fit_pose`.

    x_j = p + R exp([dtheta]x) l_j ~ p + R l_j - R [l_j]x dtheta, so the rows A_j = [I3, -R [l_j]x]
    and G = (A^T A)^-1 A^T (exact at a zero-residual fit; the same map gives [v, omega] from the
    antenna velocities, v_j = v + R (omega x l_j)).
    """
    arms = np.asarray(lever_arms, float)
    n = arms.shape[0]
    A = np.empty((n, 3, 6))
    A[:, :, :3] = np.eye(3)
    A[:, :, 3:] = -R @ skew(arms)
    A = A.reshape(3 * n, 6)
    return linalg.cho_solve(linalg.cho_factor(A.T @ A), A.T)


def body_pose(belief: Gaussian, lever_arms: np.ndarray) -> BodyPose | None:
    """The follower's body state from the antenna belief, or None when the lever arms (n, 3) do not
    determine an attitude (fewer than 3 antennas, or all on one line).

    Pose by `fit_pose`, velocity and body rate by the same least squares on the antenna
    velocities; cov = J P J^T with J = blockdiag(G, G) (`pose_sensitivity`). J neglects the
    velocity fit's dependence on the attitude error (a term |omega| |dtheta| |l|, small at the
    rates of a vehicle over an array of a metre). Bias states after the 6 n antenna states are
    left out.
    """
    arms = np.asarray(lever_arms, float).reshape(-1, 3)
    n = arms.shape[0]
    if n < 3 or spanned_dimension(arms) < 2:
        return None
    x = belief.mean
    p, R = fit_pose(x[:3 * n].reshape(n, 3), arms)
    G = pose_sensitivity(R, arms)
    vw = G @ x[3 * n:6 * n]
    J = linalg.block_diag(G, G)
    return BodyPose(p, rotmat_to_quat(R), vw[:3], vw[3:], symmetrize(J @ belief.cov[:6 * n, :6 * n] @ J.T))


# ------------------------------------------------------------------------------------------------
# The paper's configuration as one instance
# ------------------------------------------------------------------------------------------------
def from_phase_measurement(meas) -> RangingEpoch:
    """A seed 003 phase_ekf.PhaseMeasurement (M masters x 3 slots x 3 antennas) as a RangingEpoch.

    Links in the order (master m, slot i, antenna j); masked or non-finite rows become NaN. With
    RangingEkf(n=3, q=RangingNoise(antenna=q)) this is the paper's filter (tests/test_ranging.py).
    """
    M = meas.n_masters
    shape = (M, 3, 3)
    X0 = np.broadcast_to(np.asarray(meas.master_pos, float)[:, :, None, :], shape + (3,)).reshape(-1, 3)
    V0 = np.broadcast_to(np.asarray(meas.master_vel, float)[:, :, None, :], shape + (3,)).reshape(-1, 3)
    r = np.array(meas.ranges, float).reshape(shape)
    rd = np.array(meas.range_rates, float).reshape(shape)
    if meas.valid_range is not None:
        r[~np.asarray(meas.valid_range, bool)] = np.nan
    if meas.valid_range_rate is not None:
        rd[~np.asarray(meas.valid_range_rate, bool)] = np.nan
    window = None if meas.rate_window is None else np.broadcast_to(np.asarray(meas.rate_window, float), shape).reshape(-1)
    return RangingEpoch(
        antenna=np.tile(np.arange(3), 3 * M), known_pos=X0, ranges=r.reshape(-1),
        sigma_range=np.broadcast_to(np.asarray(meas.sigma_range, float), shape).reshape(-1),
        range_rates=rd.reshape(-1), known_vel=V0,
        sigma_range_rate=np.broadcast_to(np.asarray(meas.sigma_range_rate, float), shape).reshape(-1),
        rate_window=window)


__all__ = [
    "BodyPose", "DEFAULT_Q", "Fix", "RangingEkf", "RangingEpoch", "RangingNoise", "body_pose", "fit_pose",
    "from_phase_measurement", "initial_belief", "known_points", "multilaterate", "pose_sensitivity",
    "process_noise", "ranging_model", "transition",
]
