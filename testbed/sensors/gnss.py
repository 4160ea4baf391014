"""GNSS stream `gnss`: antenna position of each vehicle in the world frame (ENU, m).

Antenna: the `uwb` site on the mast (default; a roof antenna) or the body origin (CoM),
`antenna = "body"`. value = p + b(t) + v, v white N(0, diag(noise_h^2, noise_h^2, noise_v^2)),
b a first-order Gauss-Markov bias (steady-state bias_h, bias_h, bias_v; time constant bias_tau),
started from its stationary distribution. Ordinary receivers use [sensors.gnss.receiver], the
RTK vehicles [sensors.gnss.rtk].

Sky visibility ([sensors.gnss.sky] enabled, testbed.sensors.sky): at each sample the antenna
casts a ray towards every satellite of a seeded constellation; with the visible set's HDOP and
VDOP the white noise and the bias are scaled by f = (HDOP/hdop_ref, HDOP/hdop_ref, VDOP/vdop_ref)
(value = p + f (b + v); the bias process itself runs unscaled); a vehicle with fewer than
min_satellites visible has no fix and no row. The random draws are the same with or without a fix.
Scripted outages (`outages`): no receiver has a fix (no row) at a sample inside a window.

Log: gnss/value, gnss/clean (M, 3) ENU m; gnss/vehicle (M,) 1-based; gnss/rtk (M,) bool;
gnss/src = antenna site name ("uav3/uwb") or "uav3/base" for the body origin; gnss/dst = "".
With the sky: gnss/sigma (M, 3) m the declared (DOP-scaled) 1 sigma of each row, and per logged
instant (K rows of `time`, N vehicles; the state of the last GNSS sample, held): gnss/fix (K, N)
bool, gnss/sats (K, N) visible satellites, gnss/dop (K, N) PDOP (inf where no fix; vehicles
without a receiver: no fix, 0 satellites).
"""
from __future__ import annotations

import numpy as np

from testbed.sensors.base import Recorder, common_keys
from testbed.sensors.config import GnssConfig
from testbed.sensors.noise import gauss_markov
from testbed.sensors.sky import Sky, dop
from testbed.world import Physics


class Gnss:
    name = "gnss"

    def __init__(self, cfg: GnssConfig, physics: Physics, rng: np.random.Generator, period_ticks: int, tick: float, rtk_default: tuple[int, ...] = (),
                 sky_rng: np.random.Generator | None = None):
        self.cfg, self.rng, self.period_ticks = cfg, rng, period_ticks
        self.dt = period_ticks * tick
        self.vehicles = np.array(cfg.vehicles or range(1, physics.n + 1), dtype=int)
        rtk = set(cfg.rtk_vehicles or rtk_default)
        self.is_rtk = np.array([v in rtk for v in self.vehicles])
        V = len(self.vehicles)

        def per_vehicle(key: str) -> np.ndarray:
            return np.where(self.is_rtk, getattr(cfg.rtk, key), getattr(cfg.receiver, key))

        self.noise = np.stack([per_vehicle("noise_h")] * 2 + [per_vehicle("noise_v")], axis=1)  # (V, 3)
        self.bsig = np.stack([per_vehicle("bias_h")] * 2 + [per_vehicle("bias_v")], axis=1)
        tau = per_vehicle("bias_tau")  # (V,)
        self.tau_groups = [(float(v), tau == v) for v in np.unique(tau)]  # (time constant s, (V,) mask)
        self.bias = self.bsig * rng.standard_normal((V, 3))
        if cfg.antenna == "uwb":
            self.site_ids = physics.site_ids([f"uav{i}/uwb" for i in self.vehicles])
            self.src = np.array([f"uav{i}/uwb" for i in self.vehicles])
        else:
            self.site_ids = None
            self.src = np.array([f"uav{i}/base" for i in self.vehicles])
        keys = {**common_keys(3), "vehicle": ((), "i8"), "rtk": ((), "?")}
        self.sky = None
        if cfg.sky.enabled:  # sky_rng: the stream "constellation"
            self.sky = Sky(cfg.sky, physics, sky_rng, physics.body_ids[self.vehicles - 1])
            self.declared = np.hypot(self.noise, self.bsig)  # (V, 3) m: estimators.sensor_models.gnss_sigma of each receiver's table
            self.n_vehicles = physics.n
            self.held: list[tuple[int, np.ndarray, np.ndarray, np.ndarray]] = []  # (state_index, fix, sats, pdop) per sample
            keys["sigma"] = ((3,), "f8")
        self.rec = Recorder("gnss", keys)

    def sample(self, physics: Physics, t: float, state_index: int) -> None:
        V = len(self.vehicles)
        if self.site_ids is not None:
            p = physics.data.site_xpos[self.site_ids]
        else:
            p = physics.data.xpos[physics.body_ids[self.vehicles - 1]]
        n = self.rng.standard_normal((2, V, 3))
        for tau, sel in self.tau_groups:
            self.bias[sel] = gauss_markov(self.bias[sel], self.bsig[sel], tau, self.dt, n[1][sel][None])[0]
        err = self.bias + self.noise * n[0]
        out = any(a <= t < b for a, b in self.cfg.outages)  # scripted outage: no fix on any receiver
        if self.sky is None:
            sel = slice(0, 0) if out else slice(None)
            M = 0 if out else V
            self.rec.add(
                time=np.full(M, t), arrival=np.full(M, t + self.cfg.latency), state_index=np.full(M, state_index),
                value=(p + err)[sel], clean=p[sel].copy(), src=self.src[sel], dst=np.full(M, ""),
                vehicle=self.vehicles[sel], rtk=self.is_rtk[sel],
            )
            return
        sky = self.cfg.sky
        u, vis = self.sky.visible(physics, t, p)
        hdop, vdop, pdop = dop(u, vis, sky.min_satellites)
        if out:
            pdop = np.full_like(pdop, np.inf)
        fix = np.isfinite(pdop)
        f = np.stack([hdop / sky.hdop_ref] * 2 + [vdop / sky.vdop_ref], axis=1)[fix]  # (F, 3) DOP scale
        M = int(fix.sum())
        self.rec.add(
            time=np.full(M, t), arrival=np.full(M, t + self.cfg.latency), state_index=np.full(M, state_index),
            value=p[fix] + f * err[fix], clean=p[fix].copy(), src=self.src[fix], dst=np.full(M, ""),
            vehicle=self.vehicles[fix], rtk=self.is_rtk[fix], sigma=f * self.declared[fix],
        )
        self.held.append((state_index, fix, vis.sum(axis=1), pdop))

    def arrays(self) -> dict[str, np.ndarray]:
        return self.rec.arrays()

    def held_arrays(self, rows: int) -> dict[str, np.ndarray]:
        """Fix state per logged instant (rows of `time`), each held from the last GNSS sample at
        or before it: gnss/fix, gnss/sats, gnss/dop (rows, N) (module docstring); {} without the sky."""
        if self.sky is None:
            return {}
        N = self.n_vehicles
        fix, sats, pdop = np.zeros((rows, N), bool), np.zeros((rows, N), np.int64), np.full((rows, N), np.inf)
        idx = self.vehicles - 1
        starts = [h[0] for h in self.held] + [rows]
        for (r0, f, s, d), r1 in zip(self.held, starts[1:]):
            fix[r0:r1, idx], sats[r0:r1, idx], pdop[r0:r1, idx] = f, s, d
        return {"gnss/fix": fix, "gnss/sats": sats, "gnss/dop": pdop}
