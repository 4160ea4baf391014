"""The simulation loop: prescribed playback or closed-loop flight, sensors sampled from the physics.

Time advances in controller ticks of 1 / control_rate seconds. A tick is logged when truth is due
(truth_rate) or any sensor samples; at a logged tick the log stores `time`, `qpos`, `qvel` and the
reference, and every due sensor samples the physics state of that instant.

- prescribed: no integration; at each logged tick qpos, qvel and qacc are set from the analytic
  reference and `mj_inverse` computes site poses, velocities and accelerometer/gyro readings.
- flown: the controller commands the rotors every tick; `mj_step1` (position and velocity
  stages), controller, `mj_step2` (acceleration stage, then integration) so sensors see the state
  of the tick itself; the remaining physics steps of the tick hold the command.
"""
from __future__ import annotations

from dataclasses import dataclass

import mujoco
import numpy as np
from tqdm import tqdm

from testbed.control import GeometricController
from testbed.reference import evaluate
from testbed.scenario import Scenario
from testbed.sensors import make_sensors
from testbed.sensors.base import Sensor
from testbed.world import Physics, build

CHUNK = 1000  # reference instants evaluated per vectorized call


@dataclass(frozen=True, slots=True)
class Schedule:
    """Tick bookkeeping of a run: tick period (s), tick count, which ticks are logged."""

    tick: float
    substeps: int
    n_ticks: int
    logged: np.ndarray  # (n_ticks,) bool

    @property
    def times(self) -> np.ndarray:
        return np.arange(self.n_ticks) * self.tick


def schedule(scenario: Scenario, sensors: list[Sensor]) -> Schedule:
    w = scenario.world
    tick = 1.0 / w.control_rate
    n_ticks = int(round(scenario.duration * w.control_rate)) + 1
    idx = np.arange(n_ticks)
    logged = idx % max(1, int(round(w.control_rate / w.truth_rate))) == 0
    for s in sensors:
        logged |= idx % s.period_ticks == 0
    return Schedule(tick, int(round(tick / w.timestep)), n_ticks, logged)


def simulate(scenario: Scenario, physics: Physics | None = None, progress: bool = False) -> tuple[dict[str, np.ndarray], Physics]:
    """Run a scenario; returns the log arrays (data contract) and the physics at the end."""
    physics = physics or build(scenario)
    sensors = make_sensors(scenario, physics)
    sched = schedule(scenario, sensors)
    times = sched.times
    log_ticks = np.flatnonzero(sched.logged)
    K = log_ticks.size
    qpos = np.empty((K, physics.model.nq))
    qvel = np.empty((K, physics.model.nv))
    ref_pos = np.empty((K, physics.n, 3))
    ref_quat = np.empty((K, physics.n, 4))
    ctrl = np.zeros((K, physics.model.nu))
    m, d = physics.model, physics.data
    flown = scenario.motion == "flown"
    controller = GeometricController(physics, scenario.control) if flown else None
    ticks = np.arange(sched.n_ticks) if flown else log_ticks
    row = 0
    bar = tqdm(total=len(ticks), desc=f"{scenario.name} ({scenario.motion})", unit="tick", disable=not progress, leave=False)
    for c0 in range(0, len(ticks), CHUNK):
        chunk = ticks[c0 : c0 + CHUNK]
        ref = evaluate(scenario.trajectory, times[chunk], rates=not flown)
        for j, k in enumerate(chunk):
            t = times[k]
            if flown:
                mujoco.mj_step1(m, d)
                d.ctrl[physics.actuator_idx] = controller(
                    physics.pos, physics.vel, physics.rotation, physics.omega,
                    ref.pos[j], ref.vel[j], ref.acc[j], ref.yaw[j],
                )
                is_logged = sched.logged[k]
                if is_logged:
                    qpos[row], qvel[row], ctrl[row] = d.qpos, d.qvel, d.ctrl
                mujoco.mj_step2(m, d)  # acceleration stage at time t, then integrate to t + dt
            else:
                d.time = t
                physics.set_reference_state(ref, j)
                is_logged = True
                qpos[row], qvel[row] = d.qpos, d.qvel
            if is_logged:
                ref_pos[row], ref_quat[row] = ref.pos[j], ref.quat[j]
                for s in sensors:
                    if k % s.period_ticks == 0:
                        s.sample(physics, t, row)
                row += 1
            if flown and sched.substeps > 1:
                mujoco.mj_step(m, d, nstep=sched.substeps - 1)
        bar.update(len(chunk))
    bar.close()
    log = {
        "time": times[log_ticks],
        "qpos": qpos,
        "qvel": qvel,
        "reference/pos": ref_pos,
        "reference/quat": ref_quat,
        **truth_from_state(physics, qpos, qvel),
    }
    if flown:
        log["ctrl"] = ctrl
    for s in sensors:
        log.update(s.arrays())
    return log, physics


def truth_from_state(physics: Physics, qpos: np.ndarray, qvel: np.ndarray) -> dict[str, np.ndarray]:
    """Body truth of every vehicle from logged qpos/qvel (K, nq), (K, nv).

    truth/pos (K, N, 3) m and truth/vel (K, N, 3) m/s world; truth/quat (K, N, 4) wxyz;
    truth/omega (K, N, 3) rad/s body frame.
    """
    qi, vi = physics.qpos_adr[:, None] + np.arange(7), physics.dof_adr[:, None] + np.arange(6)
    return {
        "truth/pos": qpos[:, qi[:, :3]],
        "truth/quat": qpos[:, qi[:, 3:]],
        "truth/vel": qvel[:, vi[:, :3]],
        "truth/omega": qvel[:, vi[:, 3:]],
    }
