"""Sensor fidelity (issue 15 items 3 and 8): per-vehicle IMU biases drawn from the preset's prior,
per-device UWB two-way-ranging clock and antenna-delay errors.

Statistical tolerances are k standard errors of the stated sample size (k = K_SIGMA)."""
from __future__ import annotations

import math

import numpy as np
import pytest

from testbed.config import from_dict
from testbed.errors import FieldError
from testbed.config.scenario import Scenario
from testbed.sensors.presets import DPH, UG
from testbed.sim.simulate import simulate

K_SIGMA = 5.0


def scenario(sensors: dict, seed: int = 3, duration: float = 0.2, vehicles: int = 2, **extra) -> Scenario:
    """A short prescribed scenario: `vehicles` vehicles in a line 8 m apart, hovering still."""
    offsets = [[8.0 * i, 0.0, 0.0] for i in range(vehicles)]
    data = {
        "name": "fidelity-test", "description": "test", "seed": seed, "duration": duration, "motion": "prescribed",
        "world": extra.get("world", {}),
        "trajectory": {"kind": "straight-line", "start": [0.0, 0.0, 10.0], "velocity": [0.0, 0.0, 0.0], "offsets": offsets},
        "sensors": sensors,
    }
    return from_dict(Scenario, data, "test")


def _imu_bias(log: dict, vehicle: int) -> np.ndarray:
    """The true IMU bias of one vehicle (first sample): (6,) = accel (m/s^2), gyro (rad/s)."""
    return log["imu/bias"][log["imu/vehicle"] == vehicle][0]


# ----------------------------------------------------------------------------------- IMU
def test_paper004_biases_differ_per_vehicle_and_repeat_per_seed():
    """paper004: each vehicle draws its constant biases from N(0, (250 micro-g)^2) and
    N(0, (0.1 deg/h)^2) per axis; the two vehicles' biases differ, the same seed repeats them
    exactly, another seed changes them, and the bias is constant over the run."""
    sc = scenario({"imu": {"preset": "paper004"}})
    a, _ = simulate(sc)
    b, _ = simulate(scenario({"imu": {"preset": "paper004"}}))
    c, _ = simulate(scenario({"imu": {"preset": "paper004"}}, seed=4))
    b1, b2 = _imu_bias(a, 1), _imu_bias(a, 2)
    assert np.all(b1 != b2) and np.all(b1 != 0)
    np.testing.assert_array_equal(a["imu/bias"], b["imu/bias"])
    np.testing.assert_array_equal(a["imu/value"], b["imu/value"])
    assert np.all(_imu_bias(c, 1) != b1)
    for v in (1, 2):
        rows = a["imu/bias"][a["imu/vehicle"] == v]
        np.testing.assert_array_equal(rows, np.broadcast_to(rows[0], rows.shape))
    assert sc.sensors.imu.accel.bias == 0.0 and sc.sensors.imu.accel.bias_sigma == pytest.approx(250 * UG)
    assert sc.sensors.imu.gyro.bias == 0.0 and sc.sensors.imu.gyro.bias_sigma == pytest.approx(0.1 * DPH)


def test_paper004_bias_spread_matches_the_prior():
    """Over 40 vehicles x 3 axes the turn-on biases divided by the prior sigma have unit
    variance (chi-square, 120 dof: relative standard error sqrt(2/120) on the variance)."""
    sc = scenario({"imu": {"preset": "paper004"}}, vehicles=40, duration=0.02)
    log, _ = simulate(sc)
    z = np.array([_imu_bias(log, v) / np.array([250 * UG] * 3 + [0.1 * DPH] * 3) for v in range(1, 41)])
    for block in (z[:, :3], z[:, 3:]):
        var = np.mean(block ** 2)
        assert abs(var - 1) < K_SIGMA * math.sqrt(2 / block.size), var


def test_adding_a_vehicle_keeps_the_others_imu_draws():
    """Vehicle 1's IMU readings (every error term, white noise included) are the same whether
    it flies alone with an IMU or with a second one: each vehicle has its own child stream."""
    alone, _ = simulate(scenario({"imu": {"preset": "bmi088", "vehicles": [1]}}))
    both, _ = simulate(scenario({"imu": {"preset": "bmi088"}}))
    one = both["imu/vehicle"] == 1
    np.testing.assert_array_equal(alone["imu/value"], both["imu/value"][one])
    np.testing.assert_array_equal(alone["imu/bias"], both["imu/bias"][one])


HOVER = {"kind": "straight-line", "start": [0.0, 0.0, 10.0], "velocity": [0.0, 0.0, 0.0], "offsets": [[0, 0, 0], [8, 0, 0]]}
MANOEUVRE = {"kind": "waypoints", "points": [[0, 0, 10], [4, 2, 11], [0, 4, 9.5], [0, 0, 10]],
             "times": [0, 1.5, 3.0, 4.5], "offsets": [[0, 0, 0], [8, 0, 0]]}


def _vibrating(imu: dict, trajectory: dict = HOVER, motion: str = "flown", seed: int = 3, duration: float = 3.0) -> Scenario:
    """Two vehicles flying `trajectory` with an IMU table `imu`."""
    data = {"name": "vibration-test", "description": "test", "seed": seed, "duration": duration, "motion": motion,
            "trajectory": trajectory, "sensors": {"imu": imu}}
    return from_dict(Scenario, data, "test")


@pytest.mark.parametrize("preset", ["bmi088", "mpu9250"])
@pytest.mark.parametrize("rate", [200.0, 100.0])
@pytest.mark.parametrize("trajectory", [HOVER, MANOEUVRE], ids=["hover", "manoeuvre"])
def test_rotor_vibration_makes_the_in_flight_accel_noise_5_to_20_times_the_static(preset, rate, trajectory):
    """Flown, the accelerometer's noise (standard deviation of value - clean per sample, from
    0.5 s, RMS over 2 vehicles x 3 axes) is 5-20 times the static white-noise sigma N sqrt(rate),
    as on a recording of real quadrotors (docs/sensors.md: 7-17). Scale factor and misalignment are set to
    zero: they are not noise. The preset's amplitude gives 10.9 in a 200 Hz hover by its stated
    rule; the spread of that statistic from the rotors' random phases is 7.0-16.8 (quantiles
    1e-4, 1 - 1e-4, 2e5 draws of the phases), so a failure is a broken model, not bad luck. At
    100 Hz and in the manoeuvre, the aliasing and the thrust change it: still measured against 5-20."""
    exact = {"scale_sigma": 0.0, "misalign_sigma": 0.0}
    sc = _vibrating({"preset": preset, "rate_hz": rate, "accel": exact, "gyro": exact}, trajectory, duration=4.5)
    log, _ = simulate(sc)
    keep = log["imu/time"] >= 0.5
    err, vehicle = (log["imu/value"] - log["imu/clean"])[keep, :3], log["imu/vehicle"][keep]
    var = np.concatenate([err[vehicle == v].var(axis=0) for v in (1, 2)])
    ratio = math.sqrt(var.mean()) / (sc.sensors.imu.accel.noise_density * math.sqrt(rate))
    assert 5.0 <= ratio <= 20.0, ratio


def test_rotor_vibration_is_off_in_ideal_and_in_prescribed_motion():
    """`ideal` flown reads the clean values exactly; bmi088 in prescribed motion (no rotor speeds)
    reads exactly what it reads with the vibration disabled."""
    log, _ = simulate(_vibrating({"preset": "ideal"}, duration=1.0))
    np.testing.assert_array_equal(log["imu/value"], log["imu/clean"])
    on, _ = simulate(_vibrating({"preset": "bmi088"}, motion="prescribed", duration=1.0))
    off, _ = simulate(_vibrating({"preset": "bmi088", "vibration": {"enabled": False}}, motion="prescribed", duration=1.0))
    np.testing.assert_array_equal(on["imu/value"], off["imu/value"])


def test_rotor_vibration_repeats_with_the_seed_and_leaves_the_other_draws():
    """Same seed, same readings; another seed, other readings. The vibration draws from its own
    child streams: disabling it changes value - clean by exactly the vibration, never the biases."""
    a, _ = simulate(_vibrating({"preset": "bmi088"}, duration=1.0))
    b, _ = simulate(_vibrating({"preset": "bmi088"}, duration=1.0))
    c, _ = simulate(_vibrating({"preset": "bmi088"}, seed=4, duration=1.0))
    off, _ = simulate(_vibrating({"preset": "bmi088", "vibration": {"enabled": False}}, duration=1.0))
    np.testing.assert_array_equal(a["imu/value"], b["imu/value"])
    assert not np.allclose(a["imu/value"], c["imu/value"])
    np.testing.assert_array_equal(a["imu/bias"], off["imu/bias"])
    assert np.abs(a["imu/value"] - off["imu/value"])[:, :3].max() > 0.1


def test_rotor_vibration_sample_by_sample_equals_all_at_once():
    """Online (one sample per call) and offline (the whole series) give the same numbers."""
    from testbed.rng import stream_rng
    from testbed.sensors.noise import device_rng
    from testbed.sensors.vibration import RotorVibration
    from testbed.sim.world import build

    sc = _vibrating({"preset": "mpu9250"})
    physics = build(sc)
    thrust = 16.9 + np.random.default_rng(0).normal(0.0, 3.0, (50, 2, 4))

    def model():
        rngs = [device_rng(stream_rng(3, "imu"), f"uav{i}/vibration") for i in (1, 2)]
        return RotorVibration(sc.sensors.imu.vibration, physics, rngs, 0.005, 200.0)

    whole, one = model().sample(thrust), model()
    np.testing.assert_array_equal(whole, np.concatenate([one.sample(thrust[k:k + 1]) for k in range(50)]))
    assert np.abs(whole[:, :, :3]).max() > 0.1 and np.abs(whole[:, :, 3:]).max() > 0.0


def test_rotor_vibration_keys_are_checked():
    """One amplitude per harmonic in both directions; positive thrust coefficient."""
    with pytest.raises(FieldError, match="sensors.imu.vibration.accel_z"):
        _vibrating({"preset": "bmi088", "vibration": {"accel_z": [0.01]}})
    with pytest.raises(FieldError, match="thrust_coefficient"):
        _vibrating({"vibration": {"thrust_coefficient": 0.0}})


# ----------------------------------------------------------------------------------- UWB
def _exchange(mode: str, d: float, ea: float, eb: float, reply: float) -> float:
    """The range firmware computes from its timestamps, simulated on true time: a device's clock
    reads (1 + e) t. A polls at true time 0; B replies `reply` later on B's clock; for DS-TWR A
    sends a final message `reply` later on A's clock and B computes the asymmetric formula."""
    c = 299_792_458.0
    tof = d / c
    poll_rx_b = tof
    resp_tx_b = poll_rx_b + reply / (1 + eb)  # B waits `reply` on its own clock
    resp_rx_a = resp_tx_b + tof
    round_a = (1 + ea) * resp_rx_a  # A's clock, from its poll at 0
    reply_b = reply  # B's clock
    if mode == "ss-twr":
        return c * (round_a - reply_b) / 2
    final_tx_a = resp_rx_a + reply / (1 + ea)
    final_rx_b = final_tx_a + tof
    reply_a = (1 + ea) * (final_tx_a - resp_rx_a)
    round_b = (1 + eb) * (final_rx_b - resp_tx_b)
    return c * (round_a * round_b - reply_a * reply_b) / (round_a + round_b + reply_a + reply_b)


@pytest.mark.parametrize("mode", ["ss-twr", "ds-twr"])
def test_twr_range_equals_the_timestamp_exchange(mode):
    """noise.twr_range (closed form) = the range computed from simulated timestamps, for clock
    offsets up to +/-50 ppm, distances 1-150 m and reply times 0.3-5 ms; and its first-order
    form: SS-TWR d + e_A d + c T_reply (e_A - e_B)/2, DS-TWR d (1 + (e_A + e_B)/2)."""
    from testbed.sensors.noise import twr_range

    rng = np.random.default_rng(1)
    for _ in range(50):
        d, reply = rng.uniform(1, 150), rng.uniform(0.3e-3, 5e-3)
        pa, pb = rng.uniform(-50, 50, 2)
        ea, eb = 1e-6 * pa, 1e-6 * pb
        got = float(twr_range(mode, np.array([d]), np.array([pa]), np.array([pb]), reply)[0])
        # timestamps of ~5 ms in float64 carry ~1e-18 s of round-off: ~1e-9 m
        assert got == pytest.approx(_exchange(mode, d, ea, eb, reply), abs=1e-6)
        first = d + ea * d + 299_792_458.0 * reply * (ea - eb) / 2 if mode == "ss-twr" else d * (1 + (ea + eb) / 2)
        # second-order remainder: O(e) relative to the first-order error (|e| <= 5e-5), plus d e^2 < 4e-7 m
        assert got == pytest.approx(first, abs=1e-4 * abs(got - d) + 1e-6)


@pytest.mark.parametrize("mode", ["scale", "ss-twr", "ds-twr"])
def test_twr_range_variance_matches_monte_carlo(mode):
    """The first-order variance the estimators are told (estimators.sensor_models.twr_range_variance) against the
    sample variance of twr_range + antenna delays over n = 20000 draws of both devices' clocks
    and delays (chi-square: relative standard error sqrt(2/n))."""
    from estimators.sensor_models import twr_range_variance
    from testbed.sensors.noise import twr_range

    n, ppm, reply, sad = 20000, 20.0, 330e-6, 0.035
    rng = np.random.default_rng(2)
    d = np.full(n, 80.0)
    pa, pb = ppm * rng.standard_normal((2, n))
    err = twr_range(mode, d, pa, pb, reply) - d + sad * rng.standard_normal(n) + sad * rng.standard_normal(n)
    var = twr_range_variance(mode, d[:1], ppm, reply, sad)[0]
    assert abs(np.mean(err ** 2) / var - 1) < K_SIGMA * math.sqrt(2 / n)


def _uwb(mode: str, vehicles: int = 2, seed: int = 3, **keys) -> dict:
    sens = {"uwb": {"preset": "ideal", "mode": mode, "clock_ppm": 20.0, "antenna_delay_sigma": 0.035, **keys}}
    log, _ = simulate(scenario(sens, seed=seed, vehicles=vehicles, world={"anchors": [[5.0, 30.0, 10.0]]}))
    return log


@pytest.mark.parametrize("mode", ["ss-twr", "ds-twr"])
def test_uwb_twr_clock_and_antenna_delay_in_the_stream(mode):
    """In the simulated stream every range is twr(d, k_src, k_dst) + b_src + b_dst with the
    logged per-device clock offsets and antenna delays (constant over the run); both differ
    between devices, repeat for the same seed, and a third vehicle leaves the first two's
    clocks and delays unchanged (per-device child streams)."""
    from testbed.sensors.noise import twr_range

    log = _uwb(mode, reply_time=330e-6)
    dev = {str(n): i for i, n in enumerate(log["uwb/devices"])}
    ppm, delay = log["uwb/clock_ppm"], log["uwb/antenna_delay"]
    s = np.array([dev[str(x)] for x in log["uwb/src"]])
    t = np.array([dev[str(x)] for x in log["uwb/dst"]])
    d = log["uwb/clean"][:, 0]
    expected = twr_range(mode, d, ppm[s], ppm[t], 330e-6) + delay[s] + delay[t]
    np.testing.assert_allclose(log["uwb/value"][:, 0], expected, rtol=0, atol=1e-12)
    assert len(set(ppm)) == len(ppm) and len(set(delay)) == len(delay) and np.all(delay != 0)
    if mode == "ss-twr":  # T_reply c (e_A - e_B) / 2: ~1 m at 20 ppm and 0.33 ms
        assert np.abs(log["uwb/value"][:, 0] - d).max() > 0.1
    again = _uwb(mode, reply_time=330e-6)
    np.testing.assert_array_equal(again["uwb/value"], log["uwb/value"])
    three = _uwb(mode, vehicles=3, reply_time=330e-6)
    dev3 = {str(n): i for i, n in enumerate(three["uwb/devices"])}
    for name, i in dev.items():
        assert three["uwb/clock_ppm"][dev3[name]] == ppm[i] and three["uwb/antenna_delay"][dev3[name]] == delay[i]
    other = _uwb(mode, seed=4, reply_time=330e-6)
    assert np.all(other["uwb/antenna_delay"] != delay)


def test_uwb_twr_keys_are_checked():
    from testbed.config import ConfigError

    with pytest.raises(ConfigError, match="sensors.uwb.mode"):
        scenario({"uwb": {"mode": "tdoa"}})
    with pytest.raises(ConfigError, match="reply_time"):
        scenario({"uwb": {"reply_time": -1e-3}})
    with pytest.raises(ConfigError, match="antenna_delay_sigma"):
        scenario({"uwb": {"antenna_delay_sigma": -0.01}})
