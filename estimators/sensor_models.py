"""The sensor models the estimators assume: one home, used by every estimator.

What an estimator takes as the noise of a measurement, from the scenario's declared sensor model
(the plugins' Context.sensors: each [sensors.NAME] table as a dict, every default written out;
docs/sensors.md). The simulator's error injection (testbed/sensors/) draws the same errors and
points here from its docstrings; nothing here imports the simulator.

- UWB two-way ranging (testbed.sensors.noise.twr_range injects it): the first-order clock and
  antenna-delay error of a range, its variance and its joint covariance over the links of one
  epoch, and the variance an estimator gives a range taken as white noise; the sigma a filter
  gives a range whose errors stay correlated in time (docs/calibration.md, cal. 8).
- IMU: the white densities and the bias walk standing for the declared walk and Gauss-Markov
  terms (estimators.eskf.ImuNoise).
- GNSS: the declared 1-sigma of a fix per axis (white noise and Gauss-Markov bias combined).
Units SI: m, s, ppm for clock offsets.
"""
from __future__ import annotations

import numpy as np

C_LIGHT = 299_792_458.0  # m/s


# ------------------------------------------------------------------------------ UWB two-way ranging


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


# ------------------------------------------------------------------------------ IMU


def correlated_sigma(sigma: float, correlation_s: float, dt: float | None) -> float:
    """The sigma (m) a filter gives a range of declared sigma (m) whose link's errors stay
    correlated over correlation_s (s), dt s after the link's previous range (None: its first):
    the variance times the rows the link makes within that time, which carry the information of one."""
    if dt is None or dt <= 0:
        return sigma
    # docs/calibration.md, cal. 8: variance x max(1, tau_c / dt)
    return sigma * float(np.sqrt(max(1.0, correlation_s / dt)))


def _walk(errors: dict) -> float:
    """Bias random-walk density (unit/sqrt(s)) standing for the declared walk and Gauss-Markov terms."""
    gm = errors["gm_sigma"] * np.sqrt(2.0 / errors["gm_tau"]) if errors["gm_tau"] > 0 else 0.0
    return float(np.hypot(errors["bias_walk"], gm))


def vehicle_imu(imu: dict, body: str) -> dict:
    """Body `body`'s own IMU table from a declared [sensors.imu] (Context.sensors["imu"]): its
    per-body table when the dataset gives one (`[sensors.imu.BODY]`, testbed.sensors.config.declared_imu),
    else the shared one."""
    own = imu.get(body)
    return own if isinstance(own, dict) and "accel" in own else imu


def imu_noise(imu: dict):
    """The filter's IMU noise model (estimators.eskf.ImuNoise) from the declared [sensors.imu]
    table (Context.sensors["imu"]): white densities, and bias walks standing for the declared walk
    and Gauss-Markov terms."""
    from estimators.eskf import ImuNoise  # here: the scenario schema loads this module, numpy only

    acc, gyr = imu["accel"], imu["gyro"]
    return ImuNoise(acc["noise_density"], gyr["noise_density"], _walk(acc), _walk(gyr))


# ------------------------------------------------------------------------------ GNSS


def gnss_sigma(errors: dict) -> np.ndarray:
    """(3,) m declared (east, north, up) 1-sigma of a GNSS receiver error table (a dict, as
    `to_dict` or the plugins' Context.sensors give it): white noise and Gauss-Markov bias
    combined, sqrt(noise^2 + bias^2)."""
    return np.hypot([errors["noise_h"]] * 2 + [errors["noise_v"]], [errors["bias_h"]] * 2 + [errors["bias_v"]])
