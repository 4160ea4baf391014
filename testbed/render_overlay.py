"""What a rendered frame shows besides the scene: UWB links, estimate ghosts, GNSS fix state.

Read from the run directory only (testbed.render draws them):
- UWB links: the rows of log.npz `uwb/*` whose time of validity is in (t - T, t], T the
  shortest interval between two UWB samples: the links ranged at the latest sample, drawn
  between the two sites' positions of the frame, LOS and NLOS (`uwb/nlos`) in two colours;
- ghosts: feedback.npz (written by the runner when a controller flew on an estimate,
  `[control] feedback = "estimate:NAME"`): per vehicle the body positions the estimator gave
  (`uavI/time` (K,) s, `uavI/pos` (K, 3) m world) and `estimator` (NAME); the ghost at t is the
  latest estimate of time <= t;
- GNSS fix state: log.npz `gnss/fix` (T, N) bool at the logged instants `time`, the row at or
  before t.
Any of them is absent when its arrays are (older runs, scenarios without that sensor).
"""
from __future__ import annotations

import zipfile
from pathlib import Path

import numpy as np

FEEDBACK_FILE = "feedback.npz"
LOS_RGBA = np.array([0.25, 0.85, 1.0, 0.75], np.float32)
NLOS_RGBA = np.array([1.0, 0.45, 0.1, 0.9], np.float32)
GHOST_RGBA = np.array([0.95, 0.95, 0.95, 0.45], np.float32)


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
        fb = _load(Path(run_dir) / FEEDBACK_FILE)
        self.estimator = str(fb["estimator"]) if "estimator" in fb else ""
        self.ghost = [(fb.get(f"uav{i}/time"), fb.get(f"uav{i}/pos")) for i in range(1, n + 1)] if fb else None

    def links(self, t: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(src site ids, dst site ids, nlos) of the links ranged at the latest UWB sample by t."""
        if self.uwb is None:
            return np.zeros(0, int), np.zeros(0, int), np.zeros(0, bool)
        time, src, dst, nlos = self.uwb
        hi = np.searchsorted(time, t + 1e-9, side="right")
        lo = np.searchsorted(time, t - self.uwb_period + 1e-9, side="right")
        keep = (src[lo:hi] >= 0) & (dst[lo:hi] >= 0)
        return src[lo:hi][keep], dst[lo:hi][keep], nlos[lo:hi][keep]

    def ghosts(self, t: float) -> np.ndarray | None:
        """(N, 3) m world: each vehicle's latest estimate by t (NaN before its first), or None."""
        if self.ghost is None:
            return None
        out = np.full((self.n, 3), np.nan)
        for i, (time, pos) in enumerate(self.ghost):
            if time is not None and time.size:
                k = np.searchsorted(time, t + 1e-9, side="right") - 1
                if k >= 0:
                    out[i] = pos[k]
        return out

    def fixed(self, t: float) -> np.ndarray | None:
        """(N,) bool: which vehicles have a GNSS fix at t, or None without GNSS."""
        if self.fix is None:
            return None
        time, fix = self.fix
        k = int(np.clip(np.searchsorted(time, t + 1e-9, side="right") - 1, 0, len(time) - 1))
        return fix[k].astype(bool)
