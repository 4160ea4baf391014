"""The seed 003 carrier-phase EKF (phase-ekf pipeline) as a protocol estimator: `phase.ekf`.

It collects the `phase` rows of one output epoch (every master antenna to every follower antenna,
with the measured extras master_pos, master_vel, rate_periods) and, when a phase row of a later
time arrives (or at finish), turns them into the pipeline's inputs with the pipeline's own code
(testbed.pipelines.phase: phase_inputs on that epoch alone, measurement_epochs) and steps the
same filter (estimators.phase_ekf.PhaseEkfCovarianceAnalysis) with the library's online driver
(estimators.core.Stepper), so it gives the pipeline's estimates number for number.

Start: Context.prior["uavF"], the 18-state the pipeline starts from (planned state + initial
error, testbed.plugins.context.priors); the filter settings are the phase-ekf [pipeline] keys
(params; the scenario's by default; the init keys act through the prior only). The process
noise is q or q_flown by Context.motion, as in the pipeline.

Estimates at every epoch, world frame: the follower body's position and velocity with their
covariances and its attitude (no covariance), mapped from the navigation frame N with the nav
master's pose measured at that epoch (from its own antennas, as the pipeline does):
p_W = p + R p_N, v_W = v + R v_N + dR/dt p_N (R, dR/dt: N to world).
"""
from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

from estimators.core import Epoch, Gate, Stepper
from estimators.phase_ekf import AnalyzedGaussian, PhaseEkfCovarianceAnalysis
from estimators.phase_model import rotation_from_antennas
from testbed.pipelines.config import PhasePipelineConfig
from testbed.pipelines.phase import BODY_PV, BODY_POS, measurement_epochs, phase_inputs, process_noise_model
from testbed.plugins.api import Context, Estimate, Measurement
from testbed.plugins.settings import settings

_COLUMNS = ("master_pos", "master_vel", "rate_periods", "slip")


class PhaseEkf:
    """seed 003: carrier-phase EKF of the follower (18-state, nav frame of a master), body pose in world."""

    Params = PhasePipelineConfig  # its parameters (testbed.plugins.settings)

    def __init__(self, context: Context, params: dict):
        self.cfg = settings(PhasePipelineConfig, "phase-ekf", context, params, "phase.ekf")
        ph = context.sensors.get("phase")
        if ph is None:
            raise ValueError("phase.ekf needs the carrier-phase stream ([sensors.phase])")
        self.period = 1.0 / ph["phase_rate_hz"]
        self.target = f"uav{ph['follower']}"
        if self.target not in context.prior:
            raise ValueError(f"phase.ekf needs the prior of {self.target} (a scenario whose [pipeline] kind is phase-ekf)")
        mean, cov = context.prior[self.target]
        q = process_noise_model(self.cfg, context.motion)
        filt = PhaseEkfCovarianceAnalysis(q, Gate(alpha=self.cfg.gate_alpha, enabled=self.cfg.gate), self.cfg.iterations)
        self.stepper = Stepper(filt, AnalyzedGaussian(mean, cov, cov))
        self.rows: list[Measurement] = []

    def _epoch(self) -> list[Estimate]:
        """Filter the buffered epoch; its estimates in the world frame (module docstring)."""
        rows, self.rows = self.rows, []
        t = rows[0].time
        log = {"phase/time": np.full(len(rows), t), "phase/state_index": np.zeros(len(rows), int),
               "phase/src": np.array([m.src for m in rows]), "phase/dst": np.array([m.dst for m in rows]),
               "phase/value": np.stack([m.value for m in rows]),
               **{f"phase/{c}": np.stack([m.extra[c] for m in rows]) for c in _COLUMNS}}
        inp = phase_inputs(log, self.period, self.cfg.nav_master)
        b = self.stepper.step(Epoch(t, measurement_epochs(self.cfg, inp)[0]))
        p, v, R, Rd = (a[0] for a in inp.nav_pose)
        pN, vN = BODY_POS @ b.mean, BODY_PV[3:] @ b.mean
        Jp, Jv = R @ BODY_POS, R @ BODY_PV[3:] + Rd @ BODY_POS  # d(p_W, v_W) / d(18-state)
        att = Rotation.from_matrix(R @ rotation_from_antennas(b.mean)).as_quat(scalar_first=True)
        return [Estimate(time=t, target=self.target, quantity="position", value=p + R @ pN, cov=Jp @ b.cov @ Jp.T),
                Estimate(time=t, target=self.target, quantity="velocity", value=v + R @ vN + Rd @ pN, cov=Jv @ b.cov @ Jv.T),
                Estimate(time=t, target=self.target, quantity="attitude", value=att)]

    def process(self, m: Measurement) -> list[Estimate]:
        if m.stream != "phase":
            return []
        out = self._epoch() if self.rows and m.time > self.rows[0].time else []
        self.rows.append(m)
        return out

    def finish(self) -> list[Estimate]:
        return self._epoch() if self.rows else []

    def health(self) -> dict[str, int]:
        return self.stepper.track().health()
