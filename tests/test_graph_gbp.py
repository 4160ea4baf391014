"""Gaussian belief propagation (estimators.graph.gbp), the accelerated distributed option beside
the paper's scheme. Measured (testbed.synthetic swarms, tol 1e-6 m): 18 UAVs seeds 0/1 reach the
centralized optimum to 3e-5 / 4e-5 m in 331 / 398 rounds, where the consistent block-Jacobi
("fixed", damping 0.5) is still 0.44 / 0.18 m away after 1500 rounds; at 100 UAVs GBP is 4.6 cm
away after 1500 rounds. The issue's target (1 mm in <= 100 rounds at 18 and 100 UAVs) is NOT met."""
import numpy as np

from testbed.synthetic.coop import epoch_factory
from estimators.factor_graph import solve_centralized, solve_distributed
from estimators.graph.gbp import GBP_MESSAGE_BYTES, solve_gbp


def test_gbp_reaches_the_centralized_optimum_faster_than_block_jacobi():
    truth, p = epoch_factory()(18, 0)
    c = solve_centralized(p, method="lm", covariance="none")
    g = solve_gbp(p, max_rounds=600, tol=1e-6)
    assert g.converged
    assert np.linalg.norm(g.positions - c.positions, axis=1).max() < 1e-3
    assert g.messages == g.rounds * p.n and g.bytes_sent == g.messages * GBP_MESSAGE_BYTES
    j = solve_distributed(p, neighbour_model="fixed", damping=0.5, max_rounds=g.rounds, tol=1e-6)
    assert np.linalg.norm(j.positions - c.positions, axis=1).max() > 1e-2
    assert np.all(np.linalg.eigvalsh(g.cov) > 0)
