"""The seed 001 synthetic epoch generator of the tests: it lives in testbed.synthetic (the benchmark
uses it too); re-exported here under the name the tests import."""
import numpy as np

from testbed.synthetic import BOX, SyntheticEpoch, connected_positions, epoch_factory, is_connected, make_epoch

__all__ = ["BOX", "SyntheticEpoch", "connected_positions", "epoch_factory", "is_connected", "make_epoch", "nlos_epoch"]


def nlos_epoch(seed: int, bias: float = 5.0) -> tuple[SyntheticEpoch, int]:
    """An 18-UAV epoch (make_epoch seed 2000 + seed) whose range k between two SPP UAVs (drawn
    with Generator(seed)) carries a +bias metres NLOS error. Returns (epoch, k)."""
    ep0 = make_epoch(18, seed=2000 + seed)
    e0 = ep0.problem.edges
    cand = np.flatnonzero(~ep0.is_rtk[e0[:, 0]] & ~ep0.is_rtk[e0[:, 1]])
    k = int(np.random.default_rng(seed).choice(cand))
    return make_epoch(18, seed=2000 + seed, nlos={k: bias}), k
