"""Convert the LIAS UWB trolley dataset (examples/replay/trolley/, MIT) into the replay format (docs/replay.md).

    python examples/replay/trolley.py --out DATASET [--seconds S] [--force]

What the raw files are, and what this does with them (examples/replay/trolley/README.md):
- Time base: both files stamp rows with the same local wall clock ("2022-08-15 9:42:24.766", time
  zone not stated). Times here are seconds after the first UWB row, in both tables.
- World frame: the motion-capture frame, z up (the anchors' surveyed heights, 1.04 m, and the
  trolley's, 0.96 m, say so), metres. The 8 anchors' surveyed positions are the dataset README's.
- Body frame: the tags' "local reference frame" of the README, origin at the rigid body's
  centroid (so the motion capture position is the body origin), z up. The motion capture
  quaternion (wxyz, body-to-world) is of a rigid body whose frame is this one turned half a turn
  about x (z down): q_body = q_mocap (x) (0, 1, 0, 0). Found on the data: of the 24 rotations
  that permute the body axes (signs included), with either quaternion order (wxyz, xyzw), this
  one gives the smallest scatter of range minus true range, 0.084 m per link (mean over links,
  every tenth row), against 0.116 m or more for any other.
- Lever arms: the README's tag coordinates, body frame, m.
- Clocks: shifting the motion capture time by -0.3 .. +0.3 s makes the scatter larger, so the
  two clocks are taken as one (no offset).
- Defects, handled: the 10 UWB rows with empty anchor 7 cells are written without those links;
  145 motion capture rows repeat the previous row's timestamp with a different pose (up to
  1.4 cm): the pair is averaged (quaternion renormalized), so truth times increase; ranges are
  quantized to 0.01 m (noise of 0.003 m, left as it is). Every link is biased (+0.09 to
  +0.32 m): calibrate it (below).
- Ranges are written as recorded, without a sigma. Calibration segment (the rule: the first 20 %
  of the UWB span, CALIBRATION_FRACTION): the window written to spec.toml starts after it, so
  `testbed calibrate DATASET/spec.toml --window 0,START --out calib.toml` fits the segment and
  `testbed replay DATASET/spec.toml --calibration calib.toml` replays the rest (docs/calibration.md).
- --seconds S: a window of only the first S seconds after the calibration segment (tests).

The spec runs the ranging estimators with their defaults: graph.poses, ranging.ekf and
ranging.lsq (the per-epoch least-squares baseline).
"""
from __future__ import annotations

import argparse
import csv
import datetime as dt
import sys
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation, Slerp

from estimators.so3 import quat_mul
from testbed.errors import TestbedError
from testbed.outdir import Output
from testbed.replay.export import write_csv
from testbed.replay.spec import FORMAT

RAW = Path(__file__).resolve().parent / "trolley"
UWB_FILE, MOCAP_FILE = "UWB_dynamic_exp_fast.csv", "motion_capture_dynamic_exp_fast.csv"
CALIBRATION_FRACTION = 0.2
# README-dataset.md: anchors in the global frame, tags in the local (body) frame, m
ANCHORS = np.array([[-3.4203, 3.0053, 1.0442], [0.0016, 3.0110, 1.0446], [3.6056, 2.9795, 1.0463],
                    [3.6011, -0.0008, 1.0422], [3.5674, -3.0087, 1.0443], [-0.0072, -2.9652, 1.0444],
                    [-3.4673, -2.9587, 1.0445], [-3.4858, -0.0098, 1.0457]])
TAGS = np.array([[-0.0689, -0.1423, 0.0011], [-0.0750, 0.1402, 0.0016], [0.2034, 0.1451, -0.0008]])
MOCAP_TO_BODY = np.array([0.0, 1.0, 0.0, 0.0])  # half a turn about x, wxyz
BODY = "trolley"


def _clock(text: str) -> float:
    """s of the files' wall clock (a fixed origin: only differences are used)."""
    return dt.datetime.strptime(text, "%Y-%m-%d %H:%M:%S.%f").replace(tzinfo=dt.timezone.utc).timestamp()


def read_uwb(path: Path) -> tuple[np.ndarray, np.ndarray]:
    """UWB rows: times (N,) s of the files' clock; ranges (N, 8, 3) m, [anchor, tag], NaN where empty."""
    rows = list(csv.reader(path.open()))
    t = np.array([_clock(r[0]) for r in rows])
    r = np.array([[float(x) if x.strip() else np.nan for x in row[1:]] for row in rows])
    return t, r.reshape(len(rows), len(ANCHORS), len(TAGS))


def read_mocap_rows(path: Path) -> tuple[np.ndarray, np.ndarray]:
    """Motion capture rows as recorded: times (M,) s of the files' clock, and (M, 7) position m and
    quaternion wxyz of the motion capture's rigid body."""
    rows = list(csv.reader(path.open()))[1:]
    return np.array([_clock(r[0]) for r in rows]), np.array([[float(x) for x in r[1:8]] for r in rows])


def read_mocap(path: Path) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Motion capture, duplicated timestamps averaged: times (M,) s of the files' clock, body
    origin (M, 3) m world, body-to-world quaternion (M, 4) wxyz of the body frame (MOCAP_TO_BODY applied)."""
    t, v = read_mocap_rows(path)
    start = np.r_[True, np.diff(t) > 0]
    group = np.cumsum(start) - 1
    n = np.bincount(group)
    q = v[:, 3:] * np.sign(np.sum(v[:, 3:] * v[np.flatnonzero(start)[group], 3:], axis=1))[:, None]  # one hemisphere per group
    mean = np.stack([np.bincount(group, weights=c) for c in np.c_[v[:, :3], q].T], axis=1) / n[:, None]
    quat = mean[:, 3:] / np.linalg.norm(mean[:, 3:], axis=1, keepdims=True)
    return t[start], mean[:, :3], quat_mul(quat, MOCAP_TO_BODY)


def tag_positions(t: np.ndarray, tm: np.ndarray, p: np.ndarray, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The tags (N, 3, 3) m world and the body-to-world rotation (N, 3, 3) at times t (inside tm),
    from the body pose interpolated linearly (position) and by slerp (attitude)."""
    pos = np.stack([np.interp(t, tm, p[:, k]) for k in range(3)], axis=1)
    rot = Slerp(tm, Rotation.from_quat(q, scalar_first=True))(t).as_matrix()
    return pos[:, None] + np.einsum("nij,kj->nki", rot, TAGS), rot


def true_ranges(t: np.ndarray, tm: np.ndarray, p: np.ndarray, q: np.ndarray) -> np.ndarray:
    """Anchor-to-tag distances (N, 8, 3) m at times t (inside tm)."""
    tags, _ = tag_positions(t, tm, p, q)
    return np.linalg.norm(tags[:, None] - ANCHORS[None, :, None], axis=-1)


def calibration(t: np.ndarray, r: np.ndarray, tm: np.ndarray, p: np.ndarray, q: np.ndarray, end: float) -> tuple[np.ndarray, np.ndarray]:
    """Per link (8, 3): mean m of (range - true range) and its standard deviation m (ddof 1) over
    the rows with time < end: the measure of the frame search above (the dataset's calibration
    is `testbed calibrate`'s)."""
    seg = t < end
    e = r[seg] - true_ranges(t[seg], tm, p, q)
    return np.nanmean(e, axis=0), np.nanstd(e, axis=0, ddof=1)


def spec_toml(start: float, end: float) -> str:
    vec = lambda x: "[" + ", ".join(repr(float(c)) for c in x) + "]"  # noqa: E731
    lines = [f"format = {FORMAT}",
             'description = "LIAS UWB trolley, fast run, ranges as recorded (examples/replay/trolley.py)"',
             "seed = 0", "",
             *[f'[[estimators]]\nentry = "{e}"\n' for e in ("graph.poses", "ranging.ekf")],
             '[[estimators]]  # registered as ranging.lsq; by module path, so it runs before a reinstall too',
             'entry = "testbed.plugins.lsq:RangeLsq"', 'name = "ranging.lsq"', "",
             "[window]  # s after the first UWB row; starts after the calibration segment",
             f"start = {start!r}", f"end = {end!r}", "",
             f"[bodies.{BODY}.sites]  # lever arms, m, body frame (x forward, y left, z up)",
             *[f"tag{k} = {vec(a)}" for k, a in enumerate(TAGS)], "",
             "[anchors]  # surveyed, m, world (motion capture frame, z up)",
             *[f"anchor{k} = {vec(a)}" for k, a in enumerate(ANCHORS)], ""]
    return "\n".join(lines)


def convert(out: Path, *, seconds: float | None = None, force: bool = False, raw: Path = RAW) -> Path:
    """Write the dataset at out (testbed.outdir rules); returns the path of its spec.toml."""
    tu, r = read_uwb(raw / UWB_FILE)
    tm, p, q = read_mocap(raw / MOCAP_FILE)
    t0 = tu[0]
    tu, tm = np.round(tu - t0, 3), np.round(tm - t0, 3)  # the clock counts milliseconds
    start = round(float(CALIBRATION_FRACTION * tu[-1]), 3)
    end = round(float(tu[-1] if seconds is None else min(tu[-1], start + seconds)), 3)
    keep = (tm >= -1.0) & (tm <= end + 1.0)  # truth a little beyond the window, for interpolation at its edges
    keep_u = tu <= end
    tu, r = tu[keep_u], r[keep_u]
    ok = np.isfinite(r)
    n, a, k = np.nonzero(ok)
    links = {"time": tu[n], "src": np.array([f"anchor{i}" for i in a]), "dst": np.array([f"{BODY}/tag{i}" for i in k]),
             "kind": np.full(n.size, "uwb"), "value": np.round(r[n, a, k], 6)}
    truth = {"time": tm[keep], "body": np.full(keep.sum(), BODY), **{c: p[keep, i] for i, c in enumerate("xyz")},
             **{c: q[keep, i] for i, c in enumerate(("qw", "qx", "qy", "qz"))}}
    with Output(Path(out), kind="dataset", force=force) as o:
        (o.path / "spec.toml").write_text(spec_toml(start, end))
        write_csv(o.path / "links.csv", links)
        write_csv(o.path / "truth.csv", truth)
        o.commit()
    return Path(out) / "spec.toml"


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", required=True, type=Path, help="dataset directory to write")
    ap.add_argument("--seconds", type=float, help="only this many seconds after the calibration segment")
    ap.add_argument("--force", action="store_true", help="replace an earlier dataset written by the testbed")
    a = ap.parse_args(argv)
    try:
        print(convert(a.out, seconds=a.seconds, force=a.force))
    except TestbedError as e:
        print(f"trolley: error: {e}", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    sys.exit(main())
