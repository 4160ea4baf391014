"""Carrier-phase stream `phase` (seed 003): master antennas -> follower antennas.

Links (fixed order): for each master m in `masters`, master antenna slot i = 1..3 (the
transmitter; wavelength lambda_i = wavelengths[i-1]), follower antenna j = 1..3:
src = "uav{m}/ant{i}", dst = "uav{f}/ant{j}". L = 9 x masters.

Receiver model, every T = 1 / phase_rate_hz (the sensor's sampling instants):
  total phase (cycles)   Phi = r / lambda + eps,  eps ~ N(0, (phase_noise / lambda)^2)
  wrapped phase (rad)    theta = 2 pi frac(Phi) in [0, 2 pi)       (what the detector sees)
  integer ambiguity      n = floor(Phi)                            (really there, unknown)

Ambiguity resolution (explicit, per link):
  1. acquisition: a coarse range rho = r + N(0, coarse_noise^2) (code ranging on the same radio)
     fixes n_hat = round(rho / lambda - theta / 2 pi); tracked total phase Phi_hat = theta/2pi + n_hat;
  2. tracking by continuity: Phi_hat_k = Phi_hat_{k-1} + wrap(theta_k - theta_{k-1}) / 2 pi, with
     wrap to [-pi, pi): exact while |r_dot| T < lambda / 2 (T is chosen so, as in the paper);
  3. slip check at every phase sample: if round(rho_k / lambda - theta_k / 2 pi) differs from the
     tracked integer, the tracked integer is declared slipped, re-fixed from rho_k, and the link
     is flagged (`phase/slip`). Injected slips (probability slip_prob per link and phase sample)
     add +/-1..slip_max_cycles whole cycles to the tracker's count (a loop slip: the wrapped
     phase is unchanged, so only the coarse check can see it). A false alarm needs a coarse +
     phase error beyond lambda / 2 (checked: 5 sigma < lambda / 2).
  resolved range r_hat = lambda Phi_hat.

Range rate, seed 003 eq. 7: with theta_0 the newest phase and theta_k the one k periods earlier,
  r_dot_hat = (1 / (N + 1)) sum_{k=0..N} wrap(theta_k - theta_{k+1}) lambda / (2 pi T),
the average over N + 1 = rate_periods periods (fewer right after the start; NaN at the very first
sample): the mean range rate over [t - (N+1) T, t]. Its noise is sqrt(2) phase_noise / ((N+1) T).

Output every 1/rate_hz s, one row per link:
  phase/value (M, 3) = [theta (rad), r_hat (m), r_dot_hat (m/s)]
  phase/clean (M, 3) = [theta of r / lambda, r, eq. 7 applied to the true ranges] (physics)
  phase/ambiguity (M,) int: tracked integer n_hat; phase/ambiguity_clean (M,): floor(r / lambda)
  phase/wavelength (M,) m; phase/slip (M,) bool: a slip was detected (and repaired) since the
  previous output; phase/acquire (M,) bool: integer fixed for the first time since the previous
  output; phase/slip_injected (M,) bool (truth, for scoring detection); phase/coarse (M,) m: the
  coarse range at the output instant; phase/rate_periods (M,) int: periods averaged;
  phase/rate_true (M,) m/s: instantaneous true range rate at the output instant (site velocities);
  phase/master_pos, phase/master_vel (M, 3) world m, m/s: the src antenna position and velocity
  from the master's own navigation solution = truth + N(0, master_pos_noise^2),
  N(0, master_vel_noise^2) (white; default 0 reproduces the paper's "known masters").
"""
from __future__ import annotations

import numpy as np

from testbed.sensors.base import Recorder, common_keys
from testbed.sensors.config import PhaseConfig
from testbed.sim.world import Physics

TWO_PI = 2.0 * np.pi
_SIGNS = np.array([-1, 1])


def wrap_pi(x: np.ndarray) -> np.ndarray:
    """Angles wrapped to [-pi, pi)."""
    return (x + np.pi) % TWO_PI - np.pi


class Phase:
    name = "phase"

    def __init__(self, cfg: PhaseConfig, physics: Physics, rng: np.random.Generator, period_ticks: int, tick: float):
        self.cfg, self.rng, self.period_ticks = cfg, rng, period_ticks
        self.T = period_ticks * tick
        self.every = int(round(cfg.phase_rate_hz / cfg.rate_hz))
        src, dst, lam = [], [], []
        for m in cfg.masters:
            for i in (1, 2, 3):
                for j in (1, 2, 3):
                    src.append(f"uav{m}/ant{i}"), dst.append(f"uav{cfg.follower}/ant{j}"), lam.append(cfg.wavelengths[i - 1])
        self.src_names, self.dst_names = np.array(src), np.array(dst)
        self.src_ids, self.dst_ids = physics.site_ids(src), physics.site_ids(dst)
        self.lam = np.array(lam)
        L, H = len(src), cfg.rate_periods + 1
        self.theta_hist = np.zeros((H, L))  # newest first
        self.clean_hist = np.zeros((H, L))
        self.n_hist = 0
        self.phi_hat = np.zeros(L)
        self.acquired = False
        self.k = 0
        self.slip_since = np.zeros(L, dtype=bool)
        self.acq_since = np.zeros(L, dtype=bool)
        self.inj_since = np.zeros(L, dtype=bool)
        self.rec = Recorder("phase", {
            **common_keys(3), "ambiguity": ((), "i8"), "ambiguity_clean": ((), "i8"), "wavelength": ((), "f8"),
            "slip": ((), "?"), "acquire": ((), "?"), "slip_injected": ((), "?"), "coarse": ((), "f8"),
            "rate_periods": ((), "i8"), "rate_true": ((), "f8"), "master_pos": ((3,), "f8"), "master_vel": ((3,), "f8"),
        })

    def sample(self, physics: Physics, t: float, state_index: int) -> None:
        cfg, lam = self.cfg, self.lam
        L = len(lam)
        ps, pd = physics.data.site_xpos[self.src_ids], physics.data.site_xpos[self.dst_ids]
        r = np.linalg.norm(pd - ps, axis=1)
        # fixed draws per sample: phase noise, coarse noise, slip event, slip size/sign, nav errors
        e = self.rng.standard_normal((2, L))
        u = self.rng.random(L)
        # a random sign per link: the draws of rng.choice([-1, 1], L) (the same integers in [0, 2)), without
        # its argument handling, which costs several times the draw
        size = self.rng.integers(1, cfg.slip_max_cycles + 1, L) * _SIGNS[self.rng.integers(0, 2, L)]
        nav = self.rng.standard_normal((2, L, 3))
        phi = r / lam + cfg.phase_noise / lam * e[0]  # total phase, cycles
        theta = TWO_PI * (phi - np.floor(phi))  # wrapped, [0, 2 pi)
        theta = np.where(theta >= TWO_PI, 0.0, theta)
        theta_clean = TWO_PI * np.mod(r / lam, 1.0)
        rho = r + cfg.coarse_noise * e[1]
        n_coarse = np.round(rho / lam - theta / TWO_PI)
        if not self.acquired:
            self.phi_hat = theta / TWO_PI + n_coarse
            self.acquired = True
            self.acq_since[:] = True
        else:
            self.phi_hat = self.phi_hat + wrap_pi(theta - self.theta_hist[0]) / TWO_PI
            injected = u < cfg.slip_prob
            self.phi_hat = self.phi_hat + injected * size
            self.inj_since |= injected
            n_track = np.round(self.phi_hat - theta / TWO_PI)
            slipped = n_track != n_coarse
            self.phi_hat = np.where(slipped, theta / TWO_PI + n_coarse, self.phi_hat)
            self.slip_since |= slipped
        # newest first: every row one place older (in place: numpy copies an overlapping source first)
        self.theta_hist[1:], self.clean_hist[1:] = self.theta_hist[:-1], self.clean_hist[:-1]
        self.theta_hist[0], self.clean_hist[0] = theta, theta_clean
        self.n_hist = min(self.n_hist + 1, len(self.theta_hist))
        due = self.k % self.every == 0
        self.k += 1
        if not due:
            return
        periods = self.n_hist - 1
        if periods >= 1:
            # eq. 7: mean over k = 0..N of wrap(theta_k - theta_{k+1}) lambda / (2 pi T)
            dth = wrap_pi(self.theta_hist[:periods] - self.theta_hist[1 : periods + 1]).mean(axis=0)
            dcl = wrap_pi(self.clean_hist[:periods] - self.clean_hist[1 : periods + 1]).mean(axis=0)
            rate, rate_clean = dth * lam / (TWO_PI * self.T), dcl * lam / (TWO_PI * self.T)
        else:
            rate = rate_clean = np.full(L, np.nan)
        vs, vd = physics.site_vels(self.src_ids), physics.site_vels(self.dst_ids)
        rate_true = np.einsum("ij,ij->i", pd - ps, vd - vs) / r
        r_hat = lam * self.phi_hat
        self.rec.add(
            time=np.full(L, t), arrival=np.full(L, t + cfg.latency), state_index=np.full(L, state_index),
            value=np.stack([theta, r_hat, rate], axis=1), clean=np.stack([theta_clean, r, rate_clean], axis=1),
            src=self.src_names, dst=self.dst_names,
            ambiguity=np.round(self.phi_hat - theta / TWO_PI).astype(np.int64), ambiguity_clean=np.floor(r / lam).astype(np.int64),
            wavelength=lam, slip=self.slip_since.copy(), acquire=self.acq_since.copy(), slip_injected=self.inj_since.copy(),
            coarse=rho, rate_periods=np.full(L, periods), rate_true=rate_true,
            master_pos=ps + cfg.master_pos_noise * nav[0], master_vel=vs + cfg.master_vel_noise * nav[1],
        )
        self.slip_since[:] = False
        self.acq_since[:] = False
        self.inj_since[:] = False

    def arrays(self) -> dict[str, np.ndarray]:
        return self.rec.arrays()
