"""Many independent small factor graphs (epochs) solved together, vectorized across epochs.

The per-epoch problem is the one estimators.graph.model states for its Range, Height and Prior
factors, restricted to what recorded multi-robot ranging data needs: every epoch has the same free
variables (V of them, each a "pose" (6 tangent dofs: dp (3) m world, dtheta (3) rad body,
retraction p + dp, R exp([dtheta]x)) or a "point" (3 dofs, m world)); a factor's end that is not a
free variable is a fixed world point (an anchor, a site of a robot whose pose is known at that
epoch). Factors (whitened, as in estimators.graph.model):
- range: h = |e_a - e_b|, e = p + R l for a pose with body lever arm l (m), e = p for a point;
- height: h = e_z, the up coordinate of the (lever-arm) point;
- prior: h = e (3,) with a full covariance (a GNSS fix of an antenna, m^2);
- range biases (optional): B unknowns b (m), each epoch its own copy (as of the variables: epochs
  still share nothing); a range row naming bias i measures |e_a - e_b| + b_i, and every epoch has
  the prior b ~ N(b_mean, b_cov) (B rows, whitened by the Cholesky factor of b_cov), so an epoch
  without a range of link i still determines b_i (by its prior). Combining the epochs' results
  is the caller's (testbed/replay/graph.py);
- state prior (optional): each epoch's prior on all its variables at once, in information form:
  mean x_mean and information x_info (kv, kv), symmetric positive semidefinite over the
  variables' unknowns (a motion model's prediction: estimators.graph.motion; a zero eigenvalue: a
  direction the prior leaves uninformed), residual per variable d = [p - p_mean; Log(R_mean^T R)]
  (a point: p - p_mean), whitened W d with W = Lambda^1/2 U^T (x_info = U Lambda U^T), so that
  W^T W = x_info; d Log(R_mean^T R exp(dtheta)) / d dtheta = J_r^-1(Log(R_mean^T R)). The epoch's
  observability test counts only the information the prior gives. With biases, the state prior may
  cover them too (x_b, their mean: a motion model's belief correlates poses and biases): x_info is
  then over the kv + B unknowns, the residual d gains b - x_b, and the separate bias prior (b_cov)
  is not used.
Epochs share nothing, so their normal matrices are (E, k, k) dense blocks (estimators.graph.linear.
DenseNormals): the Levenberg-Marquardt iteration of estimators.graph.lm (`solve`) runs on all of
them at once with one damping factor per epoch (Madsen, Nielsen, Tingleff 2004, eq. 2.21 and
algorithm 3.16), robust losses by IRLS (estimators.graph.losses), and each epoch stops on its own
convergence test; once half of them have, the others continue alone. Observability per
epoch by the relative Cholesky pivots of estimators.graph.linear (GAUGE_RATIO). Non-convergence
and gauge freedom are results (flags per epoch), never exceptions.
Never imports mujoco, testbed or gtsam.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from estimators.graph.factors import range_terms
from estimators.graph import lm
from estimators.graph.linear import GAUGE_RATIO, DenseNormals, factor_spd
from estimators.graph.losses import Loss, loss_rho, loss_weight
from estimators.so3 import so3_exp, so3_log, so3_right_jacobian_inv

__all__ = ["EpochFactors", "EpochsResult", "solve_epochs"]

DIMS = {"pose": 6, "point": 3}


@dataclass(frozen=True, slots=True)
class EpochFactors:
    """The factors of E epochs over V free variables, as arrays (one row per factor).

    kinds: (V,) "pose" | "point". Range rows: r_epoch (R,) int in [0, E); r_a, r_b (R,) free
    variable index or -1 for a fixed end; r_arm_a, r_arm_b (R, 3): the body lever arm (m) of a
    pose end, ignored for a point end, the world point (m) of a fixed end; r_d (R,) m; r_sigma (R,) m.
    Height rows: h_epoch, h_var (free), h_arm (H, 3), h_z (H,) m up, h_sigma (H,) m.
    Prior rows: q_epoch, q_var (free), q_arm (P, 3), q_z (P, 3) m world, q_cov (P, 3, 3) m^2.
    Range biases (optional): r_bias (R,) int, the bias unknown a range adds (-1: none; None: -1
    for every range); b_mean (B,) m and b_cov (B, B) m^2 their prior in every epoch (None: B = 0).
    State prior (optional, all three or none): x_p (E, V, 3) m world and x_R (E, V, 3, 3) its
    mean (x_R ignored for points), x_info (E, kv, kv) its information (inverse covariance,
    positive semidefinite) over the kv unknowns of the variables (a pose's [dp m world, dtheta
    rad body], in variable order); x_b (E, B) m (optional, with biases): the state prior covers the
    biases too, x_info then (E, kv + B, kv + B), and b_cov is not used (None allowed).
    """

    kinds: tuple[str, ...]
    r_epoch: np.ndarray
    r_a: np.ndarray
    r_b: np.ndarray
    r_arm_a: np.ndarray
    r_arm_b: np.ndarray
    r_d: np.ndarray
    r_sigma: np.ndarray
    h_epoch: np.ndarray
    h_var: np.ndarray
    h_arm: np.ndarray
    h_z: np.ndarray
    h_sigma: np.ndarray
    q_epoch: np.ndarray
    q_var: np.ndarray
    q_arm: np.ndarray
    q_z: np.ndarray
    q_cov: np.ndarray
    r_bias: np.ndarray | None = None
    b_mean: np.ndarray | None = None
    b_cov: np.ndarray | None = None
    x_p: np.ndarray | None = None
    x_R: np.ndarray | None = None
    x_info: np.ndarray | None = None
    x_b: np.ndarray | None = None

    @property
    def n_bias(self) -> int:
        return 0 if self.b_mean is None else int(np.size(self.b_mean))

    def __post_init__(self) -> None:
        bad = [k for k in self.kinds if k not in DIMS]
        if bad:
            raise ValueError(f"EpochFactors: kinds must be 'pose' or 'point', got {bad}")
        if np.any((self.r_a == self.r_b) & (self.r_a >= 0)):
            raise ValueError("EpochFactors: a range between two sites of one free variable carries no information")
        for name in ("r_d", "r_sigma", "r_arm_a", "r_arm_b", "h_z", "h_sigma", "h_arm", "q_z", "q_cov", "q_arm"):
            if not np.all(np.isfinite(getattr(self, name))):
                raise ValueError(f"EpochFactors: {name} is not finite")
        if np.any(self.r_sigma <= 0) or np.any(self.h_sigma <= 0):
            raise ValueError("EpochFactors: sigmas must be positive")
        if self.r_bias is None:  # no range has a bias
            object.__setattr__(self, "r_bias", np.full(np.shape(self.r_epoch), -1, np.int64))
        if (self.x_p is None) != (self.x_info is None) or (self.x_p is None) != (self.x_R is None):
            raise ValueError("EpochFactors: a state prior needs x_p, x_R and x_info together")
        if self.x_info is not None and not (np.all(np.isfinite(self.x_p)) and np.all(np.isfinite(self.x_info))):
            raise ValueError("EpochFactors: the state prior is not finite")
        if np.any(np.asarray(self.r_bias) >= self.n_bias):
            raise ValueError(f"EpochFactors: r_bias names a bias beyond the {self.n_bias} of b_mean")
        if self.x_b is not None and (self.x_info is None or np.shape(self.x_b)[-1] != self.n_bias):
            raise ValueError("EpochFactors: x_b (the biases in the state prior) needs x_info and one mean per bias of b_mean")

    @staticmethod
    def empty_rows(n: int = 0) -> dict:
        """Keyword arrays of zero height and prior rows (convenience for range-only problems)."""
        z = np.zeros(n, np.int64)
        return {"h_epoch": z, "h_var": z, "h_arm": np.zeros((n, 3)), "h_z": np.zeros(n), "h_sigma": np.ones(n),
                "q_epoch": z, "q_var": z, "q_arm": np.zeros((n, 3)), "q_z": np.zeros((n, 3)), "q_cov": np.tile(np.eye(3), (n, 1, 1))}


@dataclass(frozen=True, slots=True)
class EpochsResult:
    """p: (E, V, 3) m world; R: (E, V, 3, 3) body-to-world (identity for points); cov: (E, k, k)
    tangent-space covariance (NaN where unobservable), unknowns in variable order, a pose's
    [dp world, dtheta body], then the B biases; offsets: (V,) first unknown of each variable; cost:
    (E,) final robust cost; iterations: (E,) linear solves (rejected LM steps included); converged,
    observable: (E,) bool; b: (E, B) m the biases (None without); report: the estimators.graph.lm
    Report of the iteration."""

    p: np.ndarray
    R: np.ndarray
    cov: np.ndarray
    offsets: np.ndarray
    cost: np.ndarray
    iterations: np.ndarray
    converged: np.ndarray
    observable: np.ndarray
    b: np.ndarray | None = None
    report: lm.Report | None = None


class _Layout:
    """Column map and row slots of the padded per-epoch Jacobian (E, M, k + 1); column k is a sink
    for the absent rotation columns of points."""

    def __init__(self, f: EpochFactors, n_epochs: int):
        dims = np.array([DIMS[k] for k in f.kinds], np.int64)
        self.offsets = np.concatenate([[0], np.cumsum(dims)[:-1]]).astype(np.int64)
        self.kv, self.B = int(dims.sum()), f.n_bias  # the variables' unknowns, then the biases'
        self.k = self.kv + self.B
        self.is_pose = np.array([k == "pose" for k in f.kinds], bool)
        cols = self.offsets[:, None] + np.arange(6)[None, :]
        self.colmap = np.where(self.is_pose[:, None] | (np.arange(6)[None, :] < 3), cols, self.k)
        self.E = n_epochs
        self.joint = f.x_b is not None  # the state prior covers the biases: no separate bias prior rows
        self.X = 0 if f.x_info is None else self.kv + (self.B if self.joint else 0)  # the state prior's rows per epoch
        Bp = 0 if self.joint else self.B  # the bias prior's rows per epoch
        # slots: ranges, then heights, then 3 rows per prior, then the Bp bias priors, then the X state prior
        # rows, in order within each epoch
        epochs = np.concatenate([f.r_epoch, f.h_epoch, np.repeat(f.q_epoch, 3),
                                 np.repeat(np.arange(n_epochs), Bp), np.repeat(np.arange(n_epochs), self.X)]).astype(np.int64)
        order = np.argsort(epochs, kind="stable")
        counts = np.bincount(epochs, minlength=n_epochs)
        start = np.concatenate([[0], np.cumsum(counts)[:-1]])
        slot = np.empty_like(epochs)
        slot[order] = np.arange(epochs.size) - start[epochs[order]]
        self.M = int(counts.max(initial=0))
        nr, nh = f.r_epoch.size, f.h_epoch.size
        self.r_slot, self.h_slot = slot[:nr], slot[nr:nr + nh]
        nq = 3 * f.q_epoch.size
        self.q_slot = slot[nr + nh:nr + nh + nq].reshape(-1, 3)
        nb = n_epochs * Bp
        self.b_slot = slot[nr + nh + nq:nr + nh + nq + nb].reshape(n_epochs, Bp)
        self.x_slot = slot[nr + nh + nq + nb:].reshape(n_epochs, self.X)
        if self.X:
            rows = np.arange(n_epochs)[:, None] * self.M + self.x_slot  # (E, X): the state prior's kv columns
            self.x_prior = _Cols(np.arange(n_epochs * self.X), rows.reshape(-1, 1, 1) * (self.k + 1) + np.arange(self.X)[None, None, :])
            lam, U = np.linalg.eigh(f.x_info)
            self.x_sqrt = np.sqrt(np.maximum(lam, 0.0))[:, :, None] * np.swapaxes(U, 1, 2)  # W, W^T W = x_info
        if self.B:
            kb = self.kv + np.arange(self.B)
            biased = np.flatnonzero(f.r_bias >= 0)
            # a range's bias column, and the B x B block of each epoch's bias prior
            self.r_bias = _Cols(biased, ((f.r_epoch[biased] * self.M + self.r_slot[biased]) * (self.k + 1)
                                         + self.kv + f.r_bias[biased])[:, None, None])
            if not self.joint:
                rows = np.arange(n_epochs)[:, None] * self.M + self.b_slot  # (E, B)
                self.b_prior = _Cols(np.arange(n_epochs * self.B), (rows.reshape(-1, 1, 1) * (self.k + 1) + kb[None, None, :]))
                self.b_chol = np.linalg.cholesky(f.b_cov)
        self.ends = {"ra": _Ends(self, f.r_epoch, f.r_a, f.r_arm_a, self.r_slot[:, None]),
                     "rb": _Ends(self, f.r_epoch, f.r_b, f.r_arm_b, self.r_slot[:, None]),
                     "h": _Ends(self, f.h_epoch, f.h_var, f.h_arm, self.h_slot[:, None]),
                     "q": _Ends(self, f.q_epoch, f.q_var, f.q_arm, self.q_slot)}
        self.q_chol = np.linalg.cholesky(f.q_cov) if f.q_epoch.size else None


class _Cols:
    """Factor rows `at` (f,) whose Jacobian entries sit at the flat indices flat (f, d, c) of the
    layout's (E, M, k + 1) array (the bias columns: _system fills them as an _Ends' free rows)."""

    def __init__(self, at: np.ndarray, flat: np.ndarray):
        self.at, self.flat = at, flat


class _Ends:
    """Constant data of one list of factor ends: epoch (n,), free (n,) bool, var (n,) (0 where
    fixed), lever (n, 3) (zero unless a pose), fixed (n, 3) world points; of the free ends only
    (f of them): at (f,) their rows, flat (f, d, 6) the flat indices of their Jacobian entries in
    the layout's (E, M, k + 1) array for the factor rows slots (n, d)."""

    def __init__(self, lay: "_Layout", epoch, var, arm, slots):
        self.epoch = np.asarray(epoch, np.int64)
        self.free = np.asarray(var) >= 0
        self.var = np.where(self.free, var, 0)
        pose = self.free & lay.is_pose[self.var]
        self.lever = np.where(pose[:, None], arm, 0.0)
        self.fixed = np.where(self.free[:, None], 0.0, arm)
        self.at = np.flatnonzero(self.free)
        self.all_free = self.at.size == self.free.size
        ef, vf = self.epoch[self.at], self.var[self.at]
        self.flat = (ef[:, None, None] * lay.M + np.asarray(slots)[self.at][:, :, None]) * (lay.k + 1) + lay.colmap[vf][:, None, :]

    def points(self, p, R):
        """World points (n, 3) of the ends, and the rotations (f, 3, 3) of the free ends' variables."""
        ef, vf = self.epoch[self.at], self.var[self.at]
        Rv = R[ef, vf]
        moving = p[ef, vf] + np.einsum("nij,nj->ni", Rv, self.lever[self.at])
        if self.all_free:
            return moving, Rv
        e = self.fixed.copy()
        e[self.at] = moving
        return e, Rv

    def row(self, Rv, u):
        """Tangent Jacobian rows u^T de/dx (f, 6) of the free ends for directions u (n, 3):
        [u, l x (R^T u)], since d(R exp(dtheta) l)/d dtheta = -R [l]x and u^T (-R [l]x) = (l x R^T u)^T."""
        u = u[self.at]
        a, b = self.lever[self.at], np.einsum("nji,nj->ni", Rv, u)
        cross = np.stack([a[:, 1] * b[:, 2] - a[:, 2] * b[:, 1], a[:, 2] * b[:, 0] - a[:, 0] * b[:, 2],
                          a[:, 0] * b[:, 1] - a[:, 1] * b[:, 0]], axis=1)
        return np.concatenate([u, cross], axis=1)


def _residuals(f: EpochFactors, lay: _Layout, p, R, b=None):
    """Whitened residuals and Jacobian blocks of every factor: list of (kind, epoch, slots, e (n, d),
    [(ends, J (f, d, c) of the ends' free rows)]); b (E, B) the biases (lay.B > 0)."""
    out = []
    if f.r_epoch.size:
        A, B = lay.ends["ra"], lay.ends["rb"]
        ea, Ra = A.points(p, R)
        eb, Rb = B.points(p, R)
        r, u = range_terms(ea, eb)
        blocks = [(A, (A.row(Ra, u) / f.r_sigma[A.at, None])[:, None]), (B, (-B.row(Rb, u) / f.r_sigma[B.at, None])[:, None])]
        if lay.B:
            at = lay.r_bias.at
            # a biased range measures |e_a - e_b| + b_i: d h / d b_i = 1 (docs/replay.md, "Range bias")
            r = r.copy()
            r[at] += b[f.r_epoch[at], f.r_bias[at]]
            blocks.append((lay.r_bias, (1.0 / f.r_sigma[at])[:, None, None]))
        e = ((f.r_d - r) / f.r_sigma)[:, None]
        out.append(("range", f.r_epoch, lay.r_slot[:, None], e, blocks))
    if f.h_epoch.size:
        H = lay.ends["h"]
        eh, Rh = H.points(p, R)
        up = np.broadcast_to([0.0, 0.0, 1.0], eh.shape)
        e = ((f.h_z - eh[:, 2]) / f.h_sigma)[:, None]
        out.append(("height", f.h_epoch, lay.h_slot[:, None], e, [(H, (H.row(Rh, up) / f.h_sigma[H.at, None])[:, None])]))
    if f.q_epoch.size:
        Q = lay.ends["q"]
        eq, Rq = Q.points(p, R)
        J = np.stack([Q.row(Rq, np.broadcast_to(ax, eq.shape)) for ax in np.eye(3)], axis=1)  # (n, 3, 6)
        e = np.linalg.solve(lay.q_chol, (f.q_z - eq)[..., None])[..., 0]
        # W = L^-1 (W^T W = cov^-1): whitened e = W (z - h), Jacobian W dh/dx
        out.append(("prior", f.q_epoch, lay.q_slot, e, [(Q, np.linalg.solve(lay.q_chol[Q.at], J))]))
    if lay.B and not lay.joint:
        # the bias prior: whitened W (b_mean - b), W = L^-1 (L L^T = b_cov), Jacobian W
        W = np.linalg.inv(lay.b_chol)
        e = ((f.b_mean - b) @ W.T).reshape(-1, 1)
        E = b.shape[0]
        out.append(("bias", np.repeat(np.arange(E), lay.B), lay.b_slot.reshape(-1, 1), e,
                    [(lay.b_prior, np.broadcast_to(W, (E, lay.B, lay.B)).reshape(-1, 1, lay.B))]))
    if lay.X:
        out.append(_state_prior(f, lay, p, R, b))
    return out


def _state_prior(f: EpochFactors, lay: _Layout, p, R, b):
    """The state prior's residual block (module docstring): d = [p - p_mean; Log(R_mean^T R)] per
    variable, then b - x_b with the biases in it (E, X), whitened e = W (0 - d), Jacobian W dd/dx,
    W^T W = x_info."""
    E, kv, X = p.shape[0], lay.kv, lay.X
    d, Jd = np.zeros((E, X)), np.zeros((E, X, X))
    if lay.joint:
        d[:, kv:] = b - f.x_b
        Jd[:, kv:, kv:] = np.eye(X - kv)
    poses = np.flatnonzero(lay.is_pose)
    w = so3_log(np.swapaxes(f.x_R[:, poses], -1, -2) @ R[:, poses]) if poses.size else None  # (E, P, 3)
    for i, o in enumerate(lay.offsets):
        d[:, o:o + 3] = p[:, i] - f.x_p[:, i]
        Jd[:, o:o + 3, o:o + 3] = np.eye(3)
        if lay.is_pose[i]:
            wi = w[:, int(np.searchsorted(poses, i))]
            d[:, o + 3:o + 6] = wi
            Jd[:, o + 3:o + 6, o + 3:o + 6] = so3_right_jacobian_inv(wi)
    e = -(lay.x_sqrt @ d[..., None])
    J = lay.x_sqrt @ Jd
    return ("state", np.repeat(np.arange(E), X), lay.x_slot.reshape(-1, 1), e.reshape(-1, 1), [(lay.x_prior, J.reshape(-1, 1, X))])


def _subset(f: EpochFactors, keep: np.ndarray) -> EpochFactors:
    """The factors of the epochs where keep (E,) bool, epochs renumbered in order."""
    new = np.cumsum(keep) - 1
    out = {"kinds": f.kinds, "b_mean": f.b_mean, "b_cov": f.b_cov}
    if f.x_info is not None:
        out.update(x_p=f.x_p[keep], x_R=f.x_R[keep], x_info=f.x_info[keep], x_b=None if f.x_b is None else f.x_b[keep])
    for prefix, epoch in (("r_", f.r_epoch), ("h_", f.h_epoch), ("q_", f.q_epoch)):
        rows = keep[epoch]
        for name in EpochFactors.__slots__:
            if name.startswith(prefix):
                out[name] = getattr(f, name)[rows]
        out[f"{prefix}epoch"] = new[epoch[rows]]
    return EpochFactors(**out)


def _cost(res, losses, E):
    f = np.zeros(E)
    for kind, epoch, _, e, _ in res:
        f += np.bincount(epoch, loss_rho(losses.get(kind), np.linalg.norm(e, axis=1)), minlength=E)
    return f


def _system(res, losses, lay: _Layout):
    """IRLS-weighted normal equations N (E, k, k), g (E, k) and the robust cost (E,)."""
    E, M, k = lay.E, lay.M, lay.k
    J = np.zeros(E * M * (k + 1))
    b = np.zeros((E, M))
    cost = np.zeros(E)
    for kind, epoch, slots, e, blocks in res:
        s = np.linalg.norm(e, axis=1)
        cost += np.bincount(epoch, loss_rho(losses.get(kind), s), minlength=E)
        sw = np.sqrt(loss_weight(losses.get(kind), s))[:, None]
        b[epoch[:, None], slots] = sw * e
        for ends, Jb in blocks:
            J[ends.flat] = sw[ends.at, :, None] * Jb
    J = J.reshape(E, M, k + 1)[:, :, :k]
    Jt = np.swapaxes(J, 1, 2)
    return Jt @ J, (Jt @ b[..., None])[..., 0], cost


def _retract(lay: _Layout, p, R, b, delta):
    """x (+) delta for delta (E, k); a pose: p + dp, R exp(dtheta); a point: p + dp; biases b + db."""
    cols = lay.colmap  # (V, 6); sink column k reads zero
    d = np.concatenate([delta, np.zeros((delta.shape[0], 1))], axis=1)[:, cols]  # (E, V, 6)
    p_new = p + d[..., :3]
    R_new = np.where(lay.is_pose[None, :, None, None], R @ so3_exp(d[..., 3:]), R)
    return p_new, R_new, b + delta[:, lay.kv:]


def _observability_and_cov(N):
    """Per epoch: observable (relative pivot of the Cholesky of N above GAUGE_RATIO) and N^-1."""
    E, k = N.shape[0], N.shape[1]
    diag = np.diagonal(N, axis1=1, axis2=2)
    ok = np.all(diag > 0, axis=1) & np.all(np.isfinite(N), axis=(1, 2))
    Ns = np.where(ok[:, None, None], N, np.eye(k))
    eps = 1e-13 * np.where(ok[:, None], diag, 1.0)
    try:
        L = np.linalg.cholesky(Ns + eps[:, :, None] * np.eye(k))
    except np.linalg.LinAlgError:
        L = np.zeros_like(Ns)
        for i in range(E):
            fac = factor_spd(Ns[i] + np.diag(eps[i]))
            if fac.ok:
                L[i] = np.linalg.cholesky(Ns[i] + np.diag(eps[i]))
            else:
                ok[i] = False
                L[i] = np.eye(k)
    ratio = np.diagonal(L, axis1=1, axis2=2) ** 2 / np.where(ok[:, None], diag, 1.0)
    observable = ok & (ratio.min(axis=1, initial=np.inf) > GAUGE_RATIO)
    Linv = np.linalg.solve(L, np.broadcast_to(np.eye(k), L.shape))  # triangular: L^-1
    cov = np.swapaxes(Linv, 1, 2) @ Linv
    cov[~observable] = np.nan
    return observable, cov


class _Epochs:
    """The epochs as a batch of problems for estimators.graph.lm.solve; x = (p (E, V, 3), R (E, V, 3, 3),
    b (E, B))."""

    def __init__(self, f: EpochFactors, losses: dict, E: int):
        self.f, self.losses, self.size = f, losses, E
        self.lay = _Layout(f, E)

    def evaluate(self, x):
        res = _residuals(self.f, self.lay, *x)  # at the candidates; the system of the accepted ones
        return _cost(res, self.losses, self.size), res

    def normal(self, x, res):
        N, g, _ = _system(res, self.losses, self.lay)
        return DenseNormals(N, g)

    def retract(self, x, delta):
        return _retract(self.lay, *x, delta)

    @staticmethod
    def select(mask, a, b):
        return (np.where(mask[:, None, None], a[0], b[0]), np.where(mask[:, None, None, None], a[1], b[1]),
                np.where(mask[:, None], a[2], b[2]))

    def subset(self, keep):
        return _Epochs(_subset(self.f, keep), self.losses, int(keep.sum()))


def solve_epochs(f: EpochFactors, p0: np.ndarray, R0: np.ndarray, *, losses: dict | None = None, max_iter: int = 50,
                 step_tol: float = 1e-8, cost_tol: float = 1e-12, step_sigma: float = 0.0,
                 lm_lambda: float = 1e-4) -> EpochsResult:
    """Levenberg-Marquardt on every epoch at once from p0 (E, V, 3), R0 (E, V, 3, 3) and the biases'
    prior mean (see the module docstring). losses: {"range" | "height" | "prior": Loss}. Convergence per epoch: a step
    (accepted or not) whose largest component is below step_tol, or an accepted step whose
    relative cost decrease is below cost_tol, or (step_sigma > 0) an accepted step delta shorter
    than step_sigma standard deviations of the estimate: sqrt(delta^T N delta) < step_sigma, N the
    undamped normal matrix where the step starts (the information of the epoch's solution); max_iter
    linear solves per epoch at most."""
    losses = dict(losses or {})
    for kind, loss in losses.items():
        if not isinstance(loss, Loss):
            raise ValueError(f"solve_epochs: losses[{kind!r}] must be a Loss, got {loss!r}")
    p, R = np.array(p0, float), np.array(R0, float)
    E = p.shape[0]
    b = np.tile(np.asarray(f.b_mean, float) if f.n_bias else np.zeros(0), (E, 1))
    (p, R, b), lin, report = lm.solve(_Epochs(f, losses, E), (p, R, b), method="lm", max_iter=max_iter,
                                      step_tol=step_tol, cost_tol=cost_tol, step_sigma=step_sigma, lm_lambda=lm_lambda)
    observable, cov = _observability_and_cov(lin.N)
    return EpochsResult(p, R, cov, _Layout(f, 0).offsets, report.cost, report.iterations, report.converged, observable,
                        b if f.n_bias else None, report)
