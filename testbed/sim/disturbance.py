"""Random body accelerations of the scenario's [disturbance] table (see scenario.Disturbance).

One draw per run from stream "disturbance" on the controller-tick grid (tick h):
a_k ~ N(0, q / h) per world axis and alpha_k ~ N(0, q_r / h) per body axis, held over tick k.
Integrated exactly for the translation,
    dv_{k+1} = dv_k + a_k h,   dp_{k+1} = dp_k + dv_k h + a_k h^2 / 2,
so over n ticks (dt = n h) the velocity increment is N(0, q dt) and the position increment beyond
v dt has variance q (dt^3 / 3 - h^2 dt / 12), covariance q dt^2 / 2 with the velocity increment:
the constant-velocity model's Q, to 6e-4 relative at h = 5 ms, dt = 0.1 s. The rotation is a
perturbation Delta (body-to-body) on top of the reference attitude, R = R_ref Delta, with its own
body rate w_d (random walk) and
    Delta_{k+1} = Delta_k exp(w_d,k h + alpha_k h^2 / 2),  w_d,k+1 = w_d,k + alpha_k h;
then, exactly for R = R_ref Delta (Rdot = R [w]x):
    w     = Delta^T w_ref + w_d,
    alpha = Delta^T alpha_ref - w_d x (Delta^T w_ref) + alpha_d.
"""
from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np
from scipy.spatial.transform import Rotation

from estimators.so3 import quat_mul
from testbed.reference import RefState
from testbed.rng import stream_rng
from testbed.config.scenario import Scenario


@dataclass(frozen=True, slots=True)
class Draws:
    """The run's white accelerations on every tick (n ticks) of the D disturbed vehicles.

    index: (D,) 0-based vehicle indices; accel: (n, D, 3) world m/s^2; ang_accel: (n, D, 3) body
    rad/s^2, each held over its tick.
    """

    index: np.ndarray
    accel: np.ndarray
    ang_accel: np.ndarray


@dataclass(frozen=True, slots=True)
class Realization:
    """The integrated disturbance at chosen ticks (K of them) for the D disturbed vehicles.

    index: (D,) 0-based vehicle indices; ticks: (K,) tick numbers of the rows; accel: (K, D, 3)
    world m/s^2; dp, dv: (K, D, 3) world position (m) and velocity (m/s) offsets; ang_accel:
    (K, D, 3) body rad/s^2; omega: (K, D, 3) body rate of Delta (rad/s); delta: (K, D, 4) wxyz
    quaternion of Delta (body-to-body).
    """

    index: np.ndarray
    ticks: np.ndarray
    accel: np.ndarray
    dp: np.ndarray
    dv: np.ndarray
    ang_accel: np.ndarray
    omega: np.ndarray
    delta: np.ndarray


def draw(scenario: Scenario, n_ticks: int) -> Draws | None:
    """The white accelerations of ticks 0..n_ticks-1 (stream "disturbance"), or None if the
    scenario has no disturbance. Deterministic in scenario.seed."""
    dist = scenario.disturbance
    if not dist.active:
        return None
    h = 1.0 / scenario.world.control_rate
    index = np.array([v - 1 for v in dist.vehicles] if dist.vehicles else range(scenario.vehicles), int)
    noise = stream_rng(scenario.seed, "disturbance").standard_normal((n_ticks, index.size, 6))
    return Draws(index, noise[..., :3] * np.sqrt(dist.accel_density / h),
                 noise[..., 3:] * np.sqrt(dist.angular_accel_density / h))


def realize(scenario: Scenario, ticks: np.ndarray) -> Realization | None:
    """The disturbance integrated from rest at t = 0 and kept at ticks (K,) (increasing tick
    numbers), or None if the scenario has none. Only the K rows are kept (memory)."""
    ticks = np.asarray(ticks, int)
    dr = draw(scenario, int(ticks[-1]) + 1)
    if dr is None:
        return None
    h = 1.0 / scenario.world.control_rate
    accel, ang = dr.accel, dr.ang_accel
    dv, dp = _integrate(accel, h)
    omega, _ = _integrate(ang, h)
    steps = Rotation.from_rotvec((omega * h + ang * h * h / 2).reshape(-1, 3)).as_quat(scalar_first=True).reshape(ang.shape[:-1] + (4,))
    delta = np.empty((ticks.size,) + steps.shape[1:])
    q = np.zeros(steps.shape[1:])
    q[:, 0] = 1.0
    row = 0
    for k in range(int(ticks[-1]) + 1):
        if k == ticks[row]:
            delta[row] = q
            row += 1
        q = quat_mul(q, steps[k])
    return Realization(dr.index, ticks, accel[ticks], dp[ticks], dv[ticks], ang[ticks], omega[ticks], delta)


def _integrate(a: np.ndarray, h: float) -> tuple[np.ndarray, np.ndarray]:
    """Velocity and position (n, D, 3) from rest under accelerations a (n, D, 3) held over h."""
    v = np.zeros_like(a)
    p = np.zeros_like(a)
    np.cumsum(a[:-1] * h, axis=0, out=v[1:])
    np.cumsum(v[:-1] * h + a[:-1] * (h * h / 2), axis=0, out=p[1:])
    return v, p


def perturb(ref: RefState, real: Realization, rows: slice | np.ndarray) -> RefState:
    """The reference with the disturbance added (module docstring): the motion prescribed mode
    plays back. ref's instants are the realization's rows `rows` (their ticks real.ticks[rows])."""
    i = real.index
    pos, vel, acc = ref.pos.copy(), ref.vel.copy(), ref.acc.copy()
    quat, omega, alpha = ref.quat.copy(), ref.omega.copy(), ref.alpha.copy()
    pos[:, i] += real.dp[rows]
    vel[:, i] += real.dv[rows]
    acc[:, i] += real.accel[rows]
    d = real.delta[rows]
    quat[:, i] = quat_mul(ref.quat[:, i], d)
    Dt = Rotation.from_quat(d.reshape(-1, 4), scalar_first=True).inv()  # Delta^T
    w_ref = Dt.apply(ref.omega[:, i].reshape(-1, 3)).reshape(d.shape[:-1] + (3,))
    a_ref = Dt.apply(ref.alpha[:, i].reshape(-1, 3)).reshape(w_ref.shape)
    wd = real.omega[rows]
    omega[:, i] = w_ref + wd
    alpha[:, i] = a_ref - np.cross(wd, w_ref) + real.ang_accel[rows]
    return replace(ref, pos=pos, vel=vel, acc=acc, quat=quat, omega=omega, alpha=alpha)


def wrench(draws: Draws, tick: int, mass: float, inertia: np.ndarray, rotation: np.ndarray) -> np.ndarray:
    """Flown mode: external force and torque (D, 6), world frame, at the body's centre of mass,
    that give a free body the disturbance accelerations of this tick: [m a, R (I alpha)].

    mass (kg), inertia (3,) principal moments about the body axes (kg m^2), rotation (D, 3, 3)
    the disturbed bodies' R_world_from_body now.
    """
    torque_body = inertia * draws.ang_accel[tick]
    return np.concatenate([mass * draws.accel[tick], np.einsum("dij,dj->di", rotation, torque_body)], axis=1)
