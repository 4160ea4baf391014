"""Flooding (the accelerated distributed option): the centralized answer to 1 mm in at most 100
rounds at 18 and 100 UAVs, with honest round, message and byte counts."""
import numpy as np
import pytest

from estimators.factor_graph import CoopProblem, solve_centralized
from estimators.graph.flooding import GNSS_RECORD_BYTES, RANGE_RECORD_BYTES, solve_flooding
from testbed.synthetic.coop import epoch_factory


@pytest.mark.parametrize("n", [18, 100])
def test_flooding_reaches_the_centralized_answer_within_100_rounds(n):
    _, prob = epoch_factory()(n, 0)
    c = solve_centralized(prob)
    res = solve_flooding(prob)
    assert res.converged and 1 <= res.rounds <= 100
    assert np.linalg.norm(res.positions - c.positions, axis=1).max() < 1e-3
    assert np.allclose(res.cov, c.cov, rtol=1e-12, atol=0)
    assert res.positions_history.shape == (res.rounds + 1, n, 3)
    # every record crosses every UAV once: each UAV broadcasts each record at most once
    assert res.bytes_sent <= n * (n * GNSS_RECORD_BYTES + prob.m * RANGE_RECORD_BYTES)
    assert res.deliveries == n * (n - 1) + prob.m * (n - 2)  # records each UAV did not hold at the start


def test_flooding_rounds_are_the_hops_records_travel():
    # a chain 0-1-2-3: UAV 0 learns UAV 3's GNSS fix after 3 rounds, and knows it is complete then
    pos = np.array([[0.0, 0, 0], [10, 0, 0], [20, 0, 0], [30, 0, 0]])
    prob = CoopProblem(pos, np.tile(np.eye(3), (4, 1, 1)), np.array([[0, 1], [1, 2], [2, 3]]), np.full(3, 10.0), 0.1)
    res = solve_flooding(prob)
    assert res.rounds == 3 and res.converged
    short = solve_flooding(prob, max_rounds=2)
    assert not short.converged and np.array_equal(short.positions, pos)


def test_flooding_refuses_a_disconnected_graph():
    prob = CoopProblem(np.zeros((4, 3)) + np.arange(4)[:, None], np.tile(np.eye(3), (4, 1, 1)),
                       np.array([[0, 1], [2, 3]]), np.ones(2), 0.1)
    with pytest.raises(ValueError, match="not connected"):
        solve_flooding(prob)
