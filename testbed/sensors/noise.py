"""Noise processes shared by the sensors, written once for one sample or a long stream.

All functions take pre-drawn standard normals `normals` of shape (n, ...) for n consecutive
samples at period dt (s), so a sensor advancing one sample at a time (n = 1) and a test
generating a long synthetic stream (n = 10^5) run the same code.

Discretisation of a white noise of density N (unit/sqrt(Hz)) sampled every dt: sigma_d = N / sqrt(dt)
(the average of the continuous noise over the sample interval). A random walk of density K
(unit/sqrt(s)): b_{k+1} = b_k + K sqrt(dt) w_k. A first-order Gauss-Markov process of
steady-state sigma s and time constant tau: b_{k+1} = phi b_k + s sqrt(1 - phi^2) w_k,
phi = exp(-dt / tau) (exact discretisation).
"""
from __future__ import annotations

import zlib

import numpy as np

from estimators.sensor_models import C_LIGHT


def device_rng(stream: np.random.Generator, device: str) -> np.random.Generator:
    """The child generator of one device (e.g. "uav2", "anchor1") inside a sensor stream.

    Spawned from the stream's own SeedSequence (testbed.rng.stream_rng: one per scenario seed and
    stream name) with the device name's CRC-32 appended to its spawn key: a device's draws depend
    only on (seed, stream, device), so adding a vehicle or an anchor never changes another one's.
    """
    ss = stream.bit_generator.seed_seq
    key = zlib.crc32(device.encode("utf-8"))
    return np.random.default_rng(np.random.SeedSequence(entropy=ss.entropy, spawn_key=(*ss.spawn_key, key)))


def white(density: float | np.ndarray, dt: float, normals: np.ndarray) -> np.ndarray:
    """White noise samples (n, ...) of density `density` (unit/sqrt(Hz)) at period dt (s)."""
    return np.asarray(density) / np.sqrt(dt) * normals


def random_walk(start: np.ndarray, density: float | np.ndarray, dt: float, normals: np.ndarray) -> np.ndarray:
    """Random walk path (n, ...) continuing from `start` (...): b_k = b_{k-1} + K sqrt(dt) w_k."""
    return start + np.cumsum(np.asarray(density) * np.sqrt(dt) * normals, axis=0)


def gauss_markov(start: np.ndarray, sigma: float | np.ndarray, tau: float, dt: float, normals: np.ndarray) -> np.ndarray:
    """First-order Gauss-Markov path (n, ...) from `start`; tau <= 0 gives zeros."""
    if tau <= 0:
        return np.zeros_like(normals)
    phi = np.exp(-dt / tau)
    q = np.asarray(sigma) * np.sqrt(1.0 - phi**2)
    if normals.shape[0] == 1:
        return (phi * start + q * normals[0])[None]
    from scipy.signal import lfilter  # only for long streams: keeps the import cost out of runs

    zi = (phi * np.asarray(start, float))[None] * np.ones((1, *normals.shape[1:]))
    y, _ = lfilter([1.0], [1.0, -phi], q * normals, axis=0, zi=zi)
    return y


class TriadErrors:
    """Errors of V sensor triads (C = 3 axes), seed 004 eqs. 1-4 plus MEMS terms.

    meas = (I + K) x + b_const + b_turn_on + b_walk(t) + b_gm(t) + white, per vehicle:
    K = diag(scale) + off-diagonal misalignment (drawn once), b_turn_on drawn once, b_walk a
    random walk (eq. 2/4 eta_u), b_gm a first-order Gauss-Markov bias. `apply(x, normals)` maps
    n consecutive clean samples x (n, V, 3) to measurements, normals (n, 3, V, 3) for white,
    walk and Gauss-Markov increments.
    What the estimators assume of it: the white density, and the walk and Gauss-Markov terms as
    one bias walk of density sqrt(K^2 + 2 s^2 / tau) (estimators.sensor_models.imu_noise).
    """

    def __init__(self, errors, n_triads: int, dt: float, rng: np.random.Generator):
        e = errors
        self.e, self.dt = e, dt
        z = rng.standard_normal((4, n_triads, 3))
        off = rng.standard_normal((n_triads, 3, 3))
        eye = np.eye(3)
        self.K = e.scale_sigma * z[0][:, :, None] * eye + e.misalign_sigma * off * (1 - eye)  # (V, 3, 3)
        self.b0 = e.bias + e.bias_sigma * z[1]  # (V, 3) constant + turn-on
        self.walk = np.zeros((n_triads, 3))
        self.gm = e.gm_sigma * z[2] if e.gm_tau > 0 else np.zeros((n_triads, 3))  # stationary start

    @classmethod
    def stacked(cls, triads: list[TriadErrors]) -> TriadErrors:
        """One object for the triads of several (all with the same parameters and dt), their
        scale factors, misalignments and bias states concatenated: `apply` on (n, V, 3) at once."""
        out = cls.__new__(cls)
        out.e, out.dt = triads[0].e, triads[0].dt
        for name in ("K", "b0", "walk", "gm"):
            setattr(out, name, np.concatenate([getattr(t, name) for t in triads]))
        return out

    def apply(self, x: np.ndarray, normals: np.ndarray) -> np.ndarray:
        """Measurements (n, V, 3) of clean samples x (n, V, 3); `bias_series` keeps the bias (n, V, 3)."""
        e, dt = self.e, self.dt
        bias = np.broadcast_to(self.b0, x.shape).copy()
        if e.bias_walk > 0:  # terms with zero parameters are skipped (their normals are still drawn)
            walk = random_walk(self.walk, e.bias_walk, dt, normals[:, 1])
            self.walk = walk[-1]
            bias += walk
        if e.gm_tau > 0:
            gm = gauss_markov(self.gm, e.gm_sigma, e.gm_tau, dt, normals[:, 2])
            self.gm = gm[-1]
            bias += gm
        self.bias_series = bias
        out = x + (self.K @ x[..., None])[..., 0] + bias  # (I + K) x + b
        if e.noise_density > 0:
            out += white(e.noise_density, dt, normals[:, 0])
        return out


def twr_range(mode: str, d: np.ndarray, ppm_a: np.ndarray, ppm_b: np.ndarray, reply_time: float) -> np.ndarray:
    """Range (m) that two-way ranging reports for true distances d (m), without noise or delays.

    A (the initiator, `src`) and B (the responder, `dst`) have clock frequency offsets ppm_a,
    ppm_b (ppm): a clock with offset e = 1e-6 ppm reads (1 + e) t after a true time t. Exact
    timestamp arithmetic; the first-order forms and the derivation are in docs/sensors.md.
      "scale":  d (1 + 1e-6 (ppm_a + ppm_b) / 2)            (the first-order double-sided form)
      "ss-twr": (1 + e_A) d + (c T_reply / 2) (e_A - e_B) / (1 + e_B)
                ~ d + e_A d + c T_reply (e_A - e_B) / 2, T_reply = reply_time (s) on B's clock
      "ds-twr": d (1 + e_A)(1 + e_B) / (1 + (e_A + e_B) / 2)  ~ d (1 + (e_A + e_B) / 2)
    d, ppm_a, ppm_b: (L,) per link.
    The error it injects, to first order g_A k_A + g_B k_B (+ the antenna delays b_A + b_B), is
    what the estimators assume: its gains, variance and joint covariance over links that share a
    device are estimators.sensor_models (twr_clock_gains, twr_range_variance, twr_range_covariance).
    """
    if mode == "scale":
        return d * (1.0 + 1e-6 * (ppm_a + ppm_b) / 2)
    ea, eb = 1e-6 * ppm_a, 1e-6 * ppm_b
    if mode == "ss-twr":
        # T_round (A's clock) = (1 + e_A)(2 tof + T_reply / (1 + e_B)); range = c (T_round - T_reply) / 2
        return (1.0 + ea) * d + 0.5 * C_LIGHT * reply_time * (ea - eb) / (1.0 + eb)
    if mode == "ds-twr":
        # asymmetric DS-TWR: tof = (R_A R_B - D_A D_B) / (R_A + R_B + D_A + D_B), each interval on its own clock
        return d * (1.0 + ea) * (1.0 + eb) / (1.0 + 0.5 * (ea + eb))
    raise ValueError(f"unknown two-way ranging mode {mode!r}")


def allan_deviation(y: np.ndarray, dt: float, m: np.ndarray) -> np.ndarray:
    """Non-overlapping Allan deviation of a rate signal y (n,) at averaging factors m (k,).

    tau = m dt; avar = mean((ybar_{j+1} - ybar_j)^2) / 2 over the n // m block means.
    """
    out = np.empty(len(m))
    for i, mi in enumerate(m):
        blocks = y[: (len(y) // mi) * mi].reshape(-1, mi).mean(axis=1)
        out[i] = np.sqrt(0.5 * np.mean(np.diff(blocks) ** 2))
    return out
