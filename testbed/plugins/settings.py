"""The settings of a paper built-in: its Params are its pipeline's [pipeline] config dataclass.

A paper built-in (coop.*, phase.ekf, bandwidth.*, visnav.*) declares `Params` = its pipeline's
config dataclass (testbed.config.pipelines; every field but `kind` is a parameter, with the
unit, range and doc of testbed.plugins.params). Unless a key is given in its params, it takes the
scenario's own [pipeline] value (Context.pipeline) when the scenario's pipeline is of the same
kind, else the dataclass default; an assumed sensor-model key still unset then takes the
declared sensor model (Context.sensors, the pipeline config's `assumed`); the result is checked
like a scenario's.
"""
from __future__ import annotations

from testbed.plugins.api import Context
from testbed.plugins.params import pipeline_kind, read


def settings(cls: type, context: Context, params: dict, entry: str):
    """The config `cls` (a pipeline config dataclass, its kind from its `kind` field) for estimator
    `entry`: {scenario's, if same kind} | params."""
    kind = pipeline_kind(cls)
    base = {k: v for k, v in context.pipeline.items() if k != "kind"} if context.pipeline.get("kind") == kind else {}
    return read(cls, {**base, **params, "kind": kind}, entry).assumed(context.sensors)
