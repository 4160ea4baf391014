"""Large swarms: swarm-grid scenarios scaled by count, range-gated UWB links by k-d tree, and the
sparse line-of-sight prefilter."""
from __future__ import annotations

import numpy as np
import pytest

from testbed.config import scenario
from testbed.errors import ConfigError
from testbed.sim.simulate import simulate


def _small_swarm(link_search: str, **uwb: str):
    """swarm-100 scaled to 24 vehicles on a 6-wide grid, 2 s prescribed, UWB at 5 Hz."""
    over = {"trajectory.count": "24", "trajectory.columns": "6", "sensors.uwb.link_search": f'"{link_search}"', **uwb}
    return scenario.load("swarm-100", over, motion="prescribed", duration=2.0)


def _links(log):
    return {(t, s, d): (c, n) for t, s, d, c, n in zip(log["uwb/time"].tolist(), log["uwb/src"].tolist(), log["uwb/dst"].tolist(),
                                                      log["uwb/clean"][:, 0].tolist(), log["uwb/nlos"].tolist())}


def test_count_scales_the_swarm_grid():
    sc = scenario.load("swarm-100", {"trajectory.count": "37"})
    assert sc.vehicles == 37
    bases = sc.trajectory.bases
    assert bases.shape == (37, 3)
    # rows of 10 along x, 40 m apart: vehicle 11 starts the second row
    np.testing.assert_allclose(bases[10] - bases[0], [0.0, 40.0, 0.0])
    with pytest.raises(ConfigError, match="count"):
        scenario.load("swarm-100", {"trajectory.count": "0"})
    with pytest.raises(ConfigError, match="apart"):
        scenario.load("swarm-100", {"trajectory.spacing": "[10.0, 10.0, 10.0]"})


def test_in_range_links_are_the_all_pairs_links_within_range():
    """Same measured links, true distances and NLOS flags as the all-pairs search (no losses)."""
    common = {"sensors.uwb.loss_prob": "0.0", "sensors.uwb.max_range": "45.0"}
    a, _ = simulate(_small_swarm("all-pairs", **common))
    b, _ = simulate(_small_swarm("in-range", **common))
    la, lb = _links(a), _links(b)
    assert len(la) > 100 and la.keys() == lb.keys()
    for key in la:
        assert lb[key][0] == pytest.approx(la[key][0], abs=1e-12) and lb[key][1] == la[key][1]
    tags = {(s, d) for _, s, d in la if not d.startswith("anchor")}
    assert 0 < len(tags) < 24 * 23 / 2  # range-gated: some pairs, not all of them


def test_in_range_link_bias_is_constant_per_pair():
    """Noise-free ranges minus true distance = the pair's constant bias, different across pairs."""
    quiet = {k: "0.0" for k in ("noise", "clock_ppm", "outlier_prob", "loss_prob", "nlos_bias_mean", "nlos_bias_per_m")}
    log, _ = simulate(_small_swarm("in-range", **{f"sensors.uwb.{k}": v for k, v in quiet.items()}, **{"sensors.uwb.link_bias_sigma": "0.5"}))
    bias = log["uwb/value"][:, 0] - log["uwb/clean"][:, 0]
    pairs = np.char.add(np.char.add(log["uwb/src"], ">"), log["uwb/dst"])
    per_pair = {p: bias[pairs == p] for p in np.unique(pairs)}
    assert all(len(v) >= 5 and np.ptp(v) < 1e-12 for v in per_pair.values())
    first = np.array([v[0] for v in per_pair.values()])
    assert len(np.unique(first)) == len(first) and 0.2 < first.std() < 1.0
