"""Seed 001's factor graph over a sliding window of epochs, online (the GNSS-denied flight: docs/denied.md).

Variables: at each epoch k of the window (K <= `window` epochs, oldest first) the position p_i
(3,) m and velocity v_i (3,) m/s, world ENU, of every vehicle i's antenna (the GNSS antenna =
UWB tag), stacked vehicle-major: x_k = [p_0, v_0, p_1, v_1, ...] (6n,).
Factors (seed 001's, docs/papers.md, plus the motion between epochs that a window needs):
- GNSS fix of vehicle i at epoch k: z = p_i + n, n ~ N(0, diag(sigma^2)) (sigma (3,) m, the
  receiver's declared accuracy of that fix); no fix, no factor;
- tag-to-tag range (i, j): d = |p_i - p_j| + e, e ~ N(0, sigma_d^2); tag-to-anchor range
  (i, a): d = |p_i - a| + e, anchor a (3,) m known; Huber IRLS weights on the whitened range
  residuals when `huber` is given (NLOS ranges are long-tailed; the GNSS fixes stay Gaussian:
  a robust GNSS factor lets an estimate that has drifted away ignore the fixes that would bring
  it back, measured in the loop: 290 m of vertical error after 6 s);
- motion between epochs k and k+1 (dt s), white-noise acceleration of density q (m^2/s^3 per
  axis) about a known acceleration input: [p' - p - v dt - dp; v' - v - dv] ~ N(0, q [[dt^3/3,
  dt^2/2], [dt^2/2, dt]] (x) I3), (dp, dv) the epoch's `motion` increments (e.g. an IMU's
  acceleration integrated over the interval; none: 0, the constant-velocity model);
- the prior on the oldest epoch: the first epoch's (position sigma `init_sigma_p` about the
  fixes, GNSS-free vehicles about the mean of the fixes, velocity N(0, init_sigma_v^2); the
  centralized window starts Gauss-Newton instead from the swarm's shape found from the epoch's
  ranges and placed on its fixes, estimators.layout, where the ranges connect every vehicle: a
  start at the raw fixes can fold the swarm), later the Gaussian
  left by marginalizing the epoch that slid out (Schur complement at the current estimate).

Online: `add(epoch)` appends one epoch (warm start: the previous estimate propagated at constant
velocity), marginalizes the oldest when the window is full, and takes Gauss-Newton steps on the
window until the newest epoch's estimated distance to the optimum is below `tol` of its marginal
sigmas (`_rest`; centralized) or `max_iter`: the library's iteration, estimators.graph.lm.solve,
the agents below a batch of independent problems each with its own step halving (`_solve`,
`_Chains`); a step that no halving keeps from raising the cost stops that solve, not converged.
No look-ahead: the estimate of
epoch k uses the epochs up to k only. Cost per epoch: max_iter x (K block solves of 6n x 6n),
bounded by the window length whatever the run length (the normal matrix is block-tridiagonal in
time: motion factors link only consecutive epochs; `solve_block_tridiagonal` eliminates it forward).

Two solvers share this machinery (batched over B "agents", each with s = 6 nv states per epoch):
- `Centralized`: one agent holding every vehicle (B = 1, nv = n): the whole swarm's window;
- `Distributed`: one agent per vehicle (B = n, nv = 1), seed 001's message iteration over the
  window: in round r every vehicle broadcasts its window, its current position at every window
  epoch with a 3 x 3 covariance each (BROADCAST_BYTES = 72 bytes, 9 float64, per epoch: 360
  bytes for 5 epochs), to the vehicles it ranged with in the window; each vehicle then takes one
  Gauss-Newton step on its own window, a neighbour's broadcast position at each epoch entering
  as a prior, i.e. (Schur complement, as estimators.factor_graph) the neighbour fixed there with
  the range variance inflated to sigma_d^2 + u^T Sigma_j u (u taken at the round's start and held
  through its step: `_weigh`). Rounds stop when every newest position moved less than `tol` (its
  largest component) or at `max_rounds`, or when a step diverges: the library's round iteration,
  estimators.graph.lm.iterate_rounds. A message travels through an estimators.transport.Transport (None: ideal); what
  a vehicle last received from a neighbour is what its ranges use, at every epoch of the window.
  Broadcasting only the newest epoch, each older epoch's ranges kept the neighbour's position as
  first heard while the vehicle's own state there moved on: the swarm's common position drifted
  (measured offline on a coop-denied log, docs/denied.md "Flying on the distributed window
  cascade": the swarm's mean vertical error ran to -3 m in 20 s; with the window broadcast
  0.31 m RMS vertical over 60 s, the centralized window 0.28 m).
  The start (the first epoch): round 0 is one exchange, every vehicle broadcasting its fix and
  its ranges to the vehicles it ranged with (START_BYTES + RANGE_BYTES per range: 320 bytes for
  17 ranges); each vehicle then starts Gauss-Newton at its own place in the layout of what it
  holds (estimators.layout: the shape from the ranges, placed on the fixes), the message
  iteration from round 1. Started at its own fix (3-8 m of vertical sigma in coop-denied's
  street), each vehicle's first solve settled where its neighbours' equally rough fixes put it:
  on coop-denied seed 27 the lower layer 6-7 m high and the upper 5 m low at 0.8 s, a fold that
  no single vehicle's reflection undoes, and the swarm flown on it diverged.
  No information is counted twice: the covariance a vehicle broadcasts for an epoch is that of
  its own measurements only (GNSS, anchors, motion, its prior: its window solved without any
  range to a neighbour, when that epoch was the newest), and its marginalization prior keeps only
  those (`keep_ranges`). Broadcasting the full local marginal instead (which holds what the
  neighbours told it) makes the covariances collapse round after round and epoch after epoch
  and the swarm's common position lag: on tests/test_window.py's synthetic swarm the RMS error
  grew 2.4 m -> 7.4 m over 15 epochs, against 1.0-1.2 m with the own-measurement broadcast
  (0.3-0.9 m centralized, 3-4 m GNSS alone); with the window broadcast, on the same coop-denied
  log, 9.7 m vertical RMS over 20 s (docs/denied.md).

Mirror images (`mirrors = True`, after each epoch's solve): ranges cannot tell a vehicle from
its reflection through the plane of the points it ranged to, and Gauss-Newton does not cross from
one to the other (the ranges' cost rises in between). A vehicle that started on the wrong side
stays there; flown on the estimate it climbs to correct an error it does not have, which the
reflection turns into a larger error, and so on (coop-denied seed 27, centralized cascade,
docs/denied.md "The window's start": 130 m of vertical error at 4 s). Each vehicle's trajectory over the window (and its part of the
prior, info T Lambda T, so that the prior's cost does not change) is reflected through the plane
fitted at each epoch to the neighbours it ranged to in the window (as it sees them: the current
estimate centralized, the last broadcasts distributed) and the anchors; the reflection is kept
when the window's cost falls by more than MIRROR_LOG_RATIO (its GNSS fixes and ranges off the
plane decide). Centralized: vehicle by vehicle; distributed: every vehicle at once (each
vehicle's cost is its own). The centralized window first tests each group of vehicles linked by
ranges reflected as a whole, through its middle plane at each epoch (through its mean, normal to
its direction of least extent): any reflection of the whole group keeps every range among
them, and this one moves the vehicles least, so only the GNSS fixes and anchors can refuse it.
The distributed window does not: no vehicle sees the group's cost. Since the window starts from
the swarm's shape (estimators.layout, and the distributed start exchange below) the test has not
fired in any flight measured (docs/denied.md); it stays as a guard, `mirrors = False` to turn it
off. The centralized vehicle-by-vehicle test is screened by every vehicle's cost change computed
at once (`_Window._alone`), and runs one by one only from the first vehicle the screen passes.

Tracklets (`tracklets = True`): each estimate also carries the newest epoch's position marginal
and the window's own prediction of it without that epoch's factors; `equivalent_measurement`
turns the pair into the epoch's new information (information-form difference), what a filter
fed every epoch should take to count no measurement twice (testbed.plugins.builtin_window_ins,
decorrelate).

Built on the graph library (estimators.graph): its range and motion factors (graph.factors), the
Huber loss (graph.losses), the block-tridiagonal solve and normal equations (graph.linear) and its
iterations (graph.lm): every estimate carries the lm Report of its iteration. Never imports mujoco
or testbed.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import linalg, sparse
from scipy.sparse import csgraph

from estimators import layout, window_delays
from estimators.graph import lm
from estimators.graph.factors import inflated_range_variance, motion_blocks, motion_input_blocks, range_terms
from estimators.graph.linear import BlockTridiagonalNormals, solve_block_tridiagonal
from estimators.graph.losses import huber_rho, huber_weight
from estimators.transport import Transport

__all__ = ["Epoch", "WindowEstimate", "Centralized", "Distributed", "BROADCAST_BYTES", "equivalent_measurement"]

HALVINGS = 8  # trials per Gauss-Newton step: the full step, then halved while the cost rises (7 halvings)
# the relative round-off of the window's cost: its motion terms are summed as 0.5 x^T M x - g^T x
# over positions of tens of metres, terms of ~1e4 that cancel to ~1 (measured: ~1e-12 absolute
# noise on costs of ~20, where a plain sum of squares has lm.ROUNDOFF)
COST_ROUNDOFF = 1e-12

# a vehicle's mirror image (`_Window._mirrors`) replaces it when the window's cost there is lower
# by more than this: the measurements at least 100 times likelier (cost = -log likelihood + const)
MIRROR_LOG_RATIO = float(np.log(100.0))
# the batched screen of the centralized test (`_Window._alone`) passes a vehicle whose cost change
# is within this much of the threshold, relative to the window's cost (the screen and the test sum
# the same terms in another order: they differ by rounding, far below this)
MIRROR_SCREEN = 1e-6

BROADCAST_BYTES = 72  # per window epoch: position (3 float64) + the 6 unique covariance entries (6 float64)
START_BYTES = 48  # the distributed start message: the sender's fix and its sigma (6 float64) ...
RANGE_BYTES = 16  # ... and per range it measured: the other end (int64) and the range (float64)


@dataclass(frozen=True, kw_only=True, slots=True)
class Epoch:
    """The measurements of one epoch (time t, s) of n vehicles.

    fix (n, 3) m world, NaN rows where the vehicle has no fix; fix_sigma (n, 3) m (1 sigma, east,
    north, up); edges (m, 2) vehicle indices and ranges, range_sigma (m,) m: tag-to-tag ranges;
    anchor_vehicle (a,) vehicle index, anchor_pos (a, 3) m world, anchor_range, anchor_sigma
    (a,) m: tag-to-anchor ranges; motion (n, 6) the known motion of each vehicle since the window's
    previous epoch, [dp (m), dv (m/s)] world: the acceleration integrated once (dv) and twice (dp)
    over the interval (None: none, the motion factor's mean is constant velocity); anchor_device
    (a,) the UWB device index of each anchor range's anchor (tags: the vehicle index; None: no
    antenna-delay model, estimators.window_delays).
    """

    t: float
    fix: np.ndarray
    fix_sigma: np.ndarray
    edges: np.ndarray
    ranges: np.ndarray
    range_sigma: np.ndarray
    anchor_vehicle: np.ndarray
    anchor_pos: np.ndarray
    anchor_range: np.ndarray
    anchor_sigma: np.ndarray
    motion: np.ndarray | None = None
    anchor_device: np.ndarray | None = None


@dataclass(frozen=True, kw_only=True, slots=True)
class WindowEstimate:
    """The newest epoch's estimate: time t (s); pos, vel (n, 3) m, m/s world; pos_cov, vel_cov
    (n, 3, 3) marginal covariances; iterations (GN steps or rounds); converged; mirrored
    (vehicles replaced by their mirror image at this epoch, module docstring); messages,
    bytes_sent (distributed broadcasts, 0 centralized); tracklet (with `tracklets` on: the newest
    position marginal and the window's prediction of it, `_Window._tracklet`; else None); report:
    the estimators.graph.lm Report of the epoch's iteration (centralized: its last Gauss-Newton
    solve, the one after the mirror test when a vehicle was mirrored, iterations then counting
    both; distributed: its rounds)."""

    t: float
    pos: np.ndarray
    vel: np.ndarray
    pos_cov: np.ndarray
    vel_cov: np.ndarray
    iterations: int
    converged: bool
    mirrored: int = 0
    messages: int = 0
    bytes_sent: int = 0
    tracklet: tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray] | None = None
    report: lm.Report | None = None


def equivalent_measurement(m: np.ndarray, P: np.ndarray, m_pred: np.ndarray, P_pred: np.ndarray,
                           min_info: float = 1e-4) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The new information of an epoch as one measurement of the state (the "equivalent
    measurement" or tracklet decorrelation): a marginal N(m, P) that already holds what the
    prediction N(m_pred, P_pred) held, minus that prediction.

    Information form: Lambda = P^-1 - P_pred^-1, eta = P^-1 m - P_pred^-1 m_pred; the measurement
    z = Lambda^-1 eta = m + Lambda^-1 P_pred^-1 (m - m_pred) with covariance R = Lambda^-1. Fed to a
    filter that already holds the prediction's information, it adds only the epoch's.
    Lambda is projected onto its directions of information above min_info (1 / unit^2): an
    eigenvalue below is raised to min_info (that direction carries essentially nothing).
    Batched: m, m_pred (n, d), P, P_pred (n, d, d). Returns z (n, d), R (n, d, d) and full (n,)
    bool: every eigenvalue of Lambda was above min_info (nothing projected)."""
    eye = np.broadcast_to(np.eye(m.shape[-1]), P.shape)
    Ip, Ipp = np.linalg.solve(P, eye), np.linalg.solve(P_pred, eye)
    lam = Ip - Ipp
    w, V = np.linalg.eigh(0.5 * (lam + np.swapaxes(lam, 1, 2)))
    full = (w > min_info).all(axis=1)
    R = (V / np.maximum(w, min_info)[:, None, :]) @ np.swapaxes(V, 1, 2)
    z = m + np.einsum("nij,nj->ni", R @ Ipp, m - m_pred)
    return z, 0.5 * (R + np.swapaxes(R, 1, 2)), full


class _Terms:
    """The terms `_Window._intra` adds, each kind of factor given for every window epoch at once,
    summed at the end in the order the factors come epoch by epoch: within epoch k, kind 0
    (GNSS) before 1 (anchor ranges) before 2, 3, .. (the tag-to-tag ranges' parts, `_ranges`),
    each kind's rows in their order. Every entry of the blocks, right-hand sides and costs so
    receives its terms in one fixed order, whatever the batching (`_added` adds one after the
    other). where: the window's `_where` (vehicle -> agent, slot)."""

    __slots__ = ("cost_only", "where", "parts")

    def __init__(self, cost_only: bool, where):
        self.cost_only, self.where, self.parts = cost_only, where, []

    def add(self, kind: int, k: np.ndarray, i: np.ndarray, j: np.ndarray, H3: np.ndarray | None = None,
            g3: np.ndarray | None = None, cost: np.ndarray | None = None) -> None:
        """Rows (m,) at epochs k of vehicles i: H3 (m, 3, 3) to the position block (i, j) (j of
        i's agent), g3 (m, 3) to i's right-hand side, cost (m,) to its agent's cost (None: none)."""
        self.parts.append((kind, k, i, j, H3, g3, cost))

    @staticmethod
    def _added(size: int, rows: np.ndarray, values: np.ndarray) -> np.ndarray:
        """(size, *values.shape[1:]): zeros with values (m, ...) added at rows (m,), one after the
        other in their order (np.bincount over the flat entries: what np.add.at on zeros gives,
        in a third of its time)."""
        width = int(np.prod(values.shape[1:], dtype=np.int64))
        flat = (rows[:, None] * width + np.arange(width)).ravel()
        return np.bincount(flat, values.reshape(-1), minlength=size * width).reshape(size, *values.shape[1:])

    def sum(self, B: int, K: int, nv: int) -> tuple[np.ndarray | None, np.ndarray | None, np.ndarray]:
        """(Hpp (B, K, nv, nv, 3, 3), Rp (B, K, nv, 3), C (B,)); (None, None, C) cost-only."""

        def gather(n: int) -> tuple | None:
            parts = [p for p in self.parts if p[n] is not None]
            if not parts:
                return None
            key = np.concatenate([p[1] * 8 + p[0] for p in parts])
            order = np.argsort(key, kind="stable")  # epoch by epoch, kind by kind, rows in order
            cat = [np.concatenate([p[c] for p in parts])[order] for c in (1, 2, 3, n)]
            return (*cat[:3], cat[3])

        C = np.zeros(B)
        got = gather(6)
        if got is not None:
            np.add.at(C, self.where(got[1])[0], got[3])  # one index: add.at's fast path
        if self.cost_only:
            return None, None, C
        Hpp, Rp = np.zeros((B, K, nv, nv, 3, 3)), np.zeros((B, K, nv, 3))
        got = gather(4)
        if got is not None:
            k, i, j, H3 = got
            a, li = self.where(i)
            Hpp = self._added(B * K * nv * nv, ((a * K + k) * nv + li) * nv + self.where(j)[1], H3).reshape(Hpp.shape)
        got = gather(5)
        if got is not None:
            k, i, _, g3 = got
            a, li = self.where(i)
            Rp = self._added(B * K * nv, (a * K + k) * nv + li, g3).reshape(Rp.shape)
        return Hpp, Rp, C


class _Window:
    """Common machinery (module docstring): agents, slots, window bookkeeping, motion, solve.

    Subclasses define the agent layout (`agent`, `slot` of each vehicle) and `_ranges` (how the
    tag-to-tag ranges enter)."""

    def __init__(self, n: int, *, agents: int, per_agent: int, window: int, q: float, huber: float | None,
                 max_iter: int, tol: float, init_sigma_p: float, init_sigma_v: float):
        if window < 2:
            raise ValueError(f"window must be at least 2 epochs (the newest and the one it moves from), got {window}")
        if q <= 0:
            raise ValueError(f"q (acceleration density, m^2/s^3) must be positive, got {q}")
        self.n, self.B, self.nv, self.s = n, agents, per_agent, 6 * per_agent
        self.window, self.q, self.huber, self.max_iter, self.tol = int(window), float(q), huber, int(max_iter), float(tol)
        self.init_sigma_p, self.init_sigma_v = float(init_sigma_p), float(init_sigma_v)
        self.epochs: list[Epoch] = []
        self.X = np.zeros((self.B, 0, self.s))  # (B, K, s) the window's estimate
        self.prior_info = np.zeros((self.B, self.s, self.s))
        self.prior_mean = np.zeros((self.B, self.s))
        self.prior_sens = None  # (B, s, D) d prior_mean / d antenna delays (Centralized with delay_sigma)
        self._eye = np.eye(per_agent)
        self._krons: dict[float, tuple] = {}
        self.tracklets = False  # True: each estimate carries its tracklet (`_tracklet`, one more solve)
        self.mirrors = True  # test each vehicle's mirror image after the solve (module docstring)
        self.lin = (None, None)  # (X, the normal equations at X) of the last `_solve`
        self._rows_cache = None  # `_rows`'s
        self._inputs: dict = {}  # `_input`'s parts of each epoch pair: {id(epoch k + 1): (epoch k, epoch k + 1, g0, g1, quad)}

    def _motion(self, k: int) -> tuple:
        """(M00, M01, M11) of the motion factor between window epochs k, k+1 and the same blocks
        for the agent's nv vehicles, kron(I_nv, M) (s, s), cached per interval."""
        dt = self.epochs[k + 1].t - self.epochs[k].t
        if dt not in self._krons:
            M = motion_blocks(dt, self.q)
            self._krons[dt] = M + tuple(np.kron(self._eye, m) for m in M)
        return self._krons[dt]

    def _input(self, k: int, x0: np.ndarray, x1: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
        """The known-input terms of the motion factor between window epochs k, k+1 (Epoch.motion of
        epoch k + 1) at the states x0, x1 (B, nv, 6): right-hand sides g0, g1 (B, s) to add to those
        of epochs k, k+1 and the cost (B,) to add; None without an input."""
        e0, e1 = self.epochs[k], self.epochs[k + 1]
        if e1.motion is None:
            return None
        kept = self._inputs.get(id(e1))
        if kept is None or kept[0] is not e0 or kept[1] is not e1:  # the parts that do not depend on x0, x1
            G0, G1, W = motion_input_blocks(e1.t - e0.t, self.q)
            a, l = self._where(np.arange(self.n))
            U = np.zeros((self.B, self.nv, 6))
            U[a, l] = e1.motion
            kept = (e0, e1, U @ G0.T, U @ G1.T, 0.5 * np.einsum("bvi,ij,bvj->b", U, W, U))
            live = {id(e) for e in self.epochs}
            self._inputs = {i: v for i, v in self._inputs.items() if i in live} | {id(e1): kept}
        _, _, g0, g1, quad = kept
        cost = quad - np.einsum("bvi,bvi->b", g0, x0) - np.einsum("bvi,bvi->b", g1, x1)
        return g0.reshape(self.B, self.s), g1.reshape(self.B, self.s), cost

    # index of each vehicle's first state in (agent, slot) layout
    def _where(self, i: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        raise NotImplementedError

    def _ranges(self, P: np.ndarray, ks: list[int], tags: tuple, sys: _Terms) -> None:
        """Add the tag-to-tag ranges tags of window epochs ks (`_rows`) at positions P (K, n, 3)
        to sys (kinds 2, 3, ..)."""
        raise NotImplementedError

    def _view(self, k: int) -> tuple[np.ndarray, np.ndarray]:
        """Where each vehicle i takes each vehicle j to be at window epoch k: (n, n, 3) m and
        (n, n) bool (whether i has a position for j)."""
        raise NotImplementedError

    # ------------------------------------------------------------------ mirror images
    def _mirrors(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Each vehicle's mirror through the plane of what it ranged to (module docstring): ok
        (n,) bool (a plane at every window epoch: at least 3 points), c (n, K, 3) m a point of
        the plane at each epoch, H (n, K, 3, 3) the reflection I - 2 nu nu^T (nu its normal)."""
        n, K = self.n, len(self.epochs)
        tags = np.zeros((n, n), bool)  # tags[i, j]: i ranged to j in the window
        anchors = [[] for _ in range(n)]
        for ep in self.epochs:
            tags[ep.edges[:, 0], ep.edges[:, 1]] = True
            tags[ep.edges[:, 1], ep.edges[:, 0]] = True
            for i, a in zip(ep.anchor_vehicle.tolist(), ep.anchor_pos):
                anchors[i].append(a)
        fixed = [np.unique(np.reshape(a, (-1, 3)), axis=0) for a in anchors]
        A = max(len(f) for f in fixed)
        pts = np.zeros((n, K, n + A, 3))  # per vehicle and epoch: the neighbours as it sees them, then its anchors
        mask = np.zeros((n, K, n + A), bool)
        for k in range(K):
            pos, has = self._view(k)
            pts[:, k, :n], mask[:, k, :n] = pos, has & tags
        for i, f in enumerate(fixed):
            pts[i, :, n:n + len(f)], mask[i, :, n:n + len(f)] = f, True
        ok = (mask.sum(axis=2) >= 3).all(axis=1)
        c, H = layout.mirror_plane(pts, mask)
        return ok, c, H

    def _reflect(self, which: np.ndarray, c: np.ndarray, H: np.ndarray) -> None:
        """Replace the vehicles `which` (m,) by their mirror images (c, H of `_mirrors`): positions
        and velocities at every window epoch, and their part of the prior (mean reflected, info
        T Lambda T with T the reflection of their blocks: the prior's cost unchanged)."""
        a, l = self._where(which)
        K = self.X.shape[1]
        Xv = self.X.reshape(self.B, K, self.nv, 6).copy()
        Hm, cm = H[which], c[which]  # (m, K, 3, 3), (m, K, 3)
        Xv[a, :, l, :3] = cm + np.einsum("mkij,mkj->mki", Hm, Xv[a, :, l, :3] - cm)
        Xv[a, :, l, 3:] = np.einsum("mkij,mkj->mki", Hm, Xv[a, :, l, 3:])
        self.X = Xv.reshape(self.B, K, self.s)
        pm = self.prior_mean.reshape(self.B, self.nv, 6).copy()
        H0, c0 = Hm[:, 0], cm[:, 0]
        pm[a, l, :3] = c0 + np.einsum("mij,mj->mi", H0, pm[a, l, :3] - c0)
        pm[a, l, 3:] = np.einsum("mij,mj->mi", H0, pm[a, l, 3:])
        self.prior_mean = pm.reshape(self.B, self.s)
        # T Lambda T, T the identity but H0 on each reflected vehicle's position and velocity
        # blocks (H0 symmetric): its rows of Lambda times H0 from the left, then its columns from
        # the right; no (s, s) product (the other rows and columns are Lambda's)
        L = self.prior_info.reshape(self.B, self.nv, 2, 3, self.nv, 2, 3).copy()
        L[a, l] = np.einsum("mij,mpjvqk->mpivqk", H0, L[a, l])
        L[a, :, :, :, l] = np.einsum("mvpiqk,mjk->mvpiqj", L[a, :, :, :, l], H0)
        self.prior_info = L.reshape(self.B, self.s, self.s)
        if self.prior_sens is not None:  # the prior mean's antenna-delay sensitivity, reflected with it: T J
            J = self.prior_sens.reshape(self.B, self.nv, 2, 3, -1).copy()
            J[a, l] = np.einsum("mij,mpjd->mpid", H0, J[a, l])
            self.prior_sens = J.reshape(self.prior_sens.shape)

    def _kept(self, which: np.ndarray, c: np.ndarray, H: np.ndarray, cost: np.ndarray) -> np.ndarray | None:
        """One agent (B = 1): reflect the vehicles `which` together (`_reflect`); keep it and
        return the new cost where the cost falls by more than MIRROR_LOG_RATIO, else undo, None."""
        saved = self.X, self.prior_mean, self.prior_info, self.prior_sens
        self._reflect(which, c, H)
        new = self._system(cost_only=True)[3]
        if new[0] < cost[0] - MIRROR_LOG_RATIO:
            return new
        self.X, self.prior_mean, self.prior_info, self.prior_sens = saved
        return None

    def _alone(self, ok: np.ndarray, c: np.ndarray, H: np.ndarray) -> np.ndarray:
        """The centralized window's (B = 1) mirror test batched: (n,) the change of the swarm's
        cost when vehicle i alone is replaced by its mirror image (c, H of `_mirrors`), for every
        vehicle with ok (n,) at once (0 elsewhere). Only vehicle i's own factors change (its
        fixes, anchor ranges, ranges to the others at their current positions, motion; the
        prior's cost does not, `_reflect`), and those are the cost of agent i of a Distributed
        window that holds every other vehicle at the current estimate as an exact broadcast (no
        covariance) and no prior: one cost evaluation of that view before and one after
        reflecting all of them. It screens the vehicle-by-vehicle test (`_mirror`): the same
        numbers up to rounding, so the test starts at the first vehicle within MIRROR_SCREEN of
        the threshold and runs as before from there."""
        K, n = self.X.shape[1], self.n
        view = Distributed(n, window=self.window, q=self.q, huber=self.huber)
        view.epochs = list(self.epochs)
        view.X = self.X.reshape(K, n, 6).transpose(1, 0, 2).copy()  # (n, K, 6): one agent per vehicle
        view.prior_info, view.prior_mean = np.zeros((n, 6, 6)), np.zeros((n, 6))
        P = self._pos()
        view.heard_pos = [np.broadcast_to(P[k], (n, n, 3)) for k in range(K)]
        view.heard = [np.ones((n, n), bool)] * K
        view.range_sigma = [np.stack([ep.range_sigma, ep.range_sigma]) for ep in self.epochs]
        before = view._system(cost_only=True)[3]
        view._reflect(np.flatnonzero(ok), c, H)
        return np.where(ok, view._system(cost_only=True)[3] - before, 0.0)

    def _groups(self) -> list[np.ndarray]:
        """The vehicles linked by tag-to-tag ranges anywhere in the window: one (m,) index array
        per connected group."""
        edges = np.concatenate([e.edges for e in self.epochs]).reshape(-1, 2)
        graph = sparse.coo_matrix((np.ones(len(edges)), (edges[:, 0], edges[:, 1])), shape=(self.n, self.n))
        _, label = csgraph.connected_components(graph, directed=False)
        return [np.flatnonzero(label == g) for g in np.unique(label)]

    def _mirror(self) -> int:
        """Replace vehicles by their mirror images where that lowers the window's cost by more
        than MIRROR_LOG_RATIO (module docstring). Returns how many were replaced."""
        kept = 0
        cost = self._system(cost_only=True)[3]
        if self.B == 1:  # first each ranged group as a whole, through its own middle plane
            P = self._pos()
            for g in self._groups():
                if len(g) < 4:
                    continue  # three points or fewer lie in a plane: reflected, they do not move
                c, H = layout.mirror_plane(P[:, g])  # (K, 3), (K, 3, 3): its middle plane at each epoch
                new = self._kept(g, np.broadcast_to(c, (self.n, *c.shape)), np.broadcast_to(H, (self.n, *H.shape)), cost)
                if new is not None:
                    cost, kept = new, kept + len(g)
        ok, c, H = self._mirrors()
        if not ok.any():
            return kept
        if self.B == 1:  # one cost for the swarm: vehicle by vehicle, from the first the screen passes
            alone = self._alone(ok, c, H)
            near = np.flatnonzero(alone < -MIRROR_LOG_RATIO + MIRROR_SCREEN * max(1.0, abs(float(cost[0]))))
            for i in np.flatnonzero(ok & (np.arange(self.n) >= near[0])) if near.size else ():
                new = self._kept(np.array([i]), c, H, cost)
                if new is not None:
                    cost, kept = new, kept + 1
            return kept
        saved = self.X, self.prior_mean, self.prior_info  # one agent per vehicle: all at once
        self._reflect(np.flatnonzero(ok), c, H)
        better = self._system(cost_only=True)[3] < cost - MIRROR_LOG_RATIO
        keep = better[:, None]
        self.X = np.where(keep[:, :, None], self.X, saved[0])
        self.prior_mean = np.where(keep, self.prior_mean, saved[1])
        self.prior_info = np.where(keep[:, :, None], self.prior_info, saved[2])
        return int(better.sum())

    # ------------------------------------------------------------------ assembly
    def _pos(self) -> np.ndarray:
        """(K, n, 3) positions of every vehicle at every window epoch."""
        K = self.X.shape[1]
        a, l = self._where(np.arange(self.n))
        return self.X.reshape(self.B, K, self.nv, 6)[a, :, l, :3].transpose(1, 0, 2)

    def _point(self, sys: "_Terms", kind: int, k: np.ndarray, i: np.ndarray, u: np.ndarray, r: np.ndarray,
               sigma: np.ndarray, count: bool = True) -> np.ndarray | None:
        """Rows of a factor on vehicle i's position at epochs k (m,) with residual r (m,) = z - h,
        dh/dp_i = u (m, 3), 1-sigma sigma (m,): D += w u u^T, R += w u r, cost += rho(r / sigma)
        (Huber on `huber`), w the IRLS weight / sigma^2 (count False: the cost is counted by the
        other end); kind: the factor's place among an epoch's (`_Terms`). Returns w (m,); None
        for a cost-only sys (no block assembled: the mirror test's and line search's cost, the
        same numbers)."""
        s = r / sigma
        if sys.cost_only:
            if count:
                sys.add(kind, k, i, i, cost=huber_rho(s, self.huber))
            return None
        w = huber_weight(s, self.huber) / sigma ** 2
        sys.add(kind, k, i, i, w[:, None, None] * u[:, :, None] * u[:, None, :], (w * r)[:, None] * u,
                huber_rho(s, self.huber) if count else None)
        return w

    def _rows(self, ks: list[int]) -> tuple:
        """The measurements of window epochs ks, each kind's rows of every epoch one after the
        other (epoch by epoch, in each epoch's order), with the epoch k of each row: GNSS (k, vehicle,
        fix (m, 3), weight sigma^-2 (m, 3), its information block (m, 3, 3)); anchor ranges (k,
        vehicle, anchor (m, 3), range, sigma); tag-to-tag ranges (k, edges (m, 2), range, sigma).
        Cached while the window holds the same epochs."""
        eps = [self.epochs[k] for k in ks]
        if self._rows_cache is not None:  # the same epochs (the objects, kept alive here) at the same places
            kept, kept_ks, rows = self._rows_cache
            if kept_ks == ks and all(a is b for a, b in zip(kept, eps)):
                return rows

        def cat(parts, shape=()):
            return np.concatenate(parts) if parts else np.zeros((0, *shape))

        has = [np.flatnonzero(~np.isnan(ep.fix[:, 0])) for ep in eps]
        w = [ep.fix_sigma[h] ** -2.0 for ep, h in zip(eps, has)]  # per epoch, as each epoch's own rows
        gnss = (cat([np.full(len(h), k) for k, h in zip(ks, has)]).astype(np.int64), cat(has).astype(np.int64),
                cat([ep.fix[h] for ep, h in zip(eps, has)], (3,)), cat(w, (3,)), cat([x[:, :, None] * np.eye(3) for x in w], (3, 3)))
        anchors = (cat([np.full(len(ep.anchor_vehicle), k) for k, ep in zip(ks, eps)]).astype(np.int64),
                   cat([ep.anchor_vehicle for ep in eps]).astype(np.int64), cat([ep.anchor_pos for ep in eps], (3,)),
                   cat([ep.anchor_range for ep in eps]), cat([ep.anchor_sigma for ep in eps]))
        tags = (cat([np.full(len(ep.ranges), k) for k, ep in zip(ks, eps)]).astype(np.int64),
                cat([ep.edges.reshape(-1, 2) for ep in eps], (2,)).astype(np.int64), cat([ep.ranges for ep in eps]),
                cat([ep.range_sigma for ep in eps]))
        self._rows_cache = (eps, ks, (gnss, anchors, tags))
        return gnss, anchors, tags

    def _intra(self, P: np.ndarray, ranges: bool = True, newest: bool = False, cost_only: bool = False):
        """(D, R, C): diagonal blocks (B, K, s, s), right-hand sides (B, K, s) and cost (B,) of
        every factor within an epoch (prior, GNSS, anchor ranges, tag-to-tag ranges unless `ranges` is False),
        linearized at positions P (K, n, 3). Position blocks are gathered first (B, K, nv, nv, 3, 3).
        newest: the newest epoch's own factors only (no prior, the other epochs' blocks zero).
        cost_only: (None, None, C), no block assembled (the same C).
        Each kind of factor is computed for every epoch at once and the terms summed in the order
        epoch by epoch, kind by kind (`_Terms`)."""
        K, B, nv = P.shape[0], self.B, self.nv
        sys = _Terms(cost_only, self._where)
        ks = [K - 1] if newest else list(range(K))
        gnss, anchors, tags = self._rows(ks)
        k, v, fix, w, W3 = gnss
        if v.size:  # GNSS fix: least squares, diagonal (east, north, up) information
            r = fix - P[k, v]
            sys.add(0, k, v, v, W3, w * r, 0.5 * (w * r * r).sum(1))
        k, v, pos, rng, sig = anchors
        if v.size:
            dist, u = range_terms(P[k, v], pos)
            self._point(sys, 1, k, v, u, rng - dist, sig)
        if ranges and tags[0].size:
            self._ranges(P, ks, tags, sys)
        Hpp, Rp, C = sys.sum(B, K, nv)
        if cost_only:
            e0 = self.prior_mean - self.X[:, 0]
            return None, None, C + 0.5 * np.einsum("bi,bij,bj->b", e0, self.prior_info, e0)
        D = np.zeros((B, K, nv, 6, nv, 6))
        D[:, :, :, :3, :, :3] = Hpp.transpose(0, 1, 2, 4, 3, 5)
        R = np.zeros((B, K, nv, 6))
        R[..., :3] = Rp
        D, R = D.reshape(B, K, self.s, self.s), R.reshape(B, K, self.s)
        if newest:
            return D, R, C
        e0 = self.prior_mean - self.X[:, 0]
        D[:, 0] += self.prior_info
        R[:, 0] += np.einsum("bij,bj->bi", self.prior_info, e0)
        C += 0.5 * np.einsum("bi,bij,bj->b", e0, self.prior_info, e0)
        return D, R, C

    def _system(self, ranges: bool = True, cost_only: bool = False):
        """(D, U, R, C) of the whole window at the current estimate: _intra plus the motion
        factors; U (B, K-1, s, s) the blocks H[k, k+1]. cost_only: (None, None, None, C), the same
        cost (B,) without assembling the system (the mirror test, the line search's checks)."""
        D, R, C = self._intra(self._pos(), ranges, cost_only=cost_only)
        K = self.X.shape[1]
        U = None if cost_only else np.zeros((self.B, max(K - 1, 0), self.s, self.s))
        Xv = self.X.reshape(self.B, K, self.nv, 6)
        for k in range(K - 1):
            M00, M01, M11, K00, K01, K11 = self._motion(k)
            x0, x1 = Xv[:, k], Xv[:, k + 1]  # (B, nv, 6); linear factor: rhs = -M [x0; x1]
            g0, g1 = x0 @ M00.T + x1 @ M01.T, x0 @ M01 + x1 @ M11.T
            C += 0.5 * (np.einsum("bvi,bvi->b", x0, g0) + np.einsum("bvi,bvi->b", x1, g1))
            known = self._input(k, x0, x1)
            if known is not None:
                C += known[2]
            if cost_only:
                continue
            D[:, k] += K00
            D[:, k + 1] += K11
            U[:, k] = K01
            R[:, k] -= g0.reshape(self.B, self.s)
            R[:, k + 1] -= g1.reshape(self.B, self.s)
            if known is not None:
                R[:, k] += known[0]
                R[:, k + 1] += known[1]
        return D, U, R, C

    def _solve(self, max_iter: int, tol: float | None) -> tuple[lm.Report, np.ndarray]:
        """Gauss-Newton on the window from the current estimate: estimators.graph.lm.solve with the
        agents as a batch of independent problems (`_Chains`), each agent its own step halving
        (HALVINGS trials; a step that no halving keeps from raising that agent's cost is not taken
        and stops its solve); at most max_iter steps, stopped by the rule of `_rest` below tol
        (None: no rule). Returns lm's Report and S (B, s, s), the newest epoch's information of
        the last linear solve (at the start of the last step: what the estimate's covariance is).
        lm's normal equations at the result are kept as `lin` with the estimate they belong to
        (`_linearized`: the tracklet and the consider term reuse them)."""
        chains = _Chains(self, tol, max_iter)
        self.X, lin, report = lm.solve(chains, self.X, method="gn", max_iter=max_iter, step_tol=0.0, cost_tol=0.0,
                                     max_halvings=HALVINGS - 1, stop=chains.stop, roundoff=COST_ROUNDOFF)
        self.lin = (self.X, lin)
        return report, chains.S

    def _linearized(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(D, U, R) of `_system` at the current estimate: those of the last `_solve` where the
        estimate is still its result (the same numbers), else assembled."""
        X, lin = self.lin
        if X is not self.X:
            return self._system()[:3]
        return lin.D, lin.U, lin.g.reshape(lin.D.shape[:3])

    @staticmethod
    def _sigmas(full: np.ndarray, S: np.ndarray) -> float:
        """The largest full (undamped) Gauss-Newton step (B, K, s) of a newest-epoch state in
        units of that state's marginal sigma, sqrt(diag S^-1) (S (B, s, s) the newest epoch's
        information at the step's start): with S = L L^T (Cholesky), (S^-1)_jj = sum_i (L^-1)_ij^2,
        L^-1 by a triangular inversion (no general inverse)."""
        Li = np.stack([linalg.lapack.dtrtri(c, lower=1)[0] for c in np.linalg.cholesky(S)])
        sd = np.sqrt(np.einsum("bij,bij->bj", Li, Li))
        return float((np.abs(full[:, -1]) / sd).max())

    @staticmethod
    def _rest(steps: list[float]) -> float:
        """The stopping rule of a capped online solve (centralized): how far the newest epoch (the
        output) still is from the optimum, in its own sigmas, estimated from the steps so far
        (`_sigmas`, oldest first) as a linearly converging iteration's geometric rest
        s rho / (1 - rho), s the last step and rho the larger of the last two step ratios (inf
        before three steps or while rho >= 1). The solve stops when it is below `tol`.
        Why not a step in metres: the Huber weights and the ranges' curvature make the iteration
        linear (measured in the loop: rho about 1/3; on tests/test_window.py's synthetic swarm
        up to 0.9 in its weakly observed directions), so a small step alone says little, and
        1 mm against a sigma of 0.3 m is nothing a user can see (docs/denied.md, "Why the window
        reports 'not converged' in the loop")."""
        if len(steps) < 3 or min(steps[-3:-1]) <= 0:
            return np.inf
        rho = max(steps[-1] / steps[-2], steps[-2] / steps[-3])
        return steps[-1] * rho / (1.0 - rho) if rho < 1.0 else np.inf

    def _marginalize(self) -> None:
        """Drop the oldest epoch, leaving its information on the next as the prior (Schur)."""
        D, R, _ = self._intra(self._pos(), ranges=self.keep_ranges)
        A, r0 = D[:, 0], R[:, 0]
        M00, M01, M11, K00, K01, K11 = self._motion(0)
        A = A + K00
        Xv = self.X.reshape(self.B, -1, self.nv, 6)
        x0, x1 = Xv[:, 0], Xv[:, 1]
        r0 = r0 - (x0 @ M00.T + x1 @ M01.T).reshape(self.B, self.s)
        r1 = -(x0 @ M01 + x1 @ M11.T).reshape(self.B, self.s)
        known = self._input(0, x0, x1)
        if known is not None:
            r0, r1 = r0 + known[0], r1 + known[1]
        Bm = np.broadcast_to(K01, A.shape)
        AiB = np.linalg.solve(A, Bm)
        info = K11 - np.swapaxes(Bm, 1, 2) @ AiB
        info = 0.5 * (info + np.swapaxes(info, 1, 2))
        b = r1 - np.einsum("bij,bi->bj", AiB, r0)
        self._delays_marginalized(info, AiB)
        self.prior_info = info
        self.prior_mean = self.X[:, 1] + np.linalg.solve(info, b[..., None])[..., 0]
        self.epochs.pop(0)
        self.X = self.X[:, 1:]
        self._dropped()

    keep_ranges = True  # the tag-to-tag ranges of a marginalized epoch stay in the prior

    def _dropped(self) -> None:
        """Hook: the oldest epoch left the window."""

    def _delays_marginalized(self, info: np.ndarray, AiB: np.ndarray) -> None:
        """Hook: epoch 0 is being marginalized (info (B, s, s) the new prior's information, AiB
        (B, s, s) A^-1 K01 of `_marginalize`; self.prior_info still the old prior's)."""

    def _append(self, ep: Epoch, start: np.ndarray | None = None) -> None:
        """Append epoch ep with its warm start (constant-velocity prediction; first epoch: the
        initial prior, module docstring, Gauss-Newton started at `start` (n, 3) m where given and
        finite, else at the fixes)."""
        if not self.epochs:
            fix = ep.fix
            has = ~np.isnan(fix[:, 0])
            if not has.any():
                raise ValueError(f"the first epoch (t = {ep.t:g} s) has no GNSS fix: nothing fixes the window")
            p0 = np.where(has[:, None], fix, np.nanmean(fix, axis=0))
            if start is not None:
                p0 = np.where(np.isfinite(start), start, p0)
            x = np.concatenate([p0, np.zeros_like(p0)], axis=1)  # (n, 6)
            sig = np.concatenate([np.full((self.n, 3), self.init_sigma_p), np.full((self.n, 3), self.init_sigma_v)], 1)
            self.X = np.zeros((self.B, 1, self.s))
            a, l = self._where(np.arange(self.n))
            Xv = self.X.reshape(self.B, 1, self.nv, 6)
            Xv[a, 0, l] = x
            self.X = Xv.reshape(self.B, 1, self.s)
            diag = np.zeros((self.B, self.nv, 6))
            diag[a, l] = sig ** -2.0
            self.prior_info = np.stack([np.diag(d) for d in diag.reshape(self.B, self.s)])
            self.prior_mean = self.X[:, 0].copy()
        else:
            dt = ep.t - self.epochs[-1].t
            Xv = self.X[:, -1].reshape(self.B, self.nv, 6)
            pred = np.concatenate([Xv[..., :3] + dt * Xv[..., 3:], Xv[..., 3:]], axis=-1)
            if ep.motion is not None:  # the known motion: [dp, dv] on top of constant velocity
                a, l = self._where(np.arange(self.n))
                pred[a, l] += ep.motion
            self.X = np.concatenate([self.X, pred.reshape(self.B, 1, self.s)], axis=1)
        self.epochs.append(ep)

    def _tracklet(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray] | None:
        """The newest epoch's position marginal and the window's prediction of it, both linearized
        at the current estimate: (pos (n, 3), pos_cov (n, 3, 3), pred_pos, pred_pos_cov), the
        prediction being the same window without the newest epoch's own factors (its fixes and
        ranges: what the earlier epochs, their prior and the motion factor say of it). The pair
        estimators.window.equivalent_measurement turns into the epoch's new information. None
        while the window holds one epoch (nothing predicts it)."""
        if self.X.shape[1] < 2:
            return None
        D, U, R = self._linearized()
        Dn, Rn, _ = self._intra(self._pos(), newest=True)
        delta, S = solve_block_tridiagonal(D, U, R)
        delta_p, S_p = solve_block_tridiagonal(D - Dn, U, R - Rn)
        pos, _, pc, _ = self._newest(S, delta[:, -1])
        pred, _, ppc, _ = self._newest(S_p, delta_p[:, -1])
        return pos, pc, pred, ppc

    def _newest(self, S: np.ndarray, step: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """pos, vel (n, 3), pos_cov, vel_cov (n, 3, 3) of the newest epoch (S its information;
        step (B, s): a Gauss-Newton step of the newest epoch to add to the current estimate)."""
        a, l = self._where(np.arange(self.n))
        Xn = self.X[:, -1] if step is None else self.X[:, -1] + step
        Xv = Xn.reshape(self.B, self.nv, 6)[a, l]
        C = np.linalg.solve(S, np.broadcast_to(np.eye(self.s), S.shape))
        C = C.reshape(self.B, self.nv, 6, self.nv, 6)[a, l, :, l, :]  # (n, 6, 6)
        return Xv[:, :3], Xv[:, 3:], C[:, :3, :3], C[:, 3:, 3:]


class _Chains:
    """The window's agents as a batch of B independent problems for estimators.graph.lm.solve:
    x the window's estimate X (B, K, s), their cost and normal equations those of
    `_Window._system` (block-tridiagonal, linear.BlockTridiagonalNormals), retraction x + delta.
    `stop` is lm's caller test: the centralized rule of `_Window._rest` below tol (None: never),
    and it keeps S of the last linear solve.

    A trial point's normal equations are needed only if another step may follow it: the trials
    of the last step lm can take (max_iter steps, or `stop` said converged) are evaluated for
    their cost alone (`_Window._system(cost_only=True)`, the same number) and their normal
    equations (which lm hands back, unused by the window) are built only if asked for
    (`_Deferred`). Every other evaluation builds the system and passes it on as lm's memo."""

    def __init__(self, win: _Window, tol: float | None, max_iter: int):
        self.win, self.size, self.tol, self.max_iter = win, win.B, tol, max_iter
        self.steps: list[float] = []  # each step's `_Window._sigmas`
        self.S = None
        self.taken = 0  # steps lm has solved for (one `stop` call each)
        self.last = False  # the step being tried is the last lm can take

    def evaluate(self, x: np.ndarray) -> tuple[np.ndarray, tuple | None]:
        self.win.X = x
        if self.last:
            return self.win._system(cost_only=True)[3], None
        D, U, R, C = self.win._system()
        return C, (D, U, R)

    def normal(self, x: np.ndarray, memo: tuple | None) -> BlockTridiagonalNormals:
        if memo is not None:
            return BlockTridiagonalNormals(*memo)
        return _Deferred(self, x)

    def build(self, x: np.ndarray) -> BlockTridiagonalNormals:
        """The normal equations at x (sets the window's estimate to x)."""
        self.win.X = x
        return BlockTridiagonalNormals(*self.win._system()[:3])

    @staticmethod
    def retract(x: np.ndarray, delta: np.ndarray) -> np.ndarray:
        return x + delta.reshape(x.shape)

    @staticmethod
    def select(mask: np.ndarray, a: np.ndarray, b: np.ndarray) -> np.ndarray:
        return np.where(mask[:, None, None], a, b)

    def stop(self, delta: np.ndarray, lin: BlockTridiagonalNormals) -> np.ndarray:
        """The full step delta (B, K s) solved from lin: converged (B,) by `_Window._rest`."""
        self.S = lin.S
        self.taken += 1
        if self.tol is None:
            done = np.zeros(self.size, bool)
        else:
            self.steps.append(self.win._sigmas(delta.reshape(self.win.X.shape), lin.S))
            done = np.full(self.size, self.win._rest(self.steps) <= self.tol)
        self.last = self.taken >= self.max_iter or bool(done.all())
        return done


class _Deferred:
    """The normal equations at x of `_Chains`, built on first use (`_Chains.build`); `where`
    with every entry of mask True is itself, unbuilt (lm's last accepted step)."""

    __slots__ = ("_chains", "_x", "_lin")

    def __init__(self, chains: _Chains, x: np.ndarray):
        self._chains, self._x, self._lin = chains, x, None

    def _built(self) -> BlockTridiagonalNormals:
        if self._lin is None:
            X = self._chains.win.X
            self._lin = self._chains.build(self._x)
            self._chains.win.X = X
        return self._lin

    def where(self, mask: np.ndarray, other) -> BlockTridiagonalNormals:
        return self if mask.all() else self._built().where(mask, other)

    def __getattr__(self, name: str):
        if name.startswith("_"):  # a slot not yet set (copy, pickle) or a special name: not the system's
            raise AttributeError(name)
        return getattr(self._built(), name)


class Centralized(_Window):
    """The swarm's sliding window solved as one graph (module docstring). tol: the stopping rule's
    sigmas of the newest epoch's estimated distance to the optimum (`_rest`)."""

    def __init__(self, n: int, *, window: int = 5, q: float = 1.0, huber: float | None = None, max_iter: int = 10,
                 tol: float = 0.01, init_sigma_p: float = 1e3, init_sigma_v: float = 10.0, delay_sigma: float = 0.0,
                 devices: int = 0):
        super().__init__(n, agents=1, per_agent=n, window=window, q=q, huber=huber, max_iter=max_iter, tol=tol,
                         init_sigma_p=init_sigma_p, init_sigma_v=init_sigma_v)
        # the antenna delays as consider parameters (estimators.window_delays): 1-sigma (m) of each
        # of `devices` UWB devices' delay (0: none; the ranges' sigmas then hold them, if at all)
        self.delay_sigma, self.devices = float(delay_sigma), int(devices)

    def _delays_marginalized(self, info, AiB):
        if self.delay_sigma > 0:  # eq. wd. 3
            G0 = self.prior_info[0] @ self.prior_sens[0] + window_delays.delay_gradient(
                self._pos()[0], self.epochs[0], self.devices, self.huber)
            self.prior_sens = window_delays.marginal_sensitivity(info[0], AiB[0], G0)[None]

    def _consider(self, pc: np.ndarray, vc: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The newest epoch's position and velocity covariances pc, vc (n, 3, 3) with the antenna
        delays' term sigma_b^2 J J^T added (eq. wd. 1; unchanged without delay_sigma)."""
        if self.delay_sigma <= 0:
            return pc, vc
        D, U, _ = self._linearized()
        P = self._pos()
        G = np.stack([window_delays.delay_gradient(P[k], ep, self.devices, self.huber) for k, ep in enumerate(self.epochs)])
        G[0] += self.prior_info[0] @ self.prior_sens[0]
        J = window_delays.newest_sensitivity(D[0], U[0], G).reshape(self.n, 6, self.devices)
        C = self.delay_sigma ** 2 * J @ np.swapaxes(J, 1, 2)  # (n, 6, 6)
        return pc + C[:, :3, :3], vc + C[:, 3:, 3:]

    def _where(self, i):
        return np.zeros_like(i), i

    def _view(self, k):
        P = self._pos()[k]
        return np.broadcast_to(P, (self.n, *P.shape)), np.ones((self.n, self.n), bool)

    def _ranges(self, P, ks, tags, sys):
        k, edges, d, sigma = tags
        i, j = edges[:, 0], edges[:, 1]
        dist, u = range_terms(P[k, i], P[k, j])
        r = d - dist
        w = self._point(sys, 2, k, i, u, r, sigma)
        if w is None:
            return  # cost only: counted once, at end i
        self._point(sys, 3, k, j, -u, r, sigma, count=False)
        uu = w[:, None, None] * u[:, :, None] * u[:, None, :]  # cross blocks of the pair: -w u u^T
        sys.add(4, k, i, j, -uu)
        sys.add(5, k, j, i, -uu)

    def add(self, ep: Epoch) -> WindowEstimate:
        """Append epoch ep (time-ordered), slide, solve; the newest epoch's estimate."""
        if self.epochs and ep.t <= self.epochs[-1].t:
            raise ValueError(f"epochs must be added in time order: t = {ep.t:g} s after {self.epochs[-1].t:g} s")
        if len(self.epochs) == self.window:
            self._marginalize()
        start = None if self.epochs else layout.start_positions(
            ep.fix, ep.fix_sigma, ep.edges, ep.ranges, ep.range_sigma, ep.anchor_vehicle, ep.anchor_pos, ep.anchor_range,
            ep.anchor_sigma)
        self._append(ep, start)  # the first epoch from the swarm's shape (estimators.layout)
        if self.prior_sens is None and self.delay_sigma > 0:  # the first prior: wide, moved by no delay
            self.prior_sens = np.zeros((1, self.s, self.devices))
        report, S = self._solve(self.max_iter, self.tol)
        it = int(report.iterations[0])
        mirrored = self._mirror() if self.mirrors else 0
        if mirrored:  # solve again from the mirror images
            report, S = self._solve(self.max_iter, self.tol)
            it += int(report.iterations[0])
        pos, vel, pc, vc = self._newest(S)
        pc, vc = self._consider(pc, vc)
        return WindowEstimate(t=ep.t, pos=pos, vel=vel, pos_cov=pc, vel_cov=vc, iterations=it,
                              converged=bool(report.converged[0]), mirrored=mirrored,
                              tracklet=self._tracklet() if self.tracklets else None, report=report)


class Distributed(_Window):
    """One sliding window per vehicle, seed 001's message iteration at each new epoch (module
    docstring). max_rounds: cap on rounds per epoch; transport: the channel (None: ideal).
    Rounds stop when every newest position moved less than tol (m) in the round (its largest
    component), or at max_rounds: the rounds converge linearly and slowly (a median 193 rounds to
    1e-7 m on coop-denied), so tol almost never fires and every epoch runs max_rounds. A cut on
    the step in sigmas was measured and not kept: it cost accuracy and consistency
    (docs/denied.md, "Stopping the distributed rounds early")."""

    def __init__(self, n: int, *, window: int = 5, q: float = 1.0, huber: float | None = None, max_rounds: int = 20,
                 tol: float = 1e-3, init_sigma_p: float = 1e3, init_sigma_v: float = 10.0):
        super().__init__(n, agents=n, per_agent=1, window=window, q=q, huber=huber, max_iter=max_rounds, tol=tol,
                         init_sigma_p=init_sigma_p, init_sigma_v=init_sigma_v)
        # per window epoch: what receiver r last heard of sender s: position (n, n, 3), covariance
        # (n, n, 3, 3), heard (n, n) bool; and the covariance each vehicle broadcasts for it (n, 3, 3)
        self.heard_pos: list[np.ndarray] = []
        self.heard_cov: list[np.ndarray] = []
        self.heard: list[np.ndarray] = []
        self.sent_cov: list[np.ndarray] = []

    # A neighbour's broadcast already holds what it learnt from this vehicle: kept in the prior
    # across marginalizations, that loop would count the same information again at every epoch
    # (measured: the error grows without bound). The prior keeps only the vehicle's own
    # measurements (GNSS, anchors, motion); ranges to neighbours act while in the window.
    keep_ranges = False
    broadcast = "own"  # or "marginal": the full local marginal (kept to measure the difference, docstring)

    def _where(self, i):
        return i, np.zeros_like(i)

    def _view(self, k):
        return self.heard_pos[k], self.heard[k]

    def _dropped(self):
        for table in (self.heard_pos, self.heard_cov, self.heard, self.sent_cov):
            table.pop(0)

    def _ranges(self, P, ks, tags, sys):
        k, edges, d, _ = tags
        heard = np.stack(self.heard)
        heard_pos = np.stack(self.heard_pos)
        for a, b in ((0, 1), (1, 0)):  # each end of a link uses the other end's last broadcast
            me, other = edges[:, a], edges[:, b]
            ok = heard[k, me, other]
            sigma = np.concatenate([self.range_sigma[kk][a] for kk in ks])  # `_weigh`'s, as tags
            ka, me, other, da, sigma = k[ok], me[ok], other[ok], d[ok], sigma[ok]
            dist, u = range_terms(P[ka, me], heard_pos[ka, me, other])
            self._point(sys, 2 + a, ka, me, u, da - dist, sigma)

    def _weigh(self) -> None:
        """Each range's 1-sigma with its neighbour's broadcast covariance, sqrt(sigma_d^2 + u^T
        Sigma_j u), the direction u taken at the current estimate and held until the next call
        (the next round): a sigma that moved with the iterate would make the cost another
        function than the one the Gauss-Newton step minimizes (measured: the full step raised
        the cost of most vehicles, whose steps the line search then halved 8 times)."""
        P = self._pos()
        self.range_sigma = []
        for k, ep in enumerate(self.epochs):
            sig = np.zeros((2, len(ep.ranges)))
            for a, b in ((0, 1), (1, 0)):
                me, other = ep.edges[:, a], ep.edges[:, b]
                u = range_terms(P[k, me], self.heard_pos[k][me, other])[1]
                sig[a] = np.sqrt(inflated_range_variance(ep.range_sigma ** 2, u, self.heard_cov[k][me, other]))
            self.range_sigma.append(sig)

    def _start(self, ep: Epoch, transport: Transport | None) -> tuple[np.ndarray, int, int]:
        """The start exchange (module docstring): every vehicle broadcasts its fix and its ranges
        of epoch ep to the vehicles it ranged with (START_BYTES + RANGE_BYTES per range), and each
        starts at its own place in the layout (estimators.layout) of what it holds: its own and
        the received fixes and ranges. Returns (start (n, 3) m world, NaN rows where the layout
        does not apply; messages; bytes)."""
        n, edges = self.n, ep.edges
        pairs = np.unique(np.concatenate([edges, edges[:, ::-1]]), axis=0) if edges.size else np.zeros((0, 2), np.int64)
        owned = np.bincount(edges.ravel(), minlength=n) + np.bincount(ep.anchor_vehicle, minlength=n)
        holds = np.eye(n, dtype=bool)  # holds[d, s]: d has s's start message
        messages = sent_bytes = 0
        for s in np.unique(pairs[:, 0]).tolist():
            dst = pairs[pairs[:, 0] == s, 1]
            nbytes = int(START_BYTES + RANGE_BYTES * owned[s])
            ok = np.ones(len(dst), bool) if transport is None else np.asarray(
                transport.deliver(0, np.full(len(dst), s), dst, nbytes), bool)
            holds[dst[ok], s] = True
            messages, sent_bytes = messages + 1, sent_bytes + nbytes
        start = np.full((n, 3), np.nan)
        layouts = {}  # vehicles holding the same messages compute the same layout: computed once
        shapes = {}  # and vehicles holding the same ranges the same shape (layout.start_positions)
        for d in range(n):
            key = holds[d].tobytes()  # the layout is a function of what d holds
            if key not in layouts:
                known = holds[d]
                rows = known[edges[:, 0]] | known[edges[:, 1]] if edges.size else np.zeros(0, bool)
                members = np.flatnonzero(known | np.isin(np.arange(n), edges[rows]))
                local = np.full(n, -1)
                local[members] = np.arange(len(members))
                fix = np.where(known[members, None], ep.fix[members], np.nan)
                arows = known[ep.anchor_vehicle]
                laid = layout.start_positions(fix, ep.fix_sigma[members], local[edges[rows]], ep.ranges[rows],
                                              ep.range_sigma[rows], local[ep.anchor_vehicle[arows]], ep.anchor_pos[arows],
                                              ep.anchor_range[arows], ep.anchor_sigma[arows], shapes)
                layouts[key] = (laid, local)
            laid, local = layouts[key]
            if laid is not None:
                start[d] = laid[local[d]]
        return start, messages, sent_bytes

    def add(self, ep: Epoch, transport: Transport | None = None) -> WindowEstimate:
        """Append epoch ep (time-ordered), slide, run the message iteration; the newest estimate."""
        if self.epochs and ep.t <= self.epochs[-1].t:
            raise ValueError(f"epochs must be added in time order: t = {ep.t:g} s after {self.epochs[-1].t:g} s")
        if len(self.epochs) == self.window:
            self._marginalize()
        messages = sent_bytes = first = 0
        start = None
        if not self.epochs:  # round 0 of the first epoch: the start exchange
            start, messages, sent_bytes = self._start(ep, transport)
            first = 1
        self._append(ep, start)
        n = self.n
        self.heard_pos.append(np.zeros((n, n, 3)))
        self.heard_cov.append(np.zeros((n, n, 3, 3)))
        self.heard.append(np.zeros((n, n), bool))
        # round 0's local step: own GNSS, anchors, motion and the window's older ranges only (not
        # at the first epoch: from the start exchange's layout it would step to the fix)
        self._weigh()
        S = solve_block_tridiagonal(*self._system()[:3])[1] if first else self._solve(1, None)[1]
        # (n, 3, 3): what each vehicle knows from its own measurements (GNSS, anchors, motion),
        # without any range to a neighbour: the covariance it broadcasts (module docstring)
        D, U, R, _ = self._system(ranges=False)
        self.sent_cov.append(self._newest(solve_block_tridiagonal(D, U, R)[1])[2])
        # who hears whom: the ranged pairs of every window epoch (both directions)
        edges = np.concatenate([e.edges for e in self.epochs])
        pairs = np.unique(np.concatenate([edges, edges[:, ::-1]]), axis=0) if edges.size else np.zeros((0, 2), np.int64)
        nbytes = BROADCAST_BYTES * len(self.epochs)  # the sender's whole window
        senders = np.unique(pairs[:, 0]).size  # one broadcast per sender and round

        def exchange(rnd: int, newest: np.ndarray) -> np.ndarray:
            """Round rnd: every vehicle broadcasts its window, then takes one Gauss-Newton step on
            its own; the newest positions (n, 3) after it."""
            nonlocal S, messages, sent_bytes
            if self.broadcast == "marginal":
                self.sent_cov[-1] = self._newest(S)[2]
            ok = np.ones(len(pairs), bool) if transport is None else np.asarray(
                transport.deliver(first + rnd, pairs[:, 0], pairs[:, 1], nbytes), bool)
            s_, d_ = pairs[ok, 0], pairs[ok, 1]
            P = self._pos()
            for k in range(len(self.epochs)):  # the sender's current estimate of every window epoch
                self.heard_pos[k][d_, s_] = P[k, s_]
                self.heard_cov[k][d_, s_] = self.sent_cov[k][s_]
                self.heard[k][d_, s_] = True
            self._weigh()
            messages += senders
            sent_bytes += senders * nbytes
            S = self._solve(1, None)[1]  # the tables changed: a new local system
            return self._pos()[-1]

        # rounds until every newest position moved less than tol (its largest component)
        _, _, report = lm.iterate_rounds(self._pos()[-1], exchange, max_rounds=self.max_iter if pairs.size else 0,
                                         tol=self.tol, ord=np.inf)
        mirrored = self._mirror() if self.mirrors else 0
        if mirrored:  # one local step from the mirror images (no message: the next epoch's rounds tell)
            self._weigh()
            S = self._solve(1, None)[1]
        pos, vel, pc, vc = self._newest(S)
        return WindowEstimate(t=ep.t, pos=pos, vel=vel, pos_cov=pc, vel_cov=vc, iterations=int(report.iterations[0]),
                              converged=bool(report.converged[0]) or not pairs.size, mirrored=mirrored,
                              messages=messages, bytes_sent=sent_bytes,
                              tracklet=self._tracklet() if self.tracklets else None, report=report)
