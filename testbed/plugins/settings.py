"""The settings of a built-in plugin: its pipeline's [pipeline] keys, the scenario's by default.

A built-in estimator takes the keys of its pipeline's config dataclass as `params`. Unless a key is
given there, it takes the scenario's own [pipeline] value (Context.pipeline) when the scenario's
pipeline is of the same kind, else the dataclass default; the result is checked like a scenario's.
"""
from __future__ import annotations

from testbed.config import from_dict
from testbed.plugins.api import Context


def settings(cls: type, kind: str, context: Context, params: dict, entry: str):
    """The config `cls` of pipeline `kind` for estimator `entry`: {scenario's, if same kind} | params."""
    base = {k: v for k, v in context.pipeline.items() if k != "kind"} if context.pipeline.get("kind") == kind else {}
    return from_dict(cls, {**base, **params, "kind": kind}, f"estimator {entry} params")
