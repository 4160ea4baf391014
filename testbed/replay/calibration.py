"""The calibration table of a recorded dataset (docs/replay.md, "Range bias"): a known bias and
scale per device (a site or an anchor) and per link, applied to the UWB ranges at load, and the
sigma of what remains, handed to the estimators as the prior of their bias states.

Measurement equation of a `uwb` range between src and dst, d the true distance (m):

    d_meas = (1 + s) d + b + noise,   s = s_src + s_dst + s_link,   b = b_src + b_dst + b_link

A row with an empty `dst` is a device (its bias and scale enter every link it ends); a row with
both ends is a link (either order). Empty cells: bias 0, scale 0, no sigma. A row's scale may hold
only within a span of true distances [scale_from, scale_to] (m; the span it was fitted on, docs/
calibration.md cal. 2c): beyond it, its correction is held at its value at the nearer end. Row k
then enters as b_k + s_k clamp(d, from_k, to_k) (no span: from_k = -inf, to_k = +inf), and

    d_meas = d + sum_k (b_k + s_k clamp(d, from_k, to_k)) + noise                     (cal. 2c)

is inverted exactly at load (piecewise linear, increasing: |s| <= 0.3): without spans
d = (d_meas - b) / (1 + s); the row's declared sigma is divided by the slope d d_meas / d d at d
(1 + s without spans) likewise. The sigma of a
link's remaining bias (m) is sqrt(sigma_src^2 + sigma_dst^2 + sigma_link^2) over the rows that
declare one; it is Context.sensors["uwb"]["bias_sigma"][src][dst] (both orders), absent for a
link no row with a sigma names.

A row's time offset c (s, docs/calibration.md cal. 10; device and link rows add up like the
biases) says the link's range at time t is the distance at t + c: r(t) = d(t) + c d'(t) + ...
It is not applied at load (a range's rate is the estimator's to know): it is handed to the
estimators as Context.sensors["uwb"]["time_offset"][src][dst] (s, both orders), for the links
with a nonzero one.

The calibration file (`testbed calibrate` writes it, `testbed replay --calibration FILE` reads it;
docs/calibration.md): TOML, `format`, `window` [T0, T1] (s, the files' clock: the segment it was
fitted on, never scored), `[noise]` (the estimators' defaults by parameter name: NOISE_KEYS),
`[fit]` (a record, not read), `[[links]]` rows with the columns of calibration.csv (and `sigma`,
`samples`, `tau`: a record). read_calibration_file checks every key; a mistake is one line naming the
file, the key and the value.
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from testbed.config import MAX_MAGNITUDE as MAX_PARAM, MIN_MAGNITUDE, read_toml_file
from testbed.errors import ConfigError
from testbed.replay.tables import CALIBRATION_SCHEMA, MAX_MAGNITUDE, Table, read_table

#: the largest scale error a row may declare (dimensionless): a ranging clock off by 10 % is
#: broken, not miscalibrated, and 1 + s stays far from 0 for any sum of three such rows
MAX_SCALE = 0.1
#: the largest bias a row may declare (m): beyond the span of any UWB link's systematic error
MAX_BIAS_M = 100.0
#: the calibration file's format version
FILE_FORMAT = 1
#: the calibration file's [noise] keys: estimator parameters of these names take these values
#: where the user set none (m; m^2/s^3; rad^2/s^3; s)
NOISE_KEYS = ("range_sigma", "q_translation", "q_rotation", "range_correlation")
#: the largest time offset a row may declare (s): a ranging radio's timestamps off by a second are broken
MAX_TIME_OFFSET_S = 1.0
#: the record keys of a [[links]] row besides calibration.csv's columns
LINK_RECORD_KEYS = ("sigma", "samples", "tau")


@dataclass(frozen=True, slots=True)
class Calibration:
    """Per device and per link (frozenset of the two ends): (bias m, scale, sigma_bias m or NaN,
    time offset s, scale_from m, scale_to m) (the scale's span: -inf, +inf where none is declared)."""

    devices: dict[str, tuple[float, float, float, float, float, float]]
    links: dict[frozenset, tuple[float, float, float, float, float, float]]

    def _parts(self, src: str, dst: str) -> list[tuple[float, float, float, float, float, float]]:
        """The rows of the link src-dst: its two devices' and its own, those that exist."""
        return [p for p in (self.devices.get(src), self.devices.get(dst), self.links.get(frozenset((src, dst))))
                if p is not None]

    def of(self, src: str, dst: str) -> tuple[float, float, float]:
        """(b, s, sigma of b or NaN) of the link src-dst: the sums of the measurement equation."""
        parts = self._parts(src, dst)
        sig = [p[2] for p in parts if np.isfinite(p[2])]
        return (float(sum(p[0] for p in parts)), float(sum(p[1] for p in parts)),
                float(np.sqrt(sum(x * x for x in sig))) if sig else float("nan"))

    def offset(self, src: str, dst: str) -> float:
        """The time offset c (s) of the link src-dst: the sum of its device and link rows'."""
        return float(sum(p[3] for p in self._parts(src, dst)))

    def apply(self, src: np.ndarray, dst: np.ndarray, value: np.ndarray, sigma: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Ranges and sigmas (n,) m of the links src[i]-dst[i] with the known bias and scale removed
        (cal. 2c inverted)."""
        groups: dict[tuple[str, str], list[int]] = {}
        for i, key in enumerate(zip(src.tolist(), dst.tolist())):
            groups.setdefault(key, []).append(i)
        d, slope = np.empty(value.shape), np.empty(value.shape)
        for (a, b), rows in groups.items():
            d[rows], slope[rows] = _true_range(self._parts(a, b), value[rows])
        return d, sigma / slope

    def bias_sigma(self, pairs: set[tuple[str, str]]) -> dict[str, dict[str, float]]:
        """{src: {dst: sigma m}} (both orders) of the links in pairs that have a declared sigma."""
        return _both_orders(pairs, lambda a, b: self.of(a, b)[2], np.isfinite)

    def time_offsets(self, pairs: set[tuple[str, str]]) -> dict[str, dict[str, float]]:
        """{src: {dst: c s}} (both orders) of the links in pairs that have a nonzero time offset."""
        return _both_orders(pairs, self.offset, lambda c: c != 0.0)


def _true_range(parts: list[tuple[float, ...]], r: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(d, d r / d d) (n,) of the ranges r (n,) m of one link whose rows are parts (Calibration's
    tuples): the exact inverse of cal. 2c, r = d + sum_k (b_k + s_k clamp(d, from_k, to_k)), a
    continuous increasing piecewise-linear function of d with knots at the finite span ends."""
    b, s = float(sum(p[0] for p in parts)), float(sum(p[1] for p in parts))
    knots = np.array(sorted({x for p in parts for x in p[4:6] if np.isfinite(x)}))
    if knots.size == 0:
        return (r - b) / (1.0 + s), np.full(r.shape, 1.0 + s)
    # eq. cal. 2c at the knots, and its slope on each of the knots.size + 1 pieces (at a point inside each)
    f = knots + b + sum(p[1] * np.clip(knots, p[4], p[5]) for p in parts)
    mid = np.concatenate([[knots[0] - 1.0], (knots[:-1] + knots[1:]) / 2, [knots[-1] + 1.0]])
    slopes = 1.0 + sum(p[1] * ((mid >= p[4]) & (mid <= p[5])) for p in parts)
    j = np.searchsorted(f, r, side="right")
    k = np.maximum(j - 1, 0)
    return knots[k] + (r - f[k]) / slopes[j], slopes[j]


def _both_orders(pairs: set[tuple[str, str]], value, keep) -> dict[str, dict[str, float]]:
    """{src: {dst: value(src, dst)}} in both orders over pairs, where keep(value)."""
    out: dict[str, dict[str, float]] = {}
    for a, b in sorted(pairs):
        x = value(a, b)
        if keep(x):
            out.setdefault(a, {})[b] = x
            out.setdefault(b, {})[a] = x
    return out


def read_calibration(path: Path, names: set[str]) -> Calibration:
    """Read and check calibration.csv (see _from_table); ConfigError (one line) on a mistake."""
    return _from_table(read_table(path, "calibration", CALIBRATION_SCHEMA), names)


def _from_table(t: Table, names: set[str]) -> Calibration:
    """Check the rows of a calibration table: names known (sites or anchors of the spec), no row
    twice, |bias| <= MAX_BIAS_M, |scale| <= MAX_SCALE, |time_offset| <= MAX_TIME_OFFSET_S, sigmas > 0,
    a scale's span both ends or neither, 0 <= scale_from < scale_to, and only on a row with a scale;
    ConfigError (one line) on a mistake."""
    devices: dict[str, tuple[float, float, float, float, float, float]] = {}
    links: dict[frozenset, tuple[float, float, float, float, float, float]] = {}
    first: dict[object, int] = {}
    for i in range(t["src"].size):
        src, dst = str(t["src"][i]), str(t["dst"][i])
        for col, name in (("src", src), ("dst", dst)):
            if name and name not in names:
                raise t.error(i, col, f"{name!r} is not a site (body/site) or an anchor of the spec")
        if src == dst:
            raise t.error(i, "dst", "a link from a site to itself")
        for col, lim in (("bias", MAX_BIAS_M), ("scale", MAX_SCALE), ("time_offset", MAX_TIME_OFFSET_S)):
            if abs(t[col][i]) > lim:
                raise t.error(i, col, f"must be at most {lim:g} in magnitude, got {float(t[col][i]):g}")
        for col in ("sigma_bias", "sigma_scale", "sigma_time_offset"):
            if t[col][i] <= 0:
                raise t.error(i, col, f"must be positive (or empty), got {float(t[col][i]):g}")
        key = frozenset((src, dst)) if dst else src
        if key in first:
            raise t.error(i, "src", f"{'the link ' + src + ' - ' + dst if dst else 'the device ' + src} "
                                    f"is calibrated twice (also row {first[key] + 1})")
        first[key] = i
        span = (t["scale_from"][i], t["scale_to"][i])
        if np.isnan(span).any() and not np.isnan(span).all():
            raise t.error(i, "scale_to" if np.isnan(span[1]) else "scale_from",
                          "a scale's span needs both scale_from and scale_to (or neither)")
        if not np.isnan(span).any():
            if span[0] < 0:
                raise t.error(i, "scale_from", f"must be at least 0 (a distance), got {float(span[0]):g}")
            if span[1] <= span[0]:
                raise t.error(i, "scale_to", f"must exceed scale_from ({float(span[0]):g}), got {float(span[1]):g}")
            if not np.nan_to_num(t["scale"][i]):
                raise t.error(i, "scale_from", "a span without a scale (the span is where the row's scale holds)")
        entry = (float(np.nan_to_num(t["bias"][i])), float(np.nan_to_num(t["scale"][i])), float(t["sigma_bias"][i]),
                 float(np.nan_to_num(t["time_offset"][i])), float(np.nan_to_num(span[0], nan=-np.inf)),
                 float(np.nan_to_num(span[1], nan=np.inf)))
        if dst:
            links[key] = entry
        else:
            devices[key] = entry
    if not first:
        raise ConfigError(f"{t.file}: no row (delete the file, or calibrate a device or a link)")
    return Calibration(devices, links)


@dataclass(frozen=True, slots=True)
class CalibrationFile:
    """A calibration file (module docstring): path, the bias and scale table, window (T0, T1) s of
    the files' clock, noise {NOISE_KEYS name: value}."""

    path: Path
    table: Calibration
    window: tuple[float, float]
    noise: dict[str, float]


def _number(path: Path, key: str, v: object, lo: float = -MAX_MAGNITUDE) -> float:
    """v as a float, if a finite number (not a bool) in [lo, MAX_MAGNITUDE]; else ConfigError naming path and key."""
    if isinstance(v, bool) or not isinstance(v, (int, float)) or not np.isfinite(v) or not lo <= v <= MAX_MAGNITUDE:
        raise ConfigError(f"{path}: {key}: expected a finite number in [{lo:g}, {MAX_MAGNITUDE:g}], got {v!r}")
    return float(v)


def read_calibration_file(path: Path, names: set[str]) -> CalibrationFile:
    """Read and check a calibration file (module docstring) against the spec's site and anchor
    names; ConfigError (one line naming the file, key and value) on a mistake."""
    path = Path(path)
    data = read_toml_file(path, "calibration", "name the calibration file")
    unknown = sorted(set(data) - {"format", "window", "noise", "fit", "links"})
    if unknown:
        raise ConfigError(f"{path}: {unknown[0]}: unknown key (a calibration file has format, window, noise, fit, links)")
    if data.get("format") != FILE_FORMAT:
        raise ConfigError(f"{path}: format: expected {FILE_FORMAT}, got {data.get('format')!r}")
    w = data.get("window")
    if not isinstance(w, list) or len(w) != 2:
        raise ConfigError(f"{path}: window: expected [T0, T1] (s), got {w!r}")
    window = (_number(path, "window[0]", w[0]), _number(path, "window[1]", w[1]))
    if window[1] <= window[0]:
        raise ConfigError(f"{path}: window: T1 must be after T0, got {w!r}")
    noise_t = data.get("noise", {})
    if not isinstance(noise_t, dict):
        raise ConfigError(f"{path}: noise: expected a table, got {noise_t!r}")
    if not isinstance(data.get("fit", {}), dict):
        raise ConfigError(f"{path}: fit: expected a table, got {data['fit']!r}")
    noise = {}
    for k, v in noise_t.items():
        if k not in NOISE_KEYS:
            raise ConfigError(f"{path}: noise.{k}: unknown key (known: {', '.join(NOISE_KEYS)})")
        noise[k] = _number(path, f"noise.{k}", v, lo=0.0)
        if (k == "range_sigma" or noise[k] > 0) and not MIN_MAGNITUDE <= noise[k] <= MAX_PARAM:
            raise ConfigError(f"{path}: noise.{k}: must be {'' if k == 'range_sigma' else '0 or '}in "
                              f"[{MIN_MAGNITUDE:g}, {MAX_PARAM:g}] (an estimator parameter's bounds), got {v!r}")
    rows = data.get("links", [])
    if not isinstance(rows, list) or not all(isinstance(r, dict) for r in rows):
        raise ConfigError(f"{path}: links: expected [[links]] tables")
    cols = {c: [] for c, _, _ in CALIBRATION_SCHEMA}
    for i, r in enumerate(rows):
        for k, v in r.items():
            if k not in cols and k not in LINK_RECORD_KEYS:
                raise ConfigError(f"{path}: links[{i}].{k}: unknown key (known: {', '.join([*cols, *LINK_RECORD_KEYS])})")
            if k in LINK_RECORD_KEYS:
                _number(path, f"links[{i}].{k}", v, lo=0.0)
        for c, numeric, required in CALIBRATION_SCHEMA:
            v = r.get(c)
            if v is None and required:
                raise ConfigError(f"{path}: links[{i}].{c}: missing")
            if numeric:
                cols[c].append(np.nan if v is None else _number(path, f"links[{i}].{c}", v))
            elif v is not None and not isinstance(v, str):
                raise ConfigError(f"{path}: links[{i}].{c}: expected a name (string), got {v!r}")
            else:
                cols[c].append(v or "")
    table = Table(f"{path}: [[links]]", {c: np.array(cols[c], float if numeric else str)
                                         for c, numeric, _ in CALIBRATION_SCHEMA}, None)
    return CalibrationFile(path, _from_table(table, names) if rows else Calibration({}, {}), window, noise)
