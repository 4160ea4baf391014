"""Checks shared by the physics tests (tests only)."""
from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

from testbed.reference import GRAVITY, RefState
from testbed.sim.world import Physics


def assert_imu_reads_played_state(physics: Physics, ref: RefState, k: int) -> None:
    """Play instant k of ref (prescribed playback, mj_inverse) and check MuJoCo's ideal IMU:
    accelerometer = R^T (a - g) to 1e-6 m/s^2, gyro = the body rate to 1e-9 rad/s, every vehicle
    (the imu site is at the body origin, axes aligned)."""
    physics.set_reference_state(ref, k)
    R = Rotation.from_quat(ref.quat[k], scalar_first=True).as_matrix()
    expected = np.einsum("nji,nj->ni", R, ref.acc[k] - np.array([0, 0, -GRAVITY]))
    assert np.abs(physics.accelerometer - expected).max() < 1e-6
    assert np.abs(physics.gyro - ref.omega[k]).max() < 1e-9
