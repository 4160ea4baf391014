"""Pure-numpy synthetic data of seed 003 (carrier phase): masters, the eq. 31 follower, measurements.

Masters hover (zero velocity, identity attitude) in a formation in the navigation frame N (FLU,
z up; origin = body origin of the master on the symmetry axis). The follower flies the paper's
eq. 31 trajectory. Paper frame (x fwd, y up, z right) -> ours: (x, y, z)_ours = (x, -z, y)_paper;
Euler angles: psi = psi_paper, theta = -theta_paper, phi = gamma_paper (see phase_model).
"""
from __future__ import annotations

import numpy as np

from estimators.phase_ekf import PhaseMeasurement
from estimators.phase_model import antenna_offsets, antenna_state_from_body, measurement_model
from estimators.so3 import rot_zyx, rot_zyx_dot

SPACING = 100.0  # m, adjacent masters (seed 003, docs/papers.md)
SIGMA_RANGE = 0.05  # m, 1 sigma (paper: 0.15 m is 3 sigma)
SIGMA_RATE = 0.1  # m/s, 1 sigma (paper: 0.3 m/s is 3 sigma)
F_ATT = 1.0 / 200.0  # Hz, eq. 31


def cross_formation(heights=(0, 0, 0, 0, 0), spacing: float = SPACING) -> np.ndarray:
    """Master body origins (5, 3) in N for the cross "十": centre (the reference master) and four
    arms spacing metres ahead, behind, left and right; heights (5,) m added on z."""
    p = np.array([[0, 0, 0], [spacing, 0, 0], [-spacing, 0, 0], [0, spacing, 0], [0, -spacing, 0]], float)
    p[:, 2] += np.asarray(heights, float)
    return p


def master_antennas(body_pos: np.ndarray, a: float = 1.0, b: float = 1.0) -> tuple[np.ndarray, np.ndarray]:
    """Hovering masters with identity attitude: antenna positions and velocities (M, 3, 3)."""
    X0 = body_pos[:, None, :] + antenna_offsets(a, b)[None, :, :]
    return X0, np.zeros_like(X0)


def follower_truth(t: np.ndarray, a: float = 1.0, b: float = 1.0):
    """Eq. 31 in our frame. t: (K,) s. Returns states (K, 18), body (K, 12) in the order of
    phase_model.BODY_STATE_NAMES (p, v, yaw, pitch, roll, rates)."""
    t = np.asarray(t, float)
    w = 2 * np.pi * F_ATT
    ph = w * t + np.pi / 2
    # eq. 31, paper frame: x = -200 + 4t, y(up) = 150 + 3t, z(right) = -200 + 4t
    p = np.stack([-200 + 4.0 * t, -(-200 + 4.0 * t), 150 + 3.0 * t], axis=1)
    v = np.broadcast_to(np.array([4.0, -4.0, 3.0]), p.shape)
    amp = np.array([-np.pi / 36, -np.pi / 18, np.pi / 72])  # psi, theta = -theta_paper, phi
    eul = amp[None, :] * np.sin(ph)[:, None]
    eul_d = amp[None, :] * w * np.cos(ph)[:, None]
    states = np.empty((t.size, 18))
    for k in range(t.size):
        R = rot_zyx(*eul[k])
        Rd = rot_zyx_dot(eul[k], eul_d[k])
        states[k] = antenna_state_from_body(p[k], v[k], R, Rd, a, b)
    body = np.concatenate([p, v, eul, eul_d], axis=1)
    return states, body


def measurements(states: np.ndarray, X0: np.ndarray, V0: np.ndarray, rng: np.random.Generator,
                 sigma_range: float = SIGMA_RANGE, sigma_rate: float = SIGMA_RATE) -> list[PhaseMeasurement]:
    """Noisy ranges / range rates for each state row (white Gaussian, independent rows)."""
    out = []
    M = X0.shape[0]
    for x in states:
        h, _ = measurement_model(x, X0, V0, jacobian=False)
        hh = h.reshape(M, 2, 3, 3)
        r = hh[:, 0] + sigma_range * rng.standard_normal((M, 3, 3))
        rd = hh[:, 1] + sigma_rate * rng.standard_normal((M, 3, 3))
        out.append(PhaseMeasurement(r, rd, X0, V0, sigma_range, sigma_rate))
    return out


# seed 003 (docs/papers.md) initial covariance, paper frame -> ours (x, -z, y): diagonal entries permuted
P0_POS = np.diag([1.87306, 3.70352, 3.14771])  # m^2
P0_VEL = np.diag([0.69928, 0.50587, 0.46008])  # m^2/s^2
