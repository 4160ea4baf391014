"""The safety of a flown run, from its log: contacts, separation, crashes, time without a GNSS fix.

Every flown run's metrics.json has a `flight` object computed here (testbed.runner), and `testbed
reproduce denied` scores its flights with the same function. Truth only: this is scoring.

- contacts: the logged states (every logged tick: `time`, `qpos`) replayed through MuJoCo's
  collision (Physics.contacts_at); an *event* is a (vehicle, other) pair in contact at a logged
  instant and not at the previous one, counted by the kind of the other: `vehicle`, `obstacle`
  (a `world.obstacles` geom) or `floor` (the rest of the world: floor, masts), with the time of
  the first event of each kind (s, null when none);
- min_separation_m, min_separation_s: the smallest distance between two vehicles' body origins
  over the logged instants (m) and when (s); null with a reason for a single vehicle;
- crash: a vehicle crashed at the first logged instant where one of these holds (the rules,
  fixed here and in docs/control.md):
  * contact force: the normal contact force on it exceeds CRASH_FORCE_WEIGHTS = 20 times its
    weight (m g; 20 x 6.9 kg x 9.81 m/s^2 = 1354 N for the quadrotor of models/quadrotor.xml),
    the force evaluated at the logged states in contact with the rotors off
    (Physics.contact_forces_at). Why 20: MuJoCo's soft contact stops a body within about its
    time constant (0.02 s), so a touchdown at v m/s pushes with about m v / 0.02 s, measured
    10.6 weights per m/s on the quadrotor (a 0.5 m/s touchdown: 461 N at 2 mm of penetration):
    20 weights is the force of the 2 m/s impact below, whatever the vehicle hits;
  * tilt: its body z axis points below the horizontal (tilt past CRASH_TILT_DEG = 90 deg);
  * impact: it comes into contact with the floor while its speed (the larger of that instant's
    and the previous logged instant's) exceeds CRASH_IMPACT_SPEED = 2 m/s;
- no_fix_s: with GNSS, the seconds each vehicle spent without a fix (gnss/fix at the logged
  instants, each interval charged to its end).
Network statistics are the estimators' own (their `health`, sent, dropped, bytes, latency
percentiles); `summary_line` shows those of the estimator the controller flies on.
"""
from __future__ import annotations

from collections.abc import Iterator, Mapping

import numpy as np
from scipy.spatial import cKDTree

from testbed.log import NpzLog
from testbed.reference import GRAVITY
from testbed.outputs.report import fmt
from testbed.sim.world import FLOOR, OBSTACLE, Physics

CRASH_FORCE_WEIGHTS = 20.0  # a contact force above this many times the vehicle's weight is a crash
CRASH_TILT_DEG = 90.0  # deg: a tilt past this (body z below the horizontal) is a crash
CRASH_IMPACT_SPEED = 2.0  # m/s: touching the floor faster than this is a crash
KINDS = ("vehicle", "obstacle", "floor")


def _blocks(log: Mapping[str, np.ndarray], key: str) -> Iterator[np.ndarray]:
    """Array `key` of a log a block of rows at a time (NpzLog), or whole (a dict)."""
    return log.row_blocks(key) if isinstance(log, NpzLog) else iter([np.asarray(log[key])])


def _rows(log: Mapping[str, np.ndarray], *keys: str) -> Iterator[tuple[np.ndarray, ...]]:
    """The logged rows of `keys`, one tuple per logged instant."""
    for blocks in zip(*(_blocks(log, k) for k in keys)):
        yield from zip(*blocks)


def _kind(other: int) -> str:
    return "obstacle" if other == OBSTACLE else "floor" if other == FLOOR else "vehicle"


def separation(log: Mapping[str, np.ndarray]) -> tuple[float, float] | None:
    """(smallest distance m between two vehicles' body origins, its time s) over the logged
    instants; None for a single vehicle."""
    best, when = np.inf, 0.0
    for t, p in _rows(log, "time", "truth/pos"):
        if len(p) < 2:
            return None
        d = float(cKDTree(p).query(p, k=2)[0][:, 1].min())
        if d < best:
            best, when = d, float(t)
    return best, when


def no_fix_s(log: Mapping[str, np.ndarray]) -> np.ndarray | None:
    """(N,) s without a GNSS fix per vehicle; None without GNSS."""
    if "gnss/fix" not in log:
        return None
    fix, dt = log["gnss/fix"], np.diff(log["time"])
    return ((~fix[1:]) * dt[:, None]).sum(axis=0)


def flight(log: Mapping[str, np.ndarray], physics: Physics) -> dict:
    """The `flight` object of metrics.json (module docstring). log: the run's log (N vehicles);
    physics: the run's scene (its state is overwritten by the replay)."""
    contacts = {k: {"events": 0, "first_s": None} for k in KINDS}
    limit = CRASH_FORCE_WEIGHTS * physics.vehicle_mass * GRAVITY  # N
    crashed: dict[int, tuple[float, str]] = {}  # vehicle: (time s, cause)
    before: set = set()
    speed_before = None
    for t, qpos, qvel, quat, vel in _rows(log, "time", "qpos", "qvel", "truth/quat", "truth/vel"):
        t = float(t)
        speed = np.linalg.norm(vel, axis=1)  # (N,) m/s
        r33 = 1.0 - 2.0 * (quat[:, 1] ** 2 + quat[:, 2] ** 2)  # body z . world z
        for v in np.flatnonzero(r33 < np.cos(np.radians(CRASH_TILT_DEG))).tolist():
            crashed.setdefault(v, (t, "tilt"))
        pairs = physics.contacts_at(qpos)
        now = {tuple(r) for r in pairs.tolist()}
        for v, o in sorted(now - before):
            c = contacts[_kind(o)]
            c["events"] += 1
            c["first_s"] = t if c["first_s"] is None else c["first_s"]
            hit = max(speed[v], 0.0 if speed_before is None else speed_before[v])
            if o == FLOOR and hit > CRASH_IMPACT_SPEED:
                crashed.setdefault(v, (t, "impact"))
        if now:
            for v in np.flatnonzero(physics.contact_forces_at(qpos, qvel) > limit).tolist():
                crashed.setdefault(v, (t, "contact force"))
        before, speed_before = now, speed
    out: dict = {"contacts": contacts}
    why = {}
    sep = separation(log)
    out["min_separation_m"], out["min_separation_s"] = sep if sep is not None else (None, None)
    if sep is None:
        why["min_separation_m"] = why["min_separation_s"] = "a single vehicle"
    out["crash"] = {"crashed": bool(crashed),
                    "vehicles": [{"vehicle": v + 1, "time_s": tc, "cause": cause} for v, (tc, cause) in sorted(crashed.items())],
                    "limits": {"contact_force_n": limit, "tilt_deg": CRASH_TILT_DEG, "impact_speed_m_s": CRASH_IMPACT_SPEED}}
    if (nf := no_fix_s(log)) is not None:
        out["no_fix_s"] = [float(x) for x in nf]
    if why:
        out["null_reasons"] = why
    return out


def _network(name: str, health: Mapping) -> str | None:
    """An estimator's network statistics (its health counts) in a few words; None without."""
    if "sent" not in health:
        return None
    dropped = health.get("dropped", sum(v for k, v in health.items() if k.startswith("dropped_")))
    lat = ", ".join(f"{q} {fmt(health[f'latency_{q}_us'] / 1e3)} ms" for q in ("p50", "p95") if f"latency_{q}_us" in health)
    return (f"network ({name}): {health['sent']} sent, {dropped} dropped, {health.get('bytes_sent', 0)} bytes"
            + (f", latency {lat}" if lat else ""))


def summary_line(flight: Mapping, estimators: Mapping[str, Mapping] | None = None, flown_on: str = "") -> str:
    """The flight's safety in one line, with the network statistics in the health of the
    estimator the controller flies on (`flown_on`, a key of `estimators`, metrics.json's entries),
    or, flown on the truth (""), of every estimator that reports them."""
    c = flight["contacts"]
    first = [c[k]["first_s"] for k in KINDS if c[k]["first_s"] is not None]
    parts = ["contacts " + ", ".join(f"{k} {c[k]['events']}" for k in KINDS)
             + (f" (first at {fmt(min(first))} s)" if first else "")]
    if flight["min_separation_m"] is not None:
        parts.append(f"min separation {fmt(flight['min_separation_m'])} m at {fmt(flight['min_separation_s'])} s")
    crash = flight["crash"]["vehicles"]
    parts.append(f"{len(crash)} crashed" if crash else "no crash")
    if "no_fix_s" in flight:
        nf = flight["no_fix_s"]
        parts.append(f"no GNSS fix: mean {fmt(float(np.mean(nf)))} s, max {fmt(max(nf))} s")
    for name, est in (estimators or {}).items():
        if (not flown_on or name == flown_on) and (net := _network(name, est.get("health", {}))):
            parts.append(net)
    return "safety: " + "; ".join(parts)


def crash_warning(flight: Mapping) -> str | None:
    """One line naming every crashed vehicle, its time and cause; None without a crash."""
    crash = flight["crash"]["vehicles"]
    if not crash:
        return None
    return "crash: " + ", ".join(f"uav{c['vehicle']} at {fmt(c['time_s'])} s ({c['cause']})" for c in crash)
