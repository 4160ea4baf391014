"""The `Context` of a run: geometry, declared sensor models, the pipeline's settings and priors,
and the network model.

The runtime's side of the protocol (the workflow layer): what it hands an estimator, so the
estimators import neither the simulator nor the truth. The lever arms and the priors are handed
in: the lever arms from the compiled model (testbed.sim.world.lever_arms) or a replay's dataset,
the priors from testbed.plugins.priors (the workflow's: it reads the truth where a paper starts
from it); the network model is the simulator's (testbed.sim.network.Network, Context.open_network).
"""
from __future__ import annotations

import numpy as np

from testbed.config import to_dict
from testbed.plugins.api import Context
from testbed.rng import stream_rng
from testbed.config.scenario import Scenario
from testbed.sim.network import Network


def make_context(scenario: Scenario, sites: dict[str, tuple[str, np.ndarray]], key: str, params: dict,
                 prior: dict[str, tuple[np.ndarray, np.ndarray]] | None = None, channel: object | None = None) -> Context:
    """The Context of estimator `key` in this run (its rng: stream "estimator/KEY" of the seed; its
    open_network: testbed.sim.network.Network).
    sites: {site: (vehicle body, lever arm (3,) m in its base frame)} (testbed.sim.world.lever_arms);
    prior: testbed.plugins.priors.priors(scenario, log), computed once per run (None: none); channel: its network
    (testbed.plugins.channel.Channel) or None."""
    anchors = {f"anchor{k}": np.array(p, float) for k, p in enumerate(scenario.world.anchors, start=1)}
    return Context(
        vehicles=tuple(f"uav{i}" for i in range(1, scenario.vehicles + 1)),
        sites=dict(sites),
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
        open_network=Network,
    )
