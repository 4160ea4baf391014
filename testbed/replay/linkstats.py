"""Per-link residual statistics of a recorded dataset against its truth (metrics.json `links`).

For every (kind, src, dst) of links.csv: the residual measured minus true, where true is the
distance between the two sites (m) for uwb and phase, and its rate u . (v_src - v_dst) (m/s) for
range-rate, the sites' positions and velocities from the truth of their bodies and their lever
arms (testbed.plugins.truth), anchors fixed. samples, mean, std (population), RMSE, in m or m/s.
A link whose ends lack truth at a row's time (outside the truth's span, no truth velocity for a
range rate) leaves that row out and counts it under `unscored`.
"""
from __future__ import annotations

import numpy as np

from testbed.replay.recording import RecordedTruth, Recording


def _covered(truth: RecordedTruth, end: str, t: np.ndarray, quantity: str) -> np.ndarray:
    if end in truth.anchors:
        return np.ones(t.size, bool)
    if not truth.known(end, quantity):
        return np.zeros(t.size, bool)
    lo, hi = truth.span[truth.body_of(end)]
    return (t >= lo) & (t <= hi)


class _EndTruth:
    """Truth of link ends at the times of their rows, each end evaluated once per distinct time it
    is needed at (an end is in many links: an antenna ranges every antenna of the other robots).
    rows_of: {end: rows of links.csv it is an end of}; time: (N,) s window clock."""

    def __init__(self, truth: RecordedTruth, time: np.ndarray, rows_of: dict[str, np.ndarray]):
        self.truth, self.time, self.rows_of = truth, time, rows_of
        self.cache: dict[tuple[str, str], tuple[np.ndarray, np.ndarray]] = {}

    def at(self, end: str, quantity: str, rows: np.ndarray) -> np.ndarray:
        """Truth (len(rows), 3) of `end` at the times of rows (all covered by its truth)."""
        if (end, quantity) not in self.cache:
            tu = np.unique(self.time[self.rows_of[end]])
            tu = tu[_covered(self.truth, end, tu, quantity)]
            self.cache[(end, quantity)] = (tu, self.truth.at(end, quantity, tu))
        tu, value = self.cache[(end, quantity)]
        return value[np.searchsorted(tu, self.time[rows])]


def _true(ends: _EndTruth, kind: str, src: str, dst: str, rows: np.ndarray) -> np.ndarray:
    diff = ends.at(src, "position", rows) - ends.at(dst, "position", rows)
    dist = np.linalg.norm(diff, axis=1)
    if kind != "range-rate":
        return dist
    u = diff / np.where(dist > 0, dist, 1.0)[:, None]
    return np.einsum("ni,ni->n", u, ends.at(src, "velocity", rows) - ends.at(dst, "velocity", rows))


def link_statistics(rec: Recording, truth: RecordedTruth) -> dict:
    """{kind: {"SRC->DST": {samples, mean, std, rmse, unscored}}} with units m (m/s for range-rate)."""
    if "links" not in rec.tables:
        return {}
    t = rec.tables["links"]
    time = t["time"] - rec.spec.window.start
    out: dict = {}
    keys = np.char.add(np.char.add(np.char.add(t["kind"], "\n"), np.char.add(t["src"], "->")), t["dst"])
    names, inverse = np.unique(keys, return_inverse=True)  # sorted keys; rows of key k: inverse == k
    order = np.argsort(inverse, kind="stable")
    bounds = np.searchsorted(inverse[order], np.arange(names.size + 1))
    links = []  # (kind, "SRC->DST", src, dst, rows)
    rows_of: dict[str, list[np.ndarray]] = {}
    for k, key in enumerate(names.tolist()):
        kind, link = key.split("\n")
        src, dst = link.split("->")
        rows = order[bounds[k]:bounds[k + 1]]
        links.append((kind, link, src, dst, rows))
        for end in (src, dst):
            rows_of.setdefault(end, []).append(rows)
    ends = _EndTruth(truth, time, {end: np.concatenate(r) for end, r in rows_of.items()})
    for kind, link, src, dst, rows in links:
        q = "velocity" if kind == "range-rate" else "position"
        ok = _covered(truth, src, time[rows], q) & _covered(truth, dst, time[rows], q)
        res = t["value"][rows][ok] - _true(ends, kind, src, dst, rows[ok]) if ok.any() else np.zeros(0)
        u = "m_s" if kind == "range-rate" else "m"
        stats = {"samples": int(res.size), "unscored": int((~ok).sum())}
        if res.size:
            stats.update({f"mean_{u}": float(res.mean()), f"std_{u}": float(res.std()),
                          f"rmse_{u}": float(np.sqrt(np.mean(res ** 2)))})
        out.setdefault(kind, {})[link] = stats
    return out
