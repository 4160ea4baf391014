"""A scenario's estimators: the default ones its `[pipeline]` kind names, then its own `[[estimators]]`.

A `[pipeline]` table is the paper's parameter table; its kind names the paper's estimators, which
run as plugins like any other (the built-ins take the table's keys as their settings,
testbed.plugins.settings) under the names metrics.json has always given them. `DEFAULTS` holds
every kind.
"""
from __future__ import annotations

from testbed.errors import ConfigError
from testbed.config.estimators import EstimatorSpec
from testbed.config.scenario import Scenario

# [pipeline] kind -> ((metrics.json name, registered estimator), ...), in metrics.json order
DEFAULTS: dict[str, tuple[tuple[str, str], ...]] = {
    "coop-fg": (("gnss_only", "coop.gnss_only"), ("one_shot", "coop.one_shot"), ("iterated", "coop.iterated"),
                ("centralized", "coop.centralized")),
    "bandwidth": (("bandwidth", "bandwidth.fusion"),),
    "visnav": (("ekf", "visnav.ekf"), ("ckf", "visnav.ckf"), ("hckf", "visnav.hckf"), ("mckf", "visnav.mckf"),
               ("rhcf", "visnav.rhcf")),
    "phase-ekf": (("ekf", "phase.ekf"),),
}


def default_specs(scenario: Scenario) -> tuple[EstimatorSpec, ...]:
    """The default estimators of the scenario's [pipeline] kind (none without one); a table with
    `filters` (visnav) keeps those it names, in its order."""
    kind = getattr(scenario.pipeline, "kind", None)
    entries = dict(DEFAULTS.get(kind, ()))
    names = getattr(scenario.pipeline, "filters", None) or tuple(entries)
    return tuple(EstimatorSpec(entry=entries[name], name=name) for name in names if name in entries)


def estimator_specs(scenario: Scenario) -> tuple[EstimatorSpec, ...]:
    """Every estimator a run of the scenario scores: its defaults, then its [[estimators]].
    A user estimator named like a default one is a ConfigError naming both."""
    defaults = default_specs(scenario)
    taken = {s.key for s in defaults}
    for s in scenario.estimators:
        if s.key in taken:
            raise ConfigError(f"estimator {s.entry!r}: the name {s.key!r} is taken by a default estimator of the "
                              f"{scenario.pipeline.kind} pipeline; give it another name ([[estimators]] name)")
    return defaults + tuple(scenario.estimators)
