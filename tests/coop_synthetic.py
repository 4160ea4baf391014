"""The seed 001 synthetic epoch generator of the tests: it lives in testbed.synthetic (the benchmark
uses it too); re-exported here under the name the tests import."""
from testbed.synthetic import BOX, SyntheticEpoch, connected_positions, epoch_factory, is_connected, make_epoch

__all__ = ["BOX", "SyntheticEpoch", "connected_positions", "epoch_factory", "is_connected", "make_epoch"]
