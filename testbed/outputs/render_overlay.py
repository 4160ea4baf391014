"""What a rendered frame shows besides the scene: reference paths, UWB links, the estimate with its
covariance, GNSS fix state.

Read from the run directory only (testbed.outputs.render draws them):
- reference paths: log.npz `reference/pos` (T, N, 3) m world at the logged instants `time`;
- UWB links: the rows of log.npz `uwb/*` whose time of validity is in (t - T, t], T the
  shortest interval between two UWB samples: the links ranged at the latest sample, drawn
  between the two sites' positions of the frame, LOS and NLOS (`uwb/nlos`) in two colours;
- the estimate: estimates.npz (testbed.plugins.collect.track_arrays) of one estimator, the one
  the controller flew on when the run did (feedback.npz `estimator`, written by the runner with
  `[control] feedback = "estimate:NAME"`), else the first by name: per vehicle `uavI` its world
  position estimates (K, 3) m and their covariances (K, 3, 3) m^2, and their errors against
  log.npz `truth/pos` at the estimates' own times (linear between log rows); the estimate at t is
  the latest of time <= t, drawn as its error from the vehicle's true position at t (so a vehicle
  moving between two estimates does not show its motion as an error);
- GNSS fix state: log.npz `gnss/fix` (T, N) bool at the logged instants `time`, the row at or
  before t.
Any of them is absent when its arrays are (older runs, scenarios without that sensor, runs without
a plugin estimator).
"""
from __future__ import annotations

import zipfile
from pathlib import Path

import numpy as np

from testbed.plugins.collect import ESTIMATES_FILE, load_tracks, natural

FEEDBACK_FILE = "feedback.npz"
LOS_RGBA = np.array([0.25, 0.85, 1.0, 0.75], np.float32)
NLOS_RGBA = np.array([1.0, 0.45, 0.1, 0.9], np.float32)


def feedback_arrays(track: dict, vehicles: int, name: str) -> dict[str, np.ndarray]:
    """feedback.npz's arrays from an estimator's Track ({(target, quantity): Series}): the world
    body positions of uav1..uavN (vehicles without any are left out) and the estimator's name."""
    out = {"estimator": np.array(name)}
    for i in range(1, vehicles + 1):
        s = track.get((f"uav{i}", "position"))
        if s is not None and s.frame == "world":
            out[f"uav{i}/time"], out[f"uav{i}/pos"] = s.time, s.value
    return out


def _load(path: Path) -> dict[str, np.ndarray]:
    try:
        with np.load(path, allow_pickle=False) as z:
            return {k: z[k] for k in z.files}
    except (OSError, ValueError, EOFError, zipfile.BadZipFile):
        return {}


class Overlays:
    """The overlays of one run directory (module docstring). site_id: name -> MuJoCo site id
    (-1 when absent); n: vehicle count."""

    def __init__(self, run_dir: Path, site_id, n: int):
        log = _load(Path(run_dir) / "log.npz")
        self.n = n
        self.uwb = None
        if "uwb/time" in log and log["uwb/time"].size:
            t = log["uwb/time"]
            order = np.argsort(t, kind="stable")
            names = np.unique(np.concatenate([log["uwb/src"], log["uwb/dst"]]))
            ids = {str(s): site_id(str(s)) for s in names}
            src = np.array([ids[str(s)] for s in log["uwb/src"][order]])
            dst = np.array([ids[str(s)] for s in log["uwb/dst"][order]])
            steps = np.diff(np.unique(t))
            self.uwb_period = float(steps.min()) if steps.size else np.inf
            nlos = log["uwb/nlos"][order] if "uwb/nlos" in log else np.zeros(t.size, bool)
            self.uwb = (t[order], src, dst, nlos.astype(bool))
        self.fix = (log["time"], log["gnss/fix"]) if "gnss/fix" in log and "time" in log else None
        self.reference = log["reference/pos"] if "reference/pos" in log and "time" in log else None  # (T, N, 3)
        self.time = log.get("time")
        fb = _load(Path(run_dir) / FEEDBACK_FILE)
        tracks = load_tracks(Path(run_dir) / ESTIMATES_FILE)
        flown = str(fb["estimator"]) if "estimator" in fb else ""
        self.estimator = flown if flown in tracks else min(tracks, key=natural, default="")
        self.flown = bool(flown) and flown == self.estimator
        series = [tracks[self.estimator].get((f"uav{i}", "position")) if self.estimator else None for i in range(1, n + 1)]
        self.series = [s if s is not None and s.frame == "world" and s.time.size and "truth/pos" in log else None for s in series]
        if not any(s is not None for s in self.series):
            self.series = None
        else:  # (K, 3) m world: each estimate minus the truth at its time
            self.errors = [None if s is None else s.value - np.column_stack(
                [np.interp(s.time, log["time"], log["truth/pos"][:, i, j]) for j in range(3)]) for i, s in enumerate(self.series)]

    def links(self, t: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(src site ids, dst site ids, nlos) of the links ranged at the latest UWB sample by t."""
        if self.uwb is None:
            return np.zeros(0, int), np.zeros(0, int), np.zeros(0, bool)
        time, src, dst, nlos = self.uwb
        hi = np.searchsorted(time, t + 1e-9, side="right")
        lo = np.searchsorted(time, t - self.uwb_period + 1e-9, side="right")
        keep = (src[lo:hi] >= 0) & (dst[lo:hi] >= 0)
        return src[lo:hi][keep], dst[lo:hi][keep], nlos[lo:hi][keep]

    def estimate(self, t: float) -> tuple[np.ndarray, np.ndarray] | None:
        """(N, 3) m world errors (estimate - truth at the estimate's time) and (N, 3, 3) m^2
        covariances: each vehicle's latest estimate by t (NaN before its first, and for the
        covariance of an estimate without one), or None without estimates."""
        if self.series is None:
            return None
        err, cov = np.full((self.n, 3), np.nan), np.full((self.n, 3, 3), np.nan)
        for i, s in enumerate(self.series):
            if s is not None:
                k = np.searchsorted(s.time, t + 1e-9, side="right") - 1
                if k >= 0:
                    err[i], cov[i] = self.errors[i][k], s.cov[k]
        return err, cov

    def error_sizes(self, times: np.ndarray) -> np.ndarray:
        """(F, N) m: the size of each vehicle's estimate drawing at each time, the larger of its
        error's length and the 3-sigma semi-major axis of its horizontal covariance (NaN without an
        estimate). times: (F,) s."""
        out = np.full((len(times), self.n), np.nan)
        for f, t in enumerate(times):
            est = self.estimate(float(t))
            if est is None:
                break
            err, cov = est
            c = cov[:, :2, :2]
            major = np.full(self.n, 0.0)
            ok = np.isfinite(c).all(axis=(1, 2))
            major[ok] = 3.0 * np.sqrt(np.maximum(np.linalg.eigvalsh((c[ok] + np.swapaxes(c[ok], 1, 2)) / 2)[:, -1], 0.0))
            out[f] = np.maximum(np.linalg.norm(err, axis=1), major)  # NaN where no estimate
        return out

    def fixed(self, t: float) -> np.ndarray | None:
        """(N,) bool: which vehicles have a GNSS fix at t, or None without GNSS."""
        if self.fix is None:
            return None
        time, fix = self.fix
        k = int(np.clip(np.searchsorted(time, t + 1e-9, side="right") - 1, 0, len(time) - 1))
        return fix[k].astype(bool)
