"""Trajectory library maths: minimum-snap splines through waypoints, circle, lemniscate, and the
airframe limits a reference must respect.

Pure numpy (no scipy, no MuJoCo, nothing from testbed), so that a scenario checks its trajectory
while it loads (testbed.config.scenario) and testbed.reference evaluates it, from one implementation.
Units SI, world frame ENU; arrays are (K, 3) for K instants unless a docstring says otherwise.

Minimum snap (Mellinger & Kumar 2011, "Minimum snap trajectory generation and control for
quadrotors", Sec. IV; Richter, Bry & Roy 2013, "Polynomial trajectory planning for aggressive
quadrotor flight in dense indoor environments", Sec. III: the equality-constrained QP). The
equations are numbered here (S1..S5) and quoted above the lines that implement them; the papers'
own numbering is not quoted. Segment i of S runs over t in [t_i, t_i+1], duration T_i, in the
normalized time s = (t - t_i) / T_i in [0, 1], per axis a polynomial of degree 7 (8 coefficients):
    (S1) p_i(s) = sum_k c_ik s^k,   d^r p / dt^r = T_i^-r sum_k k!/(k-r)! c_ik s^(k-r)
The cost is the integral of the squared snap (4th derivative) over the whole path:
    (S2) J = sum_i int_0^T_i (d^4 p_i/dt^4)^2 dt = sum_i c_i^T Q_i c_i,
         Q_i[j, k] = T_i^-7 a_j a_k / (j + k - 7) for j, k >= 4, a_j = j!/(j-4)!, else 0
subject to the equality constraints A c = b:
    (S3) p_i(0) = P_i and p_i(1) = P_i+1 (the waypoints are passed, at their times)
    (S4) T_i^-r p_i^(r)(1) = T_i+1^-r p_i+1^(r)(0), r = 1..4 (velocity, acceleration, jerk and
         snap continuous at every interior waypoint; a closed path also from the last segment to
         the first); an open path starts and ends at rest: p^(r) = 0, r = 1..3, at both ends
and the QP's optimum solves the KKT system
    (S5) [2Q A^T; A 0] [c; lambda] = [0; b]
one right-hand side per axis. Its optimum is C^6 at interior waypoints although only C^4 is
imposed (the Euler-Lagrange condition of J: the 5th and 6th derivatives are continuous wherever
the position alone is pinned), which tests/test_trajectories.py checks.
"""
from __future__ import annotations

import math
import xml.etree.ElementTree as ET
from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path

import numpy as np

GRAVITY = 9.81  # m/s^2, as in models/arena.xml
AIRFRAME_FILE = Path(__file__).resolve().parent.parent / "models" / "quadrotor.xml"
DEGREE = 7  # polynomial degree of a minimum-snap segment (2 x 4 - 1)
CONTINUOUS = 4  # derivatives 1..CONTINUOUS imposed continuous at interior waypoints (S4)
REST = 3  # an open path's derivatives 1..REST are zero at both ends (S4)
MAX_POINTS = 256  # waypoints of one spline: its KKT system (S5) is solved dense, ~(14 S)^2 entries
MIN_SEGMENT = 0.5  # s: shortest segment the time allocation gives (a repeated waypoint: a pause)
# Fraction of the airframe's total thrust a reference may ask for: the rest is the feedback
# controller's headroom (at full collective thrust the rotors have no differential thrust left
# for attitude torques, and a tracking error could not be corrected).
THRUST_FRACTION = 0.8
# m/s: the airframe's flight envelope in speed. The MuJoCo model has no aerodynamic drag, so
# nothing in the physics limits speed; this is the published maximum horizontal speed of the
# airframe the model stands for (DJI Matrice 300 RTK, S mode; models/quadrotor.xml).
MAX_SPEED = 23.0
SAMPLES_PER_SEGMENT = 64  # limit checks sample each spline segment at 65 instants (both ends)
SAMPLES_PER_PERIOD = 1024  # ... and a lemniscate's period at 1024


@dataclass(frozen=True, slots=True)
class Airframe:
    """One vehicle's limits, read from models/quadrotor.xml: mass (kg), max_thrust (N, all rotors
    at the top of their ctrlrange), max_speed (m/s, MAX_SPEED)."""

    mass: float
    max_thrust: float
    rotors: int
    max_speed: float = MAX_SPEED

    @property
    def max_accel(self) -> float:
        """m/s^2: the largest |a + g e_z| a reference may ask for, THRUST_FRACTION of thrust / mass."""
        return THRUST_FRACTION * self.max_thrust / self.mass

    def describe(self) -> str:
        return (f"{THRUST_FRACTION:.0%} of the airframe's {self.max_thrust / self.mass:.1f} m/s^2 "
                f"({self.rotors} rotors x {self.max_thrust / self.rotors:g} N / {self.mass:g} kg, models/quadrotor.xml)")


@lru_cache(maxsize=1)
def airframe() -> Airframe:
    """The flown airframe's mass and thrust limit from models/quadrotor.xml, the file testbed.sim.world
    builds every vehicle from: the <inertial> mass of body "base" and the sum over the <motor>
    actuators of the upper end of their ctrlrange (their own, or their default class's)."""
    root = ET.parse(AIRFRAME_FILE).getroot()
    mass = float(root.find(".//body[@name='base']/inertial").get("mass"))
    classes = {d.get("class"): d for d in root.iter("default")}

    def ctrl_max(motor: ET.Element) -> float:
        rng = motor.get("ctrlrange")
        if rng is None:
            rng = classes[motor.get("class")].find("motor").get("ctrlrange")
        return float(rng.split()[1])

    motors = root.findall("./actuator/motor")
    return Airframe(mass=mass, max_thrust=sum(ctrl_max(m) for m in motors), rotors=len(motors))


def limit_violation(t: np.ndarray, vel: np.ndarray, acc: np.ndarray) -> str | None:
    """What a reference asks beyond the airframe (`airframe()`), or None.

    t (K,) s; vel, acc (K, N, 3) or (K, 3) world (m/s, m/s^2). Checks the speed against
    max_speed, the thrust per unit mass |a + g e_z| against max_accel, and a_z > -g (upright:
    thrust along body z cannot pull down). Returns the first violation as words, worst instant."""
    af = airframe()
    vel, acc = vel.reshape(len(t), -1, 3), acc.reshape(len(t), -1, 3)
    speed = np.linalg.norm(vel, axis=-1).max(axis=1)
    lift = acc + np.array([0.0, 0.0, GRAVITY])
    need = np.linalg.norm(lift, axis=-1).max(axis=1)
    k = int(np.argmax(speed))
    if speed[k] > af.max_speed:
        return f"the reference reaches {speed[k]:.1f} m/s at t = {t[k]:.2f} s, faster than the airframe's {af.max_speed:g} m/s"
    k = int(np.argmax(need))
    if need[k] > af.max_accel:
        return (f"the reference needs {need[k]:.1f} m/s^2 of thrust per unit mass at t = {t[k]:.2f} s, "
                f"more than {af.describe()}")
    low = lift[..., 2].min(axis=1)
    k = int(np.argmin(low))
    if low[k] <= 0:
        return f"the reference accelerates downwards at {GRAVITY - low[k]:.1f} m/s^2 at t = {t[k]:.2f} s, faster than gravity (upside down)"
    return None


# ----------------------------------------------------------------------------- minimum snap


def _falling(k: np.ndarray, r: int) -> np.ndarray:
    """k! / (k - r)! elementwise (0 where k < r): the factor of s^(k-r) in d^r/ds^r s^k."""
    out = np.ones_like(k, dtype=float)
    for j in range(r):
        out *= k - j
    return out


_K = np.arange(DEGREE + 1)


def _row(s: float, r: int) -> np.ndarray:
    """(8,) d^r/ds^r of the monomials s^k at s, k = 0..7 (S1)."""
    e = np.clip(_K - r, 0, None)
    return _falling(_K, r) * s**e


def _snap_cost(T: float) -> np.ndarray:
    """(8, 8) Q_i of (S2) for a segment of duration T (s)."""
    a = _falling(_K, 4)
    j, k = np.meshgrid(_K, _K, indexing="ij")
    p = np.where((j >= 4) & (k >= 4), j + k - 7, 1)
    return np.where((j >= 4) & (k >= 4), T**-7 * np.outer(a, a) / p, 0.0)


def allocate(points: np.ndarray, speed: float, closed: bool) -> np.ndarray:
    """Time allocation (s) of the segments between consecutive points (M, 3) m at a cruise speed
    (m/s): T_i = max(|P_i+1 - P_i| / speed, MIN_SEGMENT), the first and last segments of an open
    path doubled (they start or end at rest, so their average speed is about half the cruise).
    Closed: one more segment, from the last point back to the first. Returns (S,)."""
    P = np.vstack([points, points[:1]]) if closed else points
    T = np.maximum(np.linalg.norm(np.diff(P, axis=0), axis=1) / speed, MIN_SEGMENT)
    if not closed:
        T[0] *= 2
        T[-1] *= 2 if len(T) > 1 else 1
    return T


@dataclass(frozen=True, eq=False)
class PiecewisePolynomial:
    """A spline of S degree-7 segments, (S1). knots (S+1,) s from 0; coeffs (S, 8, 3) in the
    normalized time of each segment; closed: periodic with period knots[-1], else held at rest
    at its first point before 0 and at its last after the end."""

    knots: np.ndarray
    coeffs: np.ndarray
    closed: bool

    def derivatives(self, t: np.ndarray, orders: int = 3) -> np.ndarray:
        """(orders, K, 3): d^r p/dt^r, r = 0..orders-1, at times t (K,) s (m, m/s, m/s^2, ...)."""
        t = np.asarray(t, float)
        end = self.knots[-1]
        tc = np.mod(t, end) if self.closed else np.clip(t, 0.0, end)
        seg = np.clip(np.searchsorted(self.knots, tc, side="right") - 1, 0, len(self.knots) - 2)
        T = np.diff(self.knots)[seg]
        s = (tc - self.knots[seg]) / T
        c = self.coeffs[seg]  # (K, 8, 3)
        out = np.empty((orders, len(t), 3))
        for r in range(orders):
            e = np.clip(_K - r, 0, None)
            basis = _falling(_K, r)[None] * s[:, None] ** e[None]  # (K, 8)
            # (S1) d^r p / dt^r = T^-r sum_k k!/(k-r)! c_k s^(k-r)
            out[r] = np.einsum("kj,kjd->kd", basis, c) / T[:, None] ** r
            if r and not self.closed:
                out[r][(t < 0) | (t > end)] = 0.0  # held at rest outside the path
        return out


def snap_qp(P: np.ndarray, T: np.ndarray, closed: bool) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The QP of (S2)-(S4) for waypoints P (M, 3) m and durations T (S,) s: min c^T Q c subject to
    A c = b, per axis; c stacks the S segments' 8 coefficients (S1). Returns Q (8S, 8S),
    A (m, 8S), b (m, 3)."""
    S = len(T)
    n = S * (DEGREE + 1)
    Q = np.zeros((n, n))
    rows, b = [], []

    def constraint(entries: list[tuple[int, np.ndarray]], rhs: np.ndarray) -> None:
        row = np.zeros(n)
        for seg, vals in entries:
            row[seg * 8:(seg + 1) * 8] += vals
        rows.append(row)
        b.append(rhs)

    zero = np.zeros(3)
    for i in range(S):
        # (S2) Q_i[j, k] = T_i^-7 a_j a_k / (j + k - 7)
        Q[i * 8:(i + 1) * 8, i * 8:(i + 1) * 8] = _snap_cost(T[i])
        # (S3) p_i(0) = P_i, p_i(1) = P_i+1
        constraint([(i, _row(0.0, 0))], P[i])
        constraint([(i, _row(1.0, 0))], P[(i + 1) % len(P)])
    joints = range(S) if closed else range(S - 1)
    for i in joints:
        j = (i + 1) % S
        for r in range(1, CONTINUOUS + 1):
            # (S4) T_i^-r p_i^(r)(1) - T_j^-r p_j^(r)(0) = 0, times min(T_i, T_j)^r (rows of order 1)
            u = min(T[i], T[j])
            constraint([(i, _row(1.0, r) * (u / T[i]) ** r), (j, -_row(0.0, r) * (u / T[j]) ** r)], zero)
    if not closed:
        for r in range(1, REST + 1):
            # (S4) at rest at both ends
            constraint([(0, _row(0.0, r))], zero)
            constraint([(S - 1, _row(1.0, r))], zero)
    return Q, np.array(rows), np.array(b)


@lru_cache(maxsize=64)
def _min_snap_cached(points: tuple, durations: tuple, closed: bool) -> PiecewisePolynomial:
    T = np.array(durations, float)
    Q, A, B = snap_qp(np.array(points, float), T, closed)
    n, m = len(Q), len(A)
    S = len(T)
    # (S5) [2Q A^T; A 0] [c; lambda] = [0; b]; Q scaled to entries of order 1 (same optimum)
    kkt = np.block([[2 * Q / np.abs(Q).max(), A.T], [A, np.zeros((m, m))]])
    sol = np.linalg.solve(kkt, np.vstack([np.zeros((n, 3)), B]))
    knots = np.concatenate([[0.0], np.cumsum(T)])
    return PiecewisePolynomial(knots, sol[:n].reshape(S, DEGREE + 1, 3), closed)


def min_snap(points: np.ndarray, durations: np.ndarray, closed: bool = False) -> PiecewisePolynomial:
    """The minimum-snap spline (S1-S5) through points (M, 3) m with segment durations (S,) s:
    S = M - 1 open (from rest at the first point to rest at the last), S = M closed (back to
    the first point, periodic). Cached on its arguments (a scenario's check and its evaluation
    solve once)."""
    P = tuple(map(tuple, np.asarray(points, float)))
    return _min_snap_cached(P, tuple(float(x) for x in durations), bool(closed))


# ------------------------------------------------------------------------- closed curves


def _phase(t: np.ndarray, period: float, phases: np.ndarray) -> tuple[np.ndarray, float]:
    """theta (K, N) = 2 pi t / period + phases (N,) rad, and its rate w (rad/s)."""
    w = 2 * math.pi / period
    return w * np.asarray(t, float)[:, None] + phases[None, :], w


def _place(local: np.ndarray, center: np.ndarray, heading: float, heights: np.ndarray, order: int) -> np.ndarray:
    """Rotate (K, N, 3) in-plane curve terms by heading (rad) about z; position (order 0) also
    shifted to center (3,) plus heights (N,) on z."""
    c, s = math.cos(heading), math.sin(heading)
    out = local @ np.array([[c, s, 0.0], [-s, c, 0.0], [0.0, 0.0, 1.0]])
    if order == 0:
        out = out + center + heights[None, :, None] * np.array([0.0, 0.0, 1.0])
    return out


def circle(t: np.ndarray, center: np.ndarray, radius: float, period: float, phases: np.ndarray,
           heights: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Vehicles on a horizontal circle: p = center + radius (cos theta, sin theta, 0) + heights e_z,
    theta = 2 pi t / period + phase (anticlockwise seen from above; period < 0: clockwise).
    t (K,) s; phases, heights (N,) rad, m. Returns pos, vel, acc (K, N, 3)."""
    th, w = _phase(t, period, phases)
    cs, sn, z = np.cos(th), np.sin(th), np.zeros_like(th)
    pos = radius * np.stack([cs, sn, z], -1)
    vel = radius * w * np.stack([-sn, cs, z], -1)
    acc = -radius * w * w * np.stack([cs, sn, z], -1)
    return (_place(pos, np.asarray(center, float), 0.0, heights, 0), _place(vel, None, 0.0, heights, 1),
            _place(acc, None, 0.0, heights, 2))


def lemniscate(t: np.ndarray, center: np.ndarray, size: tuple[float, float], period: float, heading: float,
               phases: np.ndarray, heights: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Vehicles on a horizontal figure-eight (lemniscate of Gerono):
    p = center + R(heading) (A sin theta, B sin theta cos theta, 0) + heights e_z, theta as `circle`;
    size = (A, B): half length along the figure's axis and its full width (its lobes reach
    +/- B / 2). It crosses itself at the centre (theta = 0, pi). Returns pos, vel, acc (K, N, 3)."""
    th, w = _phase(t, period, phases)
    A, B = size
    s1, c1, s2, c2, z = np.sin(th), np.cos(th), np.sin(2 * th), np.cos(2 * th), np.zeros_like(th)
    pos = np.stack([A * s1, B / 2 * s2, z], -1)
    vel = w * np.stack([A * c1, B * c2, z], -1)
    acc = -w * w * np.stack([A * s1, 2 * B * s2, z], -1)
    center = np.asarray(center, float)
    return (_place(pos, center, heading, heights, 0), _place(vel, center, heading, heights, 1),
            _place(acc, center, heading, heights, 2))


def spread(count: int, layer: float) -> tuple[np.ndarray, np.ndarray]:
    """A formation on a closed curve: vehicle i (0-based) at phase 2 pi i / count (rad) and height
    i layer (m) above the curve. Returns phases, heights (count,)."""
    i = np.arange(count)
    return 2 * math.pi * i / count, layer * i
