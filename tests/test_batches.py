"""Batches across the plugin boundary: an EstimateBatch is collected exactly as its rows; a
MeasurementBatch (the swarm's IMU samples of one instant, a UWB epoch) gives exactly the
estimates its rows give one at a time, offline and in the control loop."""
import dataclasses

import numpy as np
import pytest

from testbed.config import scenario
from testbed.errors import PluginError
from testbed.plugins.api import Estimate, EstimateBatch, MeasurementBatch
from testbed.plugins.collect import Collector
from testbed.plugins.context import make_context
from testbed.sim.world import lever_arms
from testbed.plugins.feed import batched, measurements, run_plugin
from testbed.plugins.loading import resolve
from testbed.config.estimators import EstimatorSpec
from testbed.sim.simulate import simulate
from testbed.stream import stream_names


class _P:
    key, entry = "x", "x"


def _estimates(rng: np.random.Generator, k: int) -> list[EstimateBatch]:
    """Batches of positions (with covariances) and attitudes (without) of uav1-uav3, with ties in
    time between batches."""
    out = []
    for b in range(k):
        t = np.full(3, float(b // 2))
        A = rng.normal(size=(3, 3, 3))
        q = rng.normal(size=(3, 4))
        out += [EstimateBatch(time=t, target=["uav3", "uav1", "uav2"], quantity="position", value=rng.normal(size=(3, 3)),
                              cov=A @ np.swapaxes(A, 1, 2) + np.eye(3)),
                EstimateBatch(time=t, target=("uav1", "uav2", "uav3"), quantity="attitude",
                              value=q / np.linalg.norm(q, axis=1, keepdims=True))]
    return out


def test_an_estimate_batch_is_collected_exactly_as_its_rows():
    batches = _estimates(np.random.default_rng(1), 6)
    whole, rows = Collector(_P(), {"uav1", "uav2", "uav3"}, 10.0), Collector(_P(), {"uav1", "uav2", "uav3"}, 10.0)
    for k, b in enumerate(batches):
        whole.add([b], f"call {k}")
        rows.add(b.rows() if k % 2 else [b.rows()[0], dataclasses.replace(b, target=b.target[1:], time=b.time[1:],
                                                                           value=b.value[1:], cov=None if b.cov is None else b.cov[1:])],
                 f"call {k}")
    a, b = whole.track(), rows.track()
    assert sorted(a) == sorted(b) == [(v, q) for v in ("uav1", "uav2", "uav3") for q in ("attitude", "position")]
    for key in a:
        for f in ("time", "value", "cov", "has_cov"):
            np.testing.assert_array_equal(getattr(a[key], f), getattr(b[key], f))


@pytest.mark.parametrize("change, message", [
    (dict(target=["uav1", "uav9", "uav2"]), "estimate of uav9 position: unknown target"),
    (dict(value=np.array([[0.0, 0, 0], [0, np.nan, 0], [0, 0, 0]])), "estimate of uav2 position: value is not finite"),
    (dict(time=np.array([1.0, 11.0, 1.0])), "estimate of uav2 position: time 11.0 s is outside the run"),
    (dict(value=np.zeros((3, 4))), r"estimates of position \(a batch of 3\): value has shape \(3, 4\), expected \(3, 3\)"),
])
def test_a_bad_row_of_an_estimate_batch_is_named(change, message):
    good = EstimateBatch(time=np.ones(3), target=["uav1", "uav2", "uav3"], quantity="position", value=np.zeros((3, 3)),
                         cov=np.tile(np.eye(3), (3, 1, 1)))
    col = Collector(_P(), {"uav1", "uav2", "uav3"}, 10.0)
    with pytest.raises(PluginError, match=f"at t = 1 s: {message}"):
        col.add([dataclasses.replace(good, **change)], "at t = 1 s")


@pytest.mark.parametrize("change, message", [
    (dict(cov_joint=np.eye(6)), r"cov_joint has shape \(6, 6\), expected \(9, 9\) for 3 targets"),
    (dict(time=np.array([1.0, 1.0, 2.0])), "cov_joint needs rows of one time of validity"),
    (dict(cov_joint=np.triu(np.ones((9, 9))) + 9 * np.eye(9)), "cov_joint is not symmetric"),
    (dict(cov=None), r"cov_joint needs cov, its \(3, 3\) diagonal blocks"),
    (dict(cov=np.tile(2 * np.eye(3), (3, 1, 1))), r"cov_joint does not have cov as its \(3, 3\) diagonal blocks"),
])
def test_a_joint_covariance_is_checked_and_kept(change, message):
    """EstimateBatch.cov_joint: kept per quantity (Track.joint) when it fits the batch, else named."""
    C = np.eye(9) + 0.1 * (np.ones((9, 9)) - np.kron(np.eye(3), np.ones((3, 3))))  # cross-covariances only
    good = EstimateBatch(time=np.ones(3), target=["uav2", "uav1", "uav3"], quantity="position", value=np.zeros((3, 3)),
                         cov=np.tile(np.eye(3), (3, 1, 1)), cov_joint=C)
    col = Collector(_P(), {"uav1", "uav2", "uav3"}, 10.0)
    col.add([good], "at t = 1 s")
    (j,) = col.track().joint["position"]
    assert (j.time, j.targets, j.frame) == (1.0, ("uav2", "uav1", "uav3"), "world") and np.array_equal(j.cov, C)
    with pytest.raises(PluginError, match=f"at t = 1 s: estimates of position \\(a batch of 3\\): {message}"):
        Collector(_P(), {"uav1", "uav2", "uav3"}, 10.0).add([dataclasses.replace(good, **change)], "at t = 1 s")


def test_a_batch_of_several_quantities_of_one_target_is_scored_as_its_rows_with_its_joint_covariance():
    """Rows of position, velocity and attitude of one target (quantity one per row): each row lands
    in its own series exactly as a single Estimate would, the (9, 9) cov_joint under the tuple of
    quantities; a cov_joint whose blocks are not cov is named."""
    C = np.eye(9) + 0.1 * (np.ones((9, 9)) - np.kron(np.eye(3), np.ones((3, 3))))
    q = np.array([0.5, 0.5, 0.5, 0.5])
    b = EstimateBatch(time=np.full(3, 2.0), target=("uav2",) * 3, quantity=("position", "velocity", "attitude"),
                      value=[np.ones(3), 2 * np.ones(3), q], cov=np.tile(np.eye(3), (3, 1, 1)), frame="uav1", cov_joint=C)
    col = Collector(_P(), {"uav1", "uav2"}, 10.0, frames={"world", "uav1"})
    col.add([b], "at t = 2 s")
    track = col.track()
    single = Collector(_P(), {"uav1", "uav2"}, 10.0, frames={"world", "uav1"})
    single.add(b.rows(), "at t = 2 s")
    for key, s in single.track().items():
        assert all(np.array_equal(getattr(s, f), getattr(track[key], f)) for f in ("time", "value", "cov", "has_cov"))
        assert track[key].frame == "uav1"
    (j,) = track.joint[("position", "velocity", "attitude")]
    assert (j.time, j.targets, j.frame) == (2.0, ("uav2",) * 3, "uav1") and np.array_equal(j.cov, C)
    bad = dataclasses.replace(b, cov=np.tile(2 * np.eye(3), (3, 1, 1)))
    with pytest.raises(PluginError, match=r"estimates of position/velocity/attitude \(a batch of 3\): cov_joint does not have cov"):
        Collector(_P(), {"uav1", "uav2"}, 10.0, frames={"world", "uav1"}).add([bad], "at t = 2 s")
    with pytest.raises(PluginError, match="quantity must be one of"):
        Collector(_P(), {"uav1", "uav2"}, 10.0, frames={"world", "uav1"}).add(
            [dataclasses.replace(b, quantity=("position", "speed", "attitude"))], "at t = 2 s")


def test_the_first_bad_covariance_of_a_batch_is_named_when_the_track_is_built():
    cov = np.tile(np.eye(3), (3, 1, 1))
    cov[2] = -np.eye(3)
    col = Collector(_P(), {"uav1", "uav2", "uav3"}, 10.0)
    col.add([Estimate(time=0.5, target="uav1", quantity="position", value=np.zeros(3), cov=np.eye(3))], "at t = 0.5 s")
    col.add([EstimateBatch(time=np.ones(3), target=["uav1", "uav2", "uav3"], quantity="position", value=np.zeros((3, 3)),
                           cov=cov)], "at t = 1 s")
    with pytest.raises(PluginError, match=r"at t = 1 s: estimate of uav3 position: cov is not positive definite"):
        col.track()


@pytest.fixture(scope="module")
def denied_log():
    """coop-denied, 3 s on the truth, every sensor; coop.ins and coop.ins_distributed resolved."""
    sc = scenario.load("coop-denied", duration=3.0, overrides={"control.feedback": "truth"})
    sc = dataclasses.replace(sc, estimators=(EstimatorSpec(entry="coop.ins", name="c"),
                                             EstimatorSpec(entry="coop.ins_distributed", name="d")))
    log, physics = simulate(sc)
    return sc, log, physics


def test_the_batched_feed_is_the_row_feed_in_runs(denied_log):
    sc, log, _ = denied_log
    rows = list(measurements(sc, log))
    items = list(batched(sc, log))
    assert any(isinstance(b, MeasurementBatch) and b.stream == "imu" for b in items)
    assert any(isinstance(b, MeasurementBatch) and b.stream == "uwb" for b in items)
    unrolled = [m for b in items for m in (b.rows() if isinstance(b, MeasurementBatch) else [b])]
    assert len(unrolled) == len(rows)
    for a, b in zip(unrolled, rows):
        assert (a.stream, a.time, a.arrival, a.src, a.dst) == (b.stream, b.time, b.arrival, b.src, b.dst)
        np.testing.assert_array_equal(a.value, b.value)
        np.testing.assert_array_equal(a.sigma, b.sigma)


def test_streams_without_a_row_feed_nothing_both_ways(denied_log):
    """A log whose streams are all empty (a swarm moved out of every range) feeds nothing, row by row
    or batched (batched raised an IndexError)."""
    sc, log, _ = denied_log
    names = set(stream_names(log))
    empty = {k: v[:0] if k.split("/")[0] in names else v for k, v in log.items()}
    assert names and list(measurements(sc, empty)) == [] and list(batched(sc, empty)) == []


@pytest.mark.parametrize("key", ["c", "d"])
def test_coop_ins_gives_the_same_estimates_from_batches_as_from_rows(denied_log, key):
    """process_batch (IMU instants and UWB epochs at once) == process row by row, bit for bit."""
    sc, log, physics = denied_log
    plugin = next(p for p in resolve(sc.estimators) if p.key == key)
    tracks = [run_plugin(plugin, make_context(sc, lever_arms(physics), plugin.key, plugin.params), feed)[0]
              for feed in (list(batched(sc, log)), list(measurements(sc, log)))]
    assert sorted(tracks[0]) == sorted(tracks[1]) and len(tracks[0]) == 3 * sc.vehicles
    for k in tracks[0]:
        for f in ("time", "value", "cov"):
            np.testing.assert_array_equal(getattr(tracks[0][k], f), getattr(tracks[1][k], f))
