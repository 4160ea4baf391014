"""`testbed bench swarm-loop`: the closed loop at scale, swarm-100 flown on the distributed filter.

The built-in `swarm-100` (100 UAVs on a 10 x 10 grid, GNSS on all, RTK on the corners, UWB among
neighbours within 60 m and to 5 anchors) with everything `coop-denied` flies on added: an IMU on
every vehicle (the BMI088 preset at 100 Hz, rotor vibration off as in coop-denied, whose filters
assume the preset's static noise), coop-denied's `[network]`, and the controller flying position
and velocity on `coop.ins_distributed` (a filter per vehicle, its broadcasts over that network),
with coop-denied's tilt limit and initialization phase. Measured as `testbed bench denied`
measures (testbed.bench.denied.bench_flown: the whole run, the estimator alone on the run's log,
the flown loop alone; CPU seconds of this process, one core), one run of DURATION_S.
"""
from __future__ import annotations

from testbed.bench.denied import bench_flown
from testbed.config import from_dict, to_dict
from testbed.config.scenario import Scenario, load
from testbed.reproduce.denied import COOP

DURATION_S = 10.0
IMU = {"preset": "bmi088", "rate_hz": 100.0, "vibration": {"enabled": False}}


def swarm_loop_scenario(duration: float = DURATION_S, vehicles: int = 100) -> Scenario:
    """swarm-100 (trajectory.count = vehicles) flown on coop.ins_distributed (module docstring)."""
    denied = load("coop-denied")
    table = to_dict(load("swarm-100", duration=duration))
    table["trajectory"]["count"] = vehicles
    table["sensors"]["imu"] = dict(IMU)
    table["network"] = to_dict(denied.network)
    table["estimators"] = [{"entry": "coop.ins_distributed", "name": COOP, "params": {"network": to_dict(denied.network)}}]
    c = denied.control
    table["control"].update(feedback=f"estimate:{COOP}", max_tilt_deg=c.max_tilt_deg, release_sigmas=c.release_sigmas)
    return from_dict(Scenario, table, "bench swarm-loop")


def bench_swarm_loop(duration: float = DURATION_S, vehicles: int = 100, repeat: int = 1) -> dict:
    """The figures of testbed.bench.denied.bench_flown for swarm_loop_scenario."""
    return bench_flown(swarm_loop_scenario(duration, vehicles), repeat)
