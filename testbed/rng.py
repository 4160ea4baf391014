"""Random streams: one seed per scenario, one independent generator per stream name.

`stream_rng(seed, "uwb")` is a `numpy.random.Generator` seeded from `SeedSequence(seed)` with a
spawn key derived from the stream's name (CRC-32), so adding a sensor never changes another
sensor's noise, and the same seed always gives the same numbers.
"""
from __future__ import annotations

import zlib

import numpy as np


def stream_rng(seed: int, name: str) -> np.random.Generator:
    """The generator of stream `name` in a scenario run with `seed`."""
    key = zlib.crc32(name.encode("utf-8"))
    return np.random.default_rng(np.random.SeedSequence(entropy=seed, spawn_key=(key,)))
