"""Cooperative inertial navigation of a swarm: one IMU error-state EKF per vehicle, batched over
the vehicles, updated by GNSS fixes, UWB ranges to anchors and UWB ranges between vehicles
(the estimate a swarm flies on through GNSS-denied space: docs/denied.md).

Per vehicle i the nominal state (world ENU, body FLU): position p (3) m and velocity v (3) m/s
of the IMU (the body origin), attitude q (4) wxyz body-to-world, accelerometer bias b_a (3) m/s^2
and gyro bias b_g (3) rad/s; the swarm's are arrays p, v, b_a, b_g (n, 3) and q (n, 4). Error
state per vehicle (15,): dp, dv, dtheta (rad, body: R_true = R Exp(dtheta)), db_a, db_g; the
swarm's error state is vehicle-major (15 n,), covariance P (15 n, 15 n).

Mechanization (Sola, "Quaternion kinematics for the error-state Kalman filter", 2017, eq. 260),
one IMU sample f (specific force, m/s^2), w (rate, rad/s) held over dt:
    a = R (f - b_a) + g,  g = (0, 0, -9.81) m/s^2
    p <- p + v dt + a dt^2 / 2;  v <- v + a dt;  q <- q (x) Exp((w - b_g) dt)
Error transition F (15, 15) per vehicle (the exact Jacobian of that step):
    F[p,v] = I dt, F[p,th] = -R [f_c]x dt^2/2, F[p,ba] = -R dt^2/2, F[v,th] = -R [f_c]x dt,
    F[v,ba] = -R dt, F[th,th] = Exp(w_c dt)^T, F[th,bg] = -J_r(w_c dt) dt ~ -I dt
Process noise Q: white accelerometer and gyro noise of densities n_a, n_g into v and theta
(n^2 dt), bias random walks q_ba, q_bg into the biases (q^2 dt) (Sola eq. 262).
The covariance is not propagated at every sample: per vehicle the transition and noise since
the last update are accumulated, Phi <- F Phi, Qa <- F Qa F^T + Q, and applied to the joint P
once before an update, P <- Phi P Phi^T + Qa (block-diagonal Phi: the same product as step by
step); each vehicle's own block is formed at every output.

Measurements (lever arm l (3,) m in the body frame of the site a row measures: the GNSS antenna,
any one of the vehicle's UWB tags, a height's site (Rows.lever); s = p + R l,
ds/ddx = [I, 0, -R [l]x, 0, 0]; c_d the antenna delay of UWB device d, a constant state):
    GNSS fix (3 rows)       z = s_i + e                        R = diag(sigma^2)
    height (1 row)          z = e_3^T s_i + e                  (a fix's third row)
    range to an anchor a    z = |s_i - a| + c_i + c_a + e      H_i = u^T ds_i/ddx, u = (s_i - a) / |s_i - a|
    range between i and j   z = |s_i - s_j| + c_i + c_j + e    H_i = u^T ds_i/ddx, H_j = -u^T ds_j/ddx
(a 1 in the columns of the delays). Centralized (`joint=True`): P is the swarm's joint
covariance, the delays shared; a range between two vehicles correlates their errors, and the
next update uses that correlation. Distributed (`joint=False`): P is block-diagonal, each
vehicle's filter its own (its core and its copy of the delays); a range between i and j enters
vehicle i's filter with j's antenna at a point j broadcast (`Rows.other`), known, its covariance
added to the range variance by the caller (testbed.plugins.builtin_coop_ins: var = sigma^2 +
kappa u^T Sigma_j u, and the same range enters j's filter with i's broadcast). The
approximation, stated: j's broadcast error changes slowly and enters every epoch as if new, so
the filters are optimistic (kappa counters it); the exact alternative is the centralized filter.
Update (one per epoch: every measurement of one time of validity): each range weighted by
Huber's function of its normalized innovation at the prior, optionally gated (NIS r^2 / S_kk
above `gate`: rejected, counted; GNSS rows are neither weighted nor gated: a filter that has
become optimistic would otherwise reject the fixes that bring it back); the rows in one iterated
update (Gauss-Newton on the error state), K = P H^T S^-1 by Cholesky, P <- P - K S K^T
(symmetrized), the error injected (x (+) dx; attitude q <- q (x) Exp(dtheta)) and the attitude
block reset G = I - [dtheta / 2]x (Sola eq. 287). Distributed filters (damped=True) take each
Gauss-Newton step only as far as it lowers their MAP cost (a backtracking line search,
SwarmIns._line_search); the centralized update is the undamped one.
Pure numpy/scipy; never imports mujoco or testbed.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import linalg

from estimators.eskf import GRAVITY, ImuNoise
from estimators.graph.losses import huber_weight
from estimators.so3 import quat_exp, quat_mul, quat_to_rotmat, skew

N_ERR = 15  # error states per vehicle
P_, V_, TH, BA, BG = (slice(3 * k, 3 * k + 3) for k in range(5))


@dataclass(frozen=True, kw_only=True, slots=True)
class Rows:
    """The measurement rows of one epoch, m scalar rows in all: value z (m,), variance var (m,),
    and for each row the vehicle i (m,) it is about, the other vehicle j (m,) (-1: none), the
    component (m,) (0..2: a GNSS fix axis; 3: a range), for a range the other end's point other
    (m, 3) m world (an anchor, or the broadcast antenna of j in the distributed filter; NaN where
    j's own state is used: the centralized range between vehicles), and dev (m, 2) the devices
    whose antenna delays bias the range (-1: none; every row of a fix). lever (m, 3) m body frame:
    the site of vehicle i the row measures (a GNSS antenna, a UWB tag, a height's site), lever_j
    (m, 3) the tag of vehicle j (a centralized range between vehicles); None: each vehicle's
    reference antenna (SwarmIns.lever)."""

    z: np.ndarray
    var: np.ndarray
    i: np.ndarray
    j: np.ndarray
    component: np.ndarray
    other: np.ndarray
    dev: np.ndarray
    lever: np.ndarray | None = None
    lever_j: np.ndarray | None = None

    def subset(self, keep: np.ndarray) -> "Rows":
        """The rows `keep` (bool or indices)."""
        return Rows(z=self.z[keep], var=self.var[keep], i=self.i[keep], j=self.j[keep], component=self.component[keep],
                    other=self.other[keep], dev=self.dev[keep], lever=None if self.lever is None else self.lever[keep],
                    lever_j=None if self.lever_j is None else self.lever_j[keep])

    def replace(self, **changes) -> "Rows":
        """These rows with the columns `changes` replaced."""
        return Rows(**{**{f: getattr(self, f) for f in Rows.__dataclass_fields__}, **changes})


def _q_rate(noise: ImuNoise) -> np.ndarray:
    """(15,) diagonal of the continuous process noise of one IMU (per second): white accel and
    gyro densities into v and theta, bias walks into b_a and b_g."""
    q = np.zeros(N_ERR)
    q[V_], q[TH] = noise.accel_density ** 2, noise.gyro_density ** 2
    q[BA], q[BG] = noise.accel_walk ** 2, noise.gyro_walk ** 2
    return q


class SwarmIns:
    """The swarm's IMU error-state EKFs (module docstring). n vehicles; lever (n, 3) m the antenna
    of each (GNSS and UWB on one site); noise: the IMU model, or one per vehicle (a list of n); joint: centralized (True) or
    distributed (False); devices: UWB devices whose antenna delays are states (constant, mean 0,
    variance delay_var m^2 each): shared by the swarm when joint, one copy per vehicle otherwise.

    Storage. joint: P (15 n + D, 15 n + D), the vehicles' blocks first, then the D delays, delays
    c (D,). distributed: P (n, 15 + D, 15 + D), one filter per vehicle (its core, then its copy of
    the delays), delays c (n, D)."""

    def __init__(self, n: int, lever: np.ndarray, noise: ImuNoise | list[ImuNoise], *, joint: bool, devices: int = 0,
                 delay_var: float = 0.0, damped: bool = False):
        self.n, self.joint, self.noise, self.D = int(n), bool(joint), noise, int(devices)
        if damped and self.joint:
            raise ValueError("the damped (line-searched) iterated update is implemented for the distributed filters")
        self.damped = bool(damped)
        self.lever = np.asarray(lever, float).reshape(self.n, 3)
        self.p = np.zeros((n, 3))
        self.v = np.zeros((n, 3))
        self.q = np.tile([1.0, 0.0, 0.0, 0.0], (n, 1))
        self.ba = np.zeros((n, 3))
        self.bg = np.zeros((n, 3))
        D = self.D
        if self.joint:
            self.c = np.zeros(D)
            self.P = np.eye(N_ERR * n + D)
            self.P[N_ERR * n:, N_ERR * n:] = np.eye(D) * delay_var
        else:
            self.c = np.zeros((n, D))
            self.P = np.tile(np.eye(N_ERR + D), (n, 1, 1))
            self.P[:, N_ERR:, N_ERR:] = np.eye(D) * delay_var
        self.active = np.zeros(n, bool)
        self.t = None  # s, the time every active filter is at
        self.Phi = np.tile(np.eye(N_ERR), (n, 1, 1))  # (n, 15, 15) since the last covariance fold
        self.Qa = np.zeros((n, N_ERR, N_ERR))
        self._q_rate = _q_rate(noise) if isinstance(noise, ImuNoise) else np.array([_q_rate(k) for k in noise])  # (15,) or (n, 15) per second
        self._dt, self._F0, self._Q = None, None, None  # the constant part of F and Q over the last dt

    # ------------------------------------------------------------------ start
    def start(self, i: int, p: np.ndarray, q: np.ndarray, ba: np.ndarray, bg: np.ndarray, P0: np.ndarray) -> None:
        """Start vehicle i: body position p (3,) m, velocity 0, attitude q (4,), biases, and its
        core covariance P0 (15, 15) (no correlation with the other vehicles or the delays). Its
        accumulated transition and noise are dropped (its rows and columns of P are replaced); the
        other vehicles' stay pending, as between any two updates."""
        self.Phi[i], self.Qa[i] = np.eye(N_ERR), 0.0
        self.p[i], self.v[i], self.q[i], self.ba[i], self.bg[i] = p, 0.0, q, ba, bg
        if self.joint:
            b = slice(N_ERR * i, N_ERR * i + N_ERR)
            self.P[b, :] = 0.0
            self.P[:, b] = 0.0
            self.P[b, b] = P0
        else:
            self.P[i, :N_ERR, :] = 0.0
            self.P[i, :, :N_ERR] = 0.0
            self.P[i, :N_ERR, :N_ERR] = P0
        self.active[i] = True

    def stop(self, i: int) -> None:
        """Vehicle i's filter stopped (a re-initialisation: it starts again with `start`): inactive,
        its correlations with the other vehicles and the delays dropped."""
        if self.joint:
            b = slice(N_ERR * i, N_ERR * i + N_ERR)
            keep = self.P[b, b].copy()
            self.P[b, :] = 0.0
            self.P[:, b] = 0.0
            self.P[b, b] = keep
        self.active[i] = False

    def innovations(self, rows: Rows) -> tuple[np.ndarray, np.ndarray]:
        """The prior innovations z - h(x) (m,) and their filter parts H_k P H_k^T (m,) of rows about
        active vehicles (each on its own filter when distributed), before an update."""
        self.fold()
        h, Hi, Hj = self._linearize(rows)
        if self.joint:
            H = self._dense(rows, Hi, Hj)
            return rows.z - h, ((H @ self.P) * H).sum(axis=1)
        return rows.z - h, self._row_variances(rows, self._local(rows, Hi))

    def set_white_noise(self, k: np.ndarray, accel_density: np.ndarray, gyro_density: np.ndarray) -> None:
        """Filters k (m,) assume white densities accel_density (m,) m/s^2/sqrt(Hz) and gyro_density
        (m,) rad/s/sqrt(Hz) from now on (their bias walks unchanged); folds what was accumulated."""
        self.fold()
        if self._q_rate.ndim == 1:
            self._q_rate = np.tile(self._q_rate, (self.n, 1))
        self._q_rate[k, V_] = np.asarray(accel_density, float)[:, None] ** 2
        self._q_rate[k, TH] = np.asarray(gyro_density, float)[:, None] ** 2
        self._dt = None  # Q is rebuilt at the next step

    # ------------------------------------------------------------------ propagation
    def propagate(self, f: np.ndarray, w: np.ndarray, dt: float) -> None:
        """Every active vehicle over dt (s) with its held IMU sample f (n, 3) m/s^2, w (n, 3) rad/s
        (rows of inactive vehicles ignored): nominal state, and the accumulated Phi, Qa."""
        if dt <= 0:
            return
        a_ = self.active
        R = quat_to_rotmat(self.q)  # (n, 3, 3)
        fc, wc = f - self.ba, w - self.bg
        # Sola eq. 260: a = R (a_m - a_b) + g
        acc = np.einsum("nij,nj->ni", R, fc) + GRAVITY
        dq = quat_exp(wc * dt)
        qn = quat_mul(self.q, dq)
        p, v, q = self.p + self.v * dt + 0.5 * dt * dt * acc, self.v + acc * dt, qn / np.linalg.norm(qn, axis=1, keepdims=True)
        if a_.all():
            self.p, self.v, self.q = p, v, q
        else:
            self.p, self.v, self.q = (np.where(a_[:, None], new, old) for new, old in ((p, self.p), (v, self.v), (q, self.q)))
        if dt != self._dt:  # the blocks of F and Q that depend on dt only
            self._dt, self._F0 = dt, np.tile(np.eye(N_ERR), (self.n, 1, 1))
            self._F0[:, P_, V_] = np.eye(3) * dt
            self._F0[:, TH, BG] = -np.eye(3) * dt
            q = self._q_rate
            self._Q = np.diag(q * dt) if q.ndim == 1 else q[:, :, None] * np.eye(N_ERR) * dt  # (15, 15) or (n, 15, 15)
        RF = R @ skew(fc)
        F = self._F0.copy()
        F[:, P_, TH] = -0.5 * dt * dt * RF
        F[:, P_, BA] = -0.5 * dt * dt * R
        F[:, V_, TH] = -RF * dt
        F[:, V_, BA] = -R * dt
        F[:, TH, TH] = np.swapaxes(quat_to_rotmat(dq), 1, 2)
        self.Phi = F @ self.Phi
        self.Qa = F @ self.Qa @ np.swapaxes(F, 1, 2) + self._Q

    def _transform(self, M: np.ndarray, Q: np.ndarray | None = None) -> None:
        """P <- M P M^T (+ Q) with M block-diagonal: M_i (n, 15, 15) on each vehicle's core, the
        identity on the delays; Q (n, 15, 15) added to the cores."""
        n, e = self.n, N_ERR
        Mt = np.swapaxes(M, 1, 2)
        if self.joint:
            nv = n * e
            A = self.P[:nv, :nv].reshape(n, e, n, e).transpose(0, 2, 1, 3)  # (n, n, e, e) blocks
            A = M[:, None] @ A @ Mt[None]
            if Q is not None:
                A[np.arange(n), np.arange(n)] += Q
            self.P[:nv, :nv] = A.transpose(0, 2, 1, 3).reshape(nv, nv)
            B = (M @ self.P[:nv, nv:].reshape(n, e, self.D)).reshape(nv, self.D)
            self.P[:nv, nv:] = B
            self.P[nv:, :nv] = B.T
        else:
            P = self.P
            P[:, :e, :e] = M @ P[:, :e, :e] @ Mt + (0.0 if Q is None else Q)
            P[:, :e, e:] = M @ P[:, :e, e:]
            P[:, e:, :e] = np.swapaxes(P[:, :e, e:], 1, 2)

    def fold(self) -> None:
        """Apply the accumulated transition and noise to P (module docstring)."""
        self._transform(self.Phi, self.Qa)
        self.Phi = np.tile(np.eye(N_ERR), (self.n, 1, 1))
        self.Qa = np.zeros((self.n, N_ERR, N_ERR))

    def blocks(self) -> np.ndarray:
        """(n, 15, 15) each vehicle's own core covariance (not folded)."""
        n, e = self.n, N_ERR
        if self.joint:
            return self.P[:n * e, :n * e].reshape(n, e, n, e)[np.arange(n), :, np.arange(n), :]
        return self.P[:, :e, :e]

    def marginals(self, k: slice = slice(None)) -> np.ndarray:
        """(n, 15, 15) each vehicle's core covariance now (the accumulated propagation applied);
        k: of the vehicles k only."""
        Phi = self.Phi[k]
        D = Phi @ self.blocks()[k] @ np.swapaxes(Phi, 1, 2) + self.Qa[k]
        return 0.5 * (D + np.swapaxes(D, 1, 2))

    # ------------------------------------------------------------------ update
    def antennas(self) -> tuple[np.ndarray, np.ndarray]:
        """Reference antenna positions s (n, 3) m world and ds/ddtheta = -R [l]x (n, 3, 3)."""
        R = quat_to_rotmat(self.q)
        return self.p + np.einsum("nij,nj->ni", R, self.lever), -R @ skew(self.lever)

    def _sites(self, i: np.ndarray, lever: np.ndarray | None) -> tuple[np.ndarray, np.ndarray]:
        """Positions s (m, 3) m world of sites at lever (m, 3) m body frame on vehicles i (m,), and
        ds/ddtheta = -R [l]x (m, 3, 3); lever None: the vehicles' reference antennas."""
        if lever is None:
            s, dS = self.antennas()
            return s[i], dS[i]
        R = quat_to_rotmat(self.q)[i]
        return self.p[i] + np.einsum("mij,mj->mi", R, lever), -R @ skew(lever)

    def _linearize(self, rows: Rows, jacobians: bool = True) -> tuple[np.ndarray, np.ndarray | None, np.ndarray | None]:
        """h (m,) at the current state, and the Jacobians: Hi (m, 15) on vehicle i's core, Hj (m, 15)
        on vehicle j's (pair rows of the centralized filter; zero otherwise); the delay columns
        are rows.dev (each 1). jacobians False: h only (Hi, Hj None)."""
        si, dSi = self._sites(rows.i, rows.lever)
        m = rows.z.size
        h = np.zeros(m)
        Hi, Hj = (np.zeros((m, N_ERR)), np.zeros((m, N_ERR))) if jacobians else (None, None)
        fix = rows.component < 3
        k = np.flatnonzero(fix)
        c = rows.component[k]
        h[k] = si[k, c]
        if jacobians:
            Hi[k, c] = 1.0
            Hi[k, 6:9] = dSi[k, c]
        k = np.flatnonzero(~fix)
        if k.size:
            i, j = rows.i[k], rows.j[k]
            known = ~np.isnan(rows.other[k, 0])
            sj, dSj = self._sites(np.maximum(j, 0), None if rows.lever_j is None else rows.lever_j[k])
            d = si[k] - np.where(known[:, None], rows.other[k], sj)
            dist = np.linalg.norm(d, axis=1)
            h[k] = dist
            if self.D:
                dev = np.maximum(rows.dev[k], 0)
                c = self.c[dev] if self.joint else np.take_along_axis(self.c[i], dev, axis=1)
                h[k] += np.where(rows.dev[k] >= 0, c, 0.0).sum(axis=1)
            if jacobians:
                u = d / np.maximum(dist, 1e-9)[:, None]
                Hi[k, 0:3] = u
                Hi[k, 6:9] = np.einsum("mk,mkl->ml", u, dSi[k])
                pair = ~known
                Hj[k[pair], 0:3] = -u[pair]
                Hj[k[pair], 6:9] = -np.einsum("mk,mkl->ml", u[pair], dSj[pair])
        return h, Hi, Hj

    def _dense(self, rows: Rows, Hi: np.ndarray, Hj: np.ndarray) -> np.ndarray:
        """The joint filter's H (m, 15 n + D)."""
        n, e, m = self.n, N_ERR, rows.z.size
        H = np.zeros((m, n * e + self.D))
        r = np.arange(m)
        H[r[:, None], e * rows.i[:, None] + np.arange(e)] = Hi
        pair = np.flatnonzero(rows.j >= 0)
        H[pair[:, None], e * rows.j[pair][:, None] + np.arange(e)] += Hj[pair]
        for col in (0, 1):
            d = np.flatnonzero(rows.dev[:, col] >= 0)
            H[d, n * e + rows.dev[d, col]] += 1.0
        return H

    def _local(self, rows: Rows, Hi: np.ndarray) -> np.ndarray:
        """Each row's H (m, 15 + D) on its own vehicle's filter (distributed)."""
        m = rows.z.size
        H = np.zeros((m, N_ERR + self.D))
        H[:, :N_ERR] = Hi
        for col in (0, 1):
            d = np.flatnonzero(rows.dev[:, col] >= 0)
            H[d, N_ERR + rows.dev[d, col]] += 1.0
        return H

    def update(self, rows: Rows, gate: float, iterations: int = 1, huber: float | None = None) -> np.ndarray:
        """One update with the epoch's rows (module docstring); rows about inactive vehicles (or
        whose other vehicle is inactive, centralized) are skipped. iterations > 1: the iterated
        EKF (Gauss-Newton on the error state, relinearized at x (+) dx_i:
        dx_{i+1} = K_i (z - h(x_i) + H_i dx_i), K_i = P H_i^T (H_i P H_i^T + R)^-1), the covariance
        from the last linearization. huber: each range row's variance divided by the Huber weight
        of its normalized innovation at the prior, nu = r / sqrt(S_kk): w = min(1, huber / |nu|)
        (Huber 1964; the update is then the robust M-estimate's first reweighting: a long-tailed
        range pulls less, but a prior that has gone wrong is still pulled back by every range, where
        a gate would reject them all). Returns (m,) int: 1 used, 0 rejected by the gate, -1 skipped."""
        self.fold()
        m = rows.z.size
        status = np.full(m, -1)
        pair = rows.j >= 0
        use = self.active[rows.i] & (~pair | self.active[np.maximum(rows.j, 0)] | ~np.isnan(rows.other[:, 0]))
        if not use.any():
            return status
        k = np.flatnonzero(use)
        rows = rows.subset(k)
        h, Hi, Hj = self._linearize(rows)
        r = rows.z - h
        # the prior innovation variance of each row, H_k P H_k^T + R_k
        if self.joint:
            H = self._dense(rows, Hi, Hj)
            S_diag = ((H @ self.P) * H).sum(axis=1) + rows.var
        else:
            H = self._local(rows, Hi)
            S_diag = self._row_variances(rows, H) + rows.var
        ok = (r ** 2 <= gate * S_diag) | (rows.component < 3)  # GNSS rows are not gated
        status[k] = ok.astype(int)
        if not ok.any():
            return status
        if huber is not None:
            nu = np.abs(r) / np.sqrt(S_diag)
            w = np.where(rows.component == 3, huber_weight(nu, huber), 1.0)
            rows = rows.replace(var=rows.var / w)
        rows = rows.subset(ok)
        step = self._joint_step if self.joint else self._local_step
        dx, g = None, None  # the iterate (None: the prior) and P^-1 times it (damped only; P is the prior until the end)
        h, Hi, Hj = h[ok], Hi[ok], Hj[ok]  # the rows' linearization at the prior, computed above
        last = max(1, int(iterations)) - 1
        for it in range(last + 1):
            if it:
                h, Hi, Hj = self._linearize_at(rows, dx)
            dx_gn, P, g_gn = step(rows, h, Hi, Hj, dx, covariance=it == last)  # the covariance of the last linearization only
            if self.damped:
                dx, g = self._line_search(rows, dx, g, dx_gn, g_gn, h)
            else:
                dx = dx_gn
        self._inject(dx)
        self.P = P
        # Sola eq. 287: reset of each attitude error block after injection
        core = dx[0]
        G = np.tile(np.eye(N_ERR), (self.n, 1, 1))
        G[:, TH, TH] -= skew(0.5 * core[:, TH])
        self._transform(G)
        self.P = np.add(self.P, np.swapaxes(self.P, -1, -2))  # symmetrized: (P + P^T) / 2, the same numbers
        self.P *= 0.5  # as 0.5 * (P + P^T) with one temporary fewer (a third of the time at 100 vehicles)
        return status

    def _joint_step(self, rows, h, Hi, Hj, dx, covariance: bool = True):
        """One Gauss-Newton step of the joint filter: (dx as (core (n, 15), delays (D,)), P after
        (None unless covariance), None)."""
        n, e = self.n, N_ERR
        H = self._dense(rows, Hi, Hj)
        x = np.zeros(n * e + self.D) if dx is None else np.concatenate([dx[0].ravel(), dx[1]])
        PHt = self.P @ H.T
        S = H @ PHt + np.diag(rows.var)
        cf = linalg.cho_factor(0.5 * (S + S.T), lower=True, check_finite=False)
        x = PHt @ linalg.cho_solve(cf, rows.z - h + H @ x, check_finite=False)
        if not covariance:
            return (x[:n * e].reshape(n, e), x[n * e:]), None, None
        L = linalg.solve_triangular(cf[0], PHt.T, lower=True, check_finite=False)  # L^-1 H P
        return (x[:n * e].reshape(n, e), x[n * e:]), self.P - L.T @ L, None

    def _padded(self, rows: Rows, H: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """The rows grouped by vehicle (distributed): order (m,) the rows sorted by vehicle (stable),
        vi, sl (m,) the vehicle and slot of each sorted row, Hb (n, M, E) each vehicle's rows of
        H (m, E), zero-padded to the most rows M of any vehicle."""
        order = np.argsort(rows.i, kind="stable")
        counts = np.bincount(rows.i, minlength=self.n)
        sl = np.arange(rows.i.size) - np.repeat(np.cumsum(counts) - counts, counts)  # position within its vehicle
        vi = rows.i[order]
        Hb = np.zeros((self.n, max(int(counts.max()), 1), H.shape[1]))
        Hb[vi, sl] = H[order]
        return order, vi, sl, Hb

    def _row_variances(self, rows: Rows, H: np.ndarray) -> np.ndarray:
        """(m,) H_k P H_k^T of each row k on its own vehicle's filter (distributed), a batched
        product per vehicle's padded rows (not each row's (E, E) covariance gathered)."""
        order, vi, sl, Hb = self._padded(rows, H)
        S = ((Hb @ self.P) * Hb).sum(axis=2)  # (n, M)
        out = np.empty(rows.z.size)
        out[order] = S[vi, sl]
        return out

    def _local_step(self, rows, h, Hi, Hj, dx, covariance: bool = True):
        """One Gauss-Newton step of every vehicle's filter at once (rows grouped by vehicle,
        padded): (dx as (core (n, 15), delays (n, D)), P after (None unless covariance),
        P^-1 dx (n, E)). The step is
        dx = P H^T lam, lam = S^-1 (z - h + H dx_prev), so P^-1 dx = H^T lam needs no inverse of P
        (the line search's prior cost)."""
        n, E = self.n, N_ERR + self.D
        H = self._local(rows, Hi)
        order, vi, sl, Hb = self._padded(rows, H)
        M = Hb.shape[1]
        x = np.zeros((n, E)) if dx is None else np.concatenate([dx[0], dx[1]], axis=1)
        rb = np.zeros((n, M))
        rb[vi, sl] = (rows.z - h)[order] + np.einsum("me,me->m", H[order], x[vi])
        Rb = np.ones((n, M))
        Rb[vi, sl] = rows.var[order]
        HP = Hb @ self.P  # (n, M, E): H P (P symmetric; contiguous operands: a third of P H^T's time)
        S = HP @ np.swapaxes(Hb, 1, 2) + Rb[:, :, None] * np.eye(M)
        L = np.linalg.cholesky(0.5 * (S + np.swapaxes(S, 1, 2)))
        y = np.linalg.solve(L, rb[..., None])  # (n, M, 1): L^-1 r, batched in C
        lam = np.linalg.solve(np.swapaxes(L, 1, 2), y)  # L^-T L^-1 r = S^-1 r
        x = (np.swapaxes(HP, 1, 2) @ lam)[..., 0]
        P = None
        if covariance:
            W = np.linalg.solve(L, HP)  # (n, M, E): L^-1 H P
            P = np.ascontiguousarray(np.swapaxes(W, 1, 2)) @ W  # one new (n, E, E) array, P subtracted in place
            np.subtract(self.P, P, out=P)
        return (x[:, :N_ERR], x[:, N_ERR:]), P, (np.swapaxes(Hb, 1, 2) @ lam)[..., 0]

    STEPS = (1.0, 0.5, 0.25, 0.125)  # step lengths tried by the line search, longest first (else 0)

    def _line_search(self, rows: Rows, dx, g, dx_gn, g_gn: np.ndarray, h: np.ndarray):
        """The damped iterated update (distributed filters): from the current iterate dx (None: the
        prior) towards the Gauss-Newton iterate dx_gn, per filter the longest step of STEPS that
        does not raise the MAP cost V(d) = d^T P^-1 d + sum_k r_k(x (+) d)^2 / var_k of its rows
        (Skoglund, Hendeby, Axehill 2015, the iterated EKF with a line search). Undamped,
        Gauss-Newton overshoots where a precise range meets metres of prior uncertainty along a
        direction it barely observes (one anchor 46 m away, 3.6 m vertical sigma: measured, the
        vertical iterate went 16.8 -> 9.6 -> 34.3 m and the covariance linearized there claimed
        0.7 m), and the filter ends confident at a wrong point. g, g_gn (n, E): P^-1 dx and
        P^-1 dx_gn (g None with dx None: zero), so that P^-1 of every point tried, on the segment
        between them, is their same combination; h (m,): the rows' predictions at x (+) dx (those
        of the Gauss-Newton step just taken). Returns the iterate taken and P^-1 times it."""
        x1 = np.concatenate(dx_gn, axis=1)  # (n, E)
        x = np.zeros_like(x1) if dx is None else np.concatenate(dx, axis=1)
        g = np.zeros_like(x1) if g is None else g

        def cost(step: float) -> np.ndarray:
            return self._cost(rows, x + step * (x1 - x), g + step * (g_gn - g))

        # V at the current iterate (at the prior, dx None, the state is taken through x (+) 0 as at
        # the other steps: its renormalized attitude can differ from the state's in the last bit)
        bound = (cost(0.0) if dx is None else self._cost(rows, x, g, h)) * (1 + 1e-12)
        a = np.zeros(self.n)  # per filter the longest step that does not raise V
        open_ = np.ones(self.n, bool)
        for step in self.STEPS:  # shorter steps only while some filter has none yet
            ok = open_ & (cost(step) <= bound)
            a[ok], open_ = step, open_ & ~ok
            if not open_.any():
                break
        x, g = x + a[:, None] * (x1 - x), g + a[:, None] * (g_gn - g)
        return (x[:, :N_ERR], x[:, N_ERR:]), g

    def _cost(self, rows: Rows, x: np.ndarray, g: np.ndarray, h: np.ndarray | None = None) -> np.ndarray:
        """(n,) the MAP cost of each filter at x (+) d, d = x (n, E) split into core and delays
        (_line_search): d^T P^-1 d + sum over its rows of r^2 / var; g (n, E): P^-1 x; h (m,):
        the rows' predictions there if known."""
        prior = (g * x).sum(axis=1)
        if h is None:
            h, _, _ = self._linearize_at(rows, (x[:, :N_ERR], x[:, N_ERR:]), jacobians=False)
        return prior + np.bincount(rows.i, (rows.z - h) ** 2 / rows.var, minlength=self.n)

    def _linearize_at(self, rows: Rows, dx, jacobians: bool = True):
        """_linearize at x (+) dx (dx None: at x), the state left as it was."""
        if dx is None:
            return self._linearize(rows, jacobians)
        x0 = (self.p, self.v, self.q, self.ba, self.bg, self.c)
        self._inject(dx)
        try:
            return self._linearize(rows, jacobians)
        finally:
            self.p, self.v, self.q, self.ba, self.bg, self.c = x0

    def _inject(self, dx) -> None:
        """x (+) dx for every vehicle, dx = (core (n, 15), delays (D,) joint or (n, D))."""
        core, dc = dx
        self.p = self.p + core[:, P_]
        self.v = self.v + core[:, V_]
        qn = quat_mul(self.q, quat_exp(core[:, TH]))
        self.q = qn / np.linalg.norm(qn, axis=1, keepdims=True)
        self.ba = self.ba + core[:, BA]
        self.bg = self.bg + core[:, BG]
        self.c = self.c + dc
