"""GNSS stream `gnss`: antenna position of each vehicle in the world frame (ENU, m).

Antenna: the `uwb` site on the mast (default; a roof antenna) or the body origin (CoM),
`antenna = "body"`. value = p + b(t) + v, v white N(0, diag(noise_h^2, noise_h^2, noise_v^2)),
b a first-order Gauss-Markov bias (steady-state bias_h, bias_h, bias_v; time constant bias_tau),
started from its stationary distribution. Ordinary receivers use [sensors.gnss.receiver], the
RTK vehicles [sensors.gnss.rtk].

Log: gnss/value, gnss/clean (M, 3) ENU m; gnss/vehicle (M,) 1-based; gnss/rtk (M,) bool;
gnss/src = antenna site name ("uav3/uwb") or "uav3/base" for the body origin; gnss/dst = "".
"""
from __future__ import annotations

import numpy as np

from testbed.sensors.base import Recorder, common_keys
from testbed.sensors.config import GnssConfig
from testbed.sensors.noise import gauss_markov
from testbed.world import Physics


class Gnss:
    name = "gnss"

    def __init__(self, cfg: GnssConfig, physics: Physics, rng: np.random.Generator, period_ticks: int, tick: float, rtk_default: tuple[int, ...] = ()):
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
        self.rec = Recorder("gnss", {**common_keys(3), "vehicle": ((), "i8"), "rtk": ((), "?")})

    def sample(self, physics: Physics, t: float, state_index: int) -> None:
        V = len(self.vehicles)
        if self.site_ids is not None:
            p = physics.data.site_xpos[self.site_ids]
        else:
            p = physics.data.xpos[physics.body_ids[self.vehicles - 1]]
        n = self.rng.standard_normal((2, V, 3))
        for tau, sel in self.tau_groups:
            self.bias[sel] = gauss_markov(self.bias[sel], self.bsig[sel], tau, self.dt, n[1][sel][None])[0]
        self.rec.add(
            time=np.full(V, t), arrival=np.full(V, t + self.cfg.latency), state_index=np.full(V, state_index),
            value=p + self.bias + self.noise * n[0], clean=p.copy(), src=self.src, dst=np.full(V, ""),
            vehicle=self.vehicles, rtk=self.is_rtk,
        )

    def arrays(self) -> dict[str, np.ndarray]:
        return self.rec.arrays()
