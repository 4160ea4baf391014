"""A motion prior between per-epoch solves: a joint Gaussian belief over robots moving at constant
velocity and body rate, predicted to each epoch and updated from the epoch's posterior.

Each robot r of the belief is a pose (p m world, R body-to-world, v m/s world, w rad/s body; error
state [dp (3) world, dtheta (3) body, dv (3), dw (3)], retraction p + dp, R exp([dtheta]x)) or a
point (p, v; [dp, dv]). The belief is one mean per robot and one joint covariance C (n, n) over
every robot's error state, robots in the order they joined. Used by testbed/replay/graph.py
(docs/replay.md, "graph.poses on sparse ranging"). Never imports mujoco, testbed or gtsam.

Prediction over dt >= 0 (white acceleration of density q_t m^2/s^3 per axis, white angular
acceleration of density q_r rad^2/s^3 per body axis):

    p <- p + v dt,   R <- R Exp(w dt)                                         (mo. 1)
    dp <- dp + dt dv,   dtheta <- Exp(w dt)^T dtheta + J_r(w dt) dt dw
    Q = [[dt^3/3, dt^2/2], [dt^2/2, dt]] (x) q I3   per (dp, dv) and per (dtheta, dw)  (mo. 2)

Update from an epoch's solve over the poses y of some robots (prior: the belief's marginal
N(y-, C_yy); posterior N(y+, P) from the ranges of the epoch and that prior), z every other
unknown (the rates, and the poses of robots absent from the epoch). The epoch's measurements
depend on y alone, so z | y keeps its conditional law and (exact for a linear model)

    K = C_zy C_yy^-1,   d = y+ (-) y-                                         (mo. 3)
    z <- z (+) K d,   C_zz <- C_zz - K (C_yy - P) K^T,   C_zy <- K P,   C_yy <- P

with (-) and (+) the tangent difference and retraction of each robot's pose.

Range biases (optional): a bias b_l (m) per link l joins the belief with add_bias, mean 0 and its
prior variance, independent of the rest; a random constant (F = 1, Q = 0 in mo. 2). An epoch's
solve over some robots' poses and some links' biases takes the belief's joint marginal over both
as its prior (prior(names, links)), and update(names, ..., links, b) is mo. 3 with y the poses and
those biases (the rates, the other robots and the other links' biases in z).
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from estimators.so3 import so3_exp, so3_log, so3_right_jacobian

__all__ = ["MotionBelief"]

#: error-state size of a robot of each kind: its pose's unknowns, then as many rates
POSE_DIMS = {"pose": 6, "point": 3}


@dataclass
class MotionBelief:
    """The joint belief (module docstring) at time t s; q_t m^2/s^3, q_r rad^2/s^3."""

    q_t: float
    q_r: float
    t: float = -np.inf
    names: list = field(default_factory=list)
    kinds: dict = field(default_factory=dict)   # name -> "pose" | "point"
    start: dict = field(default_factory=dict)   # name -> first index of its error state in cov
    p: dict = field(default_factory=dict)       # name -> (3,) m world
    R: dict = field(default_factory=dict)       # name -> (3, 3) (identity for a point)
    v: dict = field(default_factory=dict)       # name -> (3,) m/s world
    w: dict = field(default_factory=dict)       # name -> (3,) rad/s body (zero for a point)
    cov: np.ndarray = field(default_factory=lambda: np.zeros((0, 0)))
    bias: dict = field(default_factory=dict)    # link -> bias m
    bias_at: dict = field(default_factory=dict)  # link -> its index in cov
    _cache: tuple | None = field(default=None, repr=False)

    def __contains__(self, name: str) -> bool:
        return name in self.start

    def add(self, name: str, kind: str, t: float, p: np.ndarray, R: np.ndarray, cov: np.ndarray,
            v_sigma: float, rate_sigma: float) -> None:
        """A robot joins at time t (the belief is first predicted to t): pose (p, R) with the
        covariance cov (k, k) of its k = POSE_DIMS[kind] unknowns, velocity N(0, v_sigma^2 I) m/s
        and (a pose) body rate N(0, rate_sigma^2 I) rad/s, independent of the others."""
        self.predict(t)
        k = POSE_DIMS[kind]
        n = self.cov.shape[0]
        C = np.zeros((n + 2 * k, n + 2 * k))
        C[:n, :n], C[n:n + k, n:n + k] = self.cov, cov
        C[n + k:n + k + 3, n + k:n + k + 3] = v_sigma ** 2 * np.eye(3)
        if kind == "pose":
            C[n + k + 3:, n + k + 3:] = rate_sigma ** 2 * np.eye(3)
        self.names.append(name)
        self.kinds[name], self.start[name], self.cov = kind, n, C
        self.p[name], self.R[name] = np.array(p, float), np.array(R, float)
        self.v[name], self.w[name] = np.zeros(3), np.zeros(3)

    def add_bias(self, link, sigma: float) -> None:
        """A link's bias joins: mean 0 m, variance sigma^2 m^2, independent of the rest."""
        n = self.cov.shape[0]
        C = np.zeros((n + 1, n + 1))
        C[:n, :n], C[n, n] = self.cov, sigma ** 2
        self.cov, self.bias_at[link], self.bias[link] = C, n, 0.0

    def predict(self, t: float) -> None:
        """Move the belief to time t (mo. 1, mo. 2); a time not after the belief's is a no-op."""
        if not self.names or t <= self.t:
            self.t = max(self.t, t)
            return
        dt = t - self.t
        self.t = t
        n = self.cov.shape[0]
        pos, vel, att, rate = self._index()
        # mo. 2: F and Q of the error state
        F = np.eye(n)
        F[pos, vel] = dt
        Q = np.zeros((n, n))
        for a, b, q in ((pos, vel, self.q_t), (att, rate, self.q_r)):
            Q[a, a], Q[a, b], Q[b, a], Q[b, b] = q * dt ** 3 / 3, q * dt ** 2 / 2, q * dt ** 2 / 2, q * dt
        for r in self.names:
            # mo. 1
            self.p[r] = self.p[r] + self.v[r] * dt
        poses = [r for r in self.names if self.kinds[r] == "pose"]
        if poses:
            phi = np.stack([self.w[r] for r in poses]) * dt
            E = so3_exp(phi)
            a3, r3 = att.reshape(-1, 3), rate.reshape(-1, 3)
            for i, r in enumerate(poses):
                self.R[r] = self.R[r] @ E[i]
                F[np.ix_(a3[i], a3[i])] = E[i].T
                F[np.ix_(a3[i], r3[i])] = so3_right_jacobian(phi[i]) * dt
        C = F @ self.cov @ F.T + Q
        self.cov = 0.5 * (C + C.T)

    def _index(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Indices into the error state of every robot's dp, dv, and of every pose's dtheta, dw
        (robots in belief order, 3 per robot)."""
        if self._cache is None or self._cache[0] != len(self.names):
            s = [(self.start[r], POSE_DIMS[self.kinds[r]]) for r in self.names]
            tri = lambda xs: np.array([i for x in xs for i in range(x, x + 3)], np.int64)  # noqa: E731
            self._cache = (len(self.names), tri([a for a, _ in s]), tri([a + k for a, k in s]),
                           tri([a + 3 for a, k in s if k == 6]), tri([a + 9 for a, k in s if k == 6]))
        return self._cache[1:]

    def _pose_index(self, names, links=()) -> np.ndarray:
        return np.concatenate([np.arange(self.start[r], self.start[r] + POSE_DIMS[self.kinds[r]]) for r in names] +
                              [np.array([self.bias_at[k] for k in links], np.int64)])

    def prior(self, names, links=()) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The marginal over the poses of `names` (V of them, in that order), then the biases of
        `links` (B): p (V, 3), R (V, 3, 3) and their covariance (kv + B, kv + B), the unknowns in the
        order of the names, then of the links (their means: biases(links))."""
        y = self._pose_index(names, links)
        return (np.stack([self.p[r] for r in names]), np.stack([self.R[r] for r in names]),
                self.cov[np.ix_(y, y)].copy())

    def biases(self, links) -> np.ndarray:
        """(B,) m the bias means of `links`."""
        return np.array([self.bias[k] for k in links], float)

    def bias_cov(self, links) -> np.ndarray:
        """(B, B) m^2 the covariance of the biases of `links`."""
        i = np.array([self.bias_at[k] for k in links], np.int64)
        return self.cov[np.ix_(i, i)].copy()

    def update(self, names, p: np.ndarray, R: np.ndarray, P: np.ndarray, links=(), b: np.ndarray | None = None) -> None:
        """The belief after an epoch whose solve over the poses of `names` and the biases of `links`
        gave p (V, 3), R (V, 3, 3), b (B,) m with covariance P (kv + B, kv + B), from the prior of
        prior(names, links) (mo. 3)."""
        y = self._pose_index(names, links)
        z = np.setdiff1d(np.arange(self.cov.shape[0]), y)
        w = so3_log(np.stack([self.R[r].T @ R[i] for i, r in enumerate(names)]))
        d = np.concatenate([p[i] - self.p[r] if self.kinds[r] == "point" else np.concatenate([p[i] - self.p[r], w[i]])
                            for i, r in enumerate(names)] + [np.asarray(b, float) - self.biases(links) if links else np.zeros(0)])
        Cyy, Czy = self.cov[np.ix_(y, y)], self.cov[np.ix_(z, y)]
        # mo. 3
        K = np.linalg.solve(Cyy, Czy.T).T
        dz = K @ d
        C = self.cov.copy()
        C[np.ix_(z, z)] -= K @ (Cyy - P) @ K.T
        C[np.ix_(z, y)] = K @ P
        C[np.ix_(y, z)] = C[np.ix_(z, y)].T
        C[np.ix_(y, y)] = P
        self.cov = 0.5 * (C + C.T)
        for i, r in enumerate(names):
            self.p[r], self.R[r] = np.array(p[i], float), np.array(R[i], float)
        delta = np.zeros(self.cov.shape[0])
        delta[z] = dz
        for i, k in enumerate(links):
            self.bias[k] = float(b[i])
        for k, i in self.bias_at.items():
            if k not in links:
                self.bias[k] += delta[i]
        for r in self.names:
            s, k = self.start[r], POSE_DIMS[self.kinds[r]]
            if r not in names:
                self.p[r] = self.p[r] + delta[s:s + 3]
                if k == 6:
                    self.R[r] = self.R[r] @ so3_exp(delta[s + 3:s + 6])
            self.v[r] = self.v[r] + delta[s + k:s + k + 3]
            if k == 6:
                self.w[r] = self.w[r] + delta[s + 9:s + 12]
