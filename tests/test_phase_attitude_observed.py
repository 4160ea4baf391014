"""Seed 003: the attitude directions the phase EKF does not observe are reported and left out of the
attitude ANEES (estimators.phase_model.unobserved_rotation_axes, PhaseScored's attitude scores)."""
from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from estimators.phase_model import ATTITUDE_SD_LIMIT_RAD, antenna_state_from_body, rotation_covariance, \
    unobserved_rotation_axes
from testbed.config import scenario as scenario_mod
from testbed.reproduce.phase_q import score_ekf
from testbed.sim.simulate import simulate


def _rotation_map(R: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The antenna state x (18,) of a follower at rest with attitude R, and G (18, 3): the antenna
    state's change per small rotation dphi in N (R -> Exp(dphi) R), by central differences."""
    def state(Rb):
        return antenna_state_from_body(np.zeros(3), np.zeros(3), Rb, np.zeros((3, 3)), 1.0, 1.0)

    h = 1e-6
    G = np.column_stack([(state(Rotation.from_rotvec(h * e).as_matrix() @ R)
                          - state(Rotation.from_rotvec(-h * e).as_matrix() @ R)) / (2 * h) for e in np.eye(3)])
    return state(R), G


def test_rotation_covariance_is_the_covariance_of_the_rotation_that_made_the_antenna_errors():
    """An 18-state covariance made by a rotation of covariance C (P = G C G^T) gives back C."""
    R = Rotation.from_euler("ZYX", [0.3, -0.2, 0.1]).as_matrix()
    x, G = _rotation_map(R)
    S = np.random.default_rng(3).standard_normal((3, 3)) * 0.01
    C = S @ S.T
    # central differences of a smooth map at h = 1e-6: error ~ h^2, far below 1e-6 of C
    np.testing.assert_allclose(rotation_covariance(x, G @ C @ G.T), C, rtol=0, atol=1e-6 * np.abs(C).max())


def test_unobserved_axes_are_the_ones_whose_sd_exceeds_the_limit():
    R = Rotation.from_euler("ZYX", [1.0, 0.2, -0.3]).as_matrix()
    x, G = _rotation_map(R)
    axis = np.array([1.0, 2.0, 2.0]) / 3.0
    Q = np.linalg.qr(np.column_stack([axis, np.eye(3)[:, :2]]))[0]  # Q[:, 0] = +-axis
    sd = np.array([3.0, 0.5, 0.2]) * ATTITUDE_SD_LIMIT_RAD
    got = unobserved_rotation_axes(x, G @ Q @ np.diag(sd ** 2) @ Q.T @ G.T)
    assert got.shape == (1, 3)
    assert abs(got[0] @ axis) == pytest.approx(1.0, abs=1e-9)
    assert unobserved_rotation_axes(x, G @ np.diag((sd[1:2].repeat(3)) ** 2) @ G.T).shape == (0, 3)


@pytest.fixture(scope="module")
def scores() -> dict[str, dict]:
    """phase.ekf's scores on 12 s of line H000 and cross H000 (seed 1): 2 s scored after score_start."""
    out = {}
    for name in ("phase-line-h000", "phase-cross-h000"):
        sc = scenario_mod.load(name, seed=1, duration=12.0)
        out[name] = score_ekf(sc, simulate(sc)[0])
    return out


def test_line_h000_reports_its_attitude_unobserved_and_scores_no_attitude_anees(scores):
    """Masters on one line at one height do not see the follower's rotation about axes across the
    line of sight (docs/papers.md, seed 003): the filter's own covariance puts those axes beyond
    the limit at every scored epoch, and the attitude ANEES is not computed from them."""
    m = scores["phase-line-h000"]
    assert m["attitude_unobserved_fraction"] == 1.0
    assert 1 <= len(m["attitude_unobserved_axes_final"]) <= 3
    assert "anees_attitude6" not in m


def test_cross_h000_observes_its_attitude_and_scores_it(scores):
    m = scores["phase-cross-h000"]
    assert m["attitude_unobserved_fraction"] == 0.0 and m["attitude_unobserved_axes_final"] == []
    assert m["anees_attitude6_dof"] == 6 and len(m["anees_attitude6_interval_99"]) == 2 and m["n_eff_attitude6"] >= 1
