"""The network model (issue 18 part 2): loss against its stated probability (Clopper-Pearson),
Gilbert-Elliott stationary loss and burst length against theory, latency percentiles, range limit,
bandwidth budget, per-link seeding, the [network] table at the boundary.

Tolerances are derived from the sample sizes: K_SIGMA standard errors, or a 99.9 % exact
binomial interval."""
from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest
from scipy.stats import norm

from estimators.factor_graph import MESSAGE_BYTES, solve_distributed
from testbed.config import from_dict
from testbed.errors import ConfigError
from testbed.sim.network import Network, NetworkConfig, stationary_loss
from testbed.rng import stream_rng
from testbed.scoring.metrics import ranging_rate
from testbed.config.scenario import Scenario, load
from testbed.sim.simulate import simulate
from testbed.scoring.stats import clopper_pearson
from testbed.synthetic.coop import make_epoch

K_SIGMA = 5.0
LEVEL = 0.999


def net(n: int = 2, **cfg) -> Network:
    return Network(NetworkConfig(**cfg), n, stream_rng(7, "network"))


def outcomes(network: Network, m: int, src: int = 0, dst: int = 1, dt: float = 0.01) -> np.ndarray:
    """(m,) bool delivered, m messages src -> dst every dt seconds."""
    return np.array([network.send(k * dt, src, dst, 10, k) for k in range(m)])


def test_ideal_network_delivers_everything_at_once():
    nw = Network(None, 3, stream_rng(0, "network"))
    assert nw.broadcast(1.0, 0, 72, "x") == 2
    got = nw.receive(1.0, 2)
    assert [(m.src, m.dst, m.sent, m.arrival, m.payload) for m in got] == [(0, 2, 1.0, 1.0, "x")]
    s = nw.stats()
    assert s["sent"] == 2 and s["dropped"] == 0 and s["latency_max_s"] == 0.0


def test_independent_drop_fraction_is_inside_the_binomial_interval():
    p, m = 0.2, 4000
    ok = outcomes(net(loss_prob=p), m)
    ci = clopper_pearson(int((~ok).sum()), m, level=LEVEL, sided="two-sided").interval
    assert ci[0] <= p <= ci[1], ci
    assert stationary_loss(NetworkConfig(loss_prob=p)) == pytest.approx(p)


def _runs(lost: np.ndarray) -> np.ndarray:
    """Lengths of the runs of consecutive True."""
    x = np.concatenate([[0], lost.astype(int), [0]])
    d = np.diff(x)
    return np.flatnonzero(d == -1) - np.flatnonzero(d == 1)


def test_gilbert_elliott_stationary_loss_and_burst_length_match_theory():
    p, r, m = 0.05, 0.25, 40000
    ok = outcomes(net(ge_p=p, ge_r=r), m)
    lost = ~ok
    pi_b = p / (p + r)  # stationary probability of the bad state = loss (bad loses all, good none)
    assert stationary_loss(NetworkConfig(ge_p=p, ge_r=r)) == pytest.approx(pi_b)
    # variance of the mean of a two-state chain: pi (1 - pi) / m * (1 + lam) / (1 - lam), lam = 1 - p - r
    lam = 1 - p - r
    se = math.sqrt(pi_b * (1 - pi_b) / m * (1 + lam) / (1 - lam))
    assert abs(lost.mean() - pi_b) < K_SIGMA * se, (lost.mean(), pi_b, se)
    # bursts: geometric with mean 1 / r and variance (1 - r) / r^2
    bursts = _runs(lost)
    se_b = math.sqrt((1 - r) / r**2 / len(bursts))
    assert abs(bursts.mean() - 1 / r) < K_SIGMA * se_b, (bursts.mean(), 1 / r, se_b)
    # independent losses have bursts of mean 1 / (1 - q) at the same loss rate: clearly shorter
    iid = _runs(~outcomes(net(loss_prob=pi_b), m))
    assert iid.mean() < 1 / (1 - pi_b) + K_SIGMA * math.sqrt(pi_b / (1 - pi_b) ** 2 / len(iid)) < bursts.mean()


def _quantile_se(q: float, m: int, density: float) -> float:
    """Standard error of the sample q-quantile of m draws with density `density` there."""
    return math.sqrt(q * (1 - q) / m) / density


@pytest.mark.parametrize("model", ["normal", "lognormal"])
def test_latency_percentiles_as_configured(model):
    base, jit, shape, m = 0.05, 0.005, 0.5, 5000
    nw = net(latency=base, jitter=jit, jitter_model=model, jitter_shape=shape)
    assert outcomes(nw, m).all()
    s = nw.stats()
    for q, key in ((0.5, "latency_p50_s"), (0.95, "latency_p95_s")):
        z = norm.ppf(q)
        if model == "normal":
            want, dens = base + jit * z, norm.pdf(z) / jit
        else:  # base + jit exp(shape z): the quantile maps through the monotone transform
            want = base + jit * math.exp(shape * z)
            dens = norm.pdf(z) / (jit * shape * math.exp(shape * z))
        assert abs(s[key] - want) < K_SIGMA * _quantile_se(q, m, dens), (key, s[key], want)
    assert s["latency_max_s"] >= s["latency_p95_s"] >= s["latency_p50_s"] > 0


def test_receive_hands_over_in_arrival_order_only_what_has_arrived():
    nw = net(latency=0.1, jitter=0.05)
    for k in range(50):
        nw.send(0.0, 0, 1, 10, k)
    early = nw.receive(0.1, 1)
    late = nw.receive(10.0, 1)
    arr = [m.arrival for m in early + late]
    assert arr == sorted(arr) and all(a <= 0.1 for a in arr[: len(early)]) and all(m.arrival > 0.1 for m in late)
    assert len(early) + len(late) == 50 and nw.receive(20.0, 1) == []
    assert nw.stats()["delivered"] == 50 and nw.stats()["in_flight"] == 0


def test_range_limit_and_nlos_loss():
    nw = net(n=3, max_range=100.0, nlos_loss=1.0)
    nw.set_geometry(0.0, np.array([[0.0, 0, 0], [60.0, 0, 0], [150.0, 0, 0]]))
    arrival = nw.multicast(0.0, 0, np.array([1, 2]), 10, None)
    assert np.isfinite(arrival[0]) and np.isinf(arrival[1]) and nw.stats()["dropped_range"] == 1
    los = np.ones((3, 3), bool)
    los[0, 1] = False
    nw.set_geometry(1.0, np.array([[0.0, 0, 0], [60.0, 0, 0], [50.0, 0, 0]]), los)
    assert nw.broadcast(1.0, 0, 10, None) == 1  # 0 -> 1 blocked (NLOS, lost surely), 0 -> 2 clear
    assert nw.stats()["dropped_loss"] == 1


@pytest.mark.parametrize("side", ["send", "receive"])
def test_bandwidth_budget_is_respected(side):
    rate, size, dt, T = 1000.0, 100, 0.01, 10.0  # 10 kB/s offered against 1 kB/s
    nw = net(n=3, bandwidth=rate, budget_on=side)
    for k in range(int(T / dt)):
        nw.broadcast(k * dt, 0, size, k)
    s = nw.stats()
    got = s["queued"] / 2 * size  # bytes paid by each paying bucket (the sender's, or each receiver's)
    span = (int(T / dt) - 1) * dt  # first to last message, s
    # a token bucket (full at the start, depth = 1 s of rate) never passes more than depth +
    # rate span, and a saturated one passes all but less than one message of it
    assert rate * span + rate - size < got <= rate * span + rate, got
    if side == "send":
        assert s["queued"] % 2 == 0  # a broadcast is paid once and reaches both or none
    assert s["dropped_budget"] == s["sent"] - s["queued"]


def test_links_are_seeded_independently():
    a = outcomes(net(n=3, loss_prob=0.3), 500)
    nw = net(n=3, loss_prob=0.3)
    b = []
    for k in range(500):  # the same link, with traffic on another link in between
        nw.send(k * 0.01, 0, 2, 10, None)
        b.append(nw.send(k * 0.01, 0, 1, 10, None))
    assert np.array_equal(a, b)


@pytest.mark.parametrize("budget_on", ["send", "receive"])
def test_broadcast_all_is_each_broadcast_in_turn(budget_on):
    """One pass over every sender's messages (the distributed filter's epoch) draws, drops and
    queues exactly what broadcasting them one after the other does: range, a budget that runs
    out, bursty and NLOS loss, lognormal latency."""
    cfg = dict(latency=0.005, jitter=0.002, jitter_model="lognormal", loss_prob=0.05, ge_p=0.1, ge_r=0.3,
               ge_loss_bad=0.5, nlos_loss=0.2, max_range=60.0, bandwidth=1000.0, budget_on=budget_on)

    def traffic(at_once: bool) -> list:
        rs, nw, out = np.random.default_rng(5), net(n=8, **cfg), []
        for step in range(200):
            t = 0.05 * step
            nw.set_geometry(t, rs.uniform(0.0, 80.0, (8, 3)), rs.random((8, 8)) < 0.8)
            srcs = np.flatnonzero(rs.random(8) < 0.7)
            pay = [(step, int(s)) for s in srcs]
            out.append(nw.broadcast_all(t, srcs, 100, pay).tolist() if at_once else
                       [nw.broadcast(t, int(s), 100, p) for s, p in zip(srcs, pay)])
            out += [[(m.sent, m.arrival, m.src, m.payload) for m in nw.receive(t, d)] for d in range(8)]
        return out + [nw.stats()]

    each, together = traffic(False), traffic(True)
    assert together == each
    assert 0 < each[-1]["dropped_budget"] and 0 < each[-1]["dropped_range"] and 0 < each[-1]["dropped_loss"]


@pytest.mark.parametrize("budget_on", ["send", "receive"])
def test_a_round_is_each_senders_multicast_in_turn(budget_on):
    """A round of the round transport (a distributed window's messages, senders unordered) is
    each sender's multicast in sender order, then every receiver's queue drained at the round's
    end: the same arrivals in time, drops and counts (range, budget, loss)."""
    cfg = dict(latency=0.005, jitter=0.002, jitter_model="lognormal", loss_prob=0.05, ge_p=0.1, ge_r=0.3,
               ge_loss_bad=0.5, nlos_loss=0.2, max_range=60.0, bandwidth=3000.0, budget_on=budget_on)

    def traffic(rounds: bool) -> list:
        rs, nw, out = np.random.default_rng(6), net(n=8, **cfg), []
        for rnd in range(60):
            t, end = 0.01 * rnd, 0.01 * (rnd + 1)
            nw.set_geometry(t, rs.uniform(0.0, 80.0, (8, 3)), rs.random((8, 8)) < 0.8)
            pairs = np.argwhere(~np.eye(8, dtype=bool) & (rs.random((8, 8)) < 0.5))
            pairs = pairs[rs.permutation(len(pairs))]  # senders in no order
            src, dst = pairs[:, 0], pairs[:, 1]
            if rounds:
                out.append(nw.rounds(0.0, 0.01).deliver(rnd, src, dst, 200).tolist())
            else:
                ok = np.zeros(len(src), bool)
                for s in np.unique(src).tolist():
                    sel = np.flatnonzero(src == s)
                    ok[sel] = nw.multicast(t, s, dst[sel], 200, (rnd, s)) <= end
                out.append(ok.tolist())
                for d in np.unique(dst).tolist():
                    nw.receive(end, d)
        return out + [nw.stats()]

    each, together = traffic(False), traffic(True)
    assert together == each
    assert 0 < each[-1]["dropped_budget"] and 0 < each[-1]["dropped_range"] and 0 < each[-1]["dropped_loss"]


def test_network_table_is_checked_at_the_boundary():
    with pytest.raises(ConfigError, match=r"f.toml.*network.loss_prob.*1.5"):
        from_dict(NetworkConfig, {"loss_prob": 1.5}, "f.toml", "network")
    with pytest.raises(ConfigError, match=r"network.jitter_model"):
        from_dict(NetworkConfig, {"jitter_model": "pareto"}, "f.toml", "network")
    with pytest.raises(ConfigError, match=r"network.burst_bytes"):
        from_dict(NetworkConfig, {"burst_bytes": 10.0}, "f.toml", "network")


# ------------------------------------------------------------------- the estimators over it
class _Stub:
    """A transport that delivers everything or nothing, counting its calls."""

    def __init__(self, deliver_all: bool):
        self.all, self.calls = deliver_all, 0

    def deliver(self, rnd, src, dst, nbytes):
        self.calls += 1
        assert nbytes == MESSAGE_BYTES and len(src) == len(dst)
        return np.full(len(src), self.all)


def test_distributed_solver_uses_only_what_the_transport_delivers():
    prob = make_epoch(8, seed=4).problem
    ideal = solve_distributed(prob, mode="iterate", max_rounds=20)
    everything = _Stub(True)
    same = solve_distributed(prob, mode="iterate", max_rounds=20, transport=everything)
    assert np.array_equal(same.positions, ideal.positions) and everything.calls == same.rounds
    cut = solve_distributed(prob, mode="iterate", max_rounds=20, transport=_Stub(False))
    assert cut.deliveries == 0 and np.allclose(cut.positions, prob.gnss_pos)  # nothing heard: own fix only


def test_seed000_budget_is_one_instance_of_the_network_budget():
    """bandwidth.fusion sends its messages through the runtime's network (Context.channel): a
    receive budget of exactly 8 t_i bytes per step passes the design untouched, one component less
    drops messages and no node then receives more than t_i - 1 components in a step."""
    from testbed.plugins.defaults import estimator_specs
    from testbed.plugins.loading import resolve
    from testbed.plugins.run import run_estimators

    sc = load("bandwidth", duration=3.0)
    log, physics = simulate(sc)
    dt, b = sc.pipeline.dt, sc.pipeline.budget
    plugins = resolve(estimator_specs(sc))

    def fused(network):
        scores, tracks = run_estimators(replace(sc, network=network), physics, log, plugins, None)
        pos = np.stack([tracks["bandwidth"][(f"uav{i}/uwb", "position")].value for i in range(1, 5)], 1)
        return scores["bandwidth"], pos

    _, ref = fused(None)
    exact, pos = fused(NetworkConfig(budget_on="receive", bandwidth=8 * b / dt, burst_bytes=8 * b))
    assert np.array_equal(pos, ref) and exact["network"]["dropped"] == 0 and exact["within_budget"]
    tight, pos = fused(NetworkConfig(budget_on="receive", bandwidth=8 * (b - 1) / dt, burst_bytes=8 * (b - 1)))
    assert tight["network"]["dropped_budget"] > 0 and not np.array_equal(pos, ref)
    assert max(tight["bytes_received_per_step"]) <= 8 * (b - 1)
    assert tight["network"]["bytes_delivered"] <= 8 * (b - 1) * 4 * (round(3.0 / dt) + 1)


def test_seed001_messages_over_the_network():
    """The coop.* plugins run on a log with [network] (Context.channel, testbed.plugins.channel): a
    default (ideal) network gives the estimates of no network with nothing dropped or late; a lossy,
    late channel drops messages from its own stream, has the configured latency and changes the
    iterated estimate."""
    from testbed.plugins.loading import resolve
    from testbed.plugins.run import run_estimators
    from testbed.config.estimators import EstimatorSpec

    sc = load("coop-fg", duration=2.0)
    log, physics = simulate(sc)
    which = ("one_shot", "iterated")

    def scores(network):
        plugins = resolve([EstimatorSpec(entry=f"coop.{w}", name=w) for w in which])
        return run_estimators(replace(sc, network=network), physics, log, plugins, None)

    (ideal, ti), (default, td) = scores(None), scores(NetworkConfig())
    assert "network" not in ideal["iterated"]
    for w in which:
        assert default[w]["rmse_position_per_vehicle_m"] == ideal[w]["rmse_position_per_vehicle_m"]
        for key, s in ti[w].items():
            np.testing.assert_array_equal(td[w][key].value, s.value)
        assert default[w]["network"]["dropped"] == 0 and default[w]["network"]["latency_max_s"] == 0.0
    lossy = scores(NetworkConfig(loss_prob=0.5, latency=0.004, jitter=0.002))[0]
    s = lossy["iterated"]["network"]
    assert s["sent"] > 0 and s["dropped"] == s["dropped_loss"] > 0 and s["late"] >= 0
    assert 0.003 < s["latency_p50_s"] < 0.005
    assert lossy["iterated"]["rmse_position_per_vehicle_m"] != ideal["iterated"]["rmse_position_per_vehicle_m"]


# --------------------------------------------------------------------- scheduled UWB ranging
def _ranging(policy: str, slot: float = 0.02, rate: float = 10.0, duration: float = 2.0):
    offsets = [[5.0 * i, 3.0 * (i % 2), 0.0] for i in range(6)]  # 6 vehicles: P = 15 tag pairs
    sc = from_dict(Scenario, {
        "name": "sched", "description": "test", "seed": 2, "duration": duration,
        "trajectory": {"kind": "straight-line", "start": [0.0, 0.0, 5.0], "velocity": [0.5, 0.0, 0.0], "offsets": offsets},
        "sensors": {"uwb": {"preset": "ideal", "rate_hz": rate, "schedule": {"policy": policy, "slot_s": slot}}},
    }, "test")
    log, _ = simulate(sc)
    pairs = [set(zip(log["uwb/src"][log["uwb/state_index"] == k], log["uwb/dst"][log["uwb/state_index"] == k]))
             for k in np.unique(log["uwb/state_index"])]
    return sc, log, pairs


def test_schedule_serves_one_pair_per_slot():
    slot, rate = 0.02, 10.0
    sc, log, pairs = _ranging("round_robin", slot, rate)
    S = math.floor(1 / (rate * slot))  # 5 exchanges per 0.1 s cycle
    assert (log["uwb/served"] == S).all() and all(len(p) == S for p in pairs)
    per_s = ranging_rate(log, sc.duration)
    samples = len(log["uwb/served"])  # 0, 0.1, ..., 2.0 s
    assert per_s == pytest.approx(S * samples / sc.duration)
    assert S * rate <= 1 / slot < (S + 1) * rate  # pairs per second = 1 / slot, to the rounding of S
    _, full, every = _ranging("all")
    assert "uwb/served" not in full and ranging_rate(full, sc.duration) is None and all(len(p) == 15 for p in every)


def test_round_robin_serves_every_pair_within_ceil_p_over_s_samples():
    _, _, pairs = _ranging("round_robin")
    P, S = 15, 5
    window = math.ceil(P / S)
    for k in range(len(pairs) - window + 1):
        assert len(set().union(*pairs[k : k + window])) == P


def test_nearest_serves_the_nearest_pairs():
    _, log, pairs = _ranging("nearest")
    _, full, _ = _ranging("all")
    for k, served in zip(np.unique(log["uwb/state_index"]), pairs):
        rows = full["uwb/state_index"] == k
        d = full["uwb/clean"][rows, 0]
        names = list(zip(full["uwb/src"][rows], full["uwb/dst"][rows]))
        near = {names[i] for i in np.argsort(d, kind="stable")[:5]}
        assert served == near
