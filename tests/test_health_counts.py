"""Issue 15 defect 4: repairs and non-convergence are counted (core.Track.health -> metrics.json),
never silenced."""
import warnings

import numpy as np
import pytest

from estimators.core import Epoch, Gaussian, counting, drive, symmetrize, tally
from estimators.sigma_filters import SpdRepairWarning, ensure_spd
from testbed.config import scenario
from testbed.plugins import builtin_visnav


def test_symmetrize_counts_asymmetry_beyond_roundoff_only():
    P = np.array([[2.0, 0.5], [0.5, 1.0]])
    with counting() as h:
        symmetrize(P + np.array([[0.0, 1e-15], [0.0, 0.0]]))  # round-off
    assert h.covariance_repairs == 0
    with counting() as h:
        S = symmetrize(P + np.array([[0.0, 1e-3], [0.0, 0.0]]))  # beyond round-off
    assert h.covariance_repairs == 1 and np.array_equal(S, S.T)


class _Faulty:
    """Predict repairs a covariance at every epoch; update rejects 2 rows and reports one
    non-converged iteration on every second epoch (counts through core.tally)."""

    def predict(self, b, dt, u=None):
        return Gaussian(b.mean, ensure_spd(np.diag([1.0, -1.0]), what="test covariance"))

    def update(self, b, m):
        tally(rejected_measurements=2, nonconverged_iterations=int(m % 2 == 0))
        return b


def test_track_health_totals_reach_metrics():
    prior = Gaussian(np.zeros(2), np.eye(2))
    with warnings.catch_warnings(record=True) as w:
        warnings.simplefilter("always")
        track = drive(_Faulty(), prior, [Epoch(float(k), k) for k in range(1, 6)], t0=0.0)
    assert track.health() == {"covariance_repairs": 5, "rejected_measurements": 10, "nonconverged_steps": 2}
    assert sum(issubclass(x.category, SpdRepairWarning) for x in w) == 5


def test_visnav_filters_do_not_silence_repair_warnings(monkeypatch):
    """The visnav pipeline used to wrap the driver in warnings.simplefilter("ignore", SpdRepairWarning);
    the visnav.* estimators step their filter with the warning left to reach the caller."""
    from testbed.plugins.context import make_context
    from testbed.plugins.priors import priors
    from testbed.sim.world import lever_arms
    from testbed.plugins.feed import measurements
    from testbed.sim.simulate import simulate

    class Repairing:  # a stepper whose every epoch repairs a covariance
        def __init__(self, filt, prior):
            self.prior = prior

        def step(self, epoch):
            ensure_spd(np.diag([1.0, -1.0]))
            return self.prior

    sc = scenario.load("visnav", duration=0.3)
    log, physics = simulate(sc)
    monkeypatch.setattr(builtin_visnav, "Stepper", Repairing)
    est = builtin_visnav.Ekf(make_context(sc, lever_arms(physics), "ekf", {}, priors(sc, log)), {})
    with pytest.warns(SpdRepairWarning):
        out = [e for m in measurements(sc, log) for e in est.process(m)] + est.finish()
    assert out and {q for e in out for q in e.quantities()} == {"position", "velocity", "attitude"}
