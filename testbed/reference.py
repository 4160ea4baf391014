"""Reference trajectories of the four papers and the trajectory library (minimum-jerk waypoints,
minimum-snap splines, circle, lemniscate, hover: the maths in testbed.trajectories).

Every reference is analytic in position, velocity and acceleration and is evaluated for a whole
time grid at once: `evaluate(traj, t)` with t (K,) seconds returns a `RefState` of arrays
(K, N, ...) for N vehicles, world frame (ENU, metres, seconds). Attitude is either explicit
(seed 003's eq. 31 Euler angles) or "flat": the attitude a quadrotor must have to produce the
reference acceleration, thrust along body z, with the reference yaw. Body angular velocity and
acceleration come from central differences of the attitude (errors ~1e-10 rad/s, ~1e-7 rad/s^2).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree
from scipy.spatial.transform import Rotation

from testbed.errors import FieldError
from testbed.config.scenario import (Circle, Hover, Lemniscate, LeaderFollower, Obstacle, PhaseFormation, Scenario, Spline, StraightLine, SwarmBox,
                              SwarmGrid, Trajectory, Waypoints)
from testbed.trajectories import GRAVITY  # noqa: F401  (re-exported: m/s^2, models/arena.xml)

# m: circumscribed radius of a vehicle's collision box (models/quadrotor.xml: half extents
# 0.6 x 0.6 x 0.12 m centred 0.02 m above the body origin): sqrt(0.6^2 + 0.6^2 + 0.14^2).
AIRFRAME_RADIUS = 0.86
CLEARANCE_CHUNK = 4096  # reference instants per vectorized clearance test


@dataclass(frozen=True, slots=True)
class RefState:
    """Reference at K instants for N vehicles.

    pos, vel, acc: (K, N, 3) world frame (m, m/s, m/s^2); quat: (K, N, 4) wxyz body-to-world;
    omega, alpha: (K, N, 3) body-frame angular velocity (rad/s) and acceleration (rad/s^2);
    yaw: (K, N) rad.
    """

    pos: np.ndarray
    vel: np.ndarray
    acc: np.ndarray
    quat: np.ndarray
    omega: np.ndarray
    alpha: np.ndarray
    yaw: np.ndarray


# ---------------------------------------------------------------------------- translations


def _phase_masters(tr: PhaseFormation) -> np.ndarray:
    """(5, 3) master positions in the navigation frame (FLU of master 3), metres."""
    s = tr.spacing
    if tr.formation == "line":  # lateral line, master 1 on the left
        xy = [(0, 2 * s), (0, s), (0, 0), (0, -s), (0, -2 * s)]
    elif tr.formation == "cross":  # master 3 in the centre, 2/4 lateral, 1/5 fore and aft
        xy = [(s, 0), (0, s), (0, 0), (0, -s), (-s, 0)]
    else:  # V with the apex (master 3) forward, arms backward at +/- half the opening angle
        half = np.radians(120.0 if tr.formation == "vobtuse" else 30.0) / 2
        left, right = np.array([-np.cos(half), np.sin(half)]), np.array([-np.cos(half), -np.sin(half)])
        xy = [2 * s * left, s * left, (0, 0), s * right, 2 * s * right]
    return np.column_stack([np.array(xy, float), np.array(tr.heights, float)])


def _pva(tr: Trajectory, t: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Analytic position, velocity, acceleration, each (K, N, 3)."""
    K = t.shape[0]
    tt = t[:, None, None]
    if isinstance(tr, PhaseFormation):
        origin, vm = np.array(tr.nav_origin), np.array(tr.master_velocity)
        starts = np.vstack([_phase_masters(tr), tr.follower_start]) + origin
        vels = np.vstack([np.tile(vm, (5, 1)), vm + np.array(tr.follower_velocity)])
        return starts + vels * tt, np.broadcast_to(vels, (K, 6, 3)).copy(), np.zeros((K, 6, 3))
    if isinstance(tr, StraightLine):
        base = np.array(tr.start) + np.array(tr.offsets)
        v = np.broadcast_to(np.array(tr.velocity), base.shape)
        return base + v * tt, np.broadcast_to(v, (K, *base.shape)).copy(), np.zeros((K, *base.shape))
    if isinstance(tr, (SwarmBox, SwarmGrid)):
        n = tr.vehicles
        i = np.arange(n)
        period = tr.period_min + (tr.period_max - tr.period_min) * (i / max(n - 1, 1))
        w = (2 * np.pi / period)[:, None]  # (N, 1) rad/s
        phi = i[:, None] * 2.39996 + np.arange(3)[None, :] * 1.0  # (N, 3)
        A = np.array(tr.amplitude)
        arg = w * tt + phi
        return np.array(tr.bases) + A * np.sin(arg), A * w * np.cos(arg), -A * w**2 * np.sin(arg)
    if isinstance(tr, LeaderFollower):
        v = np.array(tr.leader_velocity)
        psi = np.arctan2(v[1], v[0])
        xh, yh, zh = np.array([np.cos(psi), np.sin(psi), 0]), np.array([-np.sin(psi), np.cos(psi), 0]), np.array([0, 0, 1.0])
        pl = np.array(tr.leader_start) + v * t[:, None]
        ww, wh = 2 * np.pi / tr.weave_period, 2 * np.pi / (0.7 * tr.weave_period)
        off = np.array(tr.follower_offset)
        lat = tr.weave_amp * np.array([np.sin(ww * t), ww * np.cos(ww * t), -ww**2 * np.sin(ww * t)])
        up = tr.heave_amp * np.array([np.sin(wh * t), wh * np.cos(wh * t), -wh**2 * np.sin(wh * t)])
        pf = pl + off @ np.array([xh, yh, zh]) + lat[0][:, None] * yh + up[0][:, None] * zh
        vf = v + lat[1][:, None] * yh + up[1][:, None] * zh
        af = lat[2][:, None] * yh + up[2][:, None] * zh
        return np.stack([pl, pf], 1), np.stack([np.broadcast_to(v, pl.shape), vf], 1), np.stack([np.zeros_like(pl), af], 1)
    if isinstance(tr, Waypoints):
        P, T = np.array(tr.points), np.array(tr.times)
        tc = np.clip(t, T[0], T[-1])
        seg = np.clip(np.searchsorted(T, tc, side="right") - 1, 0, len(T) - 2)
        dur = T[seg + 1] - T[seg]
        tau = (tc - T[seg]) / dur
        # minimum-jerk rest-to-rest blend s(tau) = 10 tau^3 - 15 tau^4 + 6 tau^5 and derivatives
        s = 10 * tau**3 - 15 * tau**4 + 6 * tau**5
        ds = (30 * tau**2 - 60 * tau**3 + 30 * tau**4) / dur
        dds = (60 * tau - 180 * tau**2 + 120 * tau**3) / dur**2
        d = P[seg + 1] - P[seg]
        path = P[seg] + s[:, None] * d
        off = np.array(tr.offsets)
        return path[:, None] + off, (ds[:, None] * d)[:, None] + 0 * off, (dds[:, None] * d)[:, None] + 0 * off
    if isinstance(tr, Spline):
        p, v, a = tr.path.derivatives(t)
        off = np.array(tr.offsets)
        return p[:, None] + off, v[:, None] + 0 * off, a[:, None] + 0 * off
    if isinstance(tr, (Circle, Lemniscate)):
        return tr.pva(t)
    if isinstance(tr, Hover):
        p = np.broadcast_to(np.array(tr.point) + np.array(tr.offsets), (K, tr.vehicles, 3)).copy()
        return p, np.zeros_like(p), np.zeros_like(p)
    raise TypeError(f"unknown trajectory {type(tr).__name__}")


# ------------------------------------------------------------------------------- attitudes


def _rotation(tr: Trajectory, t: np.ndarray, acc: np.ndarray | None = None, flat: bool = False) -> tuple[Rotation, np.ndarray]:
    """Attitude at times t (K,): a flat Rotation of K*N elements and yaw (K, N).

    acc: the reference acceleration (K, N, 3) at t if already evaluated (flat attitudes use it).
    flat: the flat attitude even where the trajectory prescribes one (seed 003's eq. 31).
    """
    if isinstance(tr, PhaseFormation) and not flat:
        ypr = _phase_ypr(tr, t)
        return Rotation.from_euler("ZYX", ypr.reshape(-1, 3)), ypr[..., 0]
    if acc is None:
        acc = _pva(tr, t)[2]
    yaw = _yaw(tr, t, acc.shape[1])
    return flat_rotation(acc.reshape(-1, 3), yaw.reshape(-1)), yaw


def _phase_ypr(tr: PhaseFormation, t: np.ndarray) -> np.ndarray:
    """Seed 003 eq. 31 yaw, pitch, roll (K, 6, 3) rad: a * sin(2 pi f t + phase) on the
    follower; masters level with yaw 0 (stable flight)."""
    s = np.sin(2 * np.pi * tr.attitude_freq_hz * t + tr.attitude_phase)
    ypr = np.zeros((t.shape[0], 6, 3))
    ypr[:, 5] = np.radians([tr.yaw_amp_deg, tr.pitch_amp_deg, tr.roll_amp_deg])[None] * s[:, None]
    return ypr


def _yaw(tr: Trajectory, t: np.ndarray, n: int) -> np.ndarray:
    """Reference yaw (K, N) rad of every trajectory."""
    if isinstance(tr, PhaseFormation):
        return _phase_ypr(tr, t)[..., 0]
    yaw = np.zeros((t.shape[0], n))
    if isinstance(tr, LeaderFollower):
        psi = np.arctan2(tr.leader_velocity[1], tr.leader_velocity[0])
        yaw[:, 0] = psi
        yaw[:, 1] = psi + np.radians(tr.yaw_amp_deg) * np.sin(2 * np.pi * t / tr.yaw_period)
    elif isinstance(tr, (Waypoints, Spline, Circle, Lemniscate, Hover)):
        yaw[:] = np.radians(tr.yaw_deg)
    return yaw


def flat_rotation(acc: np.ndarray, yaw: np.ndarray) -> Rotation:
    """Attitude of a quadrotor producing world acceleration acc (M, 3) with yaw (M,).

    Body z along the required thrust a + g e_z; body x the projection of the yaw heading.
    """
    zb = acc + np.array([0.0, 0.0, GRAVITY])
    zb /= np.linalg.norm(zb, axis=-1, keepdims=True)
    xc = np.stack([np.cos(yaw), np.sin(yaw), np.zeros_like(yaw)], -1)
    yb = np.cross(zb, xc)
    yb /= np.linalg.norm(yb, axis=-1, keepdims=True)
    xb = np.cross(yb, zb)
    return Rotation.from_matrix(np.stack([xb, yb, zb], -1))


def _omega(tr: Trajectory, t: np.ndarray, h: float, flat: bool = False) -> np.ndarray:
    """Body angular velocity (K, N, 3) by the central difference log(R(t-h)^T R(t+h)) / 2h."""
    r0, _ = _rotation(tr, t - h, flat=flat)
    r1, _ = _rotation(tr, t + h, flat=flat)
    return (r0.inv() * r1).as_rotvec().reshape(t.shape[0], -1, 3) / (2 * h)


def tracking(tr: Trajectory, t: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """What a tracking controller needs at times t (K,) s, the same values `evaluate` gives:
    pos, vel, acc (K, N, 3) world (m, m/s, m/s^2) and yaw (K, N) rad. No attitude: cheap."""
    pos, vel, acc = _pva(tr, t)
    return pos, vel, acc, _yaw(tr, t, pos.shape[1])


def attitude(tr: Trajectory, t: np.ndarray, acc: np.ndarray) -> np.ndarray:
    """Reference attitude quaternions (K, N, 4) wxyz at times t (K,) s, given the reference
    acceleration acc (K, N, 3) there (from `tracking`): the same values `evaluate` gives."""
    rot, _ = _rotation(tr, t, acc)
    return rot.as_quat(scalar_first=True).reshape(t.shape[0], -1, 4)


def evaluate(tr: Trajectory, t: np.ndarray | float, rates: bool = True, flat: bool = False) -> RefState:
    """The reference at times t (K,) or a scalar (K = 1), see RefState.

    rates=False skips the angular velocity and acceleration (left as zeros): what a tracking
    controller needs is position, velocity, acceleration and yaw. flat=True gives every vehicle
    the flat attitude (thrust along a + g, the reference yaw) even where the trajectory prescribes
    one: the attitude a flown quadrotor has on that path (its start state in flown mode).
    """
    t = np.atleast_1d(np.asarray(t, float))
    pos, vel, acc = _pva(tr, t)
    rot, yaw = _rotation(tr, t, acc, flat)
    quat = rot.as_quat(scalar_first=True).reshape(t.shape[0], -1, 4)
    if not rates:
        zeros = np.zeros_like(pos)
        return RefState(pos, vel, acc, quat, zeros, zeros, yaw)
    omega = _omega(tr, t, 1e-5, flat)
    ha = 1e-3
    alpha = (_omega(tr, t + ha, 1e-5, flat) - _omega(tr, t - ha, 1e-5, flat)) / (2 * ha)
    return RefState(pos, vel, acc, quat, omega, alpha, yaw)


# ------------------------------------------------------------------------------- clearance


def check_clearance(sc: Scenario, label: str) -> str | None:
    """Apply world.clearance to the problem `clearance(sc)` finds: "error" raises FieldError naming
    `label` (the scenario's file) and the key; "warn" returns the warning line (the caller shows
    it); "off", or no problem, returns None."""
    problem = clearance(sc) if sc.world.clearance != "off" else None
    if problem is None:
        return None
    key, reason = problem
    if sc.world.clearance == "error":
        raise FieldError(label, key, None, f'{reason}; set world.clearance = "warn" (or "off") to run it anyway')
    return f'{label}: {key}: {reason} (world.clearance = "warn")'


def clearance(sc: Scenario) -> tuple[str, str] | None:
    """Does the reference path of `sc` hit the floor, an obstacle or another vehicle?

    Sampled at the truth rate over the whole run (t = k / world.truth_rate s), each vehicle a
    sphere of AIRFRAME_RADIUS about its reference position: the floor (z = 0) must stay below it,
    each obstacle outside it, and two vehicles at least 2 AIRFRAME_RADIUS apart (a neighbour
    search, `_close_pair`). Returns the first problem found as (dotted key, reason), or None.
    Between samples nothing is checked: a path that crosses an obstacle thinner than the
    distance flown in 1 / truth_rate can pass.
    """
    n = int(np.floor(sc.duration * sc.world.truth_rate + 1e-9)) + 1
    for k0 in range(0, n, CLEARANCE_CHUNK):
        t = np.arange(k0, min(n, k0 + CLEARANCE_CHUNK)) / sc.world.truth_rate
        pos = _pva(sc.trajectory, t)[0]  # (K, N, 3) m
        low = pos[..., 2] < AIRFRAME_RADIUS
        if low.any():
            k, i = np.argwhere(low)[0]
            return "trajectory", (f"vehicle {i + 1}'s reference is at z = {pos[k, i, 2]:.2f} m at t = {t[k]:g} s: "
                                  f"through or within the airframe radius {AIRFRAME_RADIUS} m of the floor")
        for m, ob in enumerate(sc.world.obstacles):
            d = _obstacle_distance(ob, pos)
            if (d < AIRFRAME_RADIUS).any():
                k, i = np.argwhere(d < AIRFRAME_RADIUS)[0]
                return f"world.obstacles[{m}]", (f"vehicle {i + 1}'s reference passes {d[k, i]:.2f} m from this {ob.type} "
                                                 f"at t = {t[k]:g} s, inside its airframe radius {AIRFRAME_RADIUS} m")
        pair = _close_pair(pos, 2 * AIRFRAME_RADIUS)
        if pair is not None:
            k, i, j = pair
            return "trajectory", (f"vehicles {i + 1} and {j + 1} are {np.linalg.norm(pos[k, i] - pos[k, j]):.2f} m apart at "
                                  f"t = {t[k]:g} s, closer than two airframe radii ({2 * AIRFRAME_RADIUS:.2f} m)")
    return None


def _obstacle_distance(ob: Obstacle, pos: np.ndarray) -> np.ndarray:
    """Distance (m) from points pos (..., 3) world to the surface of `ob` (0 inside it)."""
    d = pos - np.array(ob.pos)
    if ob.type == "cylinder":  # axis along world z: size = (radius, half height, unused)
        radial = np.maximum(np.hypot(d[..., 0], d[..., 1]) - ob.size[0], 0.0)
        return np.hypot(radial, np.maximum(np.abs(d[..., 2]) - ob.size[1], 0.0))
    c, s = np.cos(np.radians(ob.yaw_deg)), np.sin(np.radians(ob.yaw_deg))
    local = np.stack([c * d[..., 0] + s * d[..., 1], -s * d[..., 0] + c * d[..., 1], d[..., 2]], -1)  # box frame
    return np.linalg.norm(np.maximum(np.abs(local) - np.array(ob.size), 0.0), axis=-1)


def _close_pair(pos: np.ndarray, r: float) -> tuple[int, int, int] | None:
    """The first (k, i, j), i < j, with |pos[k, i] - pos[k, j]| < r, or None; pos (K, N, 3) m.

    One k-d tree over all K N points with the sample index as a fourth coordinate spaced 10 r
    apart, so only points of the same instant can be neighbours: O(K N log(K N)), no loop over
    vehicles or instants.
    """
    K, N, _ = pos.shape
    if N < 2:
        return None
    pts = np.concatenate([pos.reshape(-1, 3), np.repeat(np.arange(K) * 10.0 * r, N)[:, None]], axis=1)
    pairs = cKDTree(pts).query_pairs(r * (1 - 1e-12), output_type="ndarray")
    if pairs.size == 0:
        return None
    first = pairs[np.lexsort((pairs.max(1), pairs.min(1)))[0]]
    k, i = divmod(int(first.min()), N)
    return k, i, int(first.max()) % N
