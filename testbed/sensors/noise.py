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


C_LIGHT = 299_792_458.0  # m/s


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


def twr_clock_gains(mode: str, d: np.ndarray, reply_time: float) -> tuple[np.ndarray, np.ndarray]:
    """First-order range error (m) per ppm of the initiator's and of the responder's clock offset:
    (g_A, g_B), each (L,) m/ppm, for true lengths d (L,) m (twr_range linearised in e = 1e-6 ppm):
      "scale", "ds-twr": g_A = g_B = 1e-6 d / 2
      "ss-twr":          g_A = 1e-6 (d + h), g_B = -1e-6 h,  h = c T_reply / 2
    """
    d = np.asarray(d, dtype=float)
    if mode == "ss-twr":
        h = 0.5 * C_LIGHT * reply_time
        return 1e-6 * (d + h), np.full_like(d, -1e-6 * h)
    return 0.5e-6 * d, 0.5e-6 * d


def twr_range_variance(mode: str, d: np.ndarray, clock_ppm: float, reply_time: float, antenna_delay_sigma: float) -> np.ndarray:
    """Variance (m^2) of the clock and antenna-delay error of a two-way range of true length d (m),
    to first order, with independent per-device clock offsets ~ N(0, clock_ppm^2) (ppm) and
    antenna delays ~ N(0, antenna_delay_sigma^2) (m); the white range noise is not included.
      "scale", "ds-twr": (s d)^2 / 2 + 2 sigma_ad^2
      "ss-twr":          s^2 ((d + h)^2 + h^2) + 2 sigma_ad^2,  h = c T_reply / 2
    with s = 1e-6 clock_ppm (twr_clock_gains: clock_ppm^2 (g_A^2 + g_B^2)). d: (L,) m.
    """
    g_a, g_b = twr_clock_gains(mode, d, reply_time)
    return clock_ppm ** 2 * (g_a ** 2 + g_b ** 2) + 2.0 * antenna_delay_sigma ** 2


def range_variances(uwb: dict | None, sigma: np.ndarray, d: np.ndarray, antenna_delays: bool = True) -> np.ndarray:
    """Variances (m^2) an estimator gives UWB ranges of length d (m,) m and declared noise sigma
    (m,) m, taken as white noise: sigma^2, plus (with the declared [sensors.uwb] table uwb, as in
    an estimator's Context) the two-way-ranging clock term, the two antenna-delay terms unless
    `antenna_delays` is False (an estimator that has the delays as states), and the link bias
    (twr_range_variance)."""
    var = np.asarray(sigma, float) ** 2
    if uwb is not None:
        delay = uwb["antenna_delay_sigma"] if antenna_delays else 0.0
        var = var + twr_range_variance(uwb["mode"], np.asarray(d, float), uwb["clock_ppm"], uwb["reply_time"],
                                       delay) + uwb["link_bias_sigma"] ** 2
    return var


def twr_range_covariance(mode: str, d: np.ndarray, src: np.ndarray, dst: np.ndarray, clock_ppm: float, reply_time: float,
                         antenna_delay_sigma: float) -> np.ndarray:
    """Joint covariance (L, L) m^2 of the clock and antenna-delay errors of L two-way ranges
    measured at the same time: link l from device src[l] to dst[l] (integer ids, (L,)), true length
    d[l] (m). Its error is g_A k_src + g_B k_dst + b_src + b_dst with the per-device clock offsets k
    (ppm) and antenna delays b (m) of twr_range_variance: two links that share a device share its
    terms, cov = G diag(clock_ppm^2) G^T + sigma_ad^2 B B^T (G: gains at the device columns, B:
    ones). The diagonal is twr_range_variance; the white range noise is not included.
    """
    src, dst = np.asarray(src), np.asarray(dst)
    g_a, g_b = twr_clock_gains(mode, d, reply_time)
    ids = np.unique(np.concatenate([src, dst]))
    a, b = np.searchsorted(ids, src), np.searchsorted(ids, dst)
    rows = np.arange(src.size)
    G = np.zeros((src.size, ids.size))
    B = np.zeros((src.size, ids.size))
    # src == dst never happens (a radio does not range to itself)
    G[rows, a], G[rows, b] = g_a, g_b
    B[rows, a], B[rows, b] = 1.0, 1.0
    return clock_ppm ** 2 * (G @ G.T) + antenna_delay_sigma ** 2 * (B @ B.T)


def allan_deviation(y: np.ndarray, dt: float, m: np.ndarray) -> np.ndarray:
    """Non-overlapping Allan deviation of a rate signal y (n,) at averaging factors m (k,).

    tau = m dt; avar = mean((ybar_{j+1} - ybar_j)^2) / 2 over the n // m block means.
    """
    out = np.empty(len(m))
    for i, mi in enumerate(m):
        blocks = y[: (len(y) // mi) * mi].reshape(-1, mi).mean(axis=1)
        out[i] = np.sqrt(0.5 * np.mean(np.diff(blocks) ** 2))
    return out
