"""graph.poses's motion model (docs/replay.md, "graph.poses on sparse ranging"): the epoch solver's
state prior (estimators/graph/batch.py) against the general factor graph's pose priors, and the
belief's update (estimators/graph/motion.py, mo. 3) against the Kalman filter it must equal on a
linear model."""
from __future__ import annotations

import numpy as np

from estimators.graph.batch import EpochFactors, solve_epochs
from estimators.graph.model import Graph, PosePositionPrior, PoseRotationPrior, Range, solve_graph
from estimators.graph.motion import MotionBelief
from estimators.so3 import so3_exp

ANCHORS = np.array([[5.0, 0.0, 3.0], [0.0, 6.0, 0.5], [-4.0, -3.0, 2.0], [1.0, -6.0, 0.0]])
ARMS = np.array([[0.0, 0.3, 0.0], [0.0, -0.3, 0.0]])  # two tags on one line: the prior completes the pose


def _ranges(p, R):
    """Exact ranges from each tag to each anchor, with a fixed offset pattern so the prior matters."""
    rows = [(j, a) for j in range(len(ARMS)) for a in range(len(ANCHORS))]
    d = np.array([np.linalg.norm(p + R @ ARMS[j] - ANCHORS[a]) for j, a in rows])
    return rows, d + 0.03 * np.cos(np.arange(len(d)))


def test_the_state_prior_is_the_general_graphs_position_and_rotation_priors():
    """A pose with two tags (its rotation about the tag line unmeasured) and a prior on its position
    and attitude: batch.py's state prior (information form, one epoch) and model.py's
    PosePositionPrior + PoseRotationPrior (the same block-diagonal information) give the same
    solution and covariance."""
    p_true, R_true = np.array([0.5, 0.2, 1.0]), so3_exp(np.array([0.05, -0.1, 0.7]))
    rows, d = _ranges(p_true, R_true)
    sigma = 0.05
    p_mean, R_mean = p_true + np.array([0.1, -0.05, 0.2]), R_true @ so3_exp(np.array([0.1, 0.2, -0.05]))
    cov_p, cov_R = np.diag([0.04, 0.09, 0.25]), np.diag([0.01, 0.3, 0.02])
    f = EpochFactors(
        kinds=("pose",), r_epoch=np.zeros(len(rows), np.int64), r_a=np.zeros(len(rows), np.int64),
        r_b=np.full(len(rows), -1, np.int64), r_arm_a=np.array([ARMS[j] for j, _ in rows]),
        r_arm_b=np.array([ANCHORS[a] for _, a in rows]), r_d=d, r_sigma=np.full(len(rows), sigma),
        **EpochFactors.empty_rows(), x_p=p_mean[None, None], x_R=R_mean[None, None],
        x_info=np.linalg.inv(np.block([[cov_p, np.zeros((3, 3))], [np.zeros((3, 3)), cov_R]]))[None])
    res = solve_epochs(f, p_mean[None, None], R_mean[None, None], max_iter=100, step_tol=1e-12, cost_tol=1e-15)
    assert res.converged[0] and res.observable[0]

    g = Graph()
    g.add_variable("x", "pose")
    for n, a in enumerate(ANCHORS):
        g.add_variable(("a", n), "point", fixed=True)
    for (j, a), dk in zip(rows, d):
        g.add(Range("x", ("a", a), float(dk), sigma, lever_a=ARMS[j]))
    g.add(PosePositionPrior("x", p_mean, cov_p))
    g.add(PoseRotationPrior("x", R_mean, cov_R))
    ref = solve_graph(g, {"x": (p_mean, R_mean), **{("a", n): a for n, a in enumerate(ANCHORS)}}, max_iter=100)
    assert ref.converged
    p_ref, R_ref = ref.values["x"]
    assert np.abs(res.p[0, 0] - p_ref).max() < 1e-8
    assert np.abs(res.R[0, 0] - R_ref).max() < 1e-8
    assert np.abs(res.cov[0] - ref.cov["x"]).max() < 1e-8 * np.abs(ref.cov["x"]).max()


def test_the_belief_update_is_the_kalman_filter_on_a_linear_model():
    """Two point robots at constant velocity; an epoch measures robot a's position (a linear model):
    predicting and updating the belief (mo. 1-3, the epoch solved by solve_epochs with the belief's
    marginal as its state prior) gives the Kalman filter's mean and covariance over all twelve
    unknowns, robot b and both velocities updated through their correlation."""
    q = 0.3
    b = MotionBelief(q_t=q, q_r=0.0)
    cov_a = np.array([[0.2, 0.05, 0.0], [0.05, 0.3, 0.01], [0.0, 0.01, 0.1]])
    b.add("a", "point", 0.0, np.array([1.0, 2.0, 3.0]), np.eye(3), cov_a, v_sigma=0.5, rate_sigma=1.0)
    b.add("b", "point", 0.0, np.array([-1.0, 0.0, 2.0]), np.eye(3), 0.5 * np.eye(3), v_sigma=0.7, rate_sigma=1.0)
    # correlate the two robots as an earlier inter-robot range would have
    b.cov[0:3, 6:9] = b.cov[6:9, 0:3] = 0.1 * np.eye(3)
    b.v["a"], b.v["b"] = np.array([0.3, -0.2, 0.1]), np.array([0.0, 0.4, 0.0])
    x = np.concatenate([b.p["a"], b.v["a"], b.p["b"], b.v["b"]])
    C = b.cov.copy()

    dt, z, Rz = 0.4, np.array([1.2, 1.9, 3.1]), np.diag([0.01, 0.02, 0.015])
    F1 = np.block([[np.eye(3), dt * np.eye(3)], [np.zeros((3, 3)), np.eye(3)]])
    F = np.kron(np.eye(2), F1)
    Q1 = np.kron(np.array([[dt ** 3 / 3, dt ** 2 / 2], [dt ** 2 / 2, dt]]), q * np.eye(3))
    x, C = F @ x, F @ C @ F.T + np.kron(np.eye(2), Q1)
    H = np.zeros((3, 12))
    H[:, 0:3] = np.eye(3)
    K = C @ H.T @ np.linalg.inv(H @ C @ H.T + Rz)
    x_kf, C_kf = x + K @ (z - H @ x), (np.eye(12) - K @ H) @ C

    b.predict(dt)
    p0, R0, cov0 = b.prior(("a",))
    f = EpochFactors(kinds=("point",), r_epoch=np.zeros(0, np.int64), r_a=np.zeros(0, np.int64), r_b=np.zeros(0, np.int64),
                     r_arm_a=np.zeros((0, 3)), r_arm_b=np.zeros((0, 3)), r_d=np.zeros(0), r_sigma=np.zeros(0),
                     h_epoch=np.zeros(0, np.int64), h_var=np.zeros(0, np.int64), h_arm=np.zeros((0, 3)), h_z=np.zeros(0),
                     h_sigma=np.zeros(0), q_epoch=np.zeros(1, np.int64), q_var=np.zeros(1, np.int64), q_arm=np.zeros((1, 3)),
                     q_z=z[None], q_cov=Rz[None], x_p=p0[None], x_R=R0[None], x_info=np.linalg.inv(cov0)[None])
    res = solve_epochs(f, p0[None], R0[None], max_iter=20, step_tol=1e-12, cost_tol=1e-15)
    assert res.converged[0]
    b.update(("a",), res.p[0], res.R[0], res.cov[0])
    x_b = np.concatenate([b.p["a"], b.v["a"], b.p["b"], b.v["b"]])
    assert np.abs(x_b - x_kf).max() < 1e-10
    assert np.abs(b.cov - C_kf).max() < 1e-10
