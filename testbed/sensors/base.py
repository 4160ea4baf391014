"""The interface every simulated sensor implements, and the stream buffer they share.

A sensor samples the MuJoCo state at its own instants (every `period_ticks` controller ticks),
draws its errors from its own generator (testbed.rng.stream_rng(seed, name)), and at the end
hands its arrays to the run log under the data-contract keys `NAME/time`, `NAME/value`,
`NAME/clean`, `NAME/state_index` and, for links, `NAME/src`, `NAME/dst`.
"""
from __future__ import annotations

from typing import Protocol

import numpy as np

from testbed.world import Physics


class Sensor(Protocol):
    name: str
    period_ticks: int
    rec: Recorder  # the stream's rows; rec.new_rows() gives those of the last sample (online use)

    def sample(self, physics: Physics, t: float, state_index: int) -> None:
        """Measure at time t (s) from the current physics state; state_index into log `time`."""

    def arrays(self) -> dict[str, np.ndarray]:
        """Everything measured, keyed `NAME/...` as in the data contract."""


class Recorder:
    """Accumulates one stream's rows sample by sample; `arrays()` concatenates them.

    `add(key, rows)` appends an array whose first axis is the row axis; string rows become
    fixed-width numpy unicode arrays (no pickles: the log is saved with allow_pickle=False).
    `empty` gives the trailing shape and dtype of every key, so a stream that never measured
    still writes well-formed (0, ...) arrays.
    """

    def __init__(self, name: str, empty: dict[str, tuple[tuple[int, ...], str]]):
        self.name = name
        self._empty = empty
        self._chunks: dict[str, list[np.ndarray]] = {k: [] for k in empty}
        self._cursor = 0  # chunks already handed out by new_rows

    def add(self, **rows: np.ndarray) -> None:
        for key, value in rows.items():
            self._chunks[key].append(np.asarray(value))

    def new_rows(self) -> dict[str, np.ndarray]:
        """The rows added since the previous call (the sample just taken), keyed without the
        stream prefix, with the dtypes `arrays()` gives them: what an online consumer reads
        (testbed.simulate). Empty (0, ...) arrays when nothing was added."""
        out = {}
        for key, chunks in self._chunks.items():
            shape, dtype = self._empty[key]
            new = chunks[self._cursor:]
            arr = np.concatenate(new, axis=0) if new else np.empty((0, *shape))
            out[key] = arr.astype(str) if dtype == "U" else arr.astype(dtype, copy=False)
        self._cursor = len(next(iter(self._chunks.values()), []))
        return out

    def arrays(self) -> dict[str, np.ndarray]:
        out = {}
        for key, chunks in self._chunks.items():
            shape, dtype = self._empty[key]
            if chunks:
                arr = np.concatenate(chunks, axis=0)
                if dtype == "U":
                    arr = arr.astype(str)
                else:
                    arr = arr.astype(dtype, copy=False)
            else:
                arr = np.empty((0, *shape), dtype="U1" if dtype == "U" else dtype)
            out[f"{self.name}/{key}"] = arr
        return out


def common_keys(d: int) -> dict[str, tuple[tuple[int, ...], str]]:
    """The data-contract keys of a stream with d-dimensional values (see module docstring)."""
    return {
        "time": ((), "f8"),
        "arrival": ((), "f8"),
        "state_index": ((), "i8"),
        "value": ((d,), "f8"),
        "clean": ((d,), "f8"),
        "src": ((), "U"),
        "dst": ((), "U"),
    }
