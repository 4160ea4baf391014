"""The simulation loop: prescribed playback or closed-loop flight, sensors sampled from the physics.

Time advances in controller ticks of 1 / control_rate seconds. A tick is logged when truth is due
(truth_rate) or any sensor samples; at a logged tick the log stores `time`, `qpos`, `qvel` and the
reference, and every due sensor samples the physics state of that instant.

- prescribed: no integration; at each logged tick qpos, qvel and qacc are set from the analytic
  reference and `mj_inverse` computes site poses, velocities and accelerometer/gyro readings.
- flown: the controller commands the rotors every tick; `mj_step1` (position and velocity
  stages), controller, `mj_step2` (acceleration stage, then integration) so sensors see the state
  of the tick itself; the remaining physics steps of the tick hold the command. With the joint
  rotor route (large swarms, testbed.sim.world.rotor_route) every physics step is split the
  same way to add the thrust along the current body z (testbed.sim.thrust). MuJoCo evaluates its own
  sensors (the IMU's accelerometer and gyro) only in the first physics step of the ticks where a
  sensor reading them samples (mjDSBL_SENSOR otherwise): nothing else reads sensordata, and at
  a thousand vehicles the accelerometers' acceleration pass costs a tenth of every step.

Onboard state ([control] feedback, attitude; docs/control.md): with feedback "estimate:NAME" the
caller passes the online estimator (testbed.plugins.online.OnlineEstimator, the `Feedback`
protocol here); every sensor's new rows go to it as they are recorded, it processes the arrived
ones at the end of each tick, and from the next tick on the controller takes the fed-back
vehicles' position and velocity from it. With attitude "mahony" the controller takes R and the
body rate from the onboard complementary filter (estimators.mahony) run on each IMU sample; with
attitude "estimate", R from the same estimator's latest attitude estimate and the body rate from
each vehicle's latest gyro sample.
The sensors then apply their errors at each sample (Imu.online), so the log holds exactly the
values read in the loop.

A scenario's [disturbance] (testbed.sim.disturbance) is added to the played-back motion in prescribed
mode and applied as an external force and torque, held over each tick, in flown mode.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Protocol

import mujoco
import numpy as np
from tqdm import tqdm

from estimators.mahony import Mahony
from estimators.so3 import quat_to_rotmat
from testbed.sim.control import GeometricController, heading
from testbed.sim.disturbance import Draws, Realization, draw, perturb, realize, wrench
from testbed.interrupt import poll
from testbed.log import LogWriter
from testbed.reference import GRAVITY, attitude, evaluate, tracking
from testbed.config.scenario import Scenario
from testbed.sensors.suite import make_sensors
from testbed.sensors.base import Sensor
from testbed.sim.thrust import BodyForces
from testbed.sim.world import Physics, build

CHUNK = 1000  # reference instants evaluated per vectorized call


class Feedback(Protocol):
    """An estimator in the loop (testbed.plugins.online.OnlineEstimator)."""

    def measured(self, name: str, rows: dict[str, np.ndarray]) -> None:
        """Rows a sensor just recorded (Recorder.new_rows), values as the log holds them."""

    def advance(self, t: float) -> None:
        """Process every measurement arrived by time t (s)."""

    vehicles: np.ndarray  # (N,) bool: the vehicles flown on it

    def state(self, pos: np.ndarray, vel: np.ndarray, ref_pos: np.ndarray, ref_vel: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Position and velocity (N, 3) world the controller uses."""

    def rotation(self, R: np.ndarray, R_start: np.ndarray) -> np.ndarray:
        """Attitude (N, 3, 3) body-to-world the controller uses (attitude "estimate")."""


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


def simulate(scenario: Scenario, physics: Physics | None = None, progress: bool = False,
             feedback: Feedback | None = None) -> tuple[dict[str, np.ndarray], Physics]:
    """Run a scenario; returns the log arrays (data contract) and the physics at the end.
    feedback: the estimator of [control] feedback = "estimate:NAME" (None: truth)."""
    log = LogWriter()
    physics = record(scenario, log, physics, progress, feedback)
    return log.arrays(), physics


def record(scenario: Scenario, log: LogWriter, physics: Physics | None = None, progress: bool = False,
           feedback: Feedback | None = None) -> Physics:
    """Run a scenario, writing its log into `log` as it goes: the state rows (time, qpos, qvel,
    reference, ctrl and the truth derived from them) a chunk of CHUNK ticks at a time, the
    sensors' rows as they sample (a LogWriter with a spill directory keeps the memory a run
    needs bounded whatever its duration). feedback: as in `simulate`. Returns the physics at the
    end."""
    physics = physics or build(scenario)
    sensors = make_sensors(scenario, physics)
    onboard = feedback is not None or scenario.control.attitude != "truth"
    for s in sensors:
        s.rec.sink = log
        if onboard:
            s.rec.watch()  # new_rows() hands each sample's rows to the onboard consumers
            if hasattr(s, "online"):
                s.online = True  # errors applied at each sample: the loop reads what the log will hold
    sched = schedule(scenario, sensors)
    log_ticks = np.flatnonzero(sched.logged)
    log.put("time", sched.times[log_ticks])
    # sensors sampling at each logged tick, in the order of `sensors`
    due = [[s for s in sensors if k % s.period_ticks == 0] for k in log_ticks.tolist()]
    flown = scenario.motion == "flown"
    with tqdm(total=sched.n_ticks if flown else len(log_ticks), desc=f"{scenario.name} ({scenario.motion})", unit="tick",
              disable=not progress, leave=False) as bar:
        if flown:
            _fly(scenario, physics, sched, log, due, bar, draw(scenario, sched.n_ticks),
                 _Onboard(scenario, sched, feedback) if onboard else None)
        else:
            _play(scenario, physics, sched.times[log_ticks], log, due, bar, realize(scenario, log_ticks))
    for s in sensors:
        arrays = s.arrays()
        held = getattr(s, "held_arrays", None)  # per logged instant, held between samples (gnss fix state)
        if held is not None:
            arrays.update(held(len(log_ticks)))
        for key, value in arrays.items():
            log.put(key, value)
    return physics


def _rows(physics: Physics, k: int, flown: bool) -> dict[str, np.ndarray]:
    """Empty state rows of k logged instants: qpos (k, nq), qvel (k, nv), reference/pos (k, N, 3),
    reference/quat (k, N, 4) and, flown, ctrl (k, nu)."""
    m, N = physics.model, physics.n
    rows = {"qpos": np.empty((k, m.nq)), "qvel": np.empty((k, m.nv)), "reference/pos": np.empty((k, N, 3)),
            "reference/quat": np.empty((k, N, 4))}
    if flown:
        rows["ctrl"] = np.empty((k, m.nu))
    return rows


def _append(log: LogWriter, physics: Physics, rows: dict[str, np.ndarray]) -> None:
    """Append filled state rows and the truth derived from them to the log."""
    rows.update(truth_from_state(physics, rows["qpos"], rows["qvel"]))
    for key, value in rows.items():
        log.append(key, value)


def _play(scenario: Scenario, physics: Physics, times: np.ndarray, log: LogWriter, due: list[list[Sensor]], bar: tqdm,
          dist: Realization | None) -> None:
    """Prescribed motion at the logged instants `times`: the reference state (plus the
    disturbance, realized at the logged ticks, if any) set at each; the log's reference stays
    the undisturbed plan."""
    d = physics.data
    for r0 in range(0, len(times), CHUNK):
        t = times[r0 : r0 + CHUNK]
        rows = _rows(physics, len(t), flown=False)
        ref = evaluate(scenario.trajectory, t)
        rows["reference/pos"][:] = ref.pos
        rows["reference/quat"][:] = ref.quat
        if dist is not None:
            ref = perturb(ref, dist, slice(r0, r0 + len(t)))
        for j, tj in enumerate(t.tolist()):
            poll()  # a worker asked to stop does so here (testbed.interrupt)
            d.time = tj
            physics.set_reference_state(ref, j)
            rows["qpos"][j], rows["qvel"][j] = d.qpos, d.qvel
            for s in due[r0 + j]:
                s.sample(physics, tj, r0 + j)
        _append(log, physics, rows)
        bar.update(len(t))


class _Onboard:
    """What the controller knows onboard: the fed-back estimator and the attitude filter."""

    def __init__(self, scenario: Scenario, sched: Schedule, feedback: Feedback | None):
        self.feedback = feedback
        self.att = None
        self.estimated_attitude = scenario.control.attitude == "estimate"
        c, tr = scenario.control, scenario.trajectory
        if c.attitude != "truth":
            # the reference attitude of t = 0 (where the vehicles start): the filter's start, or the
            # attitude flown on until the estimator's first
            _, _, acc0, _ = tracking(tr, np.zeros(1))
            q0 = attitude(tr, np.zeros(1), acc0)[0]
        if c.attitude == "mahony":
            self.att = Mahony(q0, c.mahony_kp, c.mahony_ki)
            self.imu_dt = sched.tick * int(round(scenario.world.control_rate / scenario.sensors.imu.rate_hz))
        if self.estimated_attitude:
            self.R_start = quat_to_rotmat(q0)
            self.rate = np.zeros((scenario.vehicles, 3))  # rad/s body: each vehicle's latest gyro sample

    def state(self, pos, vel, rotation, omega, ref_pos, ref_vel):
        """(pos, vel, R, omega) the controller uses this tick."""
        if self.feedback is not None:
            pos, vel = self.feedback.state(pos, vel, ref_pos, ref_vel)
        if self.att is not None:
            rotation, omega = self.att.R, self.att.rate
        if self.estimated_attitude:
            rotation = self.feedback.rotation(rotation, self.R_start)
            omega = np.where(self.feedback.vehicles[:, None], self.rate, omega)
        return pos, vel, rotation, omega

    def measured(self, sensor: Sensor, ref_acc: np.ndarray) -> None:
        """A sensor has sampled: its new rows to the estimator, the IMU's to the attitude filter
        (with the expected specific force ref_acc + g e3 (N, 3) of this tick)."""
        rows = sensor.rec.new_rows()
        if self.feedback is not None:
            self.feedback.measured(sensor.name, rows)
        if self.estimated_attitude and sensor.name == "imu":
            self.rate[rows["vehicle"] - 1] = rows["value"][:, 3:]
        if self.att is not None and sensor.name == "imu":
            u = ref_acc.copy()
            u[:, 2] += GRAVITY
            value = np.empty_like(rows["value"])  # (N, 6): control.attitude needs the IMU on every vehicle
            value[rows["vehicle"] - 1] = rows["value"]
            self.att.update(value[:, 3:], value[:, :3], u, self.imu_dt)

    def advance(self, t: float) -> None:
        if self.feedback is not None:
            self.feedback.advance(t)


def _fly(scenario: Scenario, physics: Physics, sched: Schedule, log: LogWriter, due: list[list[Sensor]], bar: tqdm,
         dist: Draws | None, onboard: _Onboard | None = None) -> None:
    """Flown motion: the controller in the loop at every tick; logged ticks as in the module
    docstring, with the rotor commands in ctrl. The reference is evaluated a chunk of ticks at
    a time, its attitude only at the logged ticks. dist: the disturbance wrench is set after the
    position stage of each tick and held over the tick. MuJoCo's sensors run only in the first
    step of the logged rows where a due sensor reads them, and in the last tick (the model's own
    flags are restored on return). onboard: the controller's state from onboard estimates
    (module docstring), None: truth."""
    m, d = physics.model, physics.data
    opt = m.opt
    tr = scenario.trajectory
    controller = GeometricController(physics, scenario.control)
    v = physics.views()
    pos, vel, rotation, omega, thrust = v.pos, v.vel, v.rotation, v.omega, v.ctrl
    step1, step2 = mujoco.mj_step1, mujoco.mj_step2
    rest = sched.substeps - 1  # physics steps of a tick after the controller's
    times = sched.times
    forces = BodyForces(physics)
    if dist is not None:
        mass, inertia = physics.vehicle_mass, physics.vehicle_inertia
    flags = opt.disableflags
    quiet = flags | int(mujoco.mjtDisableBit.mjDSBL_SENSOR)
    reads = [any(getattr(s, "mujoco_sensors", False) for s in row_due) for row_due in due]  # per logged row
    tick = 0
    row = 0  # logged rows so far
    opt.disableflags = quiet
    try:
        for c0 in range(0, sched.n_ticks, CHUNK):
            t = times[c0 : c0 + CHUNK]
            ref_pos, ref_vel, ref_acc, ref_yaw = tracking(tr, t)
            ref_heading = heading(ref_yaw)
            logged = sched.logged[c0 : c0 + CHUNK]
            rows = _rows(physics, int(logged.sum()), flown=True)
            qpos, qvel, ctrl = rows["qpos"], rows["qvel"], rows["ctrl"]
            rows["reference/pos"][:] = ref_pos[logged]
            rows["reference/quat"][:] = attitude(tr, t[logged], ref_acc[logged])
            j = 0  # row within the chunk
            for tj, is_logged, rp, rv, ra, rh in zip(t.tolist(), logged.tolist(), ref_pos, ref_vel, ref_acc, ref_heading):
                poll()  # a worker asked to stop does so here (testbed.interrupt)
                if tick == sched.n_ticks - 1:  # the last tick keeps MuJoCo's sensors on: the physics
                    quiet = opt.disableflags = flags  # returned reads as after plain mj_step
                if is_logged and reads[row]:
                    opt.disableflags = flags
                step1(m, d)
                if onboard is None:
                    controller(pos, vel, rotation, omega, rp, rv, ra, rh, out=thrust)
                else:
                    controller(*onboard.state(pos, vel, rotation, omega, rp, rv), rp, rv, ra, rh, out=thrust)
                if dist is not None:
                    forces.hold(dist.index, wrench(dist, tick, mass, inertia, rotation[dist.index]))
                forces.apply()
                tick += 1
                if is_logged:
                    qpos[j], qvel[j], ctrl[j] = d.qpos, d.qvel, d.ctrl
                    step2(m, d)  # acceleration stage at time t (sensors read it), then integrate to t + dt
                    opt.disableflags = quiet
                    for s in due[row]:
                        s.sample(physics, tj, row)
                        if onboard is not None:
                            onboard.measured(s, ra)
                    row += 1
                    j += 1
                else:
                    step2(m, d)
                if onboard is not None:
                    onboard.advance(tj)
                if rest:
                    forces.step(m, d, rest)
            if j:
                _append(log, physics, rows)
            bar.update(len(t))
    finally:
        opt.disableflags = flags


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
