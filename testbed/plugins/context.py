"""The `Context` of a run: geometry, declared sensor models and priors, nothing measured.

Lever arms are read from the compiled MuJoCo model (forward kinematics at the model's reference
pose: the vehicles are rigid, so a site's offset in its vehicle's base frame is constant).
"""
from __future__ import annotations

import mujoco
import numpy as np

from testbed.config import to_dict
from testbed.plugins.api import Context
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


def priors(scenario: Scenario) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """The prior the scenario's built-in estimators get, by target.

    coop-fg (seed 001): none (every epoch is anchored by its GNSS fixes alone). The other
    pipelines' priors live in their own state parametrizations and are not exposed yet: empty.
    """
    return {}


def make_context(scenario: Scenario, physics: Physics, key: str, params: dict) -> Context:
    """The Context of estimator `key` in this run (its rng: stream "estimator/KEY" of the seed)."""
    anchors = {f"anchor{k}": np.array(p, float) for k, p in enumerate(scenario.world.anchors, start=1)}
    return Context(
        vehicles=tuple(f"uav{i}" for i in range(1, scenario.vehicles + 1)),
        sites=lever_arms(physics),
        anchors=anchors,
        sensors={name: to_dict(cfg) for name, cfg in scenario.sensors.streams().items()},
        prior=priors(scenario),
        params=dict(params),
        duration=scenario.duration,
        seed=scenario.seed,
        rng=stream_rng(scenario.seed, f"estimator/{key}"),
    )
