"""The interface every simulated sensor implements, and the stream buffer they share.

A sensor samples the MuJoCo state at its own instants (every `period_ticks` controller ticks),
draws its errors from its own generator (testbed.rng.stream_rng(seed, name)), and at the end
hands its arrays to the run log under the data-contract keys `NAME/time`, `NAME/value`,
`NAME/clean`, `NAME/state_index` and, for links, `NAME/src`, `NAME/dst`.
"""
from __future__ import annotations

from typing import Protocol

import numpy as np

from testbed.log import LogWriter
from testbed.sim.world import Physics


class Sensor(Protocol):
    """name: the stream's log prefix; period_ticks: controller ticks between samples;
    mujoco_sensors: whether `sample` reads MuJoCo's own sensordata (the IMU only). In flown mode
    MuJoCo evaluates its sensors only at the ticks where such a sensor samples (testbed.sim.simulate);
    a sensor without the attribute is taken not to read them."""

    name: str
    period_ticks: int
    rec: "Recorder"  # the stream's rows; simulate points rec.sink at the run's log

    def sample(self, physics: Physics, t: float, state_index: int) -> None:
        """Measure at time t (s) from the current physics state; state_index into log `time`."""

    def arrays(self) -> dict[str, np.ndarray]:
        """Everything measured, keyed `NAME/...` as in the data contract."""


class Recorder:
    """Accumulates one stream's rows sample by sample into a log (testbed.log.LogWriter).

    `add(key, rows)` appends an array whose first axis is the row axis; string rows become
    fixed-width numpy unicode arrays (no pickles: the log is saved with allow_pickle=False).
    `empty` gives the trailing shape and dtype of every key, so a stream that never measured
    still writes well-formed (0, ...) arrays. `sink` is the recorder's own in-memory log until
    the simulation points it at the run's log, where the rows then go directly.
    """

    def __init__(self, name: str, empty: dict[str, tuple[tuple[int, ...], str]]):
        self.name = name
        self._empty = empty
        self._own = self.sink = LogWriter()
        self._new: dict[str, list[np.ndarray]] | None = None  # rows since new_rows(), once watched

    def add(self, **rows: np.ndarray) -> None:
        for key, value in rows.items():
            value, dtype = np.asarray(value), self._empty[key][1]
            value = value.astype(str) if dtype == "U" else value.astype(dtype, copy=False)
            self.sink.append(f"{self.name}/{key}", value)
            if self._new is not None:
                self._new[key].append(value)

    def watch(self) -> None:
        """Keep the rows added since the last `new_rows` call (online use; off by default, so an
        offline run holds no second copy of its rows)."""
        self._new = {k: [] for k in self._empty}

    def new_rows(self) -> dict[str, np.ndarray]:
        """The rows added since the previous call (the sample just taken), keyed without the
        stream prefix, with the dtypes the log holds: what an online consumer reads
        (testbed.sim.simulate). Empty (0, ...) arrays when nothing was added. Needs `watch()`."""
        if self._new is None:
            raise RuntimeError(f"{self.name}: new_rows() needs watch() first")
        out = {}
        for key, rows in self._new.items():
            shape, dtype = self._empty[key]
            out[key] = np.concatenate(rows, axis=0) if rows else np.empty((0, *shape), dtype="U1" if dtype == "U" else dtype)
            rows.clear()
        return out

    def arrays(self) -> dict[str, np.ndarray]:
        """The stream's keys that are not already in an outside sink: the rows added (own sink)
        and (0, ...) arrays for the keys never added."""
        out = self.sink.arrays() if self.sink is self._own else {}
        for key, (shape, dtype) in self._empty.items():
            if f"{self.name}/{key}" not in self.sink:
                out[f"{self.name}/{key}"] = np.empty((0, *shape), dtype="U1" if dtype == "U" else dtype)
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
