"""Running a scenario's plugin estimators on a run log and scoring them (the runner's one call).

Each plugin gets its own Context, the same measurements in the same order (testbed.plugins.feed),
and is scored by testbed.plugins.score against the log's truth, with the run's scoring hooks
(testbed.plugins.hooks: e.g. the PCRB of seed 003 phase-ekf); its figures overlay every plugin of the run.
With a [network] table each plugin run on the log gets its own network (Context.channel,
testbed.plugins.channel); a plugin that used it has its counts under `network`. The result is merged into metrics.json `estimators` under each plugin's key;
a plugin that fails gets its failure there instead (testbed.plugins.failures) and the others go on.
"""
from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np

from testbed.errors import PluginError
from testbed.interrupt import poll
from testbed.scoring.metrics import network_summary
from testbed.plugins.channel import Channel, uwb_rows
from testbed.plugins.context import make_context
from testbed.plugins.priors import priors
from testbed.plugins.failures import failed_entry
from testbed.plugins.feed import batched, run_plugin
from testbed.plugins.loading import Plugin
from testbed.plugins.hooks import scenario_hooks
from testbed.plugins.score import plot_errors, score
from testbed.plugins.truth import Truth
from testbed.config.scenario import Scenario
from testbed.sim.world import Physics, lever_arms


def run_estimators(scenario: Scenario, physics: Physics, log: dict[str, np.ndarray], plugins: list[Plugin],
                   plots_dir: Path | None, done: dict | None = None,
                   keep: dict | None = None) -> tuple[dict, dict]:
    """({key: scores}, {key: Track}) of every plugin (wall time under `wall_ms`, which the runner
    moves to timing.json; the Tracks go to the run's estimates.npz). done: {key: (estimates, health, wall ms)}
    of plugins already run (online, in the loop: scored, not rerun). A plugin that fails gets
    failed_entry (no Track); the caller marks the metrics (testbed.plugins.failures). keep: a dict
    that receives {key: the finished estimator object} of the plugins run here (not of `done`)."""
    if not plugins:
        return {}, {}
    done = done or {}
    feed = list(batched(scenario, log)) if any(p.key not in done for p in plugins) else []
    prior = priors(scenario, log)
    hooks = scenario_hooks(scenario, log)
    out, shown = {}, {}
    arms = lever_arms(physics)
    for p in plugins:
        poll()  # a worker asked to stop does so between plugins (testbed.interrupt)
        ctx = make_context(scenario, arms, p.key, p.params, prior)
        truth = Truth(log, ctx)
        channel = Channel(scenario.network, truth, uwb_rows(log), ctx.vehicles, scenario.seed, p.key) \
            if scenario.network is not None and p.key not in done else None
        ctx = replace(ctx, channel=channel)
        try:
            got = [] if keep is not None else None
            track, health, wall_ms = done[p.key] if p.key in done else run_plugin(p, ctx, feed, keep=got)
            if got:
                keep[p.key] = got[0]
        except PluginError as e:  # its own result; the others are still scored (testbed.plugins.failures)
            out[p.key] = failed_entry(p.entry, e)
            continue
        scores, errs = score(track, truth, hooks, health)
        network = channel.stats() if channel is not None else None
        out[p.key] = {"entry": p.entry, **scores, **({"health": health} if health else {}),
                      **({"network": network_summary(network)} if network is not None else {}), "wall_ms": wall_ms}
        shown[p.key] = (track, errs)
    if plots_dir is not None:
        plot_errors(shown, Path(plots_dir), hooks=hooks)
    return out, {key: track for key, (track, _) in shown.items()}

