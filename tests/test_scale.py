"""Large-swarm machinery: MuJoCo sensors evaluated only where read, the streamed log."""
from __future__ import annotations

import mujoco
import numpy as np

from testbed.bench.swarm import swarm_scenario
from testbed.simulate import simulate
from testbed.world import build


def test_flown_imu_reads_the_sensors_of_its_own_tick_and_model_flags_are_restored():
    """MuJoCo's sensors run only at the IMU's ticks: the clean IMU equals a fresh mj_forward of
    the logged state (same accelerometer and gyro as with sensors always on), and the model's
    disable flags are as before the run."""
    sc = swarm_scenario(3, 0.2, sensors={"imu": {"rate_hz": 100.0}})
    physics = build(sc)
    flags = physics.model.opt.disableflags
    log, physics = simulate(sc, physics)
    assert physics.model.opt.disableflags == flags
    m, d = physics.model, mujoco.MjData(physics.model)
    idx = np.searchsorted(log["time"], log["imu/time"])
    assert len(idx) > 10
    for row in idx[:: max(1, len(idx) // 5)]:
        d.qpos[:], d.qvel[:], d.ctrl[:] = log["qpos"][row], log["qvel"][row], log["ctrl"][row]
        mujoco.mj_forward(m, d)
        step = np.flatnonzero(idx == row)
        clean = log["imu/clean"][step]
        np.testing.assert_allclose(clean, d.sensordata[physics.imu_idx], rtol=0, atol=1e-9)
        assert np.abs(clean[:, :3]).max() > 5.0  # specific force of hover, not stale zeros
