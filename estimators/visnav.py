"""INS + vision (VisNav) relative navigation model of seed 004, for the filters of sigma_filters.

Frames (testbed conventions): world W is z-up; body frames are FLU (x forward, y left, z up);
quaternions are wxyz; R_a_from_b maps b-frame coordinates to a. L = leader body, F = follower
body, C = the leader's camera. The IMU of each vehicle sits at its body origin (a lever arm is
part of the configuration of whoever feeds this model; LED and camera positions are given
relative to the IMU/body origin).

State (mean, nx = 22; error state / covariance, n = 21):

    mean  error  symbol  meaning                                                 unit
    0:3   0:3    p       R_L^T (p_F - p_L): follower origin in the leader frame   m
    3:6   3:6    v       R_L^T (v_F - v_L): relative world velocity in L frame    m/s
    6:10  6:9    q/th    q = R_rel = R_L^T R_F (wxyz); error th: R = R^ Exp(th),   - / rad
                         th in the follower body frame (right perturbation)
    10:13 9:12   bgF     follower gyro bias (eq. 1-2)                             rad/s
    13:16 12:15  baF     follower accelerometer bias (eq. 3-4)                     m/s^2
    16:19 15:18  bgL     leader gyro bias                                         rad/s
    19:22 18:21  baL     leader accelerometer bias                                 m/s^2

Both vehicles' biases are states: only the combinations R_rel baF - baL and R_rel bgF - bgL
(and bgL weakly, through the -w_L x terms) are observable from relative vision; the rest keep
their prior covariance, which is consistent as long as the prior is honest.

Continuous dynamics (w_L, w_F body rates, f_L, f_F specific forces, all true values):
    dp/dt = -w_L x p + v
    dv/dt = -w_L x v + R_rel f_F - f_L        (gravity cancels: no gravity model needed)
    dR_rel/dt = R_rel [w_F]x - [w_L]x R_rel
    biases: random walks (random constants if their densities are zero).
IMU model (eq. 1-4): w_meas = (I + Kg) w + bg + eta, a_meas = (I + Ka) a + ba + eta; Kg, Ka are
known calibrations (configuration, default 0) inverted in the model: w = (I + Kg)^-1 (w_meas - bg).

Discretization over dt with the IMU readings held over the step (feed readings representative of
the interval, e.g. mid-interval samples or increments / dt). With A = Exp(-w_L dt/2),
B = Exp(w_F dt/2):
    R_mid = A R B,  R' = A R_mid B          (exact for constant rates)
    g = R_mid f_F - f_L                      (relative acceleration at mid-step, mid-step L frame)
    v' = A (A v + dt g)
    p' = A (A (p + dt v) + dt^2/2 g)          (second order in dt)
The error-state Jacobian F is the exact Jacobian of this map (tested against central differences).
Process noise: the IMU white noises (densities N, sampled as N^2/dt per reading) are mapped by
the input Jacobian, which equals minus the bias columns of F; bias random walks add N_b^2 dt.

Input u (12,) per step: [w_L_meas (3) rad/s, f_L_meas (3) m/s^2, w_F_meas (3), f_F_meas (3)],
each in its own body frame: the raw IMU readings of BOTH vehicles.

Measurements (eq. 5-13). The camera sits at c (3,) m in L, with rotation R_cam = R_L_from_C.
Camera convention = MuJoCo's: camera x right, y up, boresight along -z. LED i sits at X_i (3,) m
in F. Line of sight in C:
    r_i = R_cam^T (p + R_rel X_i - c),   b_i = r_i / |r_i|                    (eq. 9-10)
QUEST noise (eq. 13) sigma^2 (I - b b^T) is singular: we use the tangent-plane form. For each
LED, T_i (3, 2) holds two unit vectors orthogonal to the PREDICTED b_i (prior mean); the
measurement is y_i = T_i^T b_meas_i, h_i(x) = T_i^T b_i(x), R_i = sigma^2 I_2 (= T^T R_QUEST T
at the prediction). Focal-plane option (eq. 5-8), in the MuJoCo camera frame:
    alpha_i = -f r_x / r_z,  beta_i = -f r_y / r_z   (r_z < 0 in front: alpha right, beta up),
    R_i^FOCAL of eq. 8 with constants sigma, d, evaluated at the predicted (alpha, beta).

Pure numpy; never imports mujoco or testbed.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from estimators.so3 import quat_conj, quat_exp, quat_log, quat_mul, quat_to_rotmat, skew, so3_right_jacobian
from estimators.sigma_filters import ComposedFilter, FunctionMeasurement, ManifoldGaussian
from estimators.visnav_paper import (  # the paper's values (section 3.1), SI units
    PAPER_ACCEL_BIAS, PAPER_ACCEL_NOISE, PAPER_FOCAL_LENGTH, PAPER_GYRO_BIAS, PAPER_GYRO_NOISE, PAPER_VISION_SIGMA,
)


# state layout
P_, V_, Q_ = slice(0, 3), slice(3, 6), slice(6, 10)
BGF_, BAF_, BGL_, BAL_ = slice(10, 13), slice(13, 16), slice(16, 19), slice(19, 22)
dP, dV, dTH = slice(0, 3), slice(3, 6), slice(6, 9)
dBGF, dBAF, dBGL, dBAL = slice(9, 12), slice(12, 15), slice(15, 18), slice(18, 21)
NX, N_ERR = 22, 21


# --------------------------------------------------------------------------------------------
# Configuration
# --------------------------------------------------------------------------------------------
def _arr(x, shape, name):
    a = np.array(x, dtype=float)
    if a.shape != shape:
        raise ValueError(f"{name}: expected shape {shape}, got {a.shape}")
    a.setflags(write=False)
    return a


@dataclass(frozen=True, kw_only=True, slots=True, eq=False)
class ImuNoise:
    """Error model of one IMU as the filter knows it (paper eq. 1-4).

    gyro_noise: rad/sqrt(s) (white-noise density of eta_gv); accel_noise: m/s/sqrt(s) (eta_av);
    gyro_bias_rw: rad/s/sqrt(s) (eta_gu); accel_bias_rw: m/s^2/sqrt(s) (eta_au; 0 = the paper's
    constant ba); gyro_bias_sigma, accel_bias_sigma: prior std of the biases (rad/s, m/s^2);
    Kg, Ka: (3, 3) known scale-factor/misalignment matrices (dimensionless), corrected for.
    Defaults: the paper's values (section 3.1), gyro bias random walk 0 (not given).
    """

    gyro_noise: float = PAPER_GYRO_NOISE
    accel_noise: float = PAPER_ACCEL_NOISE
    gyro_bias_rw: float = 0.0
    accel_bias_rw: float = 0.0
    gyro_bias_sigma: float = PAPER_GYRO_BIAS
    accel_bias_sigma: float = PAPER_ACCEL_BIAS
    Kg: np.ndarray = field(default_factory=lambda: np.zeros((3, 3)))
    Ka: np.ndarray = field(default_factory=lambda: np.zeros((3, 3)))

    def __post_init__(self) -> None:
        object.__setattr__(self, "Kg", _arr(self.Kg, (3, 3), "ImuNoise.Kg"))
        object.__setattr__(self, "Ka", _arr(self.Ka, (3, 3), "ImuNoise.Ka"))
        for name in ("gyro_noise", "accel_noise", "gyro_bias_rw", "accel_bias_rw",
                     "gyro_bias_sigma", "accel_bias_sigma"):
            if not getattr(self, name) >= 0.0:
                raise ValueError(f"ImuNoise.{name} must be >= 0")


@dataclass(frozen=True, kw_only=True, slots=True, eq=False)
class VisNavConfig:
    """Camera, beacons and sensor errors known to the filter.

    cam_pos: (3,) m, camera origin in the leader body frame; cam_rot: (3, 3) R_L_from_C (MuJoCo
    camera axes: x right, y up, boresight -z); led_pos: (K, 3) m, LEDs in the follower body frame
    (as known to the filter: pass the surveyed values, errors are the caller's to configure);
    los_sigma: rad, LOS noise (tangent-plane std per axis); focal_length: m; focal_sigma: m on the
    focal plane (eq. 8 sigma); focal_d: eq. 8 constant d (not given by the paper);
    imu_leader, imu_follower: ImuNoise.
    """

    cam_pos: np.ndarray
    cam_rot: np.ndarray
    led_pos: np.ndarray
    los_sigma: float = PAPER_VISION_SIGMA
    focal_length: float = PAPER_FOCAL_LENGTH
    focal_sigma: float = PAPER_VISION_SIGMA * PAPER_FOCAL_LENGTH
    focal_d: float = 1.0
    imu_leader: ImuNoise = field(default_factory=ImuNoise)
    imu_follower: ImuNoise = field(default_factory=ImuNoise)

    def __post_init__(self) -> None:
        object.__setattr__(self, "cam_pos", _arr(self.cam_pos, (3,), "VisNavConfig.cam_pos"))
        object.__setattr__(self, "cam_rot", _arr(self.cam_rot, (3, 3), "VisNavConfig.cam_rot"))
        led = np.array(self.led_pos, dtype=float)
        if led.ndim != 2 or led.shape[1] != 3 or led.shape[0] < 1:
            raise ValueError(f"VisNavConfig.led_pos: expected (K, 3), got {led.shape}")
        object.__setattr__(self, "led_pos", _arr(led, led.shape, "VisNavConfig.led_pos"))
        if not np.allclose(self.cam_rot.T @ self.cam_rot, np.eye(3), atol=1e-9) or np.linalg.det(self.cam_rot) < 0:
            raise ValueError("VisNavConfig.cam_rot must be a rotation matrix")
        if not (self.los_sigma > 0 and self.focal_length > 0 and self.focal_sigma > 0 and self.focal_d >= 0):
            raise ValueError("VisNavConfig: los_sigma, focal_length, focal_sigma must be > 0, focal_d >= 0")


def _inverse_calibration(K: np.ndarray) -> np.ndarray:
    """(I + K)^-1 (3, 3) by a linear solve: maps a bias-free reading back to the true quantity."""
    return np.linalg.solve(np.eye(3) + K, np.eye(3))


def make_state(p, v, q, bgF=None, baF=None, bgL=None, baL=None) -> np.ndarray:
    """Mean vector (22,) from its parts (units and frames as in the module docstring)."""
    z = np.zeros(3)
    q = np.asarray(q, dtype=float)
    return np.concatenate([p, v, q / np.linalg.norm(q), *(z if b is None else b for b in (bgF, baF, bgL, baL))])


def imu_input(w_L, f_L, w_F, f_F) -> np.ndarray:
    """Input vector u (12,) from the measured rates (rad/s) and specific forces (m/s^2), body frames."""
    return np.concatenate([w_L, f_L, w_F, f_F]).astype(float)


# --------------------------------------------------------------------------------------------
# The model
# --------------------------------------------------------------------------------------------
@dataclass(frozen=True, slots=True, eq=False)
class RelNavModel:
    """Relative-navigation model (StateSpaceModel of sigma_filters). See the module docstring."""

    config: VisNavConfig
    dim: int = field(default=N_ERR, init=False)
    _M: tuple = field(init=False, repr=False)

    def __post_init__(self) -> None:
        cL, cF = self.config.imu_leader, self.config.imu_follower
        # (MgL, MaL, MgF, MaF): (I + K)^-1 of the known calibrations
        object.__setattr__(self, "_M", tuple(_inverse_calibration(K) for K in (cL.Kg, cL.Ka, cF.Kg, cF.Ka)))

    # ---- manifold ----
    def boxplus(self, X: np.ndarray, dX: np.ndarray) -> np.ndarray:
        """X (+) dX: X (N, 22), dX (N, 21) -> (N, 22); attitude q (x) Exp(dth)."""
        out = np.empty(np.broadcast_shapes(X.shape, dX.shape[:-1] + (NX,)))
        out[..., 0:6] = X[..., 0:6] + dX[..., 0:6]
        q = quat_mul(X[..., Q_], quat_exp(dX[..., dTH]))
        out[..., Q_] = q / np.linalg.norm(q, axis=-1, keepdims=True)
        out[..., 10:22] = X[..., 10:22] + dX[..., 9:21]
        return out

    def boxminus(self, Xa: np.ndarray, Xb: np.ndarray) -> np.ndarray:
        """Xa (-) Xb: (N, 22) x2 -> (N, 21); attitude Log(q_b^-1 (x) q_a)."""
        out = np.empty(Xa.shape[:-1] + (N_ERR,))
        out[..., 0:6] = Xa[..., 0:6] - Xb[..., 0:6]
        out[..., dTH] = quat_log(quat_mul(quat_conj(Xb[..., Q_]), Xa[..., Q_]))
        out[..., 9:21] = Xa[..., 10:22] - Xb[..., 10:22]
        return out

    # ---- inputs ----
    def _corrected(self, X: np.ndarray, u: np.ndarray):
        """Bias- and calibration-corrected (w_L, f_L, w_F, f_F), each (N, 3), and the maps M."""
        MgL, MaL, MgF, MaF = self._M
        u = np.asarray(u, dtype=float)
        # eq. 1 and 3 solved for the true rate / specific force (noise is the filter's Q)
        wL = (u[0:3] - X[..., BGL_]) @ MgL.T
        fL = (u[3:6] - X[..., BAL_]) @ MaL.T
        wF = (u[6:9] - X[..., BGF_]) @ MgF.T
        fF = (u[9:12] - X[..., BAF_]) @ MaF.T
        return wL, fL, wF, fF, (MgL, MaL, MgF, MaF)

    # ---- process ----
    def f(self, X: np.ndarray, u: np.ndarray, dt: float) -> np.ndarray:
        """Propagate a batch of states X (N, 22) over dt s with the IMU readings u (12,)."""
        wL, fL, wF, fF, _ = self._corrected(X, u)
        qA = quat_exp(-0.5 * dt * wL)
        qB = quat_exp(0.5 * dt * wF)
        A = quat_to_rotmat(qA)
        q_mid = quat_mul(quat_mul(qA, X[..., Q_]), qB)
        R_mid = quat_to_rotmat(q_mid)
        q_new = quat_mul(quat_mul(qA, q_mid), qB)
        # dv/dt = -w_L x v + R_rel f_F - f_L, evaluated at mid-step
        g = np.einsum("nij,nj->ni", R_mid, fF) - fL

        def av(M, y):
            return np.einsum("nij,nj->ni", M, y)

        out = X.copy()
        out[..., V_] = av(A, av(A, X[..., V_]) + dt * g)
        out[..., P_] = av(A, av(A, X[..., P_] + dt * X[..., V_]) + 0.5 * dt * dt * g)
        out[..., Q_] = q_new / np.linalg.norm(q_new, axis=-1, keepdims=True)
        return out

    def F(self, x: np.ndarray, u: np.ndarray, dt: float) -> np.ndarray:
        """Error-state transition (21, 21) of f at x (22,): dx' = F dx (exact Jacobian of f)."""
        X = x[None, :]
        wL, fL, wF, fF, (MgL, MaL, MgF, MaF) = self._corrected(X, u)
        wL, fL, wF, fF = wL[0], fL[0], wF[0], fF[0]
        A = quat_to_rotmat(quat_exp(-0.5 * dt * wL))
        B = quat_to_rotmat(quat_exp(0.5 * dt * wF))
        R = quat_to_rotmat(x[Q_])
        R_mid = A @ R @ B
        p, v = x[P_], x[V_]
        g = R_mid @ fF - fL
        # A(bgL + db) = A Exp(aA db); B(bgF + db) = B Exp(-bB db)
        aA = so3_right_jacobian(-0.5 * dt * wL) @ (0.5 * dt * MgL)
        bB = so3_right_jacobian(0.5 * dt * wF) @ (0.5 * dt * MgF)

        def block(sl, M=np.eye(3)):
            out = np.zeros((3, N_ERR))
            out[:, sl] = M
            return out

        # d(R_mid) = Exp(dm): dm = B^T dth - bB dbgF + (R B)^T aA dbgL
        dm = B.T @ block(dTH) - block(dBGF, bB) + block(dBGL, (R @ B).T @ aA)
        dth_new = B.T @ dm - block(dBGF, bB) + block(dBGL, (R_mid @ B).T @ aA)
        dg = -R_mid @ skew(fF) @ dm - block(dBAF, R_mid @ MaF) + block(dBAL, MaL)
        # v' = A u_v, u_v = A v + dt g
        u_v = A @ v + dt * g
        du_v = A @ block(dV) - block(dBGL, A @ skew(v) @ aA) + dt * dg
        dv_new = A @ du_v - block(dBGL, A @ skew(u_v) @ aA)
        # p' = A u_p, u_p = A w + dt^2/2 g, w = p + dt v
        w = p + dt * v
        u_p = A @ w + 0.5 * dt * dt * g
        du_p = A @ (block(dP) + dt * block(dV)) - block(dBGL, A @ skew(w) @ aA) + 0.5 * dt * dt * dg
        dp_new = A @ du_p - block(dBGL, A @ skew(u_p) @ aA)
        Fm = np.eye(N_ERR)
        Fm[dP] = dp_new
        Fm[dV] = dv_new
        Fm[dTH] = dth_new
        return Fm

    def Q(self, x: np.ndarray, u: np.ndarray, dt: float) -> np.ndarray:
        """Process noise (21, 21) over dt at x: IMU white noise through the input Jacobian
        (= minus the bias columns of F), plus the bias random walks."""
        cL, cF = self.config.imu_leader, self.config.imu_follower
        Fm = self.F(x, u, dt)
        G = -Fm[:, 9:21]   # inputs in the order of the bias states: w_F, f_F, w_L, f_L
        G[9:21] = 0.0
        q_in = np.repeat([cF.gyro_noise ** 2, cF.accel_noise ** 2, cL.gyro_noise ** 2, cL.accel_noise ** 2], 3) / dt
        Qm = (G * q_in) @ G.T
        q_rw = np.repeat([cF.gyro_bias_rw ** 2, cF.accel_bias_rw ** 2,
                          cL.gyro_bias_rw ** 2, cL.accel_bias_rw ** 2], 3) * dt
        Qm[9:21, 9:21] += np.diag(q_rw)
        return 0.5 * (Qm + Qm.T)

    # ---- prior ----
    def initial_cov(self, sigma_p: float, sigma_v: float, sigma_att: float) -> np.ndarray:
        """Diagonal prior (21, 21): position m, velocity m/s, attitude rad (per axis); biases from
        the ImuNoise prior stds."""
        cL, cF = self.config.imu_leader, self.config.imu_follower
        s = np.concatenate([np.full(3, sigma_p), np.full(3, sigma_v), np.full(3, sigma_att),
                            np.full(3, cF.gyro_bias_sigma), np.full(3, cF.accel_bias_sigma),
                            np.full(3, cL.gyro_bias_sigma), np.full(3, cL.accel_bias_sigma)])
        return np.diag(s ** 2)

    # ---- measurement geometry ----
    def camera_points(self, X: np.ndarray, leds: np.ndarray | None = None) -> np.ndarray:
        """LED positions in the camera frame r_i = R_cam^T (p + R_rel X_i - c): (N, K, 3) m."""
        led = self.config.led_pos if leds is None else self.config.led_pos[np.asarray(leds)]
        R = quat_to_rotmat(X[..., Q_])                                   # (N, 3, 3)
        # eq. 9-10 (numerator): p + R_rel X_i in L, seen from the camera, in camera axes
        r_L = X[..., None, P_] + np.einsum("nij,kj->nki", R, led) - self.config.cam_pos
        return r_L @ self.config.cam_rot                                 # rows: R_cam^T r

    def los(self, X: np.ndarray, leds: np.ndarray | None = None) -> np.ndarray:
        """Unit lines of sight b_i in the camera frame (eq. 9-10): (N, K, 3)."""
        r = self.camera_points(X, leds)
        # eq. 10: normalization
        return r / np.linalg.norm(r, axis=-1, keepdims=True)

    def focal(self, X: np.ndarray, leds: np.ndarray | None = None) -> np.ndarray:
        """Focal-plane coordinates (alpha, beta) (eq. 5-6, MuJoCo camera axes): (N, K, 2) m."""
        r = self.camera_points(X, leds)
        # eq. 5-6
        return -self.config.focal_length * r[..., :2] / r[..., 2:3]

    def _camera_point_jacobian(self, x: np.ndarray, leds: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """r (K, 3) and dr/ddx (K, 3, 21) at x."""
        r = self.camera_points(x[None, :], leds)[0]
        R = quat_to_rotmat(x[Q_])
        Rc = self.config.cam_rot
        led = self.config.led_pos[leds]
        J = np.zeros((led.shape[0], 3, N_ERR))
        J[:, :, dP] = Rc.T
        # d(R Exp(th) X)/dth = -R [X]x
        J[:, :, dTH] = -np.einsum("ij,jk,nkl->nil", Rc.T, R, skew(led))
        return r, J

    # ---- measurements ----
    def los_measurement(self, x_prior: np.ndarray, b_meas: np.ndarray, leds=None) -> FunctionMeasurement:
        """Tangent-plane LOS measurement of LEDs ``leds`` (K,) (default: all), measured unit vectors
        b_meas (K, 3) in the camera frame; built about the prior mean x_prior (22,). m = 2K."""
        leds = np.arange(self.config.led_pos.shape[0]) if leds is None else np.asarray(leds)
        b_meas = np.asarray(b_meas, dtype=float).reshape(leds.size, 3)
        b_pred = self.los(x_prior[None, :], leds)[0]
        T = tangent_basis(b_pred)                                           # (K, 3, 2)
        # eq. 11 projected on the tangent plane of the prediction
        y = np.einsum("kij,ki->kj", T, b_meas).ravel()
        # eq. 13 projected: T^T sigma^2 (I - b b^T) T = sigma^2 I_2
        R = self.config.los_sigma ** 2 * np.eye(2 * leds.size)

        def h(X):
            return np.einsum("kij,nki->nkj", T, self.los(X, leds)).reshape(X.shape[0], -1)

        def jac(x):
            r, J = self._camera_point_jacobian(x, leds)
            nr = np.linalg.norm(r, axis=-1)
            b = r / nr[:, None]
            Db = (np.eye(3)[None] - np.einsum("ki,kj->kij", b, b)) / nr[:, None, None]   # db/dr
            return np.einsum("kij,kil,klm->kjm", T, Db, J).reshape(2 * leds.size, N_ERR)

        return FunctionMeasurement(y, R, h, jac)

    def focal_noise(self, ab: np.ndarray) -> np.ndarray:
        """Eq. 8 covariance blocks (K, 2, 2) m^2 at focal-plane points ab (K, 2) m.

        Eq. 8's a, b are the normalised coordinates alpha / f, beta / f (the camera model,
        testbed/sensors/camera.py, draws its noise there); sigma = focal_sigma is in m on the plane.
        """
        c = self.config
        a, b = ab[:, 0] / c.focal_length, ab[:, 1] / c.focal_length
        d = c.focal_d
        # eq. 8
        s = c.focal_sigma ** 2 / (1.0 + d * (a * a + b * b))
        off = (d * a * b) ** 2
        return s[:, None, None] * np.stack([np.stack([(1 + d * a * a) ** 2, off], -1),
                                            np.stack([off, (1 + d * b * b) ** 2], -1)], -2)

    def focal_measurement(self, x_prior: np.ndarray, ab_meas: np.ndarray, leds=None) -> FunctionMeasurement:
        """Focal-plane measurement (eq. 5-8) of LEDs ``leds`` (K,): ab_meas (K, 2) m; R from eq. 8 at
        the predicted (alpha, beta). m = 2K."""
        leds = np.arange(self.config.led_pos.shape[0]) if leds is None else np.asarray(leds)
        ab_meas = np.asarray(ab_meas, dtype=float).reshape(leds.size, 2)
        blocks = self.focal_noise(self.focal(x_prior[None, :], leds)[0])
        R = np.zeros((2 * leds.size, 2 * leds.size))
        for k in range(leds.size):
            R[2 * k:2 * k + 2, 2 * k:2 * k + 2] = blocks[k]
        fl = self.config.focal_length

        def h(X):
            return self.focal(X, leds).reshape(X.shape[0], -1)

        def jac(x):
            r, J = self._camera_point_jacobian(x, leds)
            rx, ry, rz = r[:, 0], r[:, 1], r[:, 2]
            z = np.zeros_like(rz)
            D = -fl * np.stack([np.stack([1 / rz, z, -rx / rz ** 2], -1),
                                np.stack([z, 1 / rz, -ry / rz ** 2], -1)], -2)      # (K, 2, 3)
            return np.einsum("kij,kjl->kil", D, J).reshape(2 * leds.size, N_ERR)

        return FunctionMeasurement(ab_meas.ravel(), R, h, jac)


def tangent_basis(b: np.ndarray) -> np.ndarray:
    """Two orthonormal columns orthogonal to each unit vector: b (K, 3) -> T (K, 3, 2)."""
    b = np.asarray(b, dtype=float)
    # helper axis: the coordinate axis least aligned with b
    e = np.eye(3)[np.argmin(np.abs(b), axis=-1)]
    t1 = np.cross(b, e)
    t1 /= np.linalg.norm(t1, axis=-1, keepdims=True)
    t2 = np.cross(b, t1)
    return np.stack([t1, t2], axis=-1)


# --------------------------------------------------------------------------------------------
# The filters on raw camera frames (core.Filter)
# --------------------------------------------------------------------------------------------
@dataclass(frozen=True, slots=True, eq=False)
class CameraFrame:
    """One camera epoch as the sensor reports it.

    leds: (K,) 0-based LED indices seen; los: (K, 3) unit lines of sight in the camera frame C;
    focal: (K, 2) focal-plane coordinates alpha, beta (m).
    """

    leds: np.ndarray
    los: np.ndarray
    focal: np.ndarray


@dataclass(frozen=True, slots=True, eq=False)
class CameraFilter:
    """A filter of the seed 004 family fed with raw camera frames (a core.Filter).

    predict is the inner filter's (u: the IMU input (12,), see `imu_input`); update builds the
    frame's measurement about the PREDICTED mean (the LOS tangent bases / the eq. 8 covariance
    depend on it: `RelNavModel.los_measurement`, `focal_measurement`) and hands it to the inner
    filter's update. measurement: "los" (eqs. 9-13) or "focal" (eqs. 5-8).
    """

    inner: ComposedFilter
    measurement: str = "los"

    def predict(self, belief: ManifoldGaussian, dt: float, u: np.ndarray | None = None) -> ManifoldGaussian:
        return self.inner.predict(belief, dt, u)

    def update(self, belief: ManifoldGaussian, frame: CameraFrame) -> ManifoldGaussian:
        model = self.inner.model
        if self.measurement == "los":
            meas = model.los_measurement(belief.mean, frame.los, frame.leds)
        else:
            meas = model.focal_measurement(belief.mean, frame.focal, frame.leds)
        return self.inner.update(belief, meas)
