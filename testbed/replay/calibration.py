"""The calibration table of a recorded dataset (docs/replay.md, "Range bias"): a known bias and
scale per device (a site or an anchor) and per link, applied to the UWB ranges at load, and the
sigma of what remains, handed to the estimators as the prior of their bias states.

Measurement equation of a `uwb` range between src and dst, d the true distance (m):

    d_meas = (1 + s) d + b + noise,   s = s_src + s_dst + s_link,   b = b_src + b_dst + b_link

A row with an empty `dst` is a device (its bias and scale enter every link it ends); a row with
both ends is a link (either order). Empty cells: bias 0, scale 0, no sigma. Applied:
d = (d_meas - b) / (1 + s), the row's declared sigma divided by (1 + s) likewise. The sigma of a
link's remaining bias (m) is sqrt(sigma_src^2 + sigma_dst^2 + sigma_link^2) over the rows that
declare one; it is Context.sensors["uwb"]["bias_sigma"][src][dst] (both orders), absent for a
link no row with a sigma names.
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from testbed.errors import ConfigError
from testbed.replay.tables import CALIBRATION_SCHEMA, Table, read_table

#: the largest scale error a row may declare (dimensionless): a ranging clock off by 10 % is
#: broken, not miscalibrated, and 1 + s stays far from 0 for any sum of three such rows
MAX_SCALE = 0.1
#: the largest bias a row may declare (m): beyond the span of any UWB link's systematic error
MAX_BIAS_M = 100.0


@dataclass(frozen=True, slots=True)
class Calibration:
    """Per device and per link (frozenset of the two ends): (bias m, scale, sigma_bias m or NaN)."""

    devices: dict[str, tuple[float, float, float]]
    links: dict[frozenset, tuple[float, float, float]]

    def of(self, src: str, dst: str) -> tuple[float, float, float]:
        """(b, s, sigma of b or NaN) of the link src-dst: the sums of the measurement equation."""
        parts = [self.devices.get(src), self.devices.get(dst), self.links.get(frozenset((src, dst)))]
        parts = [p for p in parts if p is not None]
        sig = [p[2] for p in parts if np.isfinite(p[2])]
        return (float(sum(p[0] for p in parts)), float(sum(p[1] for p in parts)),
                float(np.sqrt(sum(x * x for x in sig))) if sig else float("nan"))

    def apply(self, src: np.ndarray, dst: np.ndarray, value: np.ndarray, sigma: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Ranges and sigmas (n,) of the links src[i]-dst[i] with the known bias and scale removed."""
        bs = np.array([self.of(a, b)[:2] for a, b in zip(src.tolist(), dst.tolist())]).reshape(-1, 2)
        return (value - bs[:, 0]) / (1.0 + bs[:, 1]), sigma / (1.0 + bs[:, 1])

    def bias_sigma(self, pairs: set[tuple[str, str]]) -> dict[str, dict[str, float]]:
        """{src: {dst: sigma m}} (both orders) of the links in pairs that have a declared sigma."""
        out: dict[str, dict[str, float]] = {}
        for a, b in sorted(pairs):
            s = self.of(a, b)[2]
            if np.isfinite(s):
                out.setdefault(a, {})[b] = s
                out.setdefault(b, {})[a] = s
        return out


def read_calibration(path: Path, names: set[str]) -> Calibration:
    """Read and check calibration.csv: names known (sites or anchors of the spec), no row twice,
    |bias| <= MAX_BIAS_M, |scale| <= MAX_SCALE, sigmas > 0; ConfigError (one line) on a mistake."""
    t: Table = read_table(path, "calibration", CALIBRATION_SCHEMA)
    devices: dict[str, tuple[float, float, float]] = {}
    links: dict[frozenset, tuple[float, float, float]] = {}
    first: dict[object, int] = {}
    for i in range(t["src"].size):
        src, dst = str(t["src"][i]), str(t["dst"][i])
        for col, name in (("src", src), ("dst", dst)):
            if name and name not in names:
                raise t.error(i, col, f"{name!r} is not a site (body/site) or an anchor of the spec")
        if src == dst:
            raise t.error(i, "dst", "a link from a site to itself")
        for col, lim in (("bias", MAX_BIAS_M), ("scale", MAX_SCALE)):
            if abs(t[col][i]) > lim:
                raise t.error(i, col, f"must be at most {lim:g} in magnitude, got {float(t[col][i]):g}")
        for col in ("sigma_bias", "sigma_scale"):
            if t[col][i] <= 0:
                raise t.error(i, col, f"must be positive (or empty), got {float(t[col][i]):g}")
        key = frozenset((src, dst)) if dst else src
        if key in first:
            raise t.error(i, "src", f"{'the link ' + src + ' - ' + dst if dst else 'the device ' + src} "
                                    f"is calibrated twice (also row {first[key] + 1})")
        first[key] = i
        entry = (float(np.nan_to_num(t["bias"][i])), float(np.nan_to_num(t["scale"][i])), float(t["sigma_bias"][i]))
        if dst:
            links[key] = entry
        else:
            devices[key] = entry
    if not first:
        raise ConfigError(f"{path}: no row (delete the file, or calibrate a device or a link)")
    return Calibration(devices, links)
