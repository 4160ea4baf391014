"""Bandwidth-limited distributed fusion estimator (seed 000): gains, bound, validation, faults."""
import numpy as np
import pytest
from scipy.stats import norm

from estimators import bandwidth as bw
from estimators.core import Epoch, drive, kalman_gain
from estimators.geometry import DegenerateGeometryError
from testbed.synthetic.bandwidth import M0_PAPER, P_SETS, T_SETS, X0_PAPER, paper_model, simulate

BUDGET = [5, 5, 5, 5]


# ------------------------------------------------------------------ hand-worked eqs. 18-19
def _one_node():
    A = np.array([[1.0, 1.0], [0.0, 1.0]])
    return bw.NetworkModel.create(A=A, B=[0.1, 0.0], C=np.array([[1.0, 0.0]]), W=np.diag([0.1, 0.2]),
                                  V=np.array([[0.5]]), N=1)


def test_one_node_full_bandwidth_gain_and_bound_by_hand():
    model = _one_node()
    net = bw.FusionNetwork(select=np.ones((1, 1, 2)), weights=np.ones((1, 1)))
    M0 = np.diag([1.0, 2.0])
    # eq. 18 at k = 0: A M0 C^T = [1, 0]^T, C M0 C^T + V/2 = 1 + 0.25 = 1.25 -> L = [0.8, 0]
    L0 = bw.gains(model, M0[None])[0]
    assert np.allclose(L0, [[0.8], [0.0]])
    assert np.allclose(L0, kalman_gain(model.A @ M0 @ model.C[0].T, model.C[0] @ M0 @ model.C[0].T + 0.25))
    # eq. 19 (N = 1, p = 1, T = I, Tbar = 0): M1 = 2 A M0 A^T - 2 A M0 C^T S^-1 C M0 A^T + W
    #   A M0 A^T = [[3, 2], [2, 2]];  A M0 C^T S^-1 C M0 A^T = [[0.8, 0], [0, 0]]
    #   M1 = 2 [[2.2, 2], [2, 2]] + diag(0.1, 0.2) = [[4.5, 4], [4, 4.2]]
    M, Ls = bw.bound_recursion(model, net, M0, 2)
    assert np.allclose(M[1, 0], [[4.5, 4.0], [4.0, 4.2]])
    # eq. 18 at k = 1: A M1 C^T = [8.5, 4], C M1 C^T + V/2 = 4.75 -> L = [1.7894737, 0.8421053]
    assert np.allclose(Ls[1][0][:, 0], [8.5 / 4.75, 4.0 / 4.75])
    assert np.allclose(Ls[1][0][:, 0], [1.78947368, 0.84210526])
    # the literal eq. 19 and the eq. 15 form used by bound_step agree
    S, P = net.at(0)
    assert np.allclose(bw.bound_step_eq19(model, M[1], S, P), M[2])
    # eq. 4 / 7 with one node: xhat(1) = A xhat(0) + B + L (y - C xhat(0)) = [0.1, 0] + [0.8, 0] * 1
    st = bw.FusionState(xhat=np.zeros((1, 2)), M=M0[None])
    st1, _ = bw.fusion_step(model, st, [np.array([1.0])], S, P)
    assert np.allclose(st1.xhat, [[0.9, 0.0]])
    assert np.allclose(st1.M[0], M[1, 0])


def test_eq15_form_equals_eq19_on_paper_setup():
    model = paper_model(1.0, False)
    net = bw.FusionNetwork(select=T_SETS["T2"], weights=P_SETS["P2"], budget=BUDGET)
    M, _ = bw.bound_recursion(model, net, M0_PAPER, 5)
    S, P = net.at(0)
    for k in range(5):
        assert np.allclose(bw.bound_step_eq19(model, M[k], S, P), M[k + 1], rtol=1e-10)


# ------------------------------------------------------------------ bound vs Monte Carlo
@pytest.mark.parametrize("tname,pname", [("T1", "P1"), ("T1", "P3"), ("T3", "P1")])
def test_bound_dominates_empirical_covariance_paper_setup(tname, pname):
    """M_i(k) >= Sigma_i(k): exactly (joint covariance), and by Monte Carlo on tr with a margin.

    For zero-mean Gaussian errors the trace of the sample second moment over R runs has standard
    deviation sqrt(2 tr(Sigma^2) / R); the margin is z of a 1 % Bonferroni test over all nodes and
    steps. At k = 0, M = Sigma exactly, so the margin is what keeps that step from failing half the
    time. T1+P3 is the tightest case (bound / true J about 1.9).
    """
    model = paper_model(1.0, False)
    K, R = 50, 400
    net = bw.FusionNetwork(select=T_SETS[tname], weights=P_SETS[pname], budget=BUDGET)
    M, Ls = bw.bound_recursion(model, net, M0_PAPER, K)
    Sig = bw.node_blocks(bw.exact_covariance(model, net, M0_PAPER, K, Ls), 4)
    # exact: M - Sigma positive semidefinite at every node and step
    assert (np.linalg.eigvalsh(M - Sig).min(-1) >= -1e-9 * np.linalg.eigvalsh(M).max(-1)).all()
    sim = simulate(model, net, mu0=X0_PAPER, Sigma0=M0_PAPER, K=K, runs=R, rng=np.random.default_rng(7))
    e = sim.errors
    emp = np.einsum("rkia,rkib->kiab", e, e) / R
    tr_emp = np.trace(emp, axis1=-2, axis2=-1)
    se = np.sqrt(2 * np.einsum("kiab,kiba->ki", emp, emp) / R)
    z = norm.ppf(1 - 0.01 / tr_emp.size)
    assert (tr_emp <= np.trace(M, axis1=-2, axis2=-1) + z * se).all()
    # the simulation agrees with the exact covariance: J (eq. 12) within 4 standard errors
    per_run = (e ** 2).sum(axis=(1, 2, 3))
    J_exact = np.trace(Sig, axis1=-2, axis2=-1).sum()
    assert abs(per_run.mean() - J_exact) < 4 * per_run.std(ddof=1) / np.sqrt(R)
    assert bw.j_cost(e) == pytest.approx(per_run.mean())
    assert bw.j_bound(M) >= J_exact


def test_known_input_keeps_estimates_unbiased():
    """B enters eq. 4 and eq. 6: with x(0) = xhat(0) the mean error stays 0 (no drift of B)."""
    model = paper_model(1.0, False)
    net = bw.FusionNetwork(select=T_SETS["T2"], weights=P_SETS["P1"], budget=BUDGET)
    R = 1000
    sim = simulate(model, net, mu0=X0_PAPER, Sigma0=M0_PAPER, K=30, runs=R, rng=np.random.default_rng(3),
                      x0_random=False)
    e = sim.errors[:, -1]
    assert (np.abs(e.mean(0)) < 4.5 * e.std(0, ddof=1) / np.sqrt(R)).all()


# ------------------------------------------------------------------ validation
def _T1():
    return T_SETS["T1"].copy()


def test_valid_paper_sets_pass():
    for S in T_SETS.values():
        for P in P_SETS.values():
            bw.validate_network(S, P, budget=BUDGET)


def test_budget_exceeded_names_node():
    S = _T1()
    S[1, 0] = S[0, 1] = [1, 1, 0]  # T21 with 2 components: node 1 receives 6
    with pytest.raises(ValueError, match=r"budget of node 1: receives 6 .*T\[2,1\]:2"):
        bw.validate_network(S, P_SETS["P1"], budget=BUDGET)
    with pytest.raises(ValueError, match="budget of node 1"):
        bw.FusionNetwork(select=S, weights=P_SETS["P1"], budget=BUDGET)


def test_asymmetric_T_names_pair():
    S = _T1()
    S[2, 3] = [1, 0, 0]  # T34 != T43
    with pytest.raises(ValueError, match=r"T\[3,4\] != T\[4,3\]"):
        bw.validate_network(S, P_SETS["P1"])


def test_T_must_be_diagonal_01_and_identity_on_self():
    Tm = bw.masks_to_matrices(_T1())
    Tm[1, 0, 0, 1] = 1.0
    with pytest.raises(ValueError, match=r"T\[2,1\] is not diagonal"):
        bw.as_masks(Tm)
    S = _T1()
    S[2, 2, 1] = 0.0
    with pytest.raises(ValueError, match=r"T\[3,3\] != I"):
        bw.validate_network(S, P_SETS["P1"])
    S = _T1()
    S[0, 1] = S[1, 0] = [0.5, 1, 0]
    with pytest.raises(ValueError, match=r"T\[1,2\] has a diagonal entry"):
        bw.validate_network(S, P_SETS["P1"])


def test_weights_not_summing_to_one_names_node():
    P = P_SETS["P2"].copy()
    P[2, 3] += 0.1
    with pytest.raises(ValueError, match=r"weights of node 3 sum to 1.1"):
        bw.validate_network(T_SETS["T1"], P, budget=BUDGET)
    P = P_SETS["P1"].copy()
    P[1, 0], P[1, 1] = -0.25, 0.75
    with pytest.raises(ValueError, match=r"p\[2,1\] = -0.25 < 0"):
        bw.validate_network(T_SETS["T1"], P)


def test_weight_without_link_names_pair():
    links = np.ones((4, 4), bool)
    links[0, 2] = links[2, 0] = False
    S = _T1()
    S[0, 2] = S[2, 0] = 0.0
    with pytest.raises(ValueError, match=r"p\[1,3\] = 0.25 > 0 but nodes 1 and 3 have no link"):
        bw.validate_network(S, P_SETS["P1"], links=links)
    with pytest.raises(ValueError, match=r"T\[3,1\] selects components but nodes 3 and 1 have no link"):
        bw.validate_network(_T1(), P_SETS["P1"], links=links)


def test_time_varying_selection_is_validated_per_step():
    good = lambda k: T_SETS["T1"] if k % 2 == 0 else T_SETS["T3"]
    net = bw.FusionNetwork(select=good, weights=P_SETS["P1"], budget=BUDGET)
    M, _ = bw.bound_recursion(paper_model(1.0, False), net, M0_PAPER, 4)
    assert np.isfinite(M).all()

    def bad(k):
        S = _T1()
        if k == 3:
            S[3, 1] = [1, 0, 0]
        return S

    net = bw.FusionNetwork(select=bad, weights=P_SETS["P1"], budget=BUDGET)
    with pytest.raises(ValueError, match=r"T\[2,4\] != T\[4,2\] \(step 3\)"):
        bw.bound_recursion(paper_model(1.0, False), net, M0_PAPER, 5)


# ------------------------------------------------------------------ communication, search
def test_comm_accounting_paper_budget():
    net = bw.FusionNetwork(select=T_SETS["T1"], weights=P_SETS["P1"], budget=BUDGET)
    log = bw.comm_accounting(net, 3)
    assert (log.received == 5).all() and (log.sent == 5).all()
    assert (log.bytes.sum(1) == 40).all()  # 5 float64 components per node per step
    assert log.bytes[0, 2, 0] == 16  # T31 = diag(1, 1, 0): node 3 sends node 1 two components
    assert log.within_budget()


def test_selection_search_counts_and_beats_paper_sets():
    model = paper_model(1.0, False)
    K = 15
    res = bw.search_selection(model, P_SETS["P1"], M0_PAPER, K, BUDGET)
    assert res.count == 2430 and res.method == "exhaustive"
    for S in T_SETS.values():
        bw.validate_network(res.best, P_SETS["P1"], budget=BUDGET)
        J = bw.j_bound(bw.bound_recursion(model, bw.FusionNetwork(select=S, weights=P_SETS["P1"]), M0_PAPER, K)[0])
        assert res.best_J <= J
    # the heuristic, forced, reaches the exhaustive optimum on this small case
    h = bw.search_selection(model, P_SETS["P1"], M0_PAPER, K, BUDGET, max_enumerate=10, restarts=3,
                            rng=np.random.default_rng(0))
    assert h.method == "local-search"
    bw.validate_network(h.best, P_SETS["P1"], budget=BUDGET)
    assert h.best_J == pytest.approx(res.best_J, rel=1e-9)


# ------------------------------------------------------------------ faults
def test_drops_and_node_failure_stay_bounded():
    model = paper_model(0.1, True)
    net = bw.FusionNetwork(select=T_SETS["T1"], weights=P_SETS["P1"], budget=BUDGET)
    K, R = 200, 200
    faults = bw.LinkFaults(drop_prob=0.3, failed={1: 50})  # node 2 stops sending at k = 50
    sim = simulate(model, net, mu0=X0_PAPER, Sigma0=M0_PAPER, K=K, runs=R, rng=np.random.default_rng(5),
                      faults=faults)
    e = sim.errors
    assert np.isfinite(sim.xhat).all() and np.isfinite(sim.M).all()
    rms = np.sqrt((e[:, 1:] ** 2).sum(-1).mean(axis=(0, 1)))
    naive = np.sqrt(np.trace(model.V[0]) + np.trace(model.W))  # predictor y_i(k) + B
    assert (rms < naive).all()
    assert np.abs(e).max() < 10 * naive
    # node 2 sends nothing after step 50, others send about 70 % of the nominal components
    assert (sim.comm.sent[50:, 1] == 0).all()
    assert sim.comm.within_budget()
    assert 0.6 * 5 < sim.comm.received[:50, 0].mean() < 0.8 * 5
    # total loss: compensation only, still finite
    Se = bw.LinkFaults(drop_prob=1.0).effective(T_SETS["T1"], 0, np.random.default_rng(0), 2)
    assert bw.link_components(Se).sum() == 0 and (Se[:, range(4), range(4)] == 1).all()
    with pytest.raises(ValueError, match="Generator"):
        bw.LinkFaults(drop_prob=0.1).effective(T_SETS["T1"], 0, None, 1)


# ------------------------------------------------------------------ UWB pseudo-measurement (eqs. 21-23)
def test_uwb_pseudo_measurement_exact_and_V_by_finite_differences():
    a = 20.0 * np.array([[1.0, 0, 0], [0, 1.0, 0], [0, 0, 1.0], [0, 0, 0]])
    p = np.array([13.0, 10.0, 10.17])
    r = np.linalg.norm(p - a, axis=1)
    y, V = bw.uwb_pseudo_measurement(r, a, 0.1)
    assert np.allclose(y, p, atol=1e-10)  # eqs. 21-23 are exact on noise-free ranges
    # V = sigma^2 J J^T with J = dy/dr (3, 4): check J by central differences
    h = 1e-5
    J = np.stack([(bw.uwb_pseudo_measurement(r + h * np.eye(4)[k], a, 0.1)[0]
                   - bw.uwb_pseudo_measurement(r - h * np.eye(4)[k], a, 0.1)[0]) / (2 * h) for k in range(4)], 1)
    assert np.allclose(V, 0.01 * J @ J.T, rtol=1e-6)
    # batched ranges give the same as one at a time
    yb, Vb = bw.uwb_pseudo_measurement(np.stack([r, r + 0.05]), a, 0.1)
    assert np.allclose(yb[0], y) and np.allclose(Vb[0], V)


def test_uwb_pseudo_measurement_refuses_degenerate_geometry():
    """Issue 16: coplanar anchors gave a position metres (581 m in the report) from the truth, or
    a bare LinAlgError; too few ranges went unchecked. Each now raises DegenerateGeometryError
    naming the cause. 200 random planes: the old Cholesky of H^T H succeeded on round-off for some
    of them (silently wrong); the rank check refuses all."""
    rng = np.random.default_rng(1)
    p = np.array([5.0, 7.0, 3.0])
    for _ in range(200):
        nrm = rng.standard_normal(3)
        e1 = np.cross(nrm, rng.standard_normal(3))
        e2 = np.cross(nrm, e1)
        basis = np.stack([e1 / np.linalg.norm(e1), e2 / np.linalg.norm(e2)])
        a = rng.uniform(-20, 20, (4, 2)) @ basis + rng.uniform(-5, 5, 3)
        with pytest.raises(DegenerateGeometryError, match="one plane"):
            bw.uwb_pseudo_measurement(np.linalg.norm(p - a, axis=1), a, 0.1)
    a = 20.0 * np.array([[1.0, 0, 0], [0, 1.0, 0], [0, 0, 1.0], [0, 0, 0]])
    with pytest.raises(DegenerateGeometryError, match="3 points given, at least 4"):
        bw.uwb_pseudo_measurement(np.linalg.norm(p - a[:3], axis=1), a[:3], 0.1)
    with pytest.raises(DegenerateGeometryError, match="3 ranges for 4 anchors"):
        bw.uwb_pseudo_measurement(np.linalg.norm(p - a[:3], axis=1), a, 0.1)
    # a plane lifted by 1 m at one corner spans 3-D: answered, exactly on noise-free ranges
    a_ok = np.array([[0.0, 0, 0], [20, 0, 0], [0, 20, 0], [20, 20, 1.0]])
    assert np.allclose(bw.uwb_pseudo_measurement(np.linalg.norm(p - a_ok, axis=1), a_ok, 0.1)[0], p, atol=1e-8)


def test_missing_measurement_predicts_only():
    model = paper_model(0.1, True)
    net = bw.FusionNetwork(select=T_SETS["T1"], weights=P_SETS["P1"], budget=BUDGET)
    S, P = net.at(0)
    st = bw.FusionState(xhat=np.zeros((4, 3)), M=np.broadcast_to(M0_PAPER, (4, 4, 3, 3))[0].copy())
    y = [np.full(3, np.nan)] + [np.ones(3)] * 3
    avail = np.array([False, True, True, True])
    _, lam = bw.fusion_step(model, st, y, S, P, available=avail)
    assert np.allclose(lam[0], model.B)  # lambda_1 = A xhat_1 + B, no innovation
    L = bw.gains(model, st.M)
    L[0] = np.zeros_like(L[0])
    st1, _ = bw.fusion_step(model, st, y, S, P, available=avail)
    assert np.allclose(st1.M, bw.bound_step(model, st.M, S, P, L))  # eq. 15 with L_1 = 0


# ------------------------------------------------------------------ the estimator interface
def test_fusion_filter_through_the_driver_equals_the_step_loop():
    """bw.FusionFilter under core.drive (update stores y(k), predict fuses) reproduces the
    fusion_step loop bit for bit, with a node missing its measurement on one step."""
    rng = np.random.default_rng(12)
    N, n, K = 4, 3, 6
    A, B, W = np.eye(n), np.array([0.1, 0.0, -0.05]), 0.01 * np.eye(n)
    C = (np.eye(n),) * N
    V = [np.diag(rng.uniform(0.5, 1.5, n)) for _ in range(N)]
    model = bw.NetworkModel(A=A, B=B, C=C, W=W, V=tuple(V))
    net = bw.FusionNetwork(select=T_SETS["T1"], weights=P_SETS["P2"], budget=BUDGET)
    y = rng.normal(size=(K + 1, N, n))
    avail = np.ones((K + 1, N), bool)
    avail[2, 1] = False
    st = bw.FusionState(xhat=np.zeros((N, n)), M=np.broadcast_to(np.eye(n), (N, n, n)).copy())
    ref = [st]
    for k in range(K):
        S, P = net.at(k)
        st, _ = bw.fusion_step(model, st, list(y[k]), S, P, available=avail[k])
        ref.append(st)
    meas = [bw.NodeMeasurements(y=tuple(y[k]), V=tuple(V), available=avail[k]) for k in range(K + 1)]
    epochs = [Epoch(float(k), meas[k], [(1.0, net.at(k - 1))] if k else []) for k in range(K + 1)]
    track = drive(bw.FusionFilter(A=A, B=B, C=C, W=W), ref[0], epochs)
    assert np.array_equal(track.mean, np.stack([s.xhat for s in ref]))
    assert np.array_equal(track.cov, np.stack([s.M for s in ref]))
    with pytest.raises(ValueError, match="update first"):
        bw.FusionFilter(A=A, B=B, C=C, W=W).predict(ref[0], 1.0, net.at(0))
