"""Defect 6 of issue 15: the seed 004 focal-plane covariance (eq. 8) of the filter equals the
camera's simulated noise at a focal length f != 1.

The camera (testbed/sensors/camera.py) adds eq. 8 noise to the NORMALISED coordinates
(a, b) = (alpha, beta) / f and reports alpha = f a: its covariance in m^2 is
f^2 sigma^2 R(a, b). The filter (estimators.visnav.RelNavModel.focal_noise) gets (alpha, beta) in m
and must evaluate eq. 8 at alpha / f, beta / f. Monte Carlo: the camera's errors whitened by the
filter's blocks are N(0, I_2) if and only if the two agree; the sum of squares of M whitened 2-D
errors is chi^2 with 2M dof, tested at 99.9 % (the interval follows from the sample size M).
"""
import numpy as np
import pytest
from scipy.linalg import cholesky, solve_triangular

from estimators.core import chi2_interval
from estimators.visnav import RelNavModel
from testbed.config import scenario
from testbed.plugins.builtin_visnav import estimator_config
from testbed.sim.simulate import simulate


def _whitened(f: float, seed: int) -> np.ndarray:
    """(M, 2) camera focal-plane errors whitened by the filter's eq. 8 blocks at the clean point."""
    sc = scenario.load("visnav", duration=6.0, seed=seed, overrides={
        "sensors.camera.focal_length": repr(f), "sensors.camera.glint_prob": "0.0"})
    log, _ = simulate(sc)
    model = RelNavModel(estimator_config(sc.pipeline, sc.seed, f))
    clean, value = log["camera/clean"][:, :2], log["camera/value"][:, :2]
    blocks = model.focal_noise(clean)
    return np.array([solve_triangular(cholesky(B, lower=True), e, lower=True)
                     for B, e in zip(blocks, value - clean)])


@pytest.mark.parametrize("f", [1.0, 8.0])
def test_filter_focal_covariance_matches_the_camera_noise(f):
    w = _whitened(f, seed=3)
    M = w.shape[0]
    assert M >= 200
    lo, hi = chi2_interval(2, M, 0.999)  # mean of M independent chi^2_2 samples, 99.9 %
    mean_nees = float(np.mean(np.sum(w ** 2, axis=1)))
    print(f"f = {f}: M = {M}, mean whitened |e|^2 = {mean_nees:.3f}, 99.9 % interval [{lo:.3f}, {hi:.3f}]")
    assert lo <= mean_nees <= hi
    # each component alone: chi^2 with M dof
    lo1, hi1 = chi2_interval(1, M, 0.999)
    for k in range(2):
        assert lo1 <= float(np.mean(w[:, k] ** 2)) <= hi1, k
