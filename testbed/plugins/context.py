"""The `Context` of a run: geometry, declared sensor models, the pipeline's settings and priors.

Lever arms are read from the compiled MuJoCo model (forward kinematics at the model's reference
pose: the vehicles are rigid, so a site's offset in its vehicle's base frame is constant).
"""
from __future__ import annotations

import mujoco
import numpy as np

from testbed.config import to_dict
from testbed.plugins import builtin_phase
from testbed.plugins.api import Context
from testbed.plugins.builtin_bandwidth import initial_estimate
from testbed.plugins.relnav_scores import start_prior
from testbed.rng import stream_rng
from testbed.scenario import Scenario
from testbed.world import Physics


def lever_arms(physics: Physics) -> dict[str, tuple[str, np.ndarray]]:
    """{site: (vehicle body "uavI", lever arm (3,) m in that vehicle's base frame)} for every vehicle site."""
    m = physics.model
    d = mujoco.MjData(m)  # a scratch state: the run's own data is left alone
    mujoco.mj_kinematics(m, d)
    out = {}
    for i, bid in enumerate(physics.body_ids, start=1):
        prefix = f"uav{i}/"
        R = d.xmat[bid].reshape(3, 3)
        for sid in range(m.nsite):
            name = m.site(sid).name
            if name.startswith(prefix) and m.body_rootid[m.site_bodyid[sid]] == m.body_rootid[bid]:
                arm = R.T @ (d.site_xpos[sid] - d.xpos[bid])
                arm.flags.writeable = False
                out[name] = (f"uav{i}", arm)
    return out


def priors(scenario: Scenario, log: dict[str, np.ndarray] | None) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """The prior the scenario's built-in estimators get, by target, in their own state (the
    runtime's: drawn here from the scenario streams and, where the paper starts from the truth
    plus a drawn error, the log's truth; the estimators never read it):

    coop-fg: none (every epoch is anchored by its GNSS fixes alone);
    phase-ekf: {"uavF": (18,), (18, 18)} the follower's antenna state of estimators.phase_ekf in
      the navigation frame N at the first phase epoch (planned state + the drawn initial error);
    visnav: {"uavF": (22,), (21, 21)} the follower's state relative to the leader
      (estimators.visnav layout) at the first IMU sample (truth + the drawn initial error);
    bandwidth: {"formation": (3,), (3, 3)} every node's initial estimate of the formation point
      (m, world) and M(0).
    Empty without a log or a pipeline.
    """
    kind = getattr(scenario.pipeline, "kind", None)
    if log is None or kind not in ("phase-ekf", "visnav", "bandwidth"):
        return {}
    if kind == "phase-ekf":
        _, inp, _, prior, _, _ = builtin_phase.prepare(scenario, log)
        return {f"uav{inp.follower}": (prior.mean, prior.cov)}
    if kind == "visnav":
        prior = start_prior(scenario, log)
        return {f"uav{scenario.sensors.camera.follower}": (prior.mean, prior.cov)}
    cfg = scenario.pipeline
    return {"formation": (initial_estimate(cfg, scenario.seed), np.diag(cfg.M0))}


def make_context(scenario: Scenario, physics: Physics, key: str, params: dict,
                 prior: dict[str, tuple[np.ndarray, np.ndarray]] | None = None, channel: object | None = None) -> Context:
    """The Context of estimator `key` in this run (its rng: stream "estimator/KEY" of the seed).
    prior: priors(scenario, log), computed once per run (None: none); channel: its network
    (testbed.plugins.channel.Channel) or None."""
    anchors = {f"anchor{k}": np.array(p, float) for k, p in enumerate(scenario.world.anchors, start=1)}
    return Context(
        vehicles=tuple(f"uav{i}" for i in range(1, scenario.vehicles + 1)),
        sites=lever_arms(physics),
        anchors=anchors,
        sensors={name: to_dict(cfg) for name, cfg in scenario.sensors.streams().items()},
        prior=dict(prior or {}),
        pipeline=to_dict(scenario.pipeline) if scenario.pipeline is not None else {},
        params=dict(params),
        duration=scenario.duration,
        motion=scenario.motion,
        seed=scenario.seed,
        rng=stream_rng(scenario.seed, f"estimator/{key}"),
        channel=channel,
    )
