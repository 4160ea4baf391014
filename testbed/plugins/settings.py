"""The settings of a built-in plugin: its pipeline's [pipeline] keys, the scenario's by default.

A built-in estimator takes the keys of its pipeline's config dataclass as `params`. Unless a key is
given there, it takes the scenario's own [pipeline] value (Context.pipeline) when the scenario's
pipeline is of the same kind, else the dataclass default; the result is checked like a scenario's.

`check_known` is the params check of the built-ins' `check_params` (docs/estimators.md), run
before anything is simulated: an unknown key is a FieldError naming it and its value.
"""
from __future__ import annotations

import dataclasses
from collections.abc import Iterable

from testbed.config import from_dict
from testbed.errors import FieldError
from testbed.plugins.api import Context


def check_known(params: dict, known: Iterable[str]) -> None:
    """Raise FieldError naming the first key of params that is not in known, and its value."""
    known = sorted(known)
    for key, value in params.items():
        if key not in known:
            raise FieldError("", key, value, f"unknown key (known: {', '.join(known)})")


def pipeline_keys(cls: type) -> set[str]:
    """The params a settings-based built-in takes: the fields of its pipeline's config dataclass."""
    return {f.name for f in dataclasses.fields(cls)} - {"kind"}


def settings(cls: type, kind: str, context: Context, params: dict, entry: str):
    """The config `cls` of pipeline `kind` for estimator `entry`: {scenario's, if same kind} | params."""
    base = {k: v for k, v in context.pipeline.items() if k != "kind"} if context.pipeline.get("kind") == kind else {}
    return from_dict(cls, {**base, **params, "kind": kind}, f"estimator {entry} params")
