"""The swarm's IMU error-state EKFs (estimators.coop_ins) and their plugins coop.ins /
coop.ins_distributed (testbed.plugins.builtin_coop_ins)."""
from __future__ import annotations

import numpy as np
import pytest

from estimators import coop_ins as ci
from estimators.eskf import ImuNoise
from estimators.so3 import quat_exp

NOISE = ImuNoise(2e-3, 2e-4, 1e-4, 1e-5)


def _swarm(joint: bool, n: int = 3, devices: int = 0, seed: int = 0) -> ci.SwarmIns:
    rng = np.random.default_rng(seed)
    s = ci.SwarmIns(n, rng.normal(0, 0.1, (n, 3)), NOISE, joint=joint, devices=devices, delay_var=0.03 ** 2)
    for i in range(n):
        P0 = np.diag(rng.uniform(0.01, 1.0, ci.N_ERR))
        s.start(i, rng.normal(0, 10, 3), quat_exp(rng.normal(0, 0.2, 3)), rng.normal(0, 0.01, 3),
                rng.normal(0, 1e-3, 3), P0)
    s.t = 0.0
    return s


def _rows(s: ci.SwarmIns, pairs: bool, anchors: np.ndarray, rng, devices: bool = False) -> ci.Rows:
    """Rows near the swarm's own antennas (GNSS 2 m, ranges 0.1 m of noise): a fix for every
    vehicle, a range to each anchor, and (pairs) a range between each pair."""
    n, ant = s.n, s.antennas()[0]
    z, var, i, j, comp, other, dev = [], [], [], [], [], [], []
    nan3 = np.full(3, np.nan)
    for v in range(n):
        for c in range(3):
            z.append(ant[v, c] + rng.normal(0, 2)), var.append(4.0), i.append(v), j.append(-1), comp.append(c)
            other.append(nan3), dev.append((-1, -1))
        for k, a in enumerate(anchors):
            z.append(np.linalg.norm(ant[v] - a) + rng.normal(0, 0.1)), var.append(0.01), i.append(v), j.append(-1)
            comp.append(3), other.append(a), dev.append((v, n + k) if devices else (-1, -1))
    if pairs:
        for v in range(n):
            for w in range(v + 1, n):
                z.append(np.linalg.norm(ant[v] - ant[w]) + rng.normal(0, 0.1)), var.append(0.01), i.append(v), j.append(w)
                comp.append(3), other.append(nan3), dev.append((v, w) if devices else (-1, -1))
    return ci.Rows(z=np.array(z), var=np.array(var), i=np.array(i), j=np.array(j), component=np.array(comp),
                   other=np.array(other, float), dev=np.array(dev, int))


@pytest.mark.parametrize("per_row", [False, True])
@pytest.mark.parametrize("joint", [True, False])
def test_jacobians_match_finite_differences(joint, per_row):
    """H of every row (GNSS, anchor range, range between vehicles (centralized), antenna delays)
    against central differences of h under x (+) dx, each error state in turn; per_row: each row
    at its own site's lever arm (several tags per vehicle, Rows.lever and lever_j)."""
    n, A = 3, 2
    rng = np.random.default_rng(1)
    s = _swarm(joint, n, devices=n + A)
    s.c = rng.normal(0, 0.05, s.c.shape)
    rows = _rows(s, joint, rng.normal(0, 20, (A, 3)), rng, devices=True)
    if per_row:
        rows = rows.replace(lever=rng.normal(0, 0.3, (rows.z.size, 3)), lever_j=rng.normal(0, 0.3, (rows.z.size, 3)))
        assert np.abs(s._linearize(rows)[0] - s._linearize(rows.replace(lever=None, lever_j=None))[0]).max() > 1e-3
    h, Hi, Hj = s._linearize(rows)
    H = s._dense(rows, Hi, Hj) if joint else s._local(rows, Hi)
    x0 = (s.p, s.v, s.q, s.ba, s.bg, s.c)
    eps = 1e-6
    E = ci.N_ERR + (0 if joint else s.D)
    cols = n * ci.N_ERR + s.D if joint else E
    for col in range(cols):
        num = np.zeros(rows.z.size)
        for sign in (1, -1):
            if joint:
                dx = np.zeros(cols)
                dx[col] = sign * eps
                d = (dx[:n * ci.N_ERR].reshape(n, ci.N_ERR), dx[n * ci.N_ERR:])
            else:
                dx = np.zeros((n, E))
                dx[:, col] = sign * eps  # every vehicle's filter at once: each row sees its own
                d = (dx[:, :ci.N_ERR], dx[:, ci.N_ERR:])
            s._inject(d)
            num += sign * s._linearize(rows)[0]
            s.p, s.v, s.q, s.ba, s.bg, s.c = x0
        np.testing.assert_allclose(H[:, col], num / (2 * eps), atol=1e-6)


def test_distributed_equals_centralized_without_shared_states():
    """With no range between vehicles and no antenna-delay states (the centralized filter shares
    an anchor's delay among the vehicles, the distributed one keeps a copy per vehicle) the joint
    covariance stays block-diagonal: the two filters are the same filter (estimates and
    covariances to round-off), over propagation and updates."""
    rng = np.random.default_rng(2)
    a, b = _swarm(True), _swarm(False)
    anchors = rng.normal(0, 20, (2, 3))
    for step in range(20):
        f, w = rng.normal([0, 0, 9.81], 0.5, (3, 3)), rng.normal(0, 0.1, (3, 3))
        for s in (a, b):
            s.propagate(f, w, 0.01)
        if step % 5 == 4:
            rows = _rows(a, False, anchors, np.random.default_rng(step))
            sa, sb = a.update(rows, np.inf, 3), b.update(rows, np.inf, 3)
            assert (sa == sb).all() and (sa == 1).all()
    np.testing.assert_allclose(a.p, b.p, atol=1e-9)
    np.testing.assert_allclose(a.q, b.q, atol=1e-12)
    np.testing.assert_allclose(a.marginals(), b.marginals(), atol=1e-12)


def test_gnss_update_is_the_kalman_update():
    """A GNSS fix with the lever arm zero is linear: one iteration or three, the update is
    P H^T (H P H^T + R)^-1 r, and P - P H^T S^-1 H P."""
    s = _swarm(True, n=2)
    s.lever[:] = 0.0
    P, p0 = s.P.copy(), s.p.copy()
    rows = ci.Rows(z=np.array([1.0, 2.0, 3.0]), var=np.full(3, 0.5), i=np.array([1, 1, 1]), j=np.full(3, -1),
                   component=np.arange(3), other=np.full((3, 3), np.nan), dev=np.full((3, 2), -1))
    s.update(rows, np.inf, 3)
    H = np.zeros((3, P.shape[0]))
    H[:, 15:18] = np.eye(3)
    S = H @ P @ H.T + 0.5 * np.eye(3)
    K = P @ H.T @ np.linalg.inv(S)
    dx = K @ (rows.z - p0[1])
    np.testing.assert_allclose(s.p[1], p0[1] + dx[15:18], atol=1e-12)
    np.testing.assert_allclose(s.P[15:18, 15:18], (P - K @ S @ K.T)[15:18, 15:18], atol=1e-12)


def test_gate_rejects_an_outlier_range_not_a_fix():
    """A range 100 sigma off its prediction is rejected (status 0); a GNSS fix as far off is used."""
    s = _swarm(True, n=1)
    a = np.array([[30.0, 0.0, 0.0]])
    r = float(np.linalg.norm(s.antennas()[0][0] - a[0]))
    rows = ci.Rows(z=np.array([r + 100.0, 500.0]), var=np.array([0.01, 1.0]), i=np.array([0, 0]), j=np.array([-1, -1]),
                   component=np.array([3, 0]), other=np.array([a[0], [np.nan] * 3]), dev=np.full((2, 2), -1))
    status = s.update(rows, 10.83, 1)
    assert status.tolist() == [0, 1]


def _far_anchor_epoch(damped: bool) -> tuple[ci.SwarmIns, ci.Rows, tuple]:
    """One distributed filter 3.6 m uncertain in height, 1 m across, with a 0.1 m range to an anchor
    46 m away and 6 m below and a vertical fix 14.8 m off (the geometry measured on coop-denied seed
    1002: one anchor in reach)."""
    s = ci.SwarmIns(1, np.zeros((1, 3)), NOISE, joint=False, damped=damped)
    P0 = np.diag([1.0, 2.3, 3.6, 1, 1, 1, 0.06, 0.06, 0.1, 0.1, 0.1, 0.1, 0.01, 0.01, 0.01]) ** 2
    s.start(0, np.array([-26.1, 8.2, 16.8]), np.array([1.0, 0, 0, 0]), np.zeros(3), np.zeros(3), P0)
    s.t = 0.0
    truth, anchor = np.array([-22.0, 6.9, 8.0]), np.array([20.0, -14.0, 2.0])
    rows = ci.Rows(z=np.array([truth[2] + 2.0, np.linalg.norm(truth - anchor)]), var=np.array([26.0, 0.01]),
                   i=np.array([0, 0]), j=np.array([-1, -1]), component=np.array([2, 3]),
                   other=np.array([[np.nan] * 3, anchor]), dev=np.array([[-1, -1], [-1, -1]]))
    return s, rows, (s.p.copy(), s.P[0].copy())


def _map_cost(s: ci.SwarmIns, rows: ci.Rows, prior) -> float:
    """The MAP cost of the filter's state after its update, against the prior it started from."""
    p0, P0 = prior
    d = np.zeros(ci.N_ERR)
    d[ci.P_] = s.p[0] - p0[0]
    h, _, _ = s._linearize(rows)
    return float(d @ np.linalg.solve(P0, d) + ((rows.z - h) ** 2 / rows.var).sum())


def test_damped_iterated_update_never_raises_the_map_cost():
    """The line-searched iterated update ends at a MAP cost no higher than the prior's and than one
    plain EKF step's (each step is accepted only if it does not raise the cost), on the geometry
    where Gauss-Newton overshot on coop-denied seed 1002 (one far anchor, metres of height prior)."""
    costs = {}
    for damped, iters in ((False, 1), (True, 3)):
        s, rows, prior = _far_anchor_epoch(damped)
        costs["prior"] = _map_cost(s, rows, prior)
        s.update(rows, np.inf, iters)
        costs[damped] = _map_cost(s, rows, prior)
    assert costs[True] <= costs["prior"]
    assert costs[True] <= costs[False] + 1e-9


def test_centralized_filter_refuses_the_damped_update():
    with pytest.raises(ValueError):
        ci.SwarmIns(2, np.zeros((2, 3)), NOISE, joint=True, damped=True)


def test_broadcast_check_covers_an_own_filter_that_disagrees_with_the_flown_one():
    """A vehicle whose own-measurement estimate is 16 m from its cooperative one, both claiming about
    1 m, broadcasts a covariance that covers the disagreement (d^T C^-1 d <= 1 in its direction);
    one within its covariances broadcasts its own covariance unchanged."""
    from scipy.stats import chi2

    from testbed.plugins.builtin_coop_ins import checked_broadcast

    C = np.tile(np.diag([0.6, 1.0, 1.3]) ** 2, (2, 1, 1))
    s_flown = np.zeros((2, 3))
    s_own = np.array([[0.5, -0.8, 1.0], [-0.4, 0.7, 15.8]])
    out, failed = checked_broadcast(s_own, C, s_flown, C, float(chi2.isf(1e-3, 3)))
    assert failed.tolist() == [False, True]
    np.testing.assert_array_equal(out[0], C[0])
    d = s_own[1] - s_flown[1]
    assert d @ np.linalg.solve(out[1], d) <= 1.0


def test_a_broadcast_error_is_counted_once_more_each_epoch_up_to_peer_inflation():
    from testbed.plugins.builtin_coop_ins import peer_kappa

    np.testing.assert_array_equal(peer_kappa(4.0, np.array([0, 1, 2, 3, 50])), [1.0, 2.0, 3.0, 4.0, 4.0])


def test_a_receiver_holds_each_senders_newest_broadcast():
    """CoopInsDistributed._hear at once is the rule message by message: a broadcast replaces the
    held one of its sender if it is not older (of equal times the later arrival wins)."""
    from types import SimpleNamespace

    from testbed.sim.network import Message
    from testbed.plugins.builtin_coop_ins import CoopInsDistributed

    rs, n = np.random.default_rng(3), 4
    def held():
        return SimpleNamespace(heard_t=rs.choice([-np.inf, 0.2, 0.4], (n, n)), heard_s=rs.normal(size=(n, n, 3)),
                               heard_v=rs.normal(size=(n, n, 3)), heard_cs=rs.normal(size=(n, n, 3, 3)),
                               heard_cv=rs.normal(size=(n, n, 3, 3)))
    a = held()
    b = SimpleNamespace(**{k: v.copy() for k, v in vars(a).items()})
    t0 = a.heard_t.copy()
    msgs = [Message(sent=0.0, arrival=0.0, src=int(rs.integers(n)), dst=d, nbytes=1,
                    payload=(float(rs.choice([0.2, 0.4, 0.6])), *rs.normal(size=(2, 3)), *rs.normal(size=(2, 3, 3))))
            for d in range(n) for _ in range(12)]  # several per sender, times repeated and out of order
    for m in msgs:  # the rule, one message at a time
        if m.payload[0] >= a.heard_t[m.dst, m.src]:
            a.heard_t[m.dst, m.src] = m.payload[0]
            a.heard_s[m.dst, m.src], a.heard_v[m.dst, m.src], a.heard_cs[m.dst, m.src], a.heard_cv[m.dst, m.src] = m.payload[1:]
    CoopInsDistributed._hear(b, msgs)
    assert all(np.array_equal(getattr(a, k), getattr(b, k)) for k in vars(a))
    assert not np.array_equal(a.heard_t, t0)  # something was replaced


def _mirror_start(check: bool, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """One distributed filter started 13.3 m too high (a first SPP fix, 5 m vertical sigma: coop-denied
    seed 1005's uav3 at 0.2 s), i.e. above an anchor 6 m over the vehicle (its mirror side), then 5
    epochs of a fix (1.7 / 1.7 / 5 m) and a 0.1 m range to that anchor 37 m away; check: a range is
    fused only if linear_ranges passes it at the epoch's prior. (position error (3,), sigma (3,))."""
    from testbed.plugins.builtin_coop_ins import linear_ranges

    truth, anchor, sd = np.array([-12.0, 9.0, 8.0]), np.array([20.0, -14.0, 14.0]), np.array([1.7, 1.7, 5.0])
    s = ci.SwarmIns(1, np.zeros((1, 3)), NOISE, joint=False, damped=True)
    P0 = np.diag(np.r_[sd, 1, 1, 1, 0.05, 0.05, 0.1, 0.2, 0.2, 0.2, 0.02, 0.02, 0.02]) ** 2
    s.start(0, truth + [1.25, 0.0, 13.3], np.array([1.0, 0, 0, 0]), np.zeros(3), np.zeros(3), P0)
    s.t = 0.0
    rng = np.random.default_rng(seed)
    for _ in range(5):
        rows = ci.Rows(z=np.r_[truth + rng.normal(0, sd), np.linalg.norm(truth - anchor) + rng.normal(0, 0.1)],
                       var=np.r_[sd ** 2, 0.01], i=np.zeros(4, int), j=np.full(4, -1), component=np.arange(4),
                       other=np.vstack([np.full((3, 3), np.nan), anchor]), dev=np.full((4, 2), -1))
        linear = linear_ranges(s.antennas()[0], s.P[0][None, :3, :3], anchor[None], rows.var[3:], 1.0)[0]
        s.update(rows if linear or not check else rows.subset(np.arange(3)), np.inf, 3, 1.345)
    return s.p[0] - truth, np.sqrt(np.diag(s.P[0][:3, :3]))


def test_a_range_at_a_prior_on_the_mirror_side_makes_the_filter_sure_of_it_unless_checked():
    """Fused at every epoch, the anchor range leaves the filter more than 3 sigma off in height in 2
    of 3 noise draws (the start failure of coop-denied: sure of the mirror side); fusing only what
    linear_ranges passes (the anchor from the third epoch on, once the fixes have narrowed the
    height) keeps it within 3 sigma in all 3."""
    z = {check: [abs(e[2]) / sig[2] for e, sig in (_mirror_start(check, seed) for seed in (1, 2, 3))] for check in (False, True)}
    assert sum(v > 3 for v in z[False]) == 2
    assert max(z[True]) < 3


def test_linear_ranges_refuses_a_range_whose_second_order_term_exceeds_its_noise():
    """tr(C_perp) / (2 d) against the range's sd: 5 m of height sigma across a 37 m range (0.34 m
    against 0.1 m) is refused, 0.5 m (0.003 m) passes; along the range, sigma does not count."""
    from testbed.plugins.builtin_coop_ins import linear_ranges

    s, other = np.zeros((3, 3)), np.tile([37.0, 0.0, 0.0], (3, 1))
    C = np.array([np.diag([0.01, 0.01, 25.0]), np.diag([0.01, 0.01, 0.25]), np.diag([400.0, 0.01, 0.01])])
    assert linear_ranges(s, C, other, np.full(3, 0.01), 1.0).tolist() == [False, True, True]
    d = 2 * 37.0 * 0.1  # the largest tr(C_perp) that passes
    C = np.array([np.diag([0.0, 0.5, 0.5]) * d * 0.999, np.diag([0.0, 0.5, 0.5]) * d * 1.001, np.zeros((3, 3))])
    assert linear_ranges(s, C, other, np.full(3, 0.01), 1.0).tolist() == [True, False, True]
