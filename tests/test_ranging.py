"""The generalized ranging EKF (estimators.ranging, issue 16): any antennas, lever arms, height aid."""
import dataclasses

import numpy as np
import pytest

from estimators.core import Epoch, Gaussian, chi2_interval, counting, drive, nees
from estimators.geometry import DegenerateGeometryError
from estimators.phase_ekf import PhaseEkf, PhaseMeasurement
from estimators.phase_model import measurement_model
from estimators.ranging import (
    RangingEkf,
    RangingEpoch,
    RangingNoise,
    body_pose,
    fit_pose,
    from_phase_measurement,
    initial_belief,
    known_points,
    multilaterate,
    pose_sensitivity,
    process_noise,
    ranging_model,
    transition,
)
from estimators.so3 import quat_exp, quat_log, quat_to_rotmat, rotmat_to_quat
from testbed.plugins.api import Context, Measurement
from testbed.plugins.loading import check_protocol, load_class
from testbed.plugins.ranging import RangingEkfEstimator


def _central(f, x, h):
    cols = [(f(x + h * e) - f(x - h * e)) / (2 * h) for e in np.eye(x.size)]
    return np.stack(cols, axis=-1)


def _random_epoch(rng, n, rates, window, height):
    L = int(rng.integers(1, 12))
    return RangingEpoch(
        antenna=rng.integers(0, n, L), known_pos=rng.uniform(-5, 5, (L, 3)), ranges=np.ones(L),
        range_rates=np.ones(L) if rates else None, known_vel=rng.normal(0, 1, (L, 3)) if rates else None,
        rate_window=(rng.uniform(0.1, 1.0, L) if window else None),
        height=1.0 if height else None, height_weights=rng.dirichlet(np.ones(n)) if height else None)


@pytest.mark.parametrize("seed", range(8))
def test_jacobian_matches_central_differences_for_random_antennas_and_links(seed):
    rng = np.random.default_rng(seed)
    n = int(rng.integers(1, 7))
    for rates, window, height in ((False, False, False), (True, False, True), (True, True, True)):
        ep = _random_epoch(rng, n, rates, window, height)
        x = np.concatenate([rng.uniform(-5, 5, 3 * n), rng.normal(0, 1, 3 * n)])
        h, H = ranging_model(x, n, ep)
        assert h.shape == (ep.n_links * (2 if rates else 1) + int(height),) and H.shape == (h.size, 6 * n)
        Hn = _central(lambda y: ranging_model(y, n, ep)[0], x, 1e-6)
        assert np.allclose(H, Hn, rtol=1e-6, atol=1e-7)


@pytest.mark.parametrize("seed", range(4))
def test_jacobian_with_bias_states_matches_central_differences(seed):
    """Bias states after the 6 n antenna states (docs/replay.md, "Range bias"): each link's range
    gains its bias state (or none), the rates and the height do not."""
    rng = np.random.default_rng(seed)
    n, b = int(rng.integers(1, 5)), int(rng.integers(1, 5))
    ep = _random_epoch(rng, n, True, False, True)
    ep = dataclasses.replace(ep, bias=rng.integers(-1, b, ep.n_links))
    x = np.concatenate([rng.uniform(-5, 5, 3 * n), rng.normal(0, 1, 3 * n), rng.normal(0, 0.3, b)])
    h, H = ranging_model(x, n, ep)
    h0, _ = ranging_model(x[:6 * n], n, dataclasses.replace(ep, bias=None))
    k = np.asarray(ep.bias)
    assert H.shape == (h.size, 6 * n + b)
    np.testing.assert_allclose(h[:ep.n_links], h0[:ep.n_links] + np.where(k >= 0, x[6 * n + np.maximum(k, 0)], 0.0), rtol=0, atol=1e-12)
    np.testing.assert_allclose(h[ep.n_links:], h0[ep.n_links:], rtol=0, atol=0)
    assert np.allclose(H, _central(lambda y: ranging_model(y, n, ep)[0], x, 1e-6), rtol=1e-6, atol=1e-7)


@pytest.mark.parametrize("seed", range(4))
def test_jacobian_with_time_offsets_matches_central_differences(seed):
    """A link's time offset c (docs/calibration.md, cal. 10): its range row becomes
    |x_j - X_l| + c u^T (v_j - V_l), the distance at t + c to first order, with its Jacobian (and
    bias states beside it)."""
    rng = np.random.default_rng(seed)
    n, b = int(rng.integers(1, 5)), 2
    ep = _random_epoch(rng, n, True, False, True)
    L = ep.n_links
    V = rng.normal(0, 1, (L, 3))
    ep = dataclasses.replace(ep, offset=rng.uniform(-0.2, 0.2, L), known_vel=V, bias=rng.integers(-1, b, L))
    x = np.concatenate([rng.uniform(-5, 5, 3 * n), rng.normal(0, 1, 3 * n), rng.normal(0, 0.3, b)])
    h, H = ranging_model(x, n, ep)
    h0, _ = ranging_model(x, n, dataclasses.replace(ep, offset=None))
    P, Vj = x[:3 * n].reshape(n, 3)[ep.antenna], x[3 * n:6 * n].reshape(n, 3)[ep.antenna]
    u = (P - ep.known_pos) / np.linalg.norm(P - ep.known_pos, axis=1)[:, None]
    np.testing.assert_allclose(h[:L], h0[:L] + ep.offset * np.einsum("lk,lk->l", u, Vj - V), rtol=0, atol=1e-12)
    np.testing.assert_allclose(h[L:], h0[L:], rtol=0, atol=0)
    assert np.allclose(H, _central(lambda y: ranging_model(y, n, ep)[0], x, 1e-6), rtol=1e-6, atol=1e-7)


def test_bias_states_are_held_or_walk_in_the_time_update():
    """Phi keeps a bias; Q adds bias_walk dt to its variance (0: a random constant)."""
    n, b, dt = 2, 3, 0.5
    belief = Gaussian(np.zeros(6 * n + b), np.eye(6 * n + b))
    for walk in (0.0, 0.02):
        post = RangingEkf(n=n, bias_walk=walk).predict(belief, dt)
        np.testing.assert_allclose(np.diag(post.cov)[6 * n:], 1.0 + walk * dt, rtol=1e-12)
        np.testing.assert_allclose(post.cov[6 * n:, :6 * n], 0.0, atol=0)


@pytest.mark.parametrize("seed", range(6))
def test_pose_fit_sensitivity_matches_central_differences_for_random_lever_arms(seed):
    """G = (A^T A)^-1 A^T is the derivative of the Kabsch fit at a zero-residual point."""
    rng = np.random.default_rng(100 + seed)
    n = int(rng.integers(3, 7))
    arms = rng.uniform(-0.5, 0.5, (n, 3))
    R0 = quat_to_rotmat(quat_exp(rng.normal(0, 1, 3)))
    p0 = rng.uniform(-3, 3, 3)
    x0 = (p0 + arms @ R0.T).reshape(-1)
    p, R = fit_pose(x0.reshape(n, 3), arms)
    assert np.allclose(p, p0, atol=1e-12) and np.allclose(R, R0, atol=1e-12)

    def f(x):
        pf, Rf = fit_pose(x.reshape(n, 3), arms)
        return np.concatenate([pf, quat_log(rotmat_to_quat(R0.T @ Rf))])

    assert np.allclose(pose_sensitivity(R0, arms), _central(f, x0, 1e-6), atol=1e-7)


def test_known_points_of_a_moving_body_match_differentiated_positions():
    rng = np.random.default_rng(7)
    arms, p, v, w = rng.normal(0, 0.5, (4, 3)), rng.normal(0, 2, 3), rng.normal(0, 1, 3), rng.normal(0, 1, 3)
    q = quat_exp(rng.normal(0, 1, 3))
    X, V = known_points(p, q, arms, v, w)
    R = quat_to_rotmat(q)
    assert np.allclose(X, p + arms @ R.T)
    dt = 1e-6  # d/dt (p + R l) with R' = R [w]x (body-frame rate)
    Xp, _ = known_points(p + v * dt, rotmat_to_quat(R @ quat_to_rotmat(quat_exp(w * dt))), arms)
    assert np.allclose((Xp - X) / dt, V, atol=1e-5)


def test_the_paper_configuration_is_one_instance():
    """Three antennas, M = 5 three-antenna masters, ranges and range rates (instantaneous and
    windowed): the generalized model is the paper's rows permuted, and RangingEkf(n = 3) gives
    PhaseEkf's posterior to round-off over several epochs."""
    rng = np.random.default_rng(3)
    M = 5
    X0 = rng.uniform(-30, 30, (M, 3, 3))
    V0 = rng.normal(0, 0.2, (M, 3, 3))
    x = np.concatenate([rng.uniform(-3, 3, 9), rng.normal(0, 1, 9)])
    for window in (None, 0.7):
        h_paper, H_paper = measurement_model(x, X0, V0, rate_window=window)
        meas = PhaseMeasurement(ranges=np.zeros((M, 3, 3)), range_rates=np.zeros((M, 3, 3)), master_pos=X0,
                                master_vel=V0, rate_window=window)
        h, H = ranging_model(x, 3, from_phase_measurement(meas))
        # generalized rows: all 9M ranges then all 9M rates; paper: per master 9 ranges, 9 rates
        perm = np.arange(18 * M).reshape(M, 2, 9).transpose(1, 0, 2).reshape(-1)
        assert np.allclose(h, h_paper[perm], rtol=1e-14) and np.allclose(H, H_paper[perm], rtol=1e-12, atol=1e-15)
    q = 1e-3
    paper, general = PhaseEkf(q=q), RangingEkf(n=3, q=RangingNoise(antenna=q))
    b_paper = b_gen = Gaussian(x + rng.normal(0, 0.1, 18), np.diag([0.01] * 9 + [0.04] * 9))
    truth = x.copy()
    for k in range(5):
        truth = transition(0.1, 3) @ truth
        h_true, _ = measurement_model(truth, X0, V0)
        z = h_true + rng.normal(0, 0.01, h_true.size)
        zr = z.reshape(M, 2, 3, 3)
        meas = PhaseMeasurement(ranges=zr[:, 0], range_rates=zr[:, 1], master_pos=X0, master_vel=V0,
                                sigma_range=0.01, sigma_range_rate=0.01)
        b_paper = paper.update(paper.predict(b_paper, 0.1), meas)
        b_gen = general.update(general.predict(b_gen, 0.1), from_phase_measurement(meas))
        assert np.allclose(b_gen.mean, b_paper.mean, rtol=0, atol=1e-11)
        assert np.allclose(b_gen.cov, b_paper.cov, rtol=1e-9, atol=1e-16)


# ------------------------------------------------------------------ multilateration
def test_multilaterate_says_when_it_cannot_answer():
    p = np.array([2.0, 1.0, 2.0])
    cube = np.array([[0.0, 0, 0], [4, 0, 0], [0, 4, 0], [0, 0, 4], [4, 4, 1]])
    fix = multilaterate(cube, np.linalg.norm(p - cube, axis=1), 0.05)
    assert fix.converged and fix.span == 3 and np.allclose(fix.position, p, atol=1e-9)
    with pytest.raises(DegenerateGeometryError, match="2 ranges, at least 3"):
        multilaterate(cube[:2], np.linalg.norm(p - cube[:2], axis=1), 0.05)
    line = np.array([[0.0, 0, 0], [1, 0, 0], [2, 0, 0], [3, 0, 0]])
    with pytest.raises(DegenerateGeometryError, match="one line"):
        multilaterate(line, np.linalg.norm(p - line, axis=1), 0.05)
    plane = np.array([[0.0, 0, 1], [4, 0, 1], [0, 4, 1], [4, 4, 1]])
    r = np.linalg.norm(p - plane, axis=1)
    with pytest.raises(DegenerateGeometryError, match="mirror ambiguity .no height aid"):
        multilaterate(plane, r, 0.05)
    # the mirror image p' = (2, 1, 0) fits the ranges exactly; the height picks the true one
    for h_aid, expect in ((2.1, p), (0.2, np.array([2.0, 1.0, 0.0]))):
        fix = multilaterate(plane, r, 0.05, height=h_aid, sigma_height=0.2)
        # the aid is 0.1 m off (half its sigma): the weighted fix moves by a fraction of that
        assert fix.span == 2 and np.linalg.norm(fix.position - expect) < 0.1
    vertical = np.array([[0.0, 0, 0], [0, 4, 0], [0, 0, 4], [0, 4, 4]])  # plane x = 0: images differ in x
    with pytest.raises(DegenerateGeometryError, match="height does not tell the side"):
        multilaterate(vertical, np.linalg.norm(p - vertical, axis=1), 0.05, height=2.0, sigma_height=0.1)


def test_degenerate_link_in_a_filter_run_is_skipped_and_counted():
    """A known point that coincides with the estimated antenna has no line of sight: the row is
    skipped and counted, the run goes on; an epoch without usable rows leaves the belief alone."""
    ekf = RangingEkf(n=1, q=RangingNoise(antenna=1e-3))
    prior = Gaussian(np.array([1.0, 2.0, 3.0, 0.0, 0.0, 0.0]), np.eye(6))
    anchors = np.array([[1.0, 2.0, 3.0], [5.0, 0.0, 0.0], [0.0, 5.0, 0.0], [0.0, 0.0, 6.0]])
    ep = RangingEpoch(antenna=np.zeros(4, int), known_pos=anchors, ranges=np.linalg.norm(anchors - [1.2, 2.0, 3.0], axis=1))
    only_bad = RangingEpoch(antenna=np.zeros(1, int), known_pos=anchors[:1], ranges=np.array([0.3]))
    track = drive(ekf, prior, [Epoch(0.0, only_bad), Epoch(0.5, ep), Epoch(1.0, None)])
    assert track.skipped_updates.tolist() == [1, 1, 0]
    assert np.array_equal(track.beliefs[0].mean, prior.mean)
    assert np.all(np.isfinite(track.mean)) and np.linalg.norm(track.mean[-1, :3] - [1.2, 2.0, 3.0]) < 0.05
    with counting() as h:
        post = ekf.update(prior, only_bad)
    assert h.skipped_updates == 1 and post is prior


# ------------------------------------------------------------------ 6 + 6 antennas, planar arrays, height aid
def _hexagon(radius):
    a = np.arange(6) * np.pi / 3
    return np.stack([radius * np.cos(a), radius * np.sin(a), np.zeros(6)], axis=1)


def test_six_antenna_planar_arrays_with_height_aid_converge_within_their_covariance():
    """Two robots with flat 6-antenna arrays (36 ranges per epoch, ~3.3 m): the known robot's
    array spans a horizontal plane, so ranges alone leave each follower antenna's mirror image
    through that plane; the height aid resolves it in the initial fix (a rigid 6-DOF fix from
    the lever arms, with a level prior of 0.05 rad: ground robots, level truth), and the EKF
    stays consistent. Model-matched truth (the filter's own CV model and Q), R runs, final epoch:
    the ANEES of the 36-state and of the fitted body pose (position + attitude, 6 dof) lie in
    their chi-square 99 % intervals for R runs (core.chi2_interval)."""
    n, runs, epochs, dt = 6, 24, 40, 0.5
    arms = _hexagon(0.5)
    q = RangingNoise(antenna=1e-6, translation=1e-3)
    ekf = RangingEkf(n=n, q=q)
    F, Q = transition(dt, n), process_noise(dt, n, q, np.zeros(6 * n))
    Lq = np.linalg.cholesky(Q)
    Xk, _ = known_points(np.array([0.0, 0.0, 1.0]), np.array([1.0, 0, 0, 0]), _hexagon(0.4))
    link_j = np.repeat(np.arange(n), 6)
    link_X = np.tile(Xk, (n, 1))
    sr, sh = 0.05, 0.05
    rng = np.random.default_rng(2024)
    nees_state, nees_pose, mirrored = [], [], 0
    for _ in range(runs):
        yaw = rng.uniform(-np.pi, np.pi)
        R_true = quat_to_rotmat(quat_exp(np.array([0.0, 0.0, yaw])))
        p_true = np.array([2.5, 1.0, 3.0]) + rng.normal(0, 0.1, 3)
        x = np.concatenate([(p_true + arms @ R_true.T).reshape(-1), np.tile(np.r_[rng.normal(0, 0.1, 2), 0.0], n)])
        belief = None
        for k in range(epochs):
            if k:
                x = F @ x + Lq @ rng.standard_normal(6 * n)
            P = x[:3 * n].reshape(n, 3)
            r = np.linalg.norm(P[link_j] - link_X, axis=1) + rng.normal(0, sr, link_j.size)
            ep = RangingEpoch(antenna=link_j, known_pos=link_X, ranges=r, sigma_range=sr,
                              height=P[:, 2].mean() + rng.normal(0, sh), sigma_height=sh)
            if belief is None:
                with pytest.raises(DegenerateGeometryError, match="mirror"):
                    initial_belief(RangingEpoch(antenna=link_j, known_pos=link_X, ranges=r), n, arms)
                belief = initial_belief(ep, n, arms, v_cov=0.1 ** 2, level_sigma=0.05)
                mirrored += int(np.any(np.abs(belief.mean[2:3 * n:3] - P[:, 2]) > 1.0))
            else:
                belief = ekf.predict(belief, dt)
            belief = ekf.update(belief, ep)
        nees_state.append(float(nees(belief.mean - x, belief.cov)))
        pose = body_pose(belief, arms)
        p_fit, R_fit = fit_pose(x[:3 * n].reshape(n, 3), arms)
        e = np.concatenate([pose.position - p_fit, quat_log(rotmat_to_quat(R_fit.T @ quat_to_rotmat(pose.quat)))])
        nees_pose.append(float(nees(e, pose.cov[:6, :6])))
    assert mirrored == 0
    lo, hi = chi2_interval(6 * n, runs, 0.99)
    assert lo <= np.mean(nees_state) <= hi, (np.mean(nees_state), lo, hi)
    lo, hi = chi2_interval(6, runs, 0.99)
    assert lo <= np.mean(nees_pose) <= hi, (np.mean(nees_pose), lo, hi)


def test_one_antenna_follower_has_no_body_pose_but_a_position():
    rng = np.random.default_rng(5)
    anchors = rng.uniform(-5, 5, (5, 3))
    p = np.array([0.5, -0.3, 1.2])
    ep = RangingEpoch(antenna=np.zeros(5, int), known_pos=anchors, ranges=np.linalg.norm(anchors - p, axis=1), sigma_range=0.01)
    b = initial_belief(ep, 1)
    assert np.allclose(b.mean[:3], p, atol=1e-9) and b.cov.shape == (6, 6)
    assert body_pose(b, np.zeros((1, 3))) is None
    assert body_pose(Gaussian(np.zeros(18), np.eye(18)), np.array([[0.0, 0, 0], [1, 0, 0], [2, 0, 0]])) is None


# ------------------------------------------------------------------ the plugin (testbed/plugins/ranging.py)
def test_plugin_tracks_a_follower_from_known_poses_ranges_and_height():
    """Fed one Measurement at a time as by testbed.plugins.feed: uav1's pose on the "mocap" stream (the default)
    (known, moving), 6 x 6 UWB ranges, uav2's height. The plugin builds its prior from the first
    epoch, estimates every antenna and the body (position, attitude) within a few sigma, and skips
    and counts an epoch that cannot start the filter (ranges with no height: mirror ambiguity)."""
    entry = "testbed.plugins.ranging:RangingEkfEstimator"  # the entry point the lead registers
    check_protocol(entry, load_class(entry))

    arms1, arms2 = _hexagon(0.4), _hexagon(0.5)
    sites = {f"uav{b}/ant{k + 1}": (f"uav{b}", a) for b, arms in ((1, arms1), (2, arms2)) for k, a in enumerate(arms)}
    ctx = Context(vehicles=("uav1", "uav2"), sites=sites, anchors={}, sensors={}, duration=30.0, seed=0,
                  rng=np.random.default_rng(0))
    est = RangingEkfEstimator(ctx, {"follower": "uav2", "range_sigma": 0.05, "height_sigma": 0.05, "level_sigma": 0.05,
                                    "q": 1e-6, "q_translation": 1e-3, "q_rotation": 1e-4, "v_sigma": 0.1})
    assert est.antennas == [f"uav2/ant{k}" for k in range(1, 7)]  # by default every site of the follower
    rng = np.random.default_rng(11)
    q2 = quat_exp(np.array([0.0, 0.0, 0.7]))
    R2 = quat_to_rotmat(q2)
    out = []
    for k in range(31):
        t = float(k)
        p1 = np.array([0.1 * t, 0.0, 1.0])
        p2 = np.array([2.5 + 0.1 * t, 1.0, 3.0])
        feed = [Measurement(stream="mocap", time=t, arrival=t, value=np.r_[p1, 1.0, 0, 0, 0], src="uav1")]
        X1, X2 = p1 + arms1, p2 + arms2 @ R2.T
        for i in range(6):
            for j in range(6):
                r = np.linalg.norm(X1[i] - X2[j]) + rng.normal(0, 0.05)
                feed.append(Measurement(stream="uwb", time=t, arrival=t, value=np.array([r]), src=f"uav1/ant{i + 1}",
                                        dst=f"uav2/ant{j + 1}", sigma=np.array([0.05])))
        if k > 0:  # no height at t = 0: that epoch cannot start the filter
            feed.append(Measurement(stream="height", time=t, arrival=t, value=np.array([p2[2] + rng.normal(0, 0.05)]),
                                    src="uav2", sigma=np.array([0.05])))
        for m in feed:
            out += est.process(m)
    out += est.finish()
    assert est.health()["skipped_epochs"] == 1 and min(e.time for e in out) == 1.0
    last = {(e.target, e.quantity): e for e in out if e.time == 30.0}
    pos = last[("uav2", "position")]
    err = pos.value - np.array([5.5, 1.0, 3.0])
    assert nees(err, pos.cov) < 16.3  # chi2(3) 0.999 quantile
    att = last[("uav2", "attitude")]
    e_att = quat_log(rotmat_to_quat(R2.T @ quat_to_rotmat(att.value)))
    assert nees(e_att, att.cov) < 16.3
    for j in range(6):
        a = last[(f"uav2/ant{j + 1}", "position")]
        assert np.linalg.norm(a.value - (np.array([5.5, 1.0, 3.0]) + R2 @ arms2[j])) < 5 * np.sqrt(np.trace(a.cov))


def test_plugin_says_so_when_no_range_ends_at_a_known_point():
    """Ranges from the follower to a body that never gets a pose (no pose stream, no anchors): no
    estimate, and health counts every such epoch (skipped_epochs) and row (unknown_end_rows)."""
    arms = _hexagon(0.4)
    sites = {f"uav{b}/ant{k + 1}": (f"uav{b}", a) for b in (1, 2) for k, a in enumerate(arms)}
    ctx = Context(vehicles=("uav1", "uav2"), sites=sites, anchors={}, sensors={}, duration=5.0, seed=0,
                  rng=np.random.default_rng(0))
    est = RangingEkfEstimator(ctx, {"follower": "uav2"})
    out = []
    for t in range(5):
        for i in range(6):
            out += est.process(Measurement(stream="uwb", time=float(t), arrival=float(t), value=np.array([3.0]),
                                           src=f"uav1/ant{i + 1}", dst="uav2/ant1"))
    out += est.finish()
    assert out == [] and est.health()["skipped_epochs"] == 5 and est.health()["unknown_end_rows"] == 30


def test_plugin_moves_a_one_antenna_follower_with_q_translation_alone():
    """q is the antennas' motion relative to each other (an array's flex): a follower tracked at one
    antenna gets none of it, its white acceleration is q_translation's (docs/replay.md, "Sparse
    ranging"); an array of two keeps q per antenna besides."""
    sites = {"uav1/uwb": ("uav1", np.zeros(3)), "uav2/ant1": ("uav2", np.array([0.3, 0.0, 0.0])),
             "uav2/ant2": ("uav2", np.array([-0.3, 0.0, 0.0]))}
    ctx = Context(vehicles=("uav1", "uav2"), sites=sites, anchors={}, sensors={}, duration=5.0, seed=0,
                  rng=np.random.default_rng(0))
    est = RangingEkfEstimator(ctx, {"known": [], "q": 0.5, "q_translation": 0.02})
    one, two = est.followers["uav1"], est.followers["uav2"]
    assert (one.n, two.n) == (1, 2)
    assert one.ekf.q == RangingNoise(antenna=0.0, translation=0.02, rotation=0.01)
    assert two.ekf.q == RangingNoise(antenna=0.5, translation=0.02, rotation=0.01)
    b = one.ekf.predict(Gaussian(np.zeros(6), np.zeros((6, 6))), 1.0)
    np.testing.assert_allclose(np.diag(b.cov)[:3], 0.02 / 3, rtol=1e-12)  # q_t dt^3 / 3 per axis


@pytest.mark.parametrize("src", ["uav2", "uav2/ant4"])
def test_plugin_height_is_the_up_coordinate_of_its_site_or_body(src):
    """"height" means one thing everywhere (docs/replay.md): the up coordinate of the named site or
    body. The follower's array sits 0.2 m above and 0.3 m ahead of its body origin; a height of the
    body is the origin's, a height of uav2/ant4 that antenna's. Fed exact heights of that point
    (sigma 0.01 m), the body's estimated height is within 4 sigma of the truth at the end (the old
    meaning, the antennas' centroid, would be 0.2 m off: 20 sigma of the height)."""
    arms1, arms2 = _hexagon(0.4), _hexagon(0.5) + np.array([0.3, 0.0, 0.2])
    sites = {f"uav{b}/ant{k + 1}": (f"uav{b}", a) for b, arms in ((1, arms1), (2, arms2)) for k, a in enumerate(arms)}
    ctx = Context(vehicles=("uav1", "uav2"), sites=sites, anchors={}, sensors={}, duration=10.0, seed=0,
                  rng=np.random.default_rng(0))
    est = RangingEkfEstimator(ctx, {"follower": "uav2", "range_sigma": 0.05, "level_sigma": 0.05, "q": 1e-6,
                                    "q_translation": 1e-3, "q_rotation": 1e-4, "v_sigma": 0.1})
    rng = np.random.default_rng(5)
    out = []
    for k in range(11):
        t = float(k)
        p1, p2 = np.array([0.1 * t, 0.0, 1.0]), np.array([2.5 + 0.1 * t, 1.0, 3.0])
        X1, X2 = p1 + arms1, p2 + arms2
        feed = [Measurement(stream="mocap", time=t, arrival=t, value=np.r_[p1, 1.0, 0, 0, 0], src="uav1"),
                Measurement(stream="height", time=t, arrival=t, value=np.array([p2[2] if src == "uav2" else X2[3, 2]]),
                            src=src, sigma=np.array([0.01]))]
        feed += [Measurement(stream="uwb", time=t, arrival=t, value=np.array([np.linalg.norm(X1[i] - X2[j]) + rng.normal(0, 0.05)]),
                             src=f"uav1/ant{i + 1}", dst=f"uav2/ant{j + 1}", sigma=np.array([0.05]))
                 for i in range(6) for j in range(6)]
        for m in feed:
            out += est.process(m)
    out += est.finish()
    pos = [e for e in out if e.time == 10.0 and e.target == "uav2" and e.quantity == "position"][0]
    assert abs(pos.value[2] - 3.0) < 4 * np.sqrt(pos.cov[2, 2]) and np.sqrt(pos.cov[2, 2]) < 0.05
