"""A general factor graph over points, poses and scalars (recorded data: docs/replay.md).

Variables (`Graph.add_variable(key, kind, fixed=False)`):
- "point": p (3,) m, world frame (a UAV with one tag, a velocity, an anchor when fixed);
- "pose": (p (3,) m world, R (3, 3) body-to-world rotation); tangent [dp (3) world, dtheta (3)
  body], retraction p + dp, R exp([dtheta]x) (two tags on one robot are one pose);
- "scalar": b (1,), e.g. a per-link constant range bias (m).
A fixed variable is held at its initial value (anchors, known robots).

Factors (each has `kind`, the key of the robust loss applied to it; residuals whitened):
- Prior(key, z, cov) (alias PosePositionPrior): point/scalar prior h = x, pose position prior
  h = p; PoseRotationPrior(key, R_z, cov): h = Log(R_z^T R) (z = R_z);
- Range(a, b, d, sigma, lever_a, lever_b, bias): h = |e_a - e_b| + bias, e = p + R l for a pose
  with body-frame lever arm l (m), e = p for a point; bias a scalar key or None;
- Height(key, z, sigma, lever): h = e_z, the up coordinate of the (lever-arm) point (altimeter);
- ConstantVelocity(p0, v0, p1, v1, dt, q): white-noise-acceleration model between epochs,
  h = [p1 - p0 - v0 dt; v1 - v0] = 0 with Q = q [[dt^3/3 I, dt^2/2 I], [dt^2/2 I, dt I]]
  (q: m^2/s^3 per axis); p0, p1 points or poses (their positions), v0, v1 points (m/s).
Solved by estimators.graph.lm (GN or LM with robust IRLS weights); marginal covariances in the
tangent space of each free variable; observability checked as in estimators.graph.linear.
Never imports mujoco, testbed or gtsam.
"""
from __future__ import annotations

import warnings
from dataclasses import dataclass, field

import numpy as np
from scipy import sparse

from estimators.so3 import skew, so3_exp, so3_log, so3_right_jacobian_inv
from estimators.graph.factors import motion_covariance, range_terms, sqrt_information
from estimators.graph.linear import GaugeWarning, factor_spd
from estimators.graph.lm import Report, minimize
from estimators.graph.losses import Loss, loss_rho, loss_weight

__all__ = [
    "Graph", "GraphResult", "Prior", "PosePositionPrior", "PoseRotationPrior", "Range", "Height",
    "ConstantVelocity", "solve_graph", "DIMS",
]

DIMS = {"point": 3, "pose": 6, "scalar": 1}


def _sqrt_info(cov) -> np.ndarray:
    """W with W^T W = cov^-1: (d, d), for a covariance (d, d) or a variance (scalar)."""
    return sqrt_information(np.atleast_2d(np.asarray(cov, float)))


def _endpoint(values: dict, kinds: dict, key, lever) -> tuple[np.ndarray, np.ndarray]:
    """World point of a variable (pose: p + R l) and its Jacobian (3, dim) w.r.t. the tangent."""
    if kinds[key] == "pose":
        p, R = values[key]
        lv = np.zeros(3) if lever is None else np.asarray(lever, float)
        # d(R exp(dtheta) l)/d dtheta = -R [l]x
        return p + R @ lv, np.hstack([np.eye(3), -R @ skew(lv)])
    return np.asarray(values[key], float), np.eye(3)


# ---------------------------------------------------------------------------------- factors
@dataclass(frozen=True, slots=True)
class Prior:
    """Prior on a point (z (3,), cov (3, 3)), on the position of a pose (same shapes, m, m^2) or
    on a scalar (z (1,), cov (1, 1))."""

    key: object
    z: np.ndarray
    cov: np.ndarray
    kind: str = "prior"

    def linearize(self, values, kinds):
        W = _sqrt_info(self.cov)
        if kinds[self.key] == "scalar":
            x, J = np.asarray(values[self.key], float), np.eye(1)
        else:
            x, J = _endpoint(values, kinds, self.key, None)
        return W @ (np.atleast_1d(np.asarray(self.z, float)) - x), {self.key: W @ J}


#: prior on the position of a pose (the same factor as a point prior)
PosePositionPrior = Prior


@dataclass(frozen=True, slots=True)
class PoseRotationPrior(Prior):
    """Prior on the attitude of a pose: z = R_z (3, 3) body-to-world, cov (3, 3) rad^2 (body axes)."""

    def linearize(self, values, kinds):
        W = _sqrt_info(self.cov)
        w = so3_log(np.asarray(self.z).T @ values[self.key][1])
        J = np.hstack([np.zeros((3, 3)), so3_right_jacobian_inv(w)])
        return -W @ w, {self.key: W @ J}


@dataclass(frozen=True, slots=True)
class Range:
    """Range d (m, sigma m) between point/pose a (lever_a, body m) and b (lever_b), plus an
    optional scalar bias variable (m): h = |e_a - e_b| + bias (estimators.graph.factors.range_terms:
    co-located endpoints get a fixed unit subgradient direction)."""

    a: object
    b: object
    d: float
    sigma: float
    lever_a: np.ndarray | None = None
    lever_b: np.ndarray | None = None
    bias: object = None
    kind: str = "range"

    def linearize(self, values, kinds):
        ea, Ja = _endpoint(values, kinds, self.a, self.lever_a)
        eb, Jb = _endpoint(values, kinds, self.b, self.lever_b)
        r, u = range_terms(ea, eb)
        h = float(r) + (float(values[self.bias][0]) if self.bias is not None else 0.0)
        jac = {self.a: (u @ Ja)[None] / self.sigma}
        jb = -(u @ Jb)[None] / self.sigma
        jac[self.b] = jac[self.b] + jb if self.b in jac else jb
        if self.bias is not None:
            jac[self.bias] = np.array([[1.0 / self.sigma]])
        return np.array([(self.d - h) / self.sigma]), jac


@dataclass(frozen=True, slots=True)
class Height:
    """Height (up coordinate) z (m, sigma m) of a point, or of a pose's lever-arm point."""

    key: object
    z: float
    sigma: float
    lever: np.ndarray | None = None
    kind: str = "height"

    def linearize(self, values, kinds):
        e, J = _endpoint(values, kinds, self.key, self.lever)
        return np.array([(self.z - e[2]) / self.sigma]), {self.key: J[2:3] / self.sigma}


@dataclass(frozen=True, slots=True)
class ConstantVelocity:
    """White-noise-acceleration motion factor between epochs (see the module docstring)."""

    p0: object
    v0: object
    p1: object
    v1: object
    dt: float
    q: float
    kind: str = "motion"

    def linearize(self, values, kinds):
        dt = self.dt
        W = np.kron(_sqrt_info(motion_covariance(dt, self.q)), np.eye(3))  # (6, 6)
        e0, J0 = _endpoint(values, kinds, self.p0, None)
        e1, J1 = _endpoint(values, kinds, self.p1, None)
        v0, v1 = np.asarray(values[self.v0], float), np.asarray(values[self.v1], float)
        h = np.concatenate([e1 - e0 - v0 * dt, v1 - v0])
        Z = np.zeros((3, J0.shape[1]))
        jac = {self.p0: W @ np.vstack([-J0, Z]), self.v0: W @ np.vstack([-dt * np.eye(3), -np.eye(3)])}
        jac[self.p1] = jac.get(self.p1, 0) + W @ np.vstack([J1, np.zeros((3, J1.shape[1]))])
        jac[self.v1] = jac.get(self.v1, 0) + W @ np.vstack([np.zeros((3, 3)), np.eye(3)])
        return -W @ h, jac


# ------------------------------------------------------------------------------------ graph
@dataclass
class Graph:
    """Variables (key -> kind), fixed keys and factors; build with add_variable / add."""

    kinds: dict = field(default_factory=dict)
    fixed: set = field(default_factory=set)
    factors: list = field(default_factory=list)

    def add_variable(self, key, kind: str, *, fixed: bool = False) -> None:
        if kind not in DIMS:
            raise ValueError(f"Graph: variable kind must be one of {tuple(DIMS)}, got {kind!r}")
        if key in self.kinds:
            raise ValueError(f"Graph: variable {key!r} added twice")
        self.kinds[key] = kind
        if fixed:
            self.fixed.add(key)

    def add(self, factor) -> None:
        self.factors.append(factor)


@dataclass(frozen=True, slots=True)
class GraphResult:
    """values: {key: point (3,) | (p (3,), R (3, 3)) | scalar (1,)}; cov: {free key: (d, d)}
    tangent-space marginal covariance (NaN when unobservable); cost, iterations, converged,
    history, report as estimators.graph.lm.Iterate; observable: no gauge freedom (else a GaugeWarning)."""

    values: dict
    cov: dict
    cost: float
    iterations: int
    converged: bool
    history: tuple
    observable: bool
    report: Report | None = None


def _offsets(graph: Graph) -> tuple[dict, int]:
    off, k = {}, 0
    for key, kind in graph.kinds.items():
        if key not in graph.fixed:
            off[key] = k
            k += DIMS[kind]
    return off, k


def _retract(graph: Graph, off: dict, values: dict, delta: np.ndarray) -> dict:
    out = dict(values)
    for key, o in off.items():
        kind = graph.kinds[key]
        if kind == "pose":
            p, R = values[key]
            out[key] = (p + delta[o:o + 3], R @ so3_exp(delta[o + 3:o + 6]))
        else:
            out[key] = np.asarray(values[key], float) + delta[o:o + DIMS[kind]]
    return out


def _linearize(graph: Graph, values: dict, losses: dict, off: dict, k: int):
    """(A sparse (rows, k), b (rows,), cost): IRLS-weighted whitened system and robust cost."""
    rows, cols, vals, b = [], [], [], []
    f = 0.0
    r0 = 0
    for fac in graph.factors:
        e, jac = fac.linearize(values, graph.kinds)
        s = float(np.linalg.norm(e))
        loss = losses.get(fac.kind)
        f += float(loss_rho(loss, s))
        sw = float(np.sqrt(loss_weight(loss, s)))
        d = e.size
        for key, J in jac.items():
            if key in off:
                rr, cc = np.meshgrid(r0 + np.arange(d), off[key] + np.arange(J.shape[1]), indexing="ij")
                rows.append(rr.ravel())
                cols.append(cc.ravel())
                vals.append(sw * np.asarray(J, float).ravel())
        b.append(sw * e)
        r0 += d
    cat = (lambda xs: np.concatenate(xs)) if rows else (lambda xs: np.zeros(0))
    A = sparse.csr_matrix((cat(vals), (cat(rows).astype(np.int64), cat(cols).astype(np.int64))), shape=(r0, k))
    return A, np.concatenate(b) if b else np.zeros(0), f


def solve_graph(graph: Graph, init: dict, *, method: str = "lm", losses: dict | None = None, max_iter: int = 100,
                step_tol: float = 1e-10, cost_tol: float = 1e-14, covariance: bool = True) -> GraphResult:
    """Solve the graph from the initial values init ({key: value}, every variable; fixed ones are
    held there). losses: {factor kind: Loss} ("prior", "range", "height", "motion")."""
    missing = set(graph.kinds) - set(init)
    if missing:
        raise ValueError(f"solve_graph: no initial value for {sorted(map(str, missing))}")
    losses = dict(losses or {})
    for kind, loss in losses.items():
        if not isinstance(loss, Loss):
            raise ValueError(f"solve_graph: losses[{kind!r}] must be a Loss, got {loss!r}")
    off, k = _offsets(graph)
    values = {key: (tuple(np.asarray(v, float) for v in init[key]) if graph.kinds[key] == "pose"
                    else np.atleast_1d(np.asarray(init[key], float))) for key in graph.kinds}
    res = minimize(values, lambda v: _linearize(graph, v, losses, off, k)[2],
                   lambda v: _linearize(graph, v, losses, off, k)[:2],
                   lambda v, d: _retract(graph, off, v, d), method=method, max_iter=max_iter,
                   step_tol=step_tol, cost_tol=cost_tol)
    fac = factor_spd(res.N)
    if not fac.observable:
        warnings.warn(f"solve_graph: the problem is unobservable (gauge freedom; smallest relative pivot "
                      f"{fac.min_pivot_ratio:.1e}): the estimate is one of many optima", GaugeWarning, stacklevel=2)
    cov = {}
    if covariance:
        full = fac.solve(np.eye(k)) if fac.observable else np.full((k, k), np.nan)
        for key, o in off.items():
            d = DIMS[graph.kinds[key]]
            cov[key] = full[o:o + d, o:o + d]
    return GraphResult(res.x, cov, res.cost, res.iterations, res.converged, res.history, fac.observable, res.report)
